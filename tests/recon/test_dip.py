import copy
import io

import numpy as np
import onnxruntime as ort
import pytest
import torch

from torchtof.operators import Hadamard, PatternOperator
from torchtof.recon.dip import (
    DIP,
    ZETA_KAPPA,
    ZETA_MAX,
    ZETA_MIN,
    _affine_coeffs,
    _WindowedVariance,
    auto_zeta,
    default_unet,
    dip,
    dip_input,
    fit_dip,
)
from torchtof.recon.tv import tv_norm
from torchtof.recon.unet import UNet

N = 16
FAST = {"max_iter": 20}


def _scene(b=1, c=1, dtype=torch.float32):
    x = torch.zeros(b, c, N, N, dtype=dtype)
    x[..., 3:13, 7:9] = 1
    x[..., 5:7, 3:13] = 1
    for i in range(b):
        x[i] = torch.roll(x[i], shifts=i, dims=-1)
    return x


@pytest.fixture
def A():
    return Hadamard(N, sr=0.25)


def test_fit_dip_smoke(A):
    res = fit_dip(A(_scene()), A, **FAST)
    assert res.x.shape == res.x_cal.shape == (1, 1, N, N)
    assert res.x0.shape == (1, 1, N, N)
    assert float(res.x.min()) == 0.0 and float(res.x.max()) == 1.0
    assert res.n_iter == 20 and res.best_iter == 19
    assert res.loss_history.shape == (20,)
    assert isinstance(res.unet, UNet) and not res.unet.training


def test_fit_dip_dtype(A, dtype):
    y = A(_scene(dtype=dtype))
    res = fit_dip(y, A, max_iter=5)
    assert res.x.dtype == res.x_cal.dtype == dtype
    assert next(res.unet.parameters()).dtype == dtype


def test_deterministic_bitwise(A):
    y = A(_scene())
    r1 = fit_dip(y, A, **FAST, seed=3)
    r2 = fit_dip(y, A, **FAST, seed=3)
    r3 = fit_dip(y, A, **FAST, seed=4)
    assert torch.equal(r1.x, r2.x) and torch.equal(r1.loss_history, r2.loss_history)
    assert not torch.equal(r1.x, r3.x)


def test_fit_under_no_grad_and_inference_mode(A):
    y = A(_scene())
    want = fit_dip(y, A, max_iter=5).x
    with torch.no_grad():
        assert torch.equal(fit_dip(y, A, max_iter=5).x, want)
    with torch.inference_mode():
        y_inf = A(_scene())
        assert torch.equal(DIP(A, max_iter=5, output="unit")(y_inf), want)


def test_progress_bar(A, capsys):
    res = fit_dip(A(_scene()), A, max_iter=3, progress=True)
    assert res.n_iter == 3 and "fit_dip" in capsys.readouterr().err


def test_global_rng_untouched(A):
    torch.manual_seed(123)
    want = torch.rand(3)
    torch.manual_seed(123)
    fit_dip(A(_scene()), A, max_iter=2)
    assert torch.equal(torch.rand(3), want)


def test_loss_decreases_and_fits(A):
    x = _scene()
    res = fit_dip(A(x), A, max_iter=60)
    assert res.loss_history[-1] < 0.2 * res.loss_history[0]
    # the fitted image is closer to the scene than the pseudo-inverse image
    pinv = A.pinv(A(x))
    pinv = (pinv - pinv.min()) / (pinv.max() - pinv.min())
    assert ((res.x - x) ** 2).mean() < ((pinv - x) ** 2).mean()


def test_eval_unet_reproduces_image(A):
    res = fit_dip(A(_scene()), A, **FAST)
    with torch.no_grad():
        out = res.unet(res.x0)
        train_out = copy.deepcopy(res.unet).train()(res.x0)
    lo, hi = out.min(), out.max()
    torch.testing.assert_close((out - lo) / (hi - lo), res.x, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(out, train_out, rtol=1e-5, atol=1e-6)


def test_exported_unet_reproduces_image(A):
    res = fit_dip(A(_scene()), A, **FAST)
    buf = io.BytesIO()
    torch.onnx.export(
        res.unet,
        (res.x0.repeat(2, 1, 1, 1),),
        buf,
        dynamo=False,
        input_names=["x0"],
        output_names=["image"],
        dynamic_axes={"x0": {0: "batch"}, "image": {0: "batch"}},
        opset_version=17,
    )
    sess = ort.InferenceSession(buf.getvalue(), providers=["CPUExecutionProvider"])
    x0 = torch.cat([res.x0, torch.randn(2, 1, N, N, generator=torch.Generator().manual_seed(0))])
    (got,) = sess.run(None, {"x0": x0.numpy()})
    with torch.no_grad():
        want = res.unet(x0).numpy()
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-5)
    got0 = torch.from_numpy(got[:1])
    torch.testing.assert_close(
        (got0 - got0.min()) / (got0.max() - got0.min()), res.x, rtol=1e-4, atol=1e-4
    )


