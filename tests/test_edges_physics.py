"""Edge cases of the physics, metrics, operators and data: bad arguments raise a clear error
naming the public function and the argument; degenerate but valid inputs (a zero error, a
float16 batch, a grain wider than the pattern) give defined results."""

import math

import numpy as np
import pytest
import torch

from torchtof import data as tdata
from torchtof import scenes as tscenes
from torchtof.bucket import depth_bucket, intensity_bucket, tap_buckets
from torchtof.metrics import PSNR, SSIM, DepthRMSE, depth_rmse, psnr, ssim
from torchtof.operators import (
    DMDSplit,
    Hadamard,
    combine_split,
    fwht,
    fwht2,
    gaussian_speckle_patterns,
)
from torchtof.sensor import (
    CameraReadout,
    CWToFSensor,
    adc_quantize,
    add_multipath,
    camera_rules,
    correlation_taps,
    cw_tof_sensor,
    phasor_from_depth,
    tap_amplitude,
    tof_noise,
)

NAN, INF = float("nan"), float("inf")


def _g(seed=0):
    return torch.Generator().manual_seed(seed)


# ---------------------------------------------------------------- 1. SSIM definition
def _ssim_reference(a: np.ndarray, b: np.ndarray, data_range=1.0, window=7, sigma=1.5) -> float:
    """The documented SSIM computed independently: separable ``window``-tap Gaussian of σ
    normalised to sum 1, reflect padding (``np.pad(mode="reflect")``, kornia's mode: the edge
    pixel is not repeated), c1 = (0.01 L)², c2 = (0.03 L)², mean over the full map."""
    r = window // 2
    k = np.exp(-(np.arange(-r, r + 1) ** 2) / (2 * sigma**2))
    k /= k.sum()

    def blur(img):
        p = np.pad(img, r, mode="reflect")
        rows = sum(k[i] * p[:, i : i + img.shape[1]] for i in range(window))
        return sum(k[i] * rows[i : i + img.shape[0], :] for i in range(window))

    mu_a, mu_b = blur(a), blur(b)
    var_a, var_b = blur(a * a) - mu_a**2, blur(b * b) - mu_b**2
    cov = blur(a * b) - mu_a * mu_b
    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2
    num = (2 * mu_a * mu_b + c1) * (2 * cov + c2)
    den = (mu_a**2 + mu_b**2 + c1) * (var_a + var_b + c2)
    return float((num / den).mean())


def _box_pair(seed=0):
    x = torch.zeros(1, 1, 32, 32, dtype=torch.float64)
    x[..., 8:24, 8:24] = 1
    return x + 0.2 * torch.randn(x.shape, generator=_g(seed), dtype=torch.float64), x


@pytest.mark.parametrize("case", ["random", "random_odd", "box", "ramp", "range3_window5"])
def test_ssim_known_answer(case):
    rng = np.random.default_rng(1)
    data_range, window = 1.0, 7
    if case == "random":
        a, b = rng.random((32, 32)), rng.random((32, 32))
    elif case == "random_odd":
        a, b = rng.random((17, 23)), rng.random((17, 23))
    elif case == "box":
        xh, x = _box_pair()
        a, b = xh[0, 0].numpy(), x[0, 0].numpy()
    elif case == "ramp":
        b = np.add.outer(np.arange(16.0), np.arange(20.0)) / 34
        a = b**2
    else:
        a, b = 3 * rng.random((12, 12)), 3 * rng.random((12, 12))
        data_range, window = 3.0, 5
    got = ssim(torch.from_numpy(a)[None, None], torch.from_numpy(b)[None, None], data_range,
               window)
    assert got.dtype == torch.float64
    assert abs(float(got) - _ssim_reference(a, b, data_range, window)) < 1e-10


def test_ssim_docstring_states_the_skimage_difference():
    xh, x = _box_pair()
    ours = float(ssim(xh, x))
    assert f"{ours:.3f}" in ssim.__doc__ and "structural_similarity" in ssim.__doc__
    metrics = pytest.importorskip("skimage.metrics")
    theirs = metrics.structural_similarity(
        xh[0, 0].numpy(), x[0, 0].numpy(), gaussian_weights=True, sigma=1.5,
        use_sample_covariance=False, data_range=1.0)
    assert f"{theirs:.3f}" in ssim.__doc__


