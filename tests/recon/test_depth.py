"""Depth-resolved ghost imaging (torchtof.recon.depth)."""

import math

import pytest
import torch

from torchtof.experiment import PaperExperiment
from torchtof.metrics import depth_rmse
from torchtof.operators import DMDSplit, Hadamard
from torchtof.recon import (
    CGI,
    DGI,
    TGI,
    TVAL3,
    BasisPursuit,
    DepthResolved,
    DualFrequencyDepth,
    JointTV,
    PseudoInverse,
    UnrolledTVAL3,
    depth_resolved,
    dual_frequency_depth,
    hypothesis_spacing,
    iq_buckets,
    iq_phase_amplitude,
    joint_tv,
    tap_noise_sigma,
)
from torchtof.scenes import get_scene
from torchtof.sensor import SPEED_OF_LIGHT, correlation_taps, phasor_from_depth, tap_phase


def _taps(scene_name, n, dtype=torch.float32, signal=400.0, offset=2600.0, freq=30e6):
    """Noise-free tap images ``(1, 4, n, n)`` of a scene (Eq. 6, Fig. 1 order)."""
    s = get_scene(scene_name, n, dtype=dtype)
    phasor = phasor_from_depth(signal * s.reflectance, s.depth_m, freq)
    return s, correlation_taps(phasor, offset=offset + 0.5 * signal * s.reflectance)


def _noisy(y, rel, seed, batch):
    """``batch`` copies of ``y`` plus white noise of ``rel`` × the spread of the I/Q buckets."""
    g = torch.Generator().manual_seed(seed)
    iq = iq_buckets(y)
    sigma = rel * float((iq.amax(-1) - iq.amin(-1)).max())
    yb = y.expand(batch, -1, -1)
    return yb + sigma / math.sqrt(2) * torch.randn(yb.shape, generator=g, dtype=y.dtype), sigma


# -- the I/Q algebra -------------------------------------------------------------------------


def test_iq_buckets_known_answer_and_commutes_with_A():
    y = torch.tensor([[[5.0], [1.0], [2.0], [4.0]]])
    assert iq_buckets(y).flatten().tolist() == [4.0, 2.0]  # I = c1 - c2, Q = c4 - c3
    _, taps = _taps("steps", 16, torch.float64)
    A = Hadamard(16, sr=0.25)
    i, q = taps[:, 0] - taps[:, 1], taps[:, 3] - taps[:, 2]
    want = A(torch.stack((i, q), 1))
    torch.testing.assert_close(iq_buckets(A(taps)), want)


def test_iq_is_the_phasor():
    """I = Re P and Q = Im P for the sensor's taps, so Eq. 7 on I/Q is Eq. 7 on the taps."""
    s, taps = _taps("motorcycle", 16, torch.float64)
    phasor = phasor_from_depth(400.0 * s.reflectance, s.depth_m, 30e6)
    iq = torch.cat((taps[:, 0:1] - taps[:, 1:2], taps[:, 3:4] - taps[:, 2:3]), 1)
    torch.testing.assert_close(iq, torch.cat((phasor.real, phasor.imag), 1))
    phase, amp = iq_phase_amplitude(iq)
    torch.testing.assert_close(phase, tap_phase(taps))
    torch.testing.assert_close(amp, 0.5 * phasor.abs())  # Eq. 8: a/2


def test_tap_noise_sigma_statistics_and_zero_signal():
    _, taps = _taps("motorcycle", 32)
    A = Hadamard(32, sr=0.5)
    y = A(taps)
    assert float(tap_noise_sigma(y)) < 1e-3 * float(y.abs().max())  # no signal in the null
    g = torch.Generator().manual_seed(0)
    yn = y + 3.0 * torch.randn(4, 4, A.m, generator=g)
    est = tap_noise_sigma(yn)
    truth = 3.0 * math.sqrt(2)  # Var I = Var c1 + Var c2
    assert est.shape == (4,)
    assert torch.allclose(est, torch.full_like(est, truth), rtol=0.08)


# -- acceptance: noise-free, SR 100 % ---------------------------------------------------------


