"""Unrolled TVAL3: shapes, errors, a dense reference, gradients, ONNX, shipped weights.

The slow test checks the acceptance claim: with its shipped weights the unrolled TVAL3 is
within 0.5 dB of converged TVAL3 (or better) at every shipped (n, SR) on held-out scenes.
"""

import re
import warnings

import numpy as np
import pytest
import torch

from torchtof.operators import Hadamard, LinearOperator, PatternOperator
from torchtof.recon.train import noisy_measurements, train_unrolled
from torchtof.recon.unrolled import (
    DEFAULT_N_ITER,
    PARAM_NAMES,
    WEIGHTS_DIR,
    UnrolledTVAL3,
    available_weights,
    unrolled_tval3,
)

SHIPPED = available_weights()
NAME_RE = re.compile(r"unrolled_n(\d+)_sr(\d{4})_K(\d+)\.pt")


def _net(n=8, sr=0.25, K=3, seed=0):
    """An untrained network with its scalars moved off the initialisation."""
    net = UnrolledTVAL3(Hadamard(n, sr=sr), n_layers=K, pretrained=False)
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for name in PARAM_NAMES:
            p = getattr(net, name)
            p.add_(0.5 * torch.randn(p.shape, generator=g))
    return net


def _y(net, b=2, c=1, dtype=torch.float32, seed=0):
    g = torch.Generator().manual_seed(seed)
    n = net.A.n
    return net.A(torch.rand(b, c, n, n, generator=g, dtype=torch.float64)).to(dtype)


# -- shapes, dtypes, module == function, batching ---------------------------------------------


@pytest.mark.parametrize("b", [1, 3])
def test_shapes_dtype_and_module_equals_function(b, dtype):
    net = _net()
    y = _y(net, b=b, c=2, dtype=dtype)
    out = net(y)
    assert out.shape == (b, 2, 8, 8) and out.dtype == dtype
    torch.testing.assert_close(out, unrolled_tval3(y, net.A, *net.scalars()))
    assert torch.isfinite(out).all()


def test_function_without_scalars_uses_the_shipped_ones():
    # unrolled_tval3(y, A) -> x is UnrolledTVAL3(A)(y): the shipped scalars for (n, SR)
    A = Hadamard(32, sr=0.25)
    y = A(torch.rand(2, 1, 32, 32, generator=torch.Generator().manual_seed(3)))
    net = UnrolledTVAL3(A)
    assert net.weights_file is not None
    torch.testing.assert_close(unrolled_tval3(y, A), net(y), rtol=0, atol=0)
    k = torch.ones(3)
    with pytest.raises(ValueError, match="got None for step, thresh, precond"):
        unrolled_tval3(y, A, 256 * k, 32 * k)


def test_batched_equals_stacked_and_input_untouched():
    net = _net()
    y = _y(net, b=3, dtype=torch.float64)
    y0 = y.clone()
    out = net(y)
    torch.testing.assert_close(out, torch.cat([net(y[i : i + 1]) for i in range(3)]))
    assert torch.equal(y, y0)


def test_scale_equivariance_and_zero_input():
    net = _net()
    y = _y(net, dtype=torch.float64)
    for c in (-3.7, 1e4):
        torch.testing.assert_close(net(c * y), c * net(y))
    z = net(torch.zeros(2, 1, net.A.m))
    assert torch.equal(z, torch.zeros_like(z))
    y32 = y.float()
    for c in (1e30, 1e-30):  # the norm of y must neither overflow nor underflow in float32
        torch.testing.assert_close(net(c * y32) / c, net(y32), rtol=1e-4, atol=1e-5)


def test_constant_scene_is_exact():
    """A constant image lies in the row space (DC pattern) and has no edges: it is a fixed point."""
    net = _net(seed=3)
    x = torch.full((1, 1, 8, 8), 2.5, dtype=torch.float64)
    torch.testing.assert_close(net(net.A(x)), x)


# -- known answer: a dense reference of the iteration -----------------------------------------