# ---------------------------------------------------------------- 2, 13. depth RMSE
@pytest.mark.parametrize("masked", [False, True])
def test_depth_rmse_zero_error_has_zero_gradient(dtype, masked):
    z = torch.full((2, 1, 4, 4), 2.0, dtype=dtype)
    zh = z.clone().requires_grad_(True)
    mask = torch.ones(4, 4, dtype=torch.bool) if masked else None
    out = depth_rmse(zh, z, mask)
    assert out.tolist() == [0.0, 0.0]
    out.sum().backward()
    assert torch.equal(zh.grad, torch.zeros_like(z))


def test_depth_rmse_zero_masked_error_next_to_errors_elsewhere():
    z = torch.zeros(1, 1, 2, 2, dtype=torch.float64)
    zh = torch.tensor([[[[0.0, 0.0], [3.0, 4.0]]]], dtype=torch.float64, requires_grad=True)
    mask = torch.tensor([[True, True], [False, False]])
    out = depth_rmse(zh, z, mask)
    out.sum().backward()
    assert out.tolist() == [0.0] and bool(torch.isfinite(zh.grad).all())


def test_depth_rmse_mask_scales_by_the_masked_pixels():
    # 1e-3 m inside the mask next to 1e25 m outside: (1e-3 / 5e24)² underflowed to 0
    zh = torch.tensor([1e-3, 1e25]).view(1, 1, 1, 2)
    out = depth_rmse(zh, torch.zeros_like(zh), mask=torch.tensor([[True, False]]))
    assert math.isclose(float(out), 1e-3, rel_tol=1e-6)


def test_depth_rmse_empty_image_raises():
    e = torch.zeros(1, 1, 0, 4)
    with pytest.raises(ValueError, match="depth_rmse: expected depth with at least one pixel"):
        depth_rmse(e, e)
    with pytest.raises(ValueError, match="DepthRMSE: expected reduction"):
        DepthRMSE(reduction="sum")


# ---------------------------------------------------------------- 3. camera rules
_ONE = torch.ones(1, 1, 2, 2)


@pytest.mark.parametrize("kw,exc,match", [
    ({"amp_threshold": NAN}, ValueError, "amp_threshold"),
    ({"amp_threshold": INF}, ValueError, "amp_threshold"),
    ({"amp_threshold": "x"}, TypeError, "amp_threshold"),
    ({"no_photon_m": NAN}, ValueError, "no_photon_m"),
    ({"min_m": -1.0}, ValueError, "min_m"),
    ({"min_m": "1"}, TypeError, "min_m"),
    ({"max_m": INF}, ValueError, "max_m"),
])
def test_camera_rule_parameters_are_checked_everywhere(kw, exc, match):
    with pytest.raises(exc, match=f"camera_rules: .*{match}"):
        camera_rules(_ONE, _ONE * 0, **kw)
    with pytest.raises(exc, match=f"CWToFSensor: .*{match}"):
        CWToFSensor(**kw)
    with pytest.raises(exc, match=f"CameraReadout: .*{match}"):
        CameraReadout(**kw)
    with pytest.raises(exc, match=f"cw_tof_sensor: .*{match}"):
        cw_tof_sensor(torch.ones(1, 1, 2, 2, dtype=torch.complex64), shot=None, **kw)


def test_camera_rules_dark_pixels_still_report_no_photon():
    d = torch.tensor([2.0, 3.0]).view(1, 1, 1, 2)
    a = torch.tensor([0.0, 1.0]).view(1, 1, 1, 2)
    assert camera_rules(d, a, amp_threshold=0).flatten().tolist() == [5.0, 3.0]


# ---------------------------------------------------------------- 4. correlation taps
_P = torch.full((1, 1, 2, 2), 1.0 + 1.0j)


@pytest.mark.parametrize("offset,exc", [
    (NAN, ValueError), (INF, ValueError), (torch.tensor(NAN), ValueError),
    (torch.full((1, 1, 2, 2), INF), ValueError),
    (torch.ones(3, 1, 1, 1), ValueError),  # would grow the batch from 1 to 3
    (torch.ones(3), ValueError), (torch.ones(1, 2, 2, 2), ValueError),
    ("a", TypeError), (True, TypeError), (torch.ones(1, dtype=torch.complex64), TypeError),
])
def test_correlation_taps_checks_offset(offset, exc):
    with pytest.raises(exc, match="correlation_taps: .*offset"):
        correlation_taps(_P, offset)


@pytest.mark.parametrize("cdtype,rdtype", [(torch.complex64, torch.float32),
                                           (torch.complex128, torch.float64)])