@pytest.mark.parametrize("scene", ["steps", "motorcycle", "slanted", "sky"])
@pytest.mark.parametrize("rec", ["pinv", "joint", "tgi_split"])
def test_noise_free_full_sr_depth_exact_where_masked(scene, rec):
    n = 16
    s, taps = _taps(scene, n)
    A = Hadamard(n, sr=1.0)
    if rec == "tgi_split":  # the paper's DMD buckets of complementary 0/1 patterns, TGI
        S = DMDSplit(A)
        y, module = S(taps), TGI(S)
    else:
        y = A(taps)
        module = PseudoInverse(A) if rec == "pinv" else JointTV(A, joint=True)
    res = DepthResolved(module, freq_hz=30e6, mode="taps" if rec == "tgi_split" else "iq").solve(y)
    obj = s.reflectance > 0
    assert torch.equal(res.mask, obj)  # mask on the object, off where nothing returns
    err = (res.depth - s.depth_m).abs()[res.mask]
    assert float(err.max()) < 1e-4


def test_taps_mode_equals_iq_mode_for_linear_reconstructors():
    _, taps = _taps("steps", 16, torch.float64)
    A = Hadamard(16, sr=0.375)
    y, _ = _noisy(A(taps), 0.01, 0, 2)
    a = depth_resolved(y, PseudoInverse(A), mode="iq")
    b = depth_resolved(y, PseudoInverse(A), mode="taps")
    torch.testing.assert_close(a.phase, b.phase)
    torch.testing.assert_close(a.amplitude, b.amplitude)
    assert a.images.shape == (2, 2, 16, 16) and b.images.shape == (2, 4, 16, 16)


# -- acceptance: the experiment --------------------------------------------------------------


def test_motorcycle_sr25_beats_raw_tof():
    """Default noise (shot, read, ADC, stray light, multipath), SR 25 %: depth RMSE over the
    object (every pixel: reflectance 1) below the raw ToF camera's at DMD resolution."""
    data = PaperExperiment(sr=0.25, scene="motorcycle", srs=(0.25,)).run(seed=0, realisations=2)
    A, y = data.measurements(0.25, kind="taps")
    truth = data.depth_m.expand(2, -1, -1, -1)
    raw = depth_rmse(data.raw_tof_image, truth)
    for rec in (PseudoInverse(A), JointTV(A)):
        res = DepthResolved(rec, data.config.freq_hz).solve(y)
        ours = depth_rmse(res.depth, truth)
        assert bool((ours < 0.5 * raw).all()), (ours, raw)
        assert res.mask.float().mean() > 0.95


def test_joint_beats_separate_at_low_sr():
    """Noise-limited buckets (1 % of the spread), SR 12.5 %, two scenes, 6 noise draws: the
    vectorial TV of I/Q has a lower mean depth RMSE than the same solver with TV per image."""
    n, sr = 32, 0.125
    A = Hadamard(n, sr=sr)
    wins = []
    for scene in ("steps", "motorcycle"):
        s, taps = _taps(scene, n)
        y, sigma = _noisy(A(taps), 0.01, 1, 6)
        truth = s.depth_m.expand(6, -1, -1, -1)
        e = {}
        for joint in (True, False):
            res = depth_resolved(y, JointTV(A, joint=joint), noise_sigma=sigma)
            e[joint] = depth_rmse(res.depth, truth)
        wins.append(float(e[True].mean()) < float(e[False].mean()))
        assert float((e[True] < e[False]).float().mean()) >= 0.5
    assert all(wins)


# -- the joint solver ------------------------------------------------------------------------


def _rotate(t, phi):
    c, s = math.cos(phi), math.sin(phi)
    return torch.stack((c * t[:, 0] - s * t[:, 1], s * t[:, 0] + c * t[:, 1]), 1)


def test_joint_tv_commutes_with_a_global_phase_separate_does_not():
    """Vectorial TV of (I, Q) is the complex TV of P = I + jQ: invariant to P -> e^{jφ} P."""
    _, taps = _taps("steps", 16, torch.float64)
    A = Hadamard(16, sr=0.25)
    y = iq_buckets(_noisy(A(taps), 0.02, 2, 1)[0])
    phi = 0.7
    kw = dict(mu=2.0**6, n_iter=60, adaptive=False)
    for joint, equal in ((True, True), (False, False)):
        a = _rotate(joint_tv(y, A, joint=joint, **kw), phi)
        b = joint_tv(_rotate(y, phi), A, joint=joint, **kw)
        diff = float((a - b).abs().max() / a.abs().max())
        assert (diff < 1e-9) == equal, (joint, diff)