def test_scale_invariance_and_calibration(A):
    """Known answer: the loss and the input are invariant to the scale of ``y``; a power-of-two
    scale is exact in floating point, so ``x`` is bitwise equal and ``x_cal`` scales."""
    y = A(_scene())
    r1 = fit_dip(y, A, **FAST)
    r2 = fit_dip(4 * y, A, **FAST)
    assert torch.equal(r1.x, r2.x)
    torch.testing.assert_close(r2.x_cal, 4 * r1.x_cal, rtol=1e-4, atol=1e-5)


def test_calibrated_image_units(A):
    """``x_cal`` lives in the units of the scene: its measurements match ``y`` in least squares,
    and a negative image (3 − 2·x) is recovered with its sign."""
    x = _scene()
    for scene in (x, 3 - 2 * x):
        y = A(scene)
        res = fit_dip(y, A, max_iter=40)
        assert torch.linalg.vector_norm(A(res.x_cal) - y) < 0.25 * torch.linalg.vector_norm(y)
        assert torch.corrcoef(torch.stack([res.x_cal.flatten(), scene.flatten()]))[0, 1] > 0.9


def test_affine_coeffs_known_answer():
    g = torch.Generator().manual_seed(0)
    ax, a1 = torch.randn(10, generator=g, dtype=torch.float64), torch.zeros(10, dtype=torch.float64)
    a1[0] = 4.0
    ab = _affine_coeffs(ax, a1, 3 * ax + 2 * a1)
    torch.testing.assert_close(ab, torch.tensor([3.0, 2.0], dtype=torch.float64))
    # A·1 = 0 (no DC pattern): minimum-norm answer, b = 0
    ab = _affine_coeffs(ax, torch.zeros_like(ax), -2 * ax)
    torch.testing.assert_close(ab, torch.tensor([-2.0, 0.0], dtype=torch.float64))


def test_windowed_variance_rule():
    """ES-WMV on a constructed sequence: the window variance falls, then rises; the rule
    flags the minimum and stops ``patience`` checks later."""
    steps = [1.0, 0.5, 0.25, 0.2, 0.19, 0.5, 1.0, 2.0, 4.0, 8.0]
    xs, v = [], 0.0
    for s in steps:
        v += s
        xs.append(torch.full((1, 1, 2, 2), v))
    rule = _WindowedVariance(window=2, patience=3)
    flags = [rule.update(x) for x in xs]
    improved = [i for i, (imp, _) in enumerate(flags) if imp]
    stops = [i for i, (_, stop) in enumerate(flags) if stop]
    assert improved == [1, 2, 3, 4] and stops[0] == 7


def test_wmv_early_stop_triggers(A):
    # the learning rate collapses after the first step, so the outputs freeze: the window
    # variance reaches 0 at t = 3 and never improves again
    res = fit_dip(
        A(_scene()), A,
        max_iter=100,
        early_stop="wmv",
        window=3,
        patience=4,
        lr_step=1,
        lr_gamma=1e-30,
    )
    assert res.n_iter == 8 and res.best_iter == 3


def test_wmv_returns_best_network(A):
    res = fit_dip(A(_scene()), A, max_iter=40, early_stop="wmv", window=5, patience=100)
    with torch.no_grad():
        out = res.unet(res.x0)
    torch.testing.assert_close(
        (out - out.min()) / (out.max() - out.min()), res.x, rtol=1e-5, atol=1e-5
    )
    assert 4 <= res.best_iter < 40


def test_discrepancy_stop(A):
    y = A(_scene())
    loose = fit_dip(y, A, max_iter=50, early_stop="discrepancy", noise_sigma=10.0)
    assert loose.n_iter == 1 and loose.best_iter == 0
    tight = fit_dip(y, A, max_iter=50, early_stop="discrepancy", noise_sigma=0.05)
    res = A(tight.x_cal) - y
    assert tight.n_iter < 50 and float((res**2).sum()) <= A.m * 0.05**2 * 1.001