def _dense_reference(y, A, mu, beta, step, thresh, precond):
    """The module docstring's iteration with dense matrices and an explicit inverse of M_k."""
    n = A.n
    N = n * n
    a = A.matrix(torch.float64)
    idx = torch.arange(N).reshape(n, n)
    eye = torch.eye(N, dtype=torch.float64)
    dx = eye[idx.roll(-1, dims=1).flatten()] - eye  # (Dx u)[i, j] = u[i, j+1] − u[i, j]
    dy = eye[idx.roll(-1, dims=0).flatten()] - eye
    d_op = torch.cat([dx, dy])  # (2N, N)
    s = y.norm() / 1.5
    b = y / s
    u = a.T @ b
    sig = torch.zeros(2 * N, dtype=torch.float64)
    dl = torch.zeros_like(b)
    for k in range(len(mu)):
        rho = mu[k] / beta[k]
        v = d_op @ u - sig / beta[k]
        mag = torch.sqrt(v[:N] ** 2 + v[N:] ** 2).repeat(2)
        w = torch.clamp(mag - thresh[k], min=0) / mag * v
        d = d_op.T @ (v - w) + a.T @ (rho * (a @ u - b) - dl / beta[k])
        p = torch.linalg.solve(precond[k] * eye + rho * a.T @ a, d)
        tau = step[k] * (d @ p) / (p @ (d_op.T @ d_op + rho * a.T @ a) @ p)
        u = u - tau * p
        sig = sig - beta[k] * (d_op @ u - w)
        dl = dl - mu[k] * (a @ u - b)
    return (u * s).reshape(n, n)


def test_matches_dense_reference():
    net = _net(n=8, sr=0.25, K=3, seed=1).double()
    y = _y(net, b=1, dtype=torch.float64)
    scal = [v.detach() for v in net.scalars()]
    ref = _dense_reference(y[0, 0], net.A, *scal)
    torch.testing.assert_close(net(y)[0, 0], ref, rtol=1e-9, atol=1e-10)


def test_generic_orthonormal_operator_matches_hadamard_fast_path():
    class Dense(LinearOperator):
        orthonormal_rows = True

        def __init__(self, a, n):
            super().__init__(n, a.shape[0])
            self.register_buffer("a", a)

        def forward(self, x):
            return x.flatten(-2) @ self.a.T.to(x)

        def adjoint(self, y):
            return (y @ self.a.to(y)).unflatten(-1, (self.n, self.n))

    net = _net(seed=2).double()
    y = _y(net, b=2, dtype=torch.float64)
    dense = Dense(net.A.matrix(torch.float64), 8)
    torch.testing.assert_close(unrolled_tval3(y, dense, *net.scalars()), net(y))


# -- errors ------------------------------------------------------------------------------------


def test_bad_inputs():
    A = Hadamard(8, sr=0.25)
    with pytest.raises(ValueError, match="UnrolledTVAL3: expected n_layers >= 1, got 0"):
        UnrolledTVAL3(A, n_layers=0, pretrained=False)
    with pytest.raises(TypeError, match="UnrolledTVAL3: expected n_layers to be an int"):
        UnrolledTVAL3(A, n_layers=2.0, pretrained=False)
    with pytest.raises(TypeError, match="UnrolledTVAL3: expected A to be a LinearOperator"):
        UnrolledTVAL3(torch.eye(4), pretrained=False)
    rnd = PatternOperator(torch.rand(16, 8, 8, generator=torch.Generator().manual_seed(0)))
    with pytest.raises(ValueError, match="UnrolledTVAL3: expected an operator with orthonormal"):
        UnrolledTVAL3(rnd, pretrained=False)
    net = UnrolledTVAL3(A, n_layers=2, pretrained=False)
    with pytest.raises(ValueError, match=r"unrolled_tval3: expected y of shape \(\*, \*, 16\)"):
        net(torch.zeros(1, 1, 15))
    with pytest.raises(ValueError, match="unrolled_tval3: expected y of rank 3"):
        net(torch.zeros(1, 16))
    with pytest.raises(TypeError, match="unrolled_tval3: expected y to be a floating-point"):
        net(torch.zeros(1, 1, 16, dtype=torch.int64))
    y = torch.zeros(1, 1, 16)
    y[0, 0, 3] = float("nan")
    with pytest.raises(ValueError, match="unrolled_tval3: y contains non-finite values"):
        net(y)
    k = torch.ones(2)
    with pytest.raises(ValueError, match="unrolled_tval3: expected thresh of shape \\(K,\\)"):
        unrolled_tval3(torch.zeros(1, 1, 16), A, k, k, k, torch.ones(3), k)


# -- learned scalars: positivity and gradients --------------------------------------------------


def test_scalars_positive_by_parametrisation():
    net = UnrolledTVAL3(Hadamard(8, sr=0.25), n_layers=4, pretrained=False)
    init = dict(zip(PARAM_NAMES, net.scalars(), strict=True))
    torch.testing.assert_close(init["log_mu"], torch.full((4,), 256.0))  # TVAL3's defaults
    torch.testing.assert_close(init["log_beta"], torch.full((4,), 32.0))
    torch.testing.assert_close(init["log_thresh"], torch.full((4,), 1 / 32))
    with torch.no_grad():
        for name in PARAM_NAMES:
            getattr(net, name).copy_(torch.tensor([-30.0, -1.0, 1.0, 30.0]))
    for v in net.scalars():
        assert v.shape == (4,) and (v > 0).all() and torch.isfinite(v).all()