def test_joint_tv_module_function_batch_dtype():
    _, taps = _taps("slanted", 16, torch.float64)
    A = Hadamard(16, sr=0.25)
    y, sigma = _noisy(A(taps), 0.01, 3, 3)
    y = iq_buckets(y)
    y0 = y.clone()
    x = joint_tv(y, A, noise_sigma=sigma)
    assert torch.equal(y, y0) and x.dtype == torch.float64 and x.shape == (3, 2, 16, 16)
    torch.testing.assert_close(JointTV(A)(y, noise_sigma=sigma), x)
    singles = torch.cat([joint_tv(y[i : i + 1], A, noise_sigma=sigma) for i in range(3)])
    torch.testing.assert_close(singles, x)
    assert joint_tv(torch.zeros(1, 2, A.m), A).abs().max() == 0  # all-zero -> zeros, no NaN


def test_joint_tv_errors():
    A = Hadamard(8, sr=0.5)
    y = torch.rand(1, 2, A.m)
    with pytest.raises(ValueError, match=r"joint_tv: expected y of shape \(\*, \*, 32\)"):
        joint_tv(y[..., :-1], A)
    with pytest.raises(TypeError, match="joint_tv: expected A to be a LinearOperator"):
        joint_tv(y, "A")
    with pytest.raises(ValueError, match="joint_tv: y contains non-finite"):
        joint_tv(torch.full_like(y, float("nan")), A)
    with pytest.raises(ValueError, match="joint_tv: expected n_iter >= 1"):
        joint_tv(y, A, n_iter=0)
    with pytest.raises(ValueError, match="joint_tv: expected mu to be a positive number or 'auto'"):
        joint_tv(y, A, mu="big")
    with pytest.raises(TypeError, match="JointTV: expected A to be a LinearOperator"):
        JointTV(None)


# -- DepthResolved wrapper -------------------------------------------------------------------


def _bp(A):
    return BasisPursuit(A, eps="auto")


@pytest.mark.parametrize("make", [PseudoInverse, TVAL3, JointTV, UnrolledTVAL3, _bp])
def test_any_reconstructor_shapes_module_equals_function(make):
    n = 32 if make is UnrolledTVAL3 else 16
    A = Hadamard(n, sr=0.25)
    s, taps = _taps("steps", n)
    y, _ = _noisy(A(taps), 0.01, 4, 3)
    rec = make(A)
    net = DepthResolved(rec, 30e6)
    with torch.no_grad():  # the unrolled network holds parameters
        res = net.solve(y)
    for t in (res.depth, res.amplitude, res.phase, res.mask):
        assert t.shape == (3, 1, n, n)
    assert res.images.shape == (3, 2, n, n) and res.threshold.shape == (3,)
    assert float(res.depth.min()) >= 0 and float(res.depth.max()) < SPEED_OF_LIGHT / 60e6
    with torch.no_grad():
        torch.testing.assert_close(net(y), res.depth)
        torch.testing.assert_close(depth_resolved(y, rec, 30e6).depth, res.depth)
        d, a = net.depth_amplitude(y)
    torch.testing.assert_close(a, res.amplitude)
    assert bool((depth_rmse(res.depth, s.depth_m.expand(3, -1, -1, -1)) < 0.3).all())


def test_depth_resolved_batched_equals_singles_and_iq_input():
    A = Hadamard(16, sr=0.5)
    _, taps = _taps("motorcycle", 16)
    y, _ = _noisy(A(taps), 0.01, 5, 3)
    rec = PseudoInverse(A)
    full = depth_resolved(y, rec)
    for i in range(3):
        one = depth_resolved(y[i : i + 1], rec)
        torch.testing.assert_close(one.depth, full.depth[i : i + 1])
    # I/Q input with the same noise level gives the same result
    iq = depth_resolved(iq_buckets(y), rec, noise_sigma=tap_noise_sigma(y))
    torch.testing.assert_close(iq.depth, full.depth)
    torch.testing.assert_close(iq.threshold, full.threshold)


def test_depth_gradcheck():
    A = Hadamard(8, sr=0.5)
    _, taps = _taps("steps", 8, torch.float64)
    y = A(taps).detach().requires_grad_(True)
    rec = PseudoInverse(A)
    assert torch.autograd.gradcheck(lambda t: depth_resolved(t, rec).depth, (y,))