def test_explicit_x0_and_unet_not_modified(A):
    y = A(_scene())
    x0 = torch.randn(1, 2, N, N, generator=torch.Generator().manual_seed(1))
    torch.manual_seed(0)
    net = UNet(in_ch=2, base=4, depth=2)
    state = copy.deepcopy(net.state_dict())
    y_copy, x0_copy = y.clone(), x0.clone()
    res = fit_dip(y, A, x0=x0, unet=net, max_iter=5)
    assert res.unet is not net and res.unet.in_ch == 2
    assert all(torch.equal(v, state[k]) for k, v in net.state_dict().items())
    assert torch.equal(y, y_copy) and torch.equal(x0, x0_copy) and torch.equal(res.x0, x0)


def test_dip_input(A):
    x0 = dip_input(A(_scene(b=2)), A)
    assert x0.shape == (2, 1, N, N)
    torch.testing.assert_close(x0.mean(dim=(-2, -1)), torch.zeros(2, 1), atol=1e-5, rtol=0)
    torch.testing.assert_close(x0.std(dim=(-2, -1), unbiased=False), torch.ones(2, 1))


def test_auto_zeta_known_answers(A):
    y = A(_scene())
    assert auto_zeta(y) == ZETA_MIN  # noise-free piecewise-constant scene: empty tail
    sy = float(y.std(unbiased=False))
    assert auto_zeta(y, noise_sigma=0.1 * sy) == pytest.approx(ZETA_KAPPA * 0.1)
    assert auto_zeta(y, noise_sigma=100 * sy) == ZETA_MAX
    assert auto_zeta(4 * y, noise_sigma=0.4 * sy) == auto_zeta(y, noise_sigma=0.1 * sy)


def test_tv_weight_is_effective(A):
    """The TV term is scale invariant, so a larger weight gives a flatter image (relative to its
    contrast) instead of a dimmer one."""
    y = A(_scene())
    rel_tv = []
    for zeta in (0.0, 3.0):
        res = fit_dip(y, A, max_iter=40, zeta=zeta, early_stop=None)
        with torch.no_grad():
            out = res.unet(res.x0)
        rel_tv.append(float(tv_norm(out).sum() / out.std(unbiased=False)))
    assert rel_tv[1] < 0.65 * rel_tv[0]  # about 0.5; a plain TV(x̂) term gives about 0.8


def test_default_unet_depth():
    assert default_unet(32).depth == 3 and default_unet(64).depth == 4
    assert default_unet(8).depth == 2 and default_unet(16).depth == 3


def test_general_operator():
    g = torch.Generator().manual_seed(0)
    P = PatternOperator((torch.rand(64, N, N, generator=g) > 0.5).float())
    res = fit_dip(P(_scene()), P, max_iter=5)
    assert res.x.shape == (1, 1, N, N)


@pytest.mark.parametrize(("b", "c"), [(1, 1), (3, 1), (1, 2)])
def test_dip_shapes_module_and_stacked(A, b, c):
    y = A(_scene(b, c))
    y_copy = y.clone()
    out = dip(y, A, max_iter=5)
    assert out.shape == (b, c, N, N)
    torch.testing.assert_close(DIP(A, max_iter=5)(y), out, rtol=0, atol=0)
    singles = torch.cat([dip(y[i : i + 1], A, max_iter=5) for i in range(b)])
    torch.testing.assert_close(out, singles, rtol=0, atol=0)
    assert torch.equal(y, y_copy)


def test_dip_outputs(A):
    y = A(_scene())
    res = fit_dip(y, A, max_iter=5)
    torch.testing.assert_close(dip(y, A, max_iter=5, output="unit"), res.x, rtol=0, atol=0)
    torch.testing.assert_close(dip(y, A, max_iter=5), res.x_cal, rtol=0, atol=0)
    x0 = dip_input(y, A)
    torch.testing.assert_close(dip(y, A, x0=x0, max_iter=5), res.x_cal, rtol=0, atol=0)


def test_dip_dtype(A, dtype):
    y = A(_scene(dtype=dtype))
    assert DIP(A, max_iter=3)(y).dtype == dtype


@pytest.mark.parametrize(
    ("kw", "exc", "match"),
    [
        ({"max_iter": 0}, ValueError, "fit_dip: expected max_iter >= 1, got 0"),
        ({"max_iter": 2.0}, TypeError, "fit_dip: expected max_iter to be an int"),
        ({"lr": -1.0}, ValueError, "fit_dip: expected lr > 0"),
        ({"zeta": -1.0}, ValueError, "fit_dip: expected zeta >= 0"),
        ({"zeta": "high"}, ValueError, "fit_dip: expected zeta >= 0 or 'auto', got 'high'"),
        ({"noise_sigma": 0.0}, ValueError, "fit_dip: expected noise_sigma > 0"),
        ({"window": 1}, ValueError, "fit_dip: expected window >= 2"),
        ({"lr_gamma": 2.0}, ValueError, r"fit_dip: expected lr_gamma in \(0, 1\]"),
        ({"betas": (0.5, 1.0)}, ValueError, "fit_dip: expected betas"),
        ({"early_stop": "foo"}, ValueError, "fit_dip: expected early_stop in"),
        ({"early_stop": "discrepancy"}, ValueError, "needs noise_sigma"),
        ({"unet": torch.nn.Conv2d(1, 1, 3)}, TypeError, "fit_dip: expected unet to be a UNet"),
        ({"x0": torch.zeros(1, 1, 8, 8)}, ValueError, r"fit_dip: expected x0 of shape"),
    ],
)
def test_fit_dip_bad_options(A, kw, exc, match):
    with pytest.raises(exc, match=match):
        fit_dip(A(_scene()), A, **kw)