@pytest.mark.parametrize("odtype", [torch.float16, torch.float32, torch.float64])
def test_correlation_taps_follow_the_phasor_dtype(cdtype, rdtype, odtype):
    p = _P.to(cdtype)
    off = torch.full((1, 1, 1, 2), 1.5, dtype=odtype)
    out = correlation_taps(p, off)
    assert out.dtype == rdtype
    assert torch.equal(out, correlation_taps(p, off.to(rdtype)))
    assert correlation_taps(p, 2).dtype == rdtype


# ---------------------------------------------------------------- 5. multipath
@pytest.mark.parametrize("name", ["strength", "extra_path_m"])
@pytest.mark.parametrize("value,exc,match", [
    (torch.tensor(NAN), ValueError, "non-finite"),
    (torch.full((1, 1, 2, 2), INF), ValueError, "non-finite"),
    (torch.tensor(-2.0), ValueError, ">= 0"),
    (torch.ones(3, 1, 1, 1), ValueError, "broadcastable"),
    (torch.ones(3), ValueError, "broadcastable"),
    (torch.ones(1, dtype=torch.complex64), TypeError, "real"),
])
def test_add_multipath_checks_tensor_parameters(name, value, exc, match):
    kw = {"strength": 0.3, "extra_path_m": 0.5, name: value}
    with pytest.raises(exc, match=f"add_multipath: .*{name}.*{match}"):
        add_multipath(_P, **kw)


def test_add_multipath_tensor_and_number_agree():
    p = _P.to(torch.complex128)
    out = add_multipath(p, torch.tensor(0.3, dtype=torch.float64), torch.full((2,), 0.5))
    torch.testing.assert_close(out, add_multipath(p, 0.3, 0.5))


# ---------------------------------------------------------------- 6. noisy buckets
def _noisy(recipes, b=2):
    A = Hadamard(8, sr=0.5)
    x = torch.rand(b, 1, 8, 8, generator=_g())
    return tdata.noisy_buckets(A, x, recipes, [_g(i) for i in range(b)])


@pytest.mark.parametrize("recipe,field", [
    (tdata.NoiseRecipe(NAN), "level"), (tdata.NoiseRecipe(INF), "level"),
    (tdata.NoiseRecipe(-0.1), "level"), (tdata.NoiseRecipe(0.0, NAN), "photons"),
    (tdata.NoiseRecipe(0.0, INF), "photons"), (tdata.NoiseRecipe(0.0, 0.0), "photons"),
    (tdata.NoiseRecipe(0.0, 10.0, INF), "stray"), (tdata.NoiseRecipe(0.0, 10.0, NAN), "stray"),
])
def test_noisy_buckets_checks_recipes(recipe, field):
    with pytest.raises(ValueError, match=rf"noisy_buckets: expected recipes\[1\]\.{field}"):
        _noisy([tdata.NoiseRecipe(), recipe])


def test_noisy_buckets_types_and_empty_batch():
    with pytest.raises(TypeError, match=r"noisy_buckets: expected recipes\[0\] to be a "
                                        "NoiseRecipe"):
        _noisy([(0.1, None, 0.0)] * 2)
    with pytest.raises(TypeError, match=r"noisy_buckets: expected generators\[0\]"):
        tdata.noisy_buckets(Hadamard(8, sr=0.5), torch.rand(1, 1, 8, 8),
                            [tdata.NoiseRecipe()], [0])
    out = _noisy([], b=0)
    assert out.shape == (0, 1, 32)


# ---------------------------------------------------------------- 7. combine_split
@pytest.mark.parametrize("n,exc", [(0, ValueError), (-8, ValueError), (8.5, TypeError),
                                   (8.0, TypeError), (True, TypeError)])
def test_combine_split_needs_a_positive_int(n, exc):
    with pytest.raises(exc, match="combine_split: expected n"):
        combine_split(torch.rand(1, 1, 4), n)


