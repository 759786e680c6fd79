"""Edge cases of depth-resolved GI, the scattering models and the spatial mixing, each checked
against the physics or a closed form (amplitude mask, no-photon depth, Eq. 15 before the
camera rules, channel-rotation invariance, Eq. 7's gradient at tiny amplitudes)."""

import math

import pytest
import torch

from torchtof.bucket import depth_gate, intensity_bucket
from torchtof.experiment import ExperimentConfig, PaperExperiment, simulate_frames
from torchtof.operators import Hadamard
from torchtof.recon import TGI, DepthResolved, JointTV, PseudoInverse
from torchtof.recon.depth import (
    _channel_noise_sigma,
    depth_resolved,
    dual_frequency_depth,
    iq_buckets,
    joint_tv,
)
from torchtof.scenes import Scene
from torchtof.sensor import (
    SPEED_OF_LIGHT,
    ScatteringMedium,
    add_multipath,
    area_overlap_matrix,
    blur_phasor,
    correlation_taps,
    dust_map,
    phase_to_depth,
    phasor_from_depth,
    scatter_depth,
    scatter_phasor,
    tap_amplitude,
    tap_phase,
)

F = 30e6
R = SPEED_OF_LIGHT / (2 * F)  # unambiguous range c/(2f), Eq. 1 at θ = 2π


def _square_scene(n, amp, depth, dtype=torch.float32):
    """Tap images (1, 4, n, n) of an ``amp``-bright square (rows/cols n/4 … 3n/4) at ``depth``
    on a dark background (Eq. 6, Fig. 1 order, 50 e⁻ offset)."""
    a = torch.zeros(1, 1, n, n, dtype=dtype)
    a[..., n // 4: 3 * n // 4, n // 4: 3 * n // 4] = amp
    z = torch.full((1, 1, n, n), depth, dtype=dtype)
    return a, correlation_taps(phasor_from_depth(a, z, F), offset=50.0)


def _rot(v, phi):
    """Rotate the channel pair (I, Q) of ``v`` by ``phi``: ``P → e^{jφ}P``."""
    c, s = math.cos(phi), math.sin(phi)
    return torch.stack((c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1]), 1)


# -- 1. the amplitude mask at the reconstructor's scale ----------------------------------------


def test_tgi_mask_keeps_the_object_as_the_pseudo_inverse_does():
    """TGI is 1/M of the pseudo-inverse's scale; the mask's noise term must scale with it
    (it kept 0 % of the object before)."""
    torch.manual_seed(0)
    A = Hadamard(16, sr=0.25)
    amp, taps = _square_scene(16, 100.0, 2.0)
    y = A(taps)
    y = y + 2.0 * torch.randn_like(y)
    obj = amp > 0
    for rec in (PseudoInverse(A), TGI(A)):
        res = depth_resolved(y, rec)
        assert float(res.mask[obj].float().mean()) == 1.0, type(rec).__name__
        assert abs(float(res.depth[0, 0, 8, 8]) - 2.0) < 0.05


def test_tgi_pixel_noise_matches_the_closed_form():
    """Pure noise σ on orthonormal rows: TGI = Aᵀ(y − ⟨y⟩)/M has mean pixel variance
    σ²(M − 1)/(N M²) (‖A‖_F² = M, ‖Aᵀ1‖² = M)."""
    g = torch.Generator().manual_seed(1)
    A = Hadamard(16, sr=0.25)
    m, n_pix = A.m, 256
    y = torch.randn(400, 1, m, generator=g, dtype=torch.float64)
    var = float(TGI(A)(y).pow(2).mean())
    assert abs(var / ((m - 1) / (n_pix * m * m)) - 1) < 0.03