def test_mask_false_positive_rate_on_pure_noise():
    """No object, white noise: the k = 3 rule keeps about exp(-9/2) = 1.1 % of the pixels."""
    A = Hadamard(32, sr=0.5)
    g = torch.Generator().manual_seed(6)
    y = 5.0 * torch.randn(8, 4, A.m, generator=g)
    res = depth_resolved(y, PseudoInverse(A), rel_floor=0.0)
    frac = float(res.mask.float().mean())
    assert 0.003 < frac < 0.025, frac
    strict = depth_resolved(y, PseudoInverse(A), k_sigma=5.0, rel_floor=0.0)
    assert float(strict.mask.float().mean()) < 1e-3


def test_depth_resolved_errors():
    A = Hadamard(8, sr=0.5)
    rec = PseudoInverse(A)
    y = torch.rand(1, 4, A.m)
    with pytest.raises(ValueError, match=r"depth_resolved: expected y of shape \(B, 2, M\) or"):
        depth_resolved(torch.rand(1, 3, A.m), rec)
    with pytest.raises(ValueError, match="depth_resolved: y contains non-finite"):
        depth_resolved(torch.full_like(y, float("inf")), rec)
    with pytest.raises(ValueError, match="expected mode in"):
        depth_resolved(y, rec, mode="phasor")
    with pytest.raises(ValueError, match="mode='taps' needs tap buckets"):
        depth_resolved(iq_buckets(y), rec, mode="taps")
    with pytest.raises(ValueError, match=r"expected rel_floor in \[0, 1\)"):
        depth_resolved(y, rec, rel_floor=1.0)
    with pytest.raises(ValueError, match="expected freq_hz > 0"):
        depth_resolved(y, rec, freq_hz=0.0)
    with pytest.raises(TypeError, match="expected reconstructor to be an nn.Module"):
        depth_resolved(y, lambda t: t)
    with pytest.raises(TypeError, match="expected y to be a real tensor"):
        depth_resolved(y.to(torch.complex64), rec)
    with pytest.raises(ValueError, match=r"expected the reconstructor to return \(B, 2, n, n\)"):
        depth_resolved(y, torch.nn.Identity())
    S = DMDSplit(A)
    for cls in (CGI, DGI):  # normalised per channel: the tap images lose their common scale
        with pytest.raises(ValueError, match="divides each channel by its own mean bucket"):
            depth_resolved(S(torch.rand(1, 4, 8, 8)), cls(S))
        with pytest.raises(ValueError, match="use TGI"):
            DepthResolved(cls(S))
    with pytest.raises(ValueError, match="DepthResolved: expected mode in"):
        DepthResolved(rec, mode="x")
    with pytest.raises(TypeError, match="DepthResolved: expected reconstructor"):
        DepthResolved("rec")


# -- two frequencies -------------------------------------------------------------------------


def _wrapped(d, f):
    return torch.remainder(4 * math.pi * f * d / SPEED_OF_LIGHT, 2 * math.pi)


def test_dual_frequency_known_answer_up_to_15_m():
    common = SPEED_OF_LIGHT / 2e7  # c / (2 gcd(30, 20 MHz)) = 14.99 m
    d = torch.linspace(0.0, common - 1e-3, 3001, dtype=torch.float64)
    out = dual_frequency_depth(_wrapped(d, 30e6), _wrapped(d, 20e6), 30e6, 20e6)
    assert float((out - d).abs().max()) < 1e-9
    # beyond the common range it wraps (c / (2 gcd) = c / 20 MHz)
    far = torch.tensor([16.0], dtype=torch.float64)
    got = dual_frequency_depth(_wrapped(far, 30e6), _wrapped(far, 20e6), 30e6, 20e6)
    assert abs(float(got) - (16.0 - common)) < 1e-9


def test_dual_frequency_noise_tolerance():
    """Phase noise well below the decision margin never picks the wrong wrap counts."""
    g = torch.Generator().manual_seed(7)
    d = 14.9 * torch.rand(20000, generator=g, dtype=torch.float64)
    p1 = _wrapped(d, 30e6) + 0.05 * torch.randn(d.shape, generator=g, dtype=torch.float64)
    p2 = _wrapped(d, 20e6) + 0.05 * torch.randn(d.shape, generator=g, dtype=torch.float64)
    out = dual_frequency_depth(torch.remainder(p1, 2 * math.pi), torch.remainder(p2, 2 * math.pi),
                               30e6, 20e6)
    common = SPEED_OF_LIGHT / 2e7
    err = torch.minimum((out - d).abs(), common - (out - d).abs())  # 0 ≡ 14.99 m
    assert float(err.max()) < 0.4  # a wrong wrap count errs by >= 1.5 m (5 m vs 7.5 m grids)
    assert float(err.pow(2).mean().sqrt()) < 0.05  # inverse-variance mean: below 0.04 m