# ---------------------------------------------------------------- 8. scenes
def test_draw_scene_argument_checks():
    for dt in (torch.int64, torch.bool, "float32"):
        with pytest.raises(TypeError, match="draw_scene: expected dtype"):
            tdata.draw_scene(16, 1, dtype=dt)
        with pytest.raises(TypeError, match="draw_scenes: expected dtype"):
            tdata.draw_scenes(16, 0, 0, [0], dtype=dt)
    for seed in ("a", 1.5, None, True):
        with pytest.raises(TypeError, match="draw_scene: expected seed to be an int"):
            tdata.draw_scene(16, seed)
        with pytest.raises(TypeError, match="draw_scenes: expected seed to be an int"):
            tdata.draw_scenes(16, seed, 0, [0])
    with pytest.raises(ValueError, match="draw_scene: expected seed"):
        tdata.draw_scene(16, 2**64)
    with pytest.raises(TypeError, match="draw_scenes: expected step"):
        tdata.draw_scenes(16, 0, 0.5, [0])
    with pytest.raises(TypeError, match="draw_scenes: expected indices"):
        tdata.draw_scenes(16, 0, 0, [1.5])
    # numpy integers are ints
    assert torch.equal(tdata.draw_scene(16, np.int64(3)), tdata.draw_scene(16, 3))


@pytest.mark.parametrize("bad", [NAN, INF])
def test_draw_scene_rejects_non_finite_user_images(bad):
    img = torch.rand(20, 20, generator=_g())
    img[3, 4] = bad
    with pytest.raises(ValueError, match=r"draw_scene: expected finite values in user_images\[1\]"):
        tdata.draw_scene(16, 1, family="user", user_images=[torch.rand(20, 20), img])


@pytest.mark.parametrize("dt", [torch.int64, torch.uint8, torch.bool])
def test_scene_registry_needs_a_floating_dtype(dt):
    with pytest.raises(TypeError, match="sky_character: expected dtype"):
        tscenes.sky_character(16, dtype=dt)
    with pytest.raises(TypeError, match="get_scene: expected dtype"):
        tscenes.get_scene("sky", 16, dtype=dt)
    with pytest.raises(TypeError, match="depth_steps: expected dtype"):
        tscenes.depth_steps(16, dtype=dt)


# ---------------------------------------------------------------- 9. float16
@pytest.mark.parametrize("half", [torch.float16, torch.bfloat16])
def test_dmd_split_low_precision_is_computed_in_float32(half):
    S = DMDSplit(Hadamard(256, sr=0.01))
    x = torch.full((1, 1, 256, 256), 2.0)
    out = S(x.to(half))
    assert out.dtype == half and not bool(torch.isnan(out).any())
    assert torch.equal(out, S(x).to(half))  # one rounding of the float32 result
    y = torch.rand(1, 1, S.m, generator=_g()) * 100
    assert torch.equal(S.adjoint(y.to(half)), S.adjoint(y.to(half).float()).to(half))


@pytest.mark.parametrize("half", [torch.float16, torch.bfloat16])
def test_half_buckets_are_the_float32_sum_rounded_once(half):
    # the sums accumulate in float32 (torch's reduction): 1000 × 0.1 does not stall at 256;
    # a bucket float16 cannot hold (256² px at 5 m = 327680 > 65504) is inf, never NaN
    frames = 5 * torch.rand(1, 3, 256, 256, generator=_g())
    frames[0, 0] = 5.0
    mask = torch.rand(256, 256, generator=_g(1)) > 0.5
    for fn, x in ((depth_bucket, frames), (intensity_bucket, frames),
                  (tap_buckets, frames[:, :, None].expand(1, 3, 4, 256, 256))):
        for roi in (None, mask, (0, 0, 16, 16)):
            out = fn(x.to(half), roi=roi)
            assert torch.equal(out, fn(x.to(half).float(), roi=roi).to(half))
            assert not bool(torch.isnan(out).any())


# ---------------------------------------------------------------- 10. speckle grain
def _circular_reference(z: torch.Tensor, grain: float) -> torch.Tensor:
    """Blur by the definition: every tap of the 2⌊3σ⌋+1-tap Gaussian wrapped onto the
    period (np.roll), rows then columns, then standardised."""
    r = int(3 * grain)
    k = np.exp(-(np.arange(-r, r + 1) ** 2) / (2 * grain**2))
    k /= k.sum()
    a = z.numpy()
    rows = sum(w * np.roll(a, -t, axis=-1) for w, t in zip(k, range(-r, r + 1)))
    out = sum(w * np.roll(rows, -t, axis=-2) for w, t in zip(k, range(-r, r + 1)))
    out = torch.from_numpy(out)
    return (out - out.mean(dim=(-2, -1), keepdim=True)) / out.std(dim=(-2, -1), keepdim=True)