@pytest.mark.parametrize("rec", ["pinv", "tgi"])
def test_empty_scene_passes_the_mask_with_the_rayleigh_rate(rec):
    """An empty pixel's amplitude is Rayleigh: P(A > 3σ_pix) = exp(−9/2) ≈ 1.1 %, for TGI too
    (before the fix TGI passed 0 %, its threshold 64× too high)."""
    g = torch.Generator().manual_seed(2)
    A = Hadamard(16, sr=0.25)
    y = 3.0 * torch.randn(200, 4, A.m, generator=g, dtype=torch.float64)
    module = PseudoInverse(A) if rec == "pinv" else TGI(A)
    rate = float(depth_resolved(y, module).mask.double().mean())
    assert 0.005 < rate < 0.025, rate  # exp(-4.5) = 0.0111


# -- 2. I/Q input without a noise level ----------------------------------------------------------


def _noisy_square_iq(sigma: float):
    """The square scene's I/Q buckets at n = 16, SR 25 %, with Gaussian noise of std sigma on
    the taps (seed 0)."""
    torch.manual_seed(0)
    A = Hadamard(16, sr=0.25)
    _, taps = _square_scene(16, 100.0, 1.5, torch.float64)
    y = A(taps)
    return A, iq_buckets(y + sigma * torch.randn_like(y))


def test_iq_input_without_noise_sigma_lets_jointtv_estimate_it():
    """With no measured noise the reconstructor estimates its own (a zero σ made JointTV fit
    the noise exactly: residual 1.8e-7). A TV-L2 fit leaves a residual of the order of the
    noise, ‖n‖/‖y‖ ≈ σ√M/‖y‖."""
    A, iq = _noisy_square_iq(6.0)
    res = depth_resolved(iq, JointTV(A))
    torch.testing.assert_close(res.images, JointTV(A)(iq), rtol=0, atol=0)
    noise_rel = 6.0 * math.sqrt(2) * math.sqrt(A.m) / iq.norm(dim=-1)
    assert bool((res.residual > 0.25 * noise_rel).all()), (res.residual, noise_rel)


# -- 3. global-phase invariance with mu="auto" ----------------------------------------------------


def test_joint_tv_auto_commutes_with_a_global_phase():
    A, iq = _noisy_square_iq(2.0)
    x = joint_tv(iq, A, adaptive=False, n_iter=100)
    for phi in (0.3, 0.7, 1.2, 2.0):
        xr = joint_tv(_rot(iq, phi), A, adaptive=False, n_iter=100)
        err = float((_rot(x, phi) - xr).abs().max() / xr.abs().max())
        assert err < 1e-6, (phi, err)


@pytest.mark.parametrize("c", [2, 3, 4])
def test_channel_noise_sigma_is_rotation_invariant_and_unbiased_on_white_noise(c):
    """White noise σ on C channels: ‖y_i‖ = σχ_C, so the chi quantile recovers σ; an
    orthogonal mix of the channels leaves the estimate unchanged."""
    g = torch.Generator().manual_seed(c)
    y = 0.5 * torch.randn(2, c, 65536, generator=g, dtype=torch.float64)
    s = _channel_noise_sigma(y)
    assert bool(((s / 0.5 - 1).abs() < 0.02).all()), s
    q, _ = torch.linalg.qr(torch.randn(c, c, generator=g, dtype=torch.float64))
    torch.testing.assert_close(_channel_noise_sigma(torch.einsum("dc,bcm->bdm", q, y)), s,
                               rtol=1e-12, atol=0)


# -- 4. Eq. 15 before the camera rules ----------------------------------------------------------


def _clean_cfg(**over):
    """Noise-free set-up: no shot/read noise, no ADC, no multipath, stray light or PSF."""
    kw = dict(n=8, roi_px=16, srs=(0.25,), shot=None, read_noise_e=0.0, adc_bits=None,
              multipath_strength=0.0, stray_e=0.0, psf_sigma_px=0.0, ambient_e=100.0)
    kw.update(over)
    return ExperimentConfig(**kw).validate()