def test_gradients_reach_every_parameter():
    net = _net(n=8, K=3)
    x = torch.rand(2, 1, 8, 8, generator=torch.Generator().manual_seed(5))
    loss = ((net(net.A(x)) - x) ** 2).mean()
    loss.backward()
    for name in PARAM_NAMES:
        g = getattr(net, name).grad
        assert g is not None and torch.isfinite(g).all() and (g != 0).all(), name


def test_gradcheck_float64():
    A = Hadamard(4, sr=0.5)
    g = torch.Generator().manual_seed(0)
    y = A(torch.rand(2, 1, 4, 4, generator=g, dtype=torch.float64)).requires_grad_()
    raw = [
        (np.log(v) + 0.3 * torch.randn(2, generator=g, dtype=torch.float64)).requires_grad_()
        for v in (256.0, 32.0, 1.0, 1 / 32, 4.0)
    ]

    def f(y, *raw):
        return unrolled_tval3(y, A, *(r.exp() for r in raw))

    assert torch.autograd.gradcheck(f, (y, *raw), eps=1e-6, atol=1e-5, rtol=1e-4)


# -- training -----------------------------------------------------------------------------------


def test_a_few_training_steps_reduce_the_loss():
    res = train_unrolled(n=16, sr=0.25, n_layers=3, steps=40, batch_size=8,
                         noise_level=(0.01, 0.01))
    A = res.model.A
    from torchtof.recon.synthetic import synthetic_scenes

    x = synthetic_scenes(16, seed=99, step=0, indices=range(16))
    y = noisy_measurements(A, x, 99, 0, range(16), (0.01, 0.01))
    untrained = UnrolledTVAL3(A, n_layers=3, pretrained=False)
    with torch.no_grad():
        before = ((untrained(y) - x) ** 2).mean()
        after = ((res.model(y) - x) ** 2).mean()
    assert len(res.losses) == 40 and after < 0.95 * before  # 0.90 measured


# -- ONNX ---------------------------------------------------------------------------------------


def test_onnx_export_dynamic_batch_matches_eager(tmp_path):
    """Exported at batch 2 with a dynamic batch axis; onnxruntime at batch 1 and 3."""
    import onnx
    import onnxruntime as ort

    net = _net(n=16, sr=0.25, K=3).eval()
    path = tmp_path / "unrolled.onnx"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # TorchScript exporter: fast here
        torch.onnx.export(
            net,
            (_y(net, b=2),),
            path,
            dynamo=False,
            opset_version=17,
            input_names=["y"],
            output_names=["x"],
            dynamic_axes={"y": {0: "batch"}, "x": {0: "batch"}},
        )
    onnx.checker.check_model(onnx.load(path))
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    for b in (1, 3):
        y = _y(net, b=b, seed=b + 10)
        got = sess.run(None, {"y": y.numpy()})[0]
        with torch.no_grad():
            want = net(y).numpy()
        np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-5 * np.abs(want).max())


# -- shipped weights ----------------------------------------------------------------------------


def test_shipped_weights_cover_the_paper_and_are_small():
    expected = {
        f"unrolled_n{n}_sr{code}_K{DEFAULT_N_ITER}.pt"
        for n in (32, 64)
        for code in ("0625", "1250", "1875", "2500", "3125", "3750")
    }
    assert expected <= set(SHIPPED)
    assert sum((WEIGHTS_DIR / f).stat().st_size for f in SHIPPED) < 200_000