@pytest.mark.parametrize("n,grain", [(32, 5.0), (32, 11.0), (32, 32.0), (8, 3.0), (2, 2.0)])
def test_speckle_grain_over_the_documented_range(n, grain):
    got = gaussian_speckle_patterns(2, n, grain, _g(3), torch.float64)
    z = torch.randn(2, n, n, generator=_g(3), dtype=torch.float64)
    torch.testing.assert_close(got, _circular_reference(z, grain), rtol=0, atol=1e-9)


def test_speckle_single_pixel_with_grain_raises():
    with pytest.raises(ValueError, match="gaussian_speckle_patterns: expected grain = 0"):
        gaussian_speckle_patterns(1, 1, 0.5)
    assert gaussian_speckle_patterns(1, 1, 0.0).shape == (1, 1, 1)


# ---------------------------------------------------------------- 11. fwht2
@pytest.mark.parametrize("x,exc,match", [
    (torch.full((4, 4), NAN), ValueError, "non-finite"),
    (torch.ones(3, 3), ValueError, "power of two"),
    (torch.ones(4, 6), ValueError, "power of two"),
    (torch.ones(4), ValueError, "two axes"),
    (torch.ones(4, 4, dtype=torch.int64), TypeError, "floating"),
    ([[1.0]], TypeError, "torch.Tensor"),
])
def test_fwht2_is_checked_like_fwht(x, exc, match):
    with pytest.raises(exc, match=f"fwht2: .*{match}"):
        fwht2(x)


def test_fwht2_equals_fwht_of_the_flattened_image():
    x = torch.rand(2, 8, 4, generator=_g(), dtype=torch.float64)
    assert torch.equal(fwht2(x), fwht(x.flatten(-2)).view_as(x))


# ---------------------------------------------------------------- 12. psnr, PSNR, SSIM, ADC
def test_psnr_flag_and_empty_image():
    x = torch.rand(1, 1, 4, 4, generator=_g())
    for q in ("no", 1, None):
        with pytest.raises(TypeError, match="psnr: expected quantize to be a bool"):
            psnr(x, x, quantize=q)
    e = torch.zeros(1, 1, 0, 4)
    with pytest.raises(ValueError, match="psnr: expected x with at least one pixel"):
        psnr(e, e)
    assert psnr(x[:0], x[:0]).shape == (0,)  # an empty batch stays fine


@pytest.mark.parametrize("kw,exc", [({"bits": -1}, ValueError), ({"bits": 8.0}, TypeError),
                                    ({"quantize": "yes"}, TypeError),
                                    ({"bits": None, "quantize": True}, ValueError),
                                    ({"max_db": 0.0}, ValueError),
                                    ({"reduction": "sum"}, ValueError)])
def test_psnr_module_checks_at_construction(kw, exc):
    with pytest.raises(exc, match="PSNR: "):
        PSNR(**kw)


@pytest.mark.parametrize("kw,exc", [({"window_size": 4}, ValueError),
                                    ({"window_size": 1}, ValueError),
                                    ({"window_size": 7.0}, TypeError),
                                    ({"data_range": -1.0}, ValueError),
                                    ({"reduction": "sum"}, ValueError)])
def test_ssim_module_checks_at_construction(kw, exc):
    with pytest.raises(exc, match="SSIM: "):
        SSIM(**kw)


@pytest.mark.parametrize("dt,bits", [(torch.float16, 12), (torch.float16, 16),
                                     (torch.bfloat16, 9), (torch.bfloat16, 12)])
def test_adc_rejects_bit_depths_half_precision_cannot_hold(dt, bits):
    taps = torch.full((1, 4, 1, 1), 100.0, dtype=dt)
    with pytest.raises(ValueError, match="adc_quantize: expected bits <= "):
        adc_quantize(taps, bits)
    with pytest.raises(ValueError, match="tof_noise: expected adc_bits <= "):
        tof_noise(taps, shot=None, adc_bits=bits)


@pytest.mark.parametrize("dt,bits", [(torch.float16, 11), (torch.bfloat16, 8),
                                     (torch.float32, 24), (torch.float32, 25),
                                     (torch.float32, 32), (torch.float64, 32)])
def test_adc_never_exceeds_full_scale(dt, bits):
    big = min(torch.finfo(dt).max, 1e300)
    taps = torch.tensor([0.0, 2.0, big, big / 2], dtype=dt).view(1, 4, 1, 1)
    out = adc_quantize(taps, bits)
    assert out.dtype == dt and float(out.max()) <= 2**bits - 1
    assert out.flatten()[1] == 2
    # the full scale is the largest value of the dtype that is <= 2^bits - 1
    top = out.max()
    above = torch.nextafter(top, torch.tensor(INF, dtype=dt))
    assert float(above) > 2**bits - 1 or float(top) == torch.finfo(dt).max