def test_fit_dip_bad_data(A):
    y = A(_scene())
    with pytest.raises(ValueError, match=r"fit_dip: expected y of shape \(\*, \*, 64\), got"):
        fit_dip(y[..., :-1], A)
    bad = y.clone()
    bad[..., 3] = float("nan")
    with pytest.raises(ValueError, match="fit_dip: y contains non-finite values"):
        fit_dip(bad, A)
    with pytest.raises(ValueError, match=r"fit_dip: expected y of shape \(1, 1, 64\) \(one image"):
        fit_dip(y.repeat(2, 1, 1), A)
    with pytest.raises(ValueError, match="fit_dip: y is constant"):
        fit_dip(torch.ones_like(y), A)
    with pytest.raises(TypeError, match="fit_dip: expected A to be a LinearOperator"):
        fit_dip(y, torch.nn.Identity())
    with pytest.raises(TypeError, match="fit_dip: expected y of dtype float32 or float64"):
        fit_dip(y.half(), A)
    with pytest.raises(
        ValueError, match=r"dip: expected y of rank 3 \(B, C, M\), got shape \(1, 64"
    ):
        DIP(A)(y[0])


def test_fit_dip_bad_depth(A):
    y = A(_scene())
    with pytest.raises(
        ValueError,
        match="fit_dip: expected n divisible by 2\\^depth = 16 with a bottleneck of at least 2x2",
    ):
        fit_dip(y, A, unet=UNet(depth=4), max_iter=2)
    P = PatternOperator(torch.rand(30, 12, 12, generator=torch.Generator().manual_seed(0)))
    with pytest.raises(ValueError, match="fit_dip: expected n divisible by 2\\^depth = 8"):
        fit_dip(P(torch.rand(1, 1, 12, 12)), P, unet=UNet(depth=3), max_iter=2)


def test_bad_module_config(A):
    with pytest.raises(ValueError, match="DIP: expected output in"):
        DIP(A, output="raw")
    with pytest.raises(TypeError, match="DIP: expected A to be a LinearOperator"):
        DIP(torch.nn.Identity())


# -- contract: (y, A), threads, detached target, empty batch, solve, renamed options -----------


def test_fit_dip_seeded_fits_in_threads_match_serial(A):
    # the seed drives the fit's own generator: fits run in 2 threads at once equal the serial
    # fits bit for bit, and the global RNG is neither read nor advanced
    import threading

    y = A(_scene())
    serial = {s: fit_dip(y, A, max_iter=2, seed=s).x for s in (1, 2)}
    state = torch.random.get_rng_state()
    out = {}

    def run(s):
        for _ in range(2):
            out.setdefault(s, []).append(fit_dip(y, A, max_iter=2, seed=s).x)
            torch.rand(100)  # another thread drawing from the global RNG must not matter

    threads = [threading.Thread(target=run, args=(s,)) for s in (1, 2)]
    torch.manual_seed(0)
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for s in (1, 2):
        assert all(torch.equal(x, serial[s]) for x in out[s]), s
    assert not torch.equal(serial[1], serial[2])
    torch.random.set_rng_state(state)
    fit_dip(y, A, max_iter=2, seed=1)
    assert torch.equal(torch.random.get_rng_state(), state)


def test_default_unet_generator_draws_match_manual_seed():
    # the own-generator initialisation keeps the weights of the seeded global RNG (and so every
    # published DIP number)
    for n in (16, 64):
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(5)
            ref = default_unet(n)
        new = default_unet(n, generator=torch.Generator().manual_seed(5))
        for (k, a), b in zip(ref.state_dict().items(), new.state_dict().values(), strict=True):
            assert torch.equal(a, b), k