def test_depth_scattering_model_stays_in_the_camera_output_domain():
    """D' = αD + Dˢ (the paper, Eq. 15) on the Eq. 1 depth, then clip to [1, 5] m, 0.25 m
    steps and 5 m for pixels without photons: a lit pixel at 2 m reads
    round4(0.6·2 + 0.4·dust)/4, a dark one 5 m, which the 3 m gate removes."""
    cfg = _clean_cfg(scattering=True, scattering_model="depth", alpha=0.6, depth_s_m=0.4)
    n, p = cfg.n, cfg.roi_px
    refl = torch.zeros(1, 1, n, n)
    refl[..., : n // 2, :] = 1.0  # top half lit, bottom half dark
    scene = Scene(refl, torch.full((1, 1, n, n), 2.0))
    dust = dust_map(p, cfg.dust_sigma_px, torch.Generator().manual_seed(cfg.dust_seed))
    fr = simulate_frames(scene, torch.ones(1, n, n), cfg, torch.Generator().manual_seed(0),
                         dust)
    d = fr.depth[0, 0]
    lit = torch.zeros(p, p, dtype=torch.bool)
    lit[: p // 2] = True
    expect = (4 * (0.6 * 2.0 + 0.4 * dust[0, 0])).round() / 4
    torch.testing.assert_close(d[lit], expect.clamp(1.0, 5.0)[lit], rtol=0, atol=1e-6)
    assert bool((d[~lit] == 5.0).all())  # no photon: the camera's 5 m, not 0.6·5 = 3 m
    assert bool((depth_gate(fr.depth, 3.0)[0, 0][~lit] == 0).all())
    k = (d - cfg.min_m) / cfg.step_m
    assert bool(((k - k.round()).abs() < 1e-5).all()) and bool((d >= 1).all())


def test_depth_scattering_model_leaves_the_light_as_in_air():
    """Eq. 15 is a model of the depth map, not of the light: taps and intensity buckets are
    those of air (same noise draws), the depth buckets are not."""
    kw = dict(n=8, roi_px=16, srs=(0.25,))
    air = PaperExperiment(0.25, **kw).run(seed=0)
    dep = PaperExperiment(0.25, scattering=True, scattering_model="depth", **kw).run(seed=0)
    for k in ("taps", "intensity"):
        assert torch.equal(air.buckets[k], dep.buckets[k])
    assert not torch.equal(air.buckets["depth"], dep.buckets["depth"])
    assert float(dep.raw_tof.min()) >= 1.0 and float(dep.raw_tof.max()) <= 5.0


# -- 5. masked pixels report the no-photon depth ---------------------------------------------


def test_masked_pixels_report_the_no_photon_depth_on_request():
    """Two dark rows: round-off phase gives them arbitrary depths (4.24 and 0.26 m were
    seen); the mask marks them. By default every pixel keeps its Eq. 1 depth (the mask is
    the caller's to apply); with no_photon_m the masked pixels report it and the exported
    forward carries the mask; lit pixels keep the exact Eq. 1 depth of their phase."""
    A = Hadamard(8, sr=1.0)
    z = torch.full((1, 1, 8, 8), 1.5, dtype=torch.float64)
    z[..., 4:] = 3.5
    amp = torch.full((1, 1, 8, 8), 100.0, dtype=torch.float64)
    amp[..., :2, :] = 0.0
    y = A(correlation_taps(phasor_from_depth(amp, z, F), offset=50.0))
    res = depth_resolved(y, PseudoInverse(A))
    dark = amp == 0
    assert torch.equal(res.mask, ~dark)
    torch.testing.assert_close(res.depth[~dark], z[~dark], rtol=0, atol=1e-9)
    assert torch.equal(res.depth, phase_to_depth(res.phase, F))  # no fill by default
    assert torch.equal(DepthResolved(PseudoInverse(A), F)(y), res.depth)
    zero = depth_resolved(y, PseudoInverse(A), no_photon_m=0.0)
    assert bool((zero.depth[dark] == 0.0).all())
    five = depth_resolved(y, PseudoInverse(A), no_photon_m=5.0)
    assert bool((five.depth[dark] == 5.0).all())
    assert torch.equal(five.depth[~dark], res.depth[~dark])
    net = DepthResolved(PseudoInverse(A), F, no_photon_m=5.0)
    assert torch.equal(net(y), five.depth)
    assert torch.equal(net(y) == 5.0, ~res.mask)
    assert bool((depth_gate(five.depth, 3.0)[dark] == 0).all())  # the camera's 5 m: gated out


def test_no_photon_m_is_checked():
    A = Hadamard(8, sr=0.5)
    y = torch.rand(1, 4, A.m)
    with pytest.raises(ValueError, match="depth_resolved: expected no_photon_m"):
        depth_resolved(y, PseudoInverse(A), no_photon_m=-1.0)
    with pytest.raises(TypeError, match="DepthResolved: expected no_photon_m"):
        DepthResolved(PseudoInverse(A), no_photon_m="5")


# -- 6. the Eq. 8 intensity bucket is not linear in the light ----------------------------------


def test_intensity_bucket_of_eq8_amplitudes_falls_when_an_opposite_return_adds():
    """½|P_s + P_o| with the object's return half a range behind the stray one: 1000 e⁻ of
    stray light and 400 e⁻ more from the object give ½|1000 − 400| = 300 < 500."""
    stray = phasor_from_depth(1000.0, torch.full((1, 1, 1, 1), 2.0 + R / 2, dtype=torch.float64),
                              F)
    obj = phasor_from_depth(400.0, torch.full((1, 1, 1, 1), 2.0, dtype=torch.float64), F)
    off = intensity_bucket(tap_amplitude(correlation_taps(stray, offset=3000.0)))
    on = intensity_bucket(tap_amplitude(correlation_taps(stray + obj, offset=3000.0)))
    assert abs(float(off) - 500.0) < 1e-9 and abs(float(on) - 300.0) < 1e-9


# -- 7. the experiment's configuration -----------------------------------------------------------


def test_zero_multipath_spread_is_an_unspread_copy():
    """multipath_sigma_px = 0: each pixel sees P(1 + s e^{j4πfΔ/c}); noise-free, every lit
    pixel reads the depth of that phasor sum (Eq. 1 of its phase)."""
    cfg = _clean_cfg(multipath_strength=0.35, multipath_extra_m=1.6, multipath_sigma_px=0.0,
                     step_m=None)
    n = cfg.n
    scene = Scene(torch.ones(1, 1, n, n), torch.full((1, 1, n, n), 2.0))
    fr = simulate_frames(scene, torch.ones(1, n, n), cfg, torch.Generator().manual_seed(0))
    k = 4 * math.pi * F / SPEED_OF_LIGHT
    p = complex(math.cos(k * 2.0), math.sin(k * 2.0)) * (
        1 + 0.35 * complex(math.cos(k * 1.6), math.sin(k * 1.6)))
    want = (math.atan2(p.imag, p.real) % (2 * math.pi)) / k
    torch.testing.assert_close(fr.depth, torch.full_like(fr.depth, want), rtol=0, atol=1e-5)


@pytest.mark.parametrize("over, msg", [
    (dict(stray_sigma_px=0.0), "expected stray_sigma_px > 0"),
    (dict(dust_sigma_px=0.0), "expected dust_sigma_px > 0"),
    (dict(stray_far_m=1.0), "expected stray_far_m >= stray_near_m"),
    (dict(multipath_sigma_px=-1.0), "expected multipath_sigma_px >= 0"),
])
def test_experiment_config_names_the_field(over, msg):
    # the call the user made is named: PaperExperiment, or the config's own validate()
    with pytest.raises(ValueError, match=f"^PaperExperiment: {msg}"):
        PaperExperiment(0.25, n=8, roi_px=16, srs=(0.25,), **over)
    from torchtof.experiment import ExperimentConfig

    with pytest.raises(ValueError, match=f"^ExperimentConfig: {msg}"):
        ExperimentConfig(n=8, roi_px=16, srs=(0.25,), **over).validate()


# -- 8, 9. mixing ----------------------------------------------------------------------------


def test_area_overlap_matrix_refuses_an_integer_dtype():
    with pytest.raises(TypeError, match="area_overlap_matrix: expected dtype"):
        area_overlap_matrix(2, 3, dtype=torch.int64)
    torch.testing.assert_close(area_overlap_matrix(2, 3, dtype=torch.float64),
                               torch.tensor([[1.0, 0.0], [0.5, 0.5], [0.0, 1.0]],
                                            dtype=torch.float64))


def test_blur_radius_is_clipped_per_axis():
    """A 2×64 image blurred with σ = 6 along its rows gets the full ⌈3σ⌉ = 18 kernel
    (the sampled Gaussian, normalised), not one clipped to the 2 rows."""
    x = torch.zeros(1, 1, 2, 64, dtype=torch.float64)
    x[..., 32] = 1.0  # a line along H: the column blur leaves it as is
    w = torch.tensor([math.exp(-0.5 * (k / 6.0) ** 2) for k in range(-18, 19)],
                     dtype=torch.float64)
    want = torch.zeros(64, dtype=torch.float64)
    want[14:51] = w / w.sum()
    out = blur_phasor(x, 6.0)
    torch.testing.assert_close(out[0, 0, 0], want, rtol=0, atol=1e-15)
    torch.testing.assert_close(out[0, 0, 1], want, rtol=0, atol=1e-15)
    t = blur_phasor(x.transpose(-1, -2), 6.0)
    torch.testing.assert_close(t[0, 0, :, 0], want, rtol=0, atol=1e-15)


# -- 10. multipath ---------------------------------------------------------------------------


def test_multipath_maps_follow_the_phasor_device_and_blur_is_checked():
    p = torch.ones(1, 1, 4, 4, dtype=torch.complex64, device="meta")
    assert add_multipath(p, torch.full((1, 1, 4, 4), 0.3), 1.0).device.type == "meta"
    assert add_multipath(p, 0.3, torch.full((1, 1, 4, 4), 1.0)).device.type == "meta"
    q = torch.ones(1, 1, 4, 4, dtype=torch.complex64)
    with pytest.raises(ValueError, match="add_multipath: expected blur_sigma > 0"):
        add_multipath(q, 0.3, 1.0, blur_sigma=-1.0)
    # a map of Δ = c/(4f) (a quarter range: phase π) and s = 1 cancels a uniform field
    out = add_multipath(q, torch.ones(1, 1, 4, 4, dtype=torch.float64),
                        torch.full((1, 1, 4, 4), SPEED_OF_LIGHT / (4 * F), dtype=torch.float64))
    assert float(out.abs().max()) < 1e-6


# -- 11. scattering, dual frequency, Eq. 7's gradient -------------------------------------------


def test_scattering_terms_are_non_negative_for_numbers_and_tensors_alike():
    d = torch.ones(1, 1, 2, 2)
    with pytest.raises(ValueError, match="scatter_depth: expected depth_s >= 0"):
        scatter_depth(d, 0.5, -torch.ones(1, 1, 2, 2))
    p = torch.ones(1, 1, 4, 4, dtype=torch.complex64)
    with pytest.raises(ValueError, match="scatter_phasor: expected backscatter >= 0"):
        scatter_phasor(p, 0.5, None, -torch.ones(1, 1, 4, 4))
    with pytest.raises(ValueError, match="ScatteringMedium: depth_s contains non-finite"):
        ScatteringMedium(0.5, depth_s=torch.full((1, 1, 64, 64), float("nan")))
    with pytest.raises(ValueError, match="ScatteringMedium: expected depth_s >= 0"):
        ScatteringMedium(0.5, depth_s=-torch.ones(1, 1, 64, 64))
    assert scatter_depth(torch.full((1, 1, 2, 2), 2.0), 0.5, 1.0).unique().tolist() == [2.0]


@pytest.mark.parametrize("seed, exc", [(1.7, TypeError), ("a", TypeError), (True, TypeError),
                                       (2**64, ValueError)])
def test_scattering_medium_seed_is_checked(seed, exc):
    with pytest.raises(exc, match="ScatteringMedium: expected seed"):
        ScatteringMedium(0.5, size=(4, 4), seed=seed)


def test_scattering_medium_names_its_own_dust_sigma():
    with pytest.raises(ValueError, match="ScatteringMedium: expected dust_sigma_px > 0"):
        ScatteringMedium(0.5, size=(4, 4), dust_sigma_px=-1.0)


def test_scattering_medium_seed_gives_the_dust_map_of_that_seed():
    m = ScatteringMedium(0.5, size=(8, 8), seed=3, dust_sigma_px=2.0)
    want = dust_map((8, 8), 2.0, torch.Generator().manual_seed(3), dtype=torch.float64)
    assert torch.equal(m.dust, want)


def test_dual_frequency_depth_checks_the_phase_range():
    ok = torch.tensor([0.5, 2.0])
    with pytest.raises(ValueError, match=r"dual_frequency_depth: expected phase_1 in \[0, 2π\)"):
        dual_frequency_depth(torch.tensor([7.0, 1.0]), ok, 30e6, 20e6)
    with pytest.raises(ValueError, match=r"dual_frequency_depth: expected phase_2 in \[0, 2π\)"):
        dual_frequency_depth(ok, torch.tensor([-1.0, 1.0]), 30e6, 20e6)
    # float32 remainder can round up to float32(2π) > 2π: that phase is 0 (a depth of 0 m)
    top = torch.remainder(torch.tensor([-1e-9]), 2 * math.pi)
    assert float(top) >= 2 * math.pi
    d = dual_frequency_depth(top, top, 30e6, 20e6)
    assert float(d) < 1e-3 or float(d) > SPEED_OF_LIGHT / 2e7 - 1e-3


@pytest.mark.parametrize("v", [1e-37, 3e-30, 1e-22, 3e-20, 1e-19, 1.0, 1e20, 1e30])
def test_tap_phase_gradient_is_the_closed_form_at_tiny_and_huge_amplitudes(v):
    """θ = atan2(c₄ − c₃, c₁ − c₂) at taps (v, 0, 0, v): θ = π/4 and ∂θ/∂c = (−1, 1, −1, 1)/(2v)
    (∂θ/∂q = i/r², ∂θ/∂i = −q/r²), finite wherever 1/(2v) is (it was inf/NaN below 1e-19 in
    float32, where r² underflows)."""
    taps = torch.tensor([v, 0.0, 0.0, v], dtype=torch.float32).view(1, 4, 1, 1).requires_grad_()
    th = tap_phase(taps)
    assert abs(float(th.detach()) - math.pi / 4) < 1e-6
    (g,) = torch.autograd.grad(th.sum(), taps)
    want = torch.tensor([-1.0, 1.0, -1.0, 1.0], dtype=torch.float64) / (2 * v)
    torch.testing.assert_close(g.flatten().double(), want, rtol=1e-5, atol=0)


def test_tap_phase_equals_atan2_bit_for_bit_on_ordinary_taps():
    g = torch.Generator().manual_seed(0)
    for dt in (torch.float32, torch.float64):
        taps = 3000.0 + 500.0 * torch.randn(4, 4, 32, 32, generator=g, dtype=dt)
        theta = torch.atan2(taps[:, 3] - taps[:, 2], taps[:, 0] - taps[:, 1]).unsqueeze(1)
        theta = torch.where(theta < 0, theta + 2 * math.pi, theta)
        theta = torch.where(theta >= 2 * math.pi, theta - 2 * math.pi, theta)
        assert torch.equal(tap_phase(taps), theta)


def test_dual_frequency_result_x_is_the_unwrapped_depth():
    """``x`` is the reconstructor contract's name for the output: the unwrapped depth, not
    the first frequency's wrapped one (a return at 6 m reads 1.0 m at 30 MHz alone)."""
    from torchtof.recon import DualFrequencyDepth

    A = Hadamard(8, sr=1.0)
    z = torch.full((1, 1, 8, 8), 6.0, dtype=torch.float64)
    ys = [A(correlation_taps(phasor_from_depth(100.0, z, f), offset=50.0)) for f in (30e6, 20e6)]
    res = DualFrequencyDepth(PseudoInverse(A), 30e6, 20e6).solve(*ys)
    torch.testing.assert_close(res.depth, z, rtol=0, atol=1e-9)
    assert torch.equal(res.x, res.depth)