@pytest.mark.parametrize("fname", SHIPPED)
def test_pretrained_loads_every_shipped_file(fname):
    n, code, K = (int(v) for v in NAME_RE.fullmatch(fname).groups())
    blob = torch.load(WEIGHTS_DIR / fname, weights_only=True)
    assert blob["meta"]["n"] == n and blob["meta"]["n_iter"] == K
    A = Hadamard(n, m=blob["meta"]["m"])
    assert round(A.sr * 10000) == code
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a matching file must load without the fallback warning
        net = UnrolledTVAL3(A, n_layers=K)
    assert net.weights_file == str(WEIGHTS_DIR / fname)
    untrained = UnrolledTVAL3(A, n_layers=K, pretrained=False)
    assert not torch.equal(net.log_mu, untrained.log_mu)
    for v in net.scalars():
        assert (v > 0).all() and torch.isfinite(v).all()
    x = torch.zeros(1, 1, n, n)
    x[..., n // 4 : n // 2, n // 4 : 3 * n // 4] = 1.0
    with torch.no_grad():
        assert torch.isfinite(net(A(x))).all()


def test_fallback_and_mismatch(tmp_path):
    A16 = Hadamard(16, sr=0.25)
    with pytest.warns(UserWarning, match="no shipped weights for Hadamard\\(n=16"):
        net = UnrolledTVAL3(A16, n_layers=3)
    assert net.weights_file is None
    ref = UnrolledTVAL3(A16, n_layers=3, pretrained=False)
    for a, b in zip(net.scalars(), ref.scalars(), strict=True):
        torch.testing.assert_close(a, b)
    # round trip through a file, then a file that does not match
    trained = _net(n=16, K=3)
    path = tmp_path / "w.pt"
    trained.save_weights(path, note="test")
    loaded = UnrolledTVAL3(A16, n_layers=3, pretrained=path)
    for a, b in zip(loaded.scalars(), trained.scalars(), strict=True):
        torch.testing.assert_close(a, b)
    with pytest.raises(ValueError, match="UnrolledTVAL3.load_weights: weights file .* was trained"):
        UnrolledTVAL3(A16, n_layers=4, pretrained=path)
    with pytest.raises(ValueError, match="UnrolledTVAL3.load_weights: weights file .* was trained"):
        UnrolledTVAL3(Hadamard(16, sr=0.5), n_layers=3, pretrained=path)


# -- acceptance (slow) --------------------------------------------------------------------------


def _held_out(n):
    """Scenes training never draws: another seed, scikit-image silhouettes, 天, depth maps."""
    from torchtof.recon.synthetic import synthetic_scenes
    from torchtof.scenes import binary_scene, depth_steps, motorcycle_depth, sky_character

    fixed = [sky_character(n)] + [
        binary_scene(k, n) for k in ("horse", "camera", "coins", "rocket")
    ]
    fixed += [depth_steps(n, seed=3).depth_m / 3.0, motorcycle_depth(n) / 4.0]
    return torch.cat([synthetic_scenes(n, 10**6, 0, range(16))] + fixed)


@pytest.mark.slow
@pytest.mark.parametrize("fname", SHIPPED)
def test_within_half_a_db_of_converged_tval3(fname):
    """Held-out scenes, bucket noise 1 % of the spread; PSNR on the [0, 1] scale, mean over
    scenes; TVAL3 run to its stopping rule with its default ``mu="auto"`` and with the
    published ``mu=2**8``; the unrolled network must be within 0.5 dB of the better one."""
    from torchtof.recon.tval3 import TVAL3

    n, _, K = (int(v) for v in NAME_RE.fullmatch(fname).groups())
    m = torch.load(WEIGHTS_DIR / fname, weights_only=True)["meta"]["m"]
    A = Hadamard(n, m=m)
    x = _held_out(n)
    y = noisy_measurements(A, x, 777, 0, range(len(x)), (0.01, 0.01))

    def psnr(xh):
        return float((10 * torch.log10(1.0 / ((xh - x) ** 2).mean(dim=(1, 2, 3)))).mean())

    with torch.no_grad():
        p_unrolled = psnr(UnrolledTVAL3(A, n_layers=K)(y))
        p_tval3 = max(psnr(TVAL3(A)(y)), psnr(TVAL3(A, mu=2**8)(y)))
    assert p_unrolled >= p_tval3 - 0.5, (p_unrolled, p_tval3)


def test_complex_y_is_refused_by_name():
    A = Hadamard(8, sr=0.5)
    net = UnrolledTVAL3(A, n_layers=2, pretrained=False)
    y = A(torch.rand(1, 1, 8, 8)).to(torch.complex64)
    with pytest.raises(TypeError, match="unrolled_tval3: expected y to be a real floating"):
        net(y)


def test_solve_reports_the_fixed_layers():
    A = Hadamard(8, sr=0.5)
    net = UnrolledTVAL3(A, n_layers=3, pretrained=False)
    y = A(torch.rand(2, 1, 8, 8, dtype=torch.float64))
    res = net.solve(y)
    assert torch.equal(res.x, net(y)) and res.n_iter.tolist() == [[3], [3]]
    assert res.stop_reason == "fixed" and bool(res.converged.all())
    torch.testing.assert_close(res.residual, (A(res.x) - y).norm(dim=-1) / y.norm(dim=-1))


def test_n_iter_still_works_with_a_warning():
    A = Hadamard(8, sr=0.5)
    with pytest.warns(DeprecationWarning, match="n_iter= is renamed n_layers="):
        net = UnrolledTVAL3(A, n_iter=4, pretrained=False)
    assert net.n_layers == 4 and net.log_mu.shape == (4,)