def test_dip_detaches_a_target_that_requires_grad(A):
    y = A(_scene()).requires_grad_(True)
    want = fit_dip(y.detach(), A, max_iter=5).x
    assert torch.equal(fit_dip(y, A, max_iter=5).x, want)
    x = DIP(A, max_iter=5, output="unit")(y)
    assert torch.equal(x, want) and not x.requires_grad and y.grad is None


def test_dip_empty_batch(A):
    y = A(_scene())[:0]
    assert dip(y, A, max_iter=3).shape == (0, 1, N, N)
    res = DIP(A, max_iter=3).solve(y)
    assert res.x.shape == (0, 1, N, N) and res.n_iter.shape == (0, 1) and res.stop_reason == ()


def test_dip_solve_reports_each_sample(A):
    y = A(_scene(b=2))
    res = DIP(A, max_iter=30, window=3, patience=2).solve(y)
    singles = [fit_dip(y[i : i + 1], A, max_iter=30, window=3, patience=2) for i in range(2)]
    assert res.n_iter.tolist() == [[s.n_iter] for s in singles]
    assert res.stop_reason == tuple((s.stop_reason,) for s in singles)
    assert res.converged.tolist() == [[s.stop_reason != "max_iter"] for s in singles]
    want = (A(res.x) - y).norm(dim=-1) / y.norm(dim=-1)
    torch.testing.assert_close(res.residual, want)


def test_fit_dip_stop_reasons(A):
    y = A(_scene())
    assert fit_dip(y, A, max_iter=3, early_stop=None).stop_reason == "max_iter"
    assert fit_dip(y, A, max_iter=50, early_stop="discrepancy",
                   noise_sigma=10.0).stop_reason == "discrepancy"


def test_old_argument_order_and_names_warn(A):
    y = A(_scene())
    want = fit_dip(y, A, max_iter=4)
    with pytest.warns(DeprecationWarning, match=r"fit_dip\(y, A"):
        old = fit_dip(A, y, max_iter=4)
    assert torch.equal(old.x, want.x)
    with pytest.warns(DeprecationWarning, match="n_iter= is renamed max_iter="):
        assert torch.equal(fit_dip(y, A, n_iter=4).x, want.x)
    with pytest.warns(DeprecationWarning, match="dip_input"):
        assert torch.equal(dip_input(A, y), dip_input(y, A))
    with pytest.warns(DeprecationWarning, match="n_iter= is renamed max_iter="):
        assert DIP(A, n_iter=4).fit_kwargs == {"max_iter": 4}
    with pytest.raises(TypeError, match="got both max_iter= and its old name n_iter="):
        fit_dip(y, A, max_iter=5, n_iter=4)


def test_noise_sigma_auto_is_the_tail_estimate(A):
    from torchtof.recon.noise import tail_noise_sigma

    g = torch.Generator().manual_seed(0)
    y = A(_scene()) + 0.05 * torch.randn(1, 1, A.m, generator=g)
    sigma = float(tail_noise_sigma(y)[0, 0])
    kw = dict(max_iter=30, early_stop="discrepancy")
    assert torch.equal(fit_dip(y, A, noise_sigma="auto", **kw).x,
                       fit_dip(y, A, noise_sigma=sigma, **kw).x)
    with pytest.raises(ValueError, match="fit_dip: expected noise_sigma > 0, None or 'auto'"):
        fit_dip(y, A, noise_sigma="pairs")


def test_dip_x0_with_nan_names_dip():
    from torchtof.operators import Hadamard
    from torchtof.recon import dip
    A = Hadamard(8, sr=0.5)
    y = A(torch.rand(1, 1, 8, 8))
    with pytest.raises(ValueError, match=r"^dip: x0 contains non-finite"):
        dip(y, A, x0=torch.full((1, 1, 8, 8), float("nan")), max_iter=2)


def test_dip_calibrated_image_at_the_ends_of_float32():
    # the calibration's sums overflowed at 1e38 (NaN image, no error); the fit runs on an
    # exact power-of-two rescale, so c·y gives c times the image
    from torchtof.operators import Hadamard
    from torchtof.recon import dip
    A = Hadamard(16, sr=0.25)
    x = torch.zeros(1, 1, 16, 16)
    x[..., 3:10, 4:12] = 1.0
    y = A(x)
    y = y / y.abs().max()
    ref = dip(y, A, max_iter=15)
    for c in (2.0**126, 2.0**-120):
        torch.testing.assert_close(dip(c * y, A, max_iter=15) / c, ref, rtol=0, atol=0)
    got = dip(torch.full((1, 1, 64), 1e38), A, max_iter=5)  # constant buckets: b = y/(A1)
    torch.testing.assert_close(got, torch.full_like(got, 6.25e36), rtol=1e-6, atol=0)