def test_dual_frequency_is_the_inverse_variance_mean():
    """Closed form: phases of depth d at f₁ and d + δ at f₂ (equal phase noise, weights ∝ f²)
    combine to d + δ·f₂²/(f₁² + f₂²) = d + 4δ/13 for 30 and 20 MHz; either frequency alone
    gives d or d + δ."""
    d = torch.tensor([0.3, 2.2, 4.1, 6.7, 9.05, 12.8], dtype=torch.float64)
    delta = 0.06
    out = dual_frequency_depth(_wrapped(d, 30e6), _wrapped(d + delta, 20e6), 30e6, 20e6)
    torch.testing.assert_close(out, d + delta * 4 / 13, rtol=0, atol=1e-9)


def test_dual_frequency_on_a_scene_beyond_5_m():
    n = 16
    s = get_scene("steps_far", n)
    assert float(s.depth_m.max()) > 7.0
    A = Hadamard(n, sr=0.5)
    ys = []
    for f in (30e6, 20e6):
        _, taps = _taps("steps_far", n, freq=f)
        ys.append(_noisy(A(taps), 0.005, 8, 2)[0])
    net = DualFrequencyDepth(JointTV(A), 30e6, 20e6)
    depth = net(*ys)
    res = net.solve(*ys)
    torch.testing.assert_close(res.depth, depth)
    assert float(res.mask.float().mean()) > 0.9  # hypotheses agree on (almost) every pixel
    single = DepthResolved(JointTV(A), 30e6)(ys[0])
    truth = s.depth_m.expand(2, -1, -1, -1)
    assert bool((depth_rmse(depth, truth) < 0.15).all())
    assert bool((depth_rmse(single, truth) > 1.0).all())  # one frequency wraps at 5 m


def test_dual_frequency_gap_flags_inconsistent_phases():
    assert abs(hypothesis_spacing(30e6, 20e6) - SPEED_OF_LIGHT / 1.2e8) < 1e-12  # 2.498 m
    d = torch.tensor([2.0, 6.0], dtype=torch.float64)
    p1, p2 = _wrapped(d, 30e6), _wrapped(d, 20e6)
    _, gap = dual_frequency_depth(p1, p2, 30e6, 20e6, return_gap=True)
    assert float(gap.max()) < 1e-9
    # a 20 MHz phase off by 1 m leaves a gap of 1 m (the next hypothesis is 1.498 m away)
    bad = _wrapped(d + 1.0, 20e6)
    _, gap = dual_frequency_depth(p1, bad, 30e6, 20e6, return_gap=True)
    torch.testing.assert_close(gap, torch.full_like(gap, 1.0))


def test_dual_frequency_errors():
    p = torch.zeros(2, 2)
    with pytest.raises(ValueError, match="two different frequencies"):
        dual_frequency_depth(p, p, 30e6, 30e6)
    with pytest.raises(ValueError, match="same shape"):
        dual_frequency_depth(p, p[0], 30e6, 20e6)
    with pytest.raises(ValueError, match="expected max_m <= the common range"):
        dual_frequency_depth(p, p, 30e6, 20e6, max_m=20.0)
    with pytest.raises(ValueError, match="phase_1 contains non-finite"):
        dual_frequency_depth(p / 0, p, 30e6, 20e6)
    with pytest.raises(ValueError, match="expected freq_hz > 0"):
        DualFrequencyDepth(PseudoInverse(Hadamard(8, sr=0.5)), 30e6, -1.0)


# -- ONNX --------------------------------------------------------------------------------------