def test_adc_exact_full_scale_where_the_dtype_holds_it():
    for dt, bits in ((torch.float16, 11), (torch.bfloat16, 8), (torch.float32, 24),
                     (torch.float64, 32)):
        taps = torch.full((1, 4, 1, 1), 1e30 if dt != torch.float16 else 6e4, dtype=dt)
        assert float(adc_quantize(taps, bits).max()) == 2**bits - 1


def test_sensor_chain_unchanged_on_ordinary_input():
    depth = torch.full((1, 1, 2, 2), 2.0, dtype=torch.float64)
    p = phasor_from_depth(100.0, depth, 30e6)
    frame = cw_tof_sensor(p, shot=None, adc_bits=None, amp_threshold=1, no_photon_m=5)
    torch.testing.assert_close(frame.depth, depth)


def test_tap_amplitude_does_not_overflow_in_the_differences():
    # c1 - c2 = 6e38 overflows float32, but the amplitude (c1 - c2)/2 = 3e38 does not:
    # Eq. 8 must return it, not NaN (inf/inf inside the scaled hypot).
    taps = torch.tensor([3e38, -3e38, 0.0, 0.0]).view(1, 4, 1, 1)
    amp = tap_amplitude(taps)
    assert torch.isfinite(amp).all()
    assert amp.item() == pytest.approx(3e38, rel=1e-6)
    # an amplitude beyond float32's range is inf, as the exact value rounds to
    big = torch.tensor([3e38, -3e38, -3e38, 3e38]).view(1, 4, 1, 1)
    assert tap_amplitude(big).item() == math.inf


def test_cw_tof_sensor_refuses_intensity_below_half_the_phasor():
    # I >= |P|/2 for any sum of returns (triangle inequality); below it the Eq. 6 taps
    # B + ½Re(P e^{jτ}) go negative, which no camera measures.
    p = torch.full((1, 1, 2, 2), 100.0 + 0j)
    with pytest.raises(ValueError, match="intensity >= \\|phasor\\|/2"):
        cw_tof_sensor(p, torch.full((1, 1, 2, 2), 10.0), shot=None)
    # exactly |P|/2 (and a rounding below it) is a fully modulated return
    f = cw_tof_sensor(p, torch.full((1, 1, 2, 2), 50.0 * (1 - 1e-6)), shot=None, adc_bits=None)
    assert (f.taps >= -1e-3).all()
    f = cw_tof_sensor(p, torch.full((1, 1, 2, 2), 50.0), shot=None, adc_bits=None)
    assert f.amplitude.flatten().tolist() == [50.0] * 4


def test_integer_arguments_accept_numpy_integers_everywhere():
    """One rule for integer arguments (``check_int``, ``check_power_of_two``): a Python or
    numpy integer is an int and comes back as a Python int; a bool, a float or a numpy bool
    is not; the bound is checked after the conversion."""
    from torchtof._checks import check_int, check_power_of_two
    from torchtof.experiment import ExperimentConfig

    for v in (np.int64(5), np.uint8(5), np.int32(5), 5):
        got = check_int(v, "k", "f", lo=1, hi=8)
        assert got == 5 and type(got) is int
    for bad in (True, np.bool_(True), 5.0, np.float64(5), "5", None):
        with pytest.raises(TypeError, match="f: expected k to be an int"):
            check_int(bad, "k", "f")
    with pytest.raises(ValueError, match=r"f: expected k <= 4, got 5"):
        check_int(np.int64(5), "k", "f", hi=4)
    got = check_power_of_two(np.int64(32), "n", "f")
    assert got == 32 and type(got) is int
    with pytest.raises(ValueError, match="power of two"):
        check_power_of_two(np.int64(24), "n", "f")
    # the experiment's integer fields follow the same rule (they had their own copy)
    ExperimentConfig(n=np.int64(16), roi_px=np.int32(32), stray_seed=np.int64(3)).validate()
    with pytest.raises(TypeError, match="ExperimentConfig: expected roi_px to be an int"):
        ExperimentConfig(n=16, roi_px=32.0).validate()
    with pytest.raises(ValueError, match=r"ExperimentConfig: expected adc_bits <= 32, got 33"):
        ExperimentConfig(n=16, adc_bits=33).validate()