def test_onnx_export_with_the_unrolled_reconstructor_inside(tmp_path):
    """`torchtof export depth_resolved`: taps -> depth, amplitude with the shipped unrolled
    TVAL3 inside; onnxruntime matches eager PyTorch on a batch of another size, and the
    exported depth is a depth map (close to the truth of a scene it never saw)."""
    import numpy as np

    import torchtof.onnx as tto
    from torchtof.apps.onnx_models import MODELS, export_model

    path = export_model("depth_resolved", n=32, sr=0.25, path=tmp_path / "d.onnx")
    module, (y,) = MODELS["depth_resolved"](32, 0.25, batch=3, seed=4)
    assert isinstance(module.net.reconstructor, UnrolledTVAL3)
    assert module.net.reconstructor.weights_file is not None
    report = tto.check(path, module, (y,))
    assert [o["name"] for o in report["outputs"]] == ["depth", "amplitude"]
    sess = tto.ort_session(path)
    depth, amp = sess.run(None, {"taps": y.numpy()})
    assert depth.shape == (3, 1, 32, 32) and amp.shape == (3, 1, 32, 32)
    s, taps = _taps("steps", 32)  # a scene of its own: 1.5–3 m
    A = Hadamard(32, sr=0.25)
    got = sess.run(None, {"taps": A(taps).expand(2, -1, -1).numpy()})[0]
    rmse = float(np.sqrt(((got - s.depth_m.numpy()) ** 2).mean()))
    assert rmse < 0.1, rmse


@pytest.mark.parametrize("boundary", ["periodic", "neumann"])
def test_joint_tv_bounds_and_boundary(boundary):
    # noise-free tap-like images (>= 0) at SR 50 %: recovered under either boundary; with
    # bounds (0, 0.6) the box is honoured (the true images exceed 0.6, so it is active)
    n = 16
    A = Hadamard(n, sr=0.5).double()
    x = torch.zeros(1, 2, n, n, dtype=torch.float64)
    x[:, 0, 3:9, 0:7] = 1.0
    x[:, 1, 3:9, 0:7] = 0.5
    free = joint_tv(A(x), A, mu=2**8, n_iter=600, boundary=boundary)
    assert (free - x).abs().max() < 1e-2
    box = joint_tv(A(x), A, mu=2**8, n_iter=600, boundary=boundary, bounds=(0.0, 0.6))
    assert box.min() >= 0 and box.max() <= 0.6 + 1e-12
    with pytest.raises(ValueError, match="joint_tv: expected boundary in"):
        joint_tv(A(x), A, boundary="zero")


def test_depth_result_carries_the_reconstructors_solve_result():
    A = Hadamard(8, sr=0.5)
    g = torch.Generator().manual_seed(0)
    y = A(torch.rand(2, 4, 8, 8, generator=g)) + 3.0 * A(torch.ones(2, 4, 8, 8))
    res = depth_resolved(y, TVAL3(A, mu=2**8, max_iter=40))
    assert res.x is res.depth
    assert res.n_iter.shape == (2, 2) and res.converged.shape == (2, 2)
    assert len(res.stop_reason) == 2 and len(res.stop_reason[0]) == 2
    ref = TVAL3(A, mu=2**8, max_iter=40)(iq_buckets(y))
    torch.testing.assert_close(res.images, ref)


@pytest.mark.parametrize("iq, err", [
    (torch.full((1, 2, 2, 2), float("nan")), ValueError),
    (torch.zeros(1, 2, 2, 2, dtype=torch.complex64), TypeError),
    (torch.zeros(1, 2, 2, 2, dtype=torch.int64), TypeError),
])
def test_iq_phase_amplitude_errors_name_itself_and_iq(iq, err):
    from torchtof.recon.depth import iq_phase_amplitude
    with pytest.raises(err, match=r"^iq_phase_amplitude: .*\biq\b"):
        iq_phase_amplitude(iq)


@pytest.mark.parametrize("m", [16, 32])
def test_joint_tv_auto_keeps_the_image_at_few_buckets(m):
    # n = 16 with 16 or 32 buckets: the tail estimate reads the scene's high-order rows as
    # noise; without TVAL3's hold-out check mu="auto" chose a TV-L2 weight so small that the
    # image was flat (std 1e-8). The check keeps the constrained model where it predicts the
    # held-out buckets as well.
    from torchtof.operators import Hadamard
    from torchtof.recon.depth import joint_tv
    A = Hadamard(16, m=m)
    x = torch.zeros(1, 1, 16, 16, dtype=torch.float64)
    x[..., 3:11, 4:13] = 1.0
    y = A(x)
    got = joint_tv(y, A, return_result=True)
    ref = joint_tv(y, A, mu=256.0, return_result=True)  # the published constrained model
    assert float(got.x.std()) > 0.5 * float(ref.x.std())
    assert float(got.residual.max()) < 0.2
