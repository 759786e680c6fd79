"""Tests of the CW-ToF correlation model (paper Eqs. 1, 6, 7, 8) and the camera rules (§2.2)."""

import math

import pytest
import torch

from torchtof.sensor.functional import (
    SPEED_OF_LIGHT,
    camera_rules,
    correlation_taps,
    phase_to_depth,
    phasor_from_depth,
    tap_amplitude,
    tap_phase,
    unambiguous_range,
)

F = 30e6
R = SPEED_OF_LIGHT / (2 * F)
DTYPES = [torch.float32, torch.float64]
CDTYPE = {torch.float32: torch.complex64, torch.float64: torch.complex128}


def _phasor(b=1, h=3, w=4, dtype=torch.complex128, seed=0):
    g = torch.Generator().manual_seed(seed)
    return torch.randn(b, 1, h, w, dtype=dtype, generator=g)


# ---------------------------------------------------------------- range, phasor, depth
def test_unambiguous_range_30mhz():
    assert unambiguous_range(30e6) == SPEED_OF_LIGHT / 60e6
    assert unambiguous_range(30e6) == pytest.approx(4.997, abs=1e-3)


@pytest.mark.parametrize("f", [0.0, -30e6, float("nan"), float("inf")])
def test_unambiguous_range_bad_freq(f):
    with pytest.raises(ValueError, match="unambiguous_range: expected freq_hz"):
        unambiguous_range(f)


@pytest.mark.parametrize("dtype", DTYPES)
def test_phasor_from_depth_dtype_and_phase(dtype):
    d = torch.tensor([0.0, 1.0, 2.5], dtype=dtype).view(1, 1, 1, 3)
    p = phasor_from_depth(3.0, d, F)
    assert p.dtype == CDTYPE[dtype] and p.shape == d.shape
    expected = torch.polar(torch.full_like(d, 3.0), 4 * math.pi * F * d / SPEED_OF_LIGHT)
    torch.testing.assert_close(p, expected)
    # per-pixel amplitude broadcasts
    p2 = phasor_from_depth(torch.tensor([1.0, 2.0, 3.0], dtype=dtype), d, F)
    torch.testing.assert_close(p2.abs().flatten(), torch.tensor([1.0, 2.0, 3.0], dtype=dtype))


def test_phasor_from_depth_errors():
    with pytest.raises(TypeError, match="phasor_from_depth: expected depth_m to be a real"):
        phasor_from_depth(1.0, torch.zeros(1, 1, 2, 2, dtype=torch.complex64), F)
    with pytest.raises(ValueError, match="phasor_from_depth: expected freq_hz"):
        phasor_from_depth(1.0, torch.zeros(1, 1, 2, 2), -F)


def test_phase_to_depth_known_values():
    ph = torch.tensor([0.0, math.pi, 2 * math.pi], dtype=torch.float64)
    torch.testing.assert_close(
        phase_to_depth(ph, F), torch.tensor([0.0, R / 2, R], dtype=torch.float64)
    )
    with pytest.raises(ValueError, match="phase_to_depth: expected freq_hz"):
        phase_to_depth(ph, 0.0)
    with pytest.raises(TypeError, match="phase_to_depth: expected phase to be a real"):
        phase_to_depth(ph.to(torch.complex128), F)


# ---------------------------------------------------------------- taps
def test_correlation_taps_known_answer_fig1():
    # P = 2 (θ = 0), B = 1: c = B + |P|/2 cos(τ), τ = 0, π, π/2, 3π/2
    p = torch.full((1, 1, 1, 1), 2.0 + 0j)
    assert correlation_taps(p, 1.0).flatten().tolist() == [2.0, 0.0, 1.0, 1.0]
    # P = 2j (θ = π/2): cos(π/2 + τ) = −sin τ -> (0, 0, −1, 1)·|P|/2
    p = torch.full((1, 1, 1, 1), 2.0j)
    assert correlation_taps(p, 1.0).flatten().tolist() == [1.0, 1.0, 0.0, 2.0]
    # text order: τ = 0, π/2, π, 3π/2
    assert correlation_taps(p, 1.0, order="text").flatten().tolist() == [1.0, 0.0, 1.0, 2.0]


def test_correlation_taps_matches_cosine_formula():
    p = _phasor(2, 3, 3)
    taps = correlation_taps(p, 5.0)
    theta, a = p.angle(), p.abs()
    for k, tau in enumerate([0.0, math.pi, math.pi / 2, 3 * math.pi / 2]):
        torch.testing.assert_close(taps[:, k : k + 1], 5.0 + 0.5 * a * torch.cos(theta + tau))


@pytest.mark.parametrize("b", [1, 3])
def test_correlation_taps_shape_and_tensor_offset(b):
    p = _phasor(b, 2, 5)
    off = torch.rand(b, 1, 2, 5, dtype=torch.float64)
    taps = correlation_taps(p, off)
    assert taps.shape == (b, 4, 2, 5)
    torch.testing.assert_close(taps.mean(dim=1, keepdim=True), off)  # cosines cancel


def test_correlation_taps_linear_in_phasor():
    p1, p2 = _phasor(seed=1), _phasor(seed=2)
    torch.testing.assert_close(
        correlation_taps(p1 + p2, 0.0), correlation_taps(p1, 0.0) + correlation_taps(p2, 0.0)
    )


def test_correlation_taps_batched_equals_singles_and_no_inplace():
    p = _phasor(3)
    p0 = p.clone()
    out = correlation_taps(p, 1.0)
    torch.testing.assert_close(
        out, torch.cat([correlation_taps(p[i : i + 1], 1.0) for i in range(3)])
    )
    assert torch.equal(p, p0)


@pytest.mark.parametrize("dtype", DTYPES)
def test_correlation_taps_dtype(dtype):
    assert correlation_taps(_phasor(dtype=CDTYPE[dtype]), 1.0).dtype == dtype


def test_correlation_taps_errors():
    with pytest.raises(TypeError, match="correlation_taps: expected phasor to be a complex tensor"):
        correlation_taps(torch.ones(1, 1, 2, 2), 0.0)
    with pytest.raises(TypeError, match="correlation_taps: expected phasor to be a torch.Tensor"):
        correlation_taps([1.0], 0.0)
    with pytest.raises(ValueError, match=r"correlation_taps: expected phasor of rank 4"):
        correlation_taps(torch.ones(1, 2, 2, dtype=torch.complex64), 0.0)
    with pytest.raises(ValueError, match=r"correlation_taps: expected phasor of shape \(\*, 1"):
        correlation_taps(torch.ones(1, 2, 2, 2, dtype=torch.complex64), 0.0)
    with pytest.raises(ValueError, match="correlation_taps: expected order in"):
        correlation_taps(torch.ones(1, 1, 2, 2, dtype=torch.complex64), 0.0, order="abcd")
    with pytest.raises(ValueError, match="non-finite"):
        correlation_taps(torch.full((1, 1, 2, 2), complex("nan+0j")), 0.0)


def test_correlation_taps_gradcheck():
    p = _phasor(1, 2, 2).requires_grad_()
    off = torch.rand(1, 1, 2, 2, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda p, o: correlation_taps(p, o), (p, off))


# ---------------------------------------------------------------- Eq. 7 / Eq. 8 round trip
def test_round_trip_whole_range_float64():
    depth = torch.linspace(0, R, 257, dtype=torch.float64)[:-1]  # [0, R)
    amp = torch.tensor([1e-3, 0.5, 1.0, 37.0, 1e4], dtype=torch.float64)
    d = depth.view(1, 1, -1, 1).expand(1, 1, -1, amp.numel())
    a = amp.view(1, 1, 1, -1).expand_as(d)
    taps = correlation_taps(phasor_from_depth(a, d, F), offset=3.0)
    phase = tap_phase(taps)
    torch.testing.assert_close(phase, 4 * math.pi * F * d / SPEED_OF_LIGHT, rtol=0, atol=1e-6)
    torch.testing.assert_close(tap_amplitude(taps), a / 2, rtol=0, atol=1e-6)
    torch.testing.assert_close(phase_to_depth(phase, F), d, rtol=0, atol=1e-6)


def test_zero_phase_is_exactly_zero():
    taps = correlation_taps(phasor_from_depth(5.0, torch.zeros(1, 1, 1, 1), F), 2.5)
    assert tap_phase(taps).item() == 0.0


def test_phase_in_half_open_interval():
    # θ slightly below 0 (i.e. just below 2π) must never return 2π itself
    p = torch.polar(
        torch.ones(1, 1, 1, 3, dtype=torch.float64),
        torch.tensor([-1e-17, -1e-12, 2 * math.pi - 1e-15], dtype=torch.float64).view(1, 1, 1, 3),
    )
    ph = tap_phase(correlation_taps(p, 0.0))  # no offset to absorb the tiny phase
    assert bool(((ph >= 0) & (ph < 2 * math.pi)).all())


def test_wrap_around_beyond_range():
    d = torch.tensor([R * (1 + 1e-6), R + 0.01, R + 1.2, 2 * R + 0.3], dtype=torch.float64)
    taps = correlation_taps(phasor_from_depth(1.0, d.view(1, 1, 1, 4), F), 1.0)
    got = phase_to_depth(tap_phase(taps), F).flatten()
    torch.testing.assert_close(
        got, torch.tensor([R * 1e-6, 0.01, 1.2, 0.3], dtype=torch.float64), rtol=0, atol=1e-8
    )
    assert got[0] < 1e-5  # "just beyond the range" reads ≈ 0


def test_text_order_degenerates():
    theta = torch.linspace(0, 2 * math.pi, 50, dtype=torch.float64)[:-1].view(1, 1, 1, -1)
    p = torch.polar(torch.full_like(theta, 2.0), theta)
    taps = correlation_taps(p, 3.0, order="text")
    c1, c2, c3, c4 = taps.unbind(1)
    torch.testing.assert_close(c4 - c3, c1 - c2)  # ratio of Eq. 7 is always 1
    ph = tap_phase(taps)
    near = torch.minimum((ph - math.pi / 4).abs(), (ph - 5 * math.pi / 4).abs())
    assert float(near.max()) < 1e-9
    # the fig1 order recovers θ on the same phasors
    torch.testing.assert_close(tap_phase(correlation_taps(p, 3.0)), theta)


def test_amplitude_is_half_phasor_amplitude():
    p = torch.full((1, 1, 1, 1), 3.0 + 4.0j, dtype=torch.complex128)
    assert tap_amplitude(correlation_taps(p, 5.0)).item() == pytest.approx(2.5)


def test_phase_amplitude_errors():
    for fn in (tap_phase, tap_amplitude):
        name = fn.__name__
        with pytest.raises(ValueError, match=rf"{name}: expected taps of shape \(\*, 4"):
            fn(torch.ones(1, 3, 2, 2))
        with pytest.raises(ValueError, match=rf"{name}: expected taps of rank 4"):
            fn(torch.ones(4, 2, 2))
        with pytest.raises(TypeError, match=rf"{name}: expected taps to be a real"):
            fn(torch.ones(1, 4, 2, 2, dtype=torch.complex64))


def test_zero_amplitude_gradients_are_finite():
    taps = torch.full((1, 4, 2, 2), 7.0, dtype=torch.float64, requires_grad=True)
    (tap_phase(taps).sum() + tap_amplitude(taps).sum()).backward()
    assert torch.isfinite(taps.grad).all() and bool((taps.grad == 0).all())
    p = torch.zeros(1, 1, 2, 2, dtype=torch.complex128, requires_grad=True)
    t = correlation_taps(p, 1.0)
    (tap_phase(t).sum() + tap_amplitude(t).sum()).backward()
    assert torch.isfinite(torch.view_as_real(p.grad)).all()


@pytest.mark.parametrize("dtype", DTYPES)
def test_phase_amplitude_dtype(dtype):
    taps = correlation_taps(_phasor(dtype=CDTYPE[dtype]), 2.0)
    assert tap_phase(taps).dtype == dtype and tap_amplitude(taps).dtype == dtype
    assert tap_phase(taps).shape == (1, 1, 3, 4)


def test_phase_amplitude_gradcheck():
    g = torch.Generator().manual_seed(3)
    taps = torch.rand(1, 4, 2, 3, dtype=torch.float64, generator=g).requires_grad_()
    # keep atan2 away from its branch cut (negative real axis) for finite differences
    with torch.no_grad():
        taps[:, 0] += 1.0
    assert torch.autograd.gradcheck(tap_phase, (taps,))
    assert torch.autograd.gradcheck(tap_amplitude, (taps,))


# ---------------------------------------------------------------- camera rules (§2.2)
def _rules_in(values, amps=None, dtype=torch.float64):
    d = torch.tensor(values, dtype=dtype).view(1, 1, 1, -1)
    a = torch.ones_like(d) if amps is None else torch.tensor(amps, dtype=dtype).view_as(d)
    return d, a


def test_rule_clip_low():
    d, a = _rules_in([-1.0, 0.0, 0.999, 1.0, 1.3])
    assert camera_rules(d, a).flatten().tolist() == [1.0, 1.0, 1.0, 1.0, 1.3]


def test_rule_clip_high():
    d, a = _rules_in([4.9, 5.0, 5.2, 9.0])
    assert camera_rules(d, a).flatten().tolist() == [4.9, 5.0, 5.0, 5.0]


def test_rule_no_photon():
    d, a = _rules_in([2.0, 2.0, 2.0, 0.2], amps=[0.0, 1.0, 3.0, 0.0])
    assert camera_rules(d, a).flatten().tolist() == [5.0, 2.0, 2.0, 5.0]
    # raised threshold: amplitude <= threshold is dark
    assert camera_rules(d, a, amp_threshold=1.0).flatten().tolist() == [5.0, 5.0, 2.0, 5.0]
    assert camera_rules(d, a, no_photon_m=4.0).flatten().tolist() == [4.0, 2.0, 2.0, 4.0]


def test_rule_step_quarter_metre():
    d, a = _rules_in([1.0, 1.12, 1.13, 2.1, 3.374, 3.376, 4.99, 0.2, 7.0])
    out = camera_rules(d, a, step_m=0.25).flatten().tolist()
    assert out == [1.0, 1.0, 1.25, 2.0, 3.25, 3.5, 5.0, 1.0, 5.0]
    # a step that does not divide [1, 5] never rounds past max_m
    d, a = _rules_in([4.99])
    assert camera_rules(d, a, step_m=1.5).item() == 5.0


def test_rules_gradient_straight_through():
    d, a = _rules_in([0.5, 2.1, 3.0, 6.0], amps=[1.0, 1.0, 0.0, 1.0])
    d.requires_grad_()
    camera_rules(d, a, step_m=0.25).sum().backward()
    assert d.grad.flatten().tolist() == [0.0, 1.0, 0.0, 0.0]


def test_rules_gradcheck():
    d = torch.tensor([1.5, 2.2, 4.1, 3.3], dtype=torch.float64).view(1, 1, 2, 2).requires_grad_()
    a = torch.ones_like(d)
    assert torch.autograd.gradcheck(lambda x: camera_rules(x, a), (d,))


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("b", [1, 3])
def test_rules_dtype_shape_batch(dtype, b):
    g = torch.Generator().manual_seed(0)
    d = 6 * torch.rand(b, 1, 3, 3, generator=g).to(dtype)
    a = torch.rand(b, 1, 3, 3, generator=g).to(dtype)
    d0 = d.clone()
    out = camera_rules(d, a, amp_threshold=0.3, step_m=0.25)
    assert out.dtype == dtype and out.shape == (b, 1, 3, 3)
    singles = [
        camera_rules(d[i : i + 1], a[i : i + 1], amp_threshold=0.3, step_m=0.25) for i in range(b)
    ]
    torch.testing.assert_close(out, torch.cat(singles))
    assert torch.equal(d, d0)


def test_rules_errors():
    d, a = _rules_in([1.0, 2.0])
    with pytest.raises(ValueError, match="camera_rules: expected max_m > min_m"):
        camera_rules(d, a, min_m=5.0, max_m=1.0)
    with pytest.raises(ValueError, match="camera_rules: expected step_m > 0"):
        camera_rules(d, a, step_m=0.0)
    with pytest.raises(ValueError, match="camera_rules: expected amplitude of shape"):
        camera_rules(d, a[..., :1])
    with pytest.raises(ValueError, match=r"camera_rules: expected depth of shape \(\*, 1"):
        camera_rules(torch.ones(1, 2, 1, 2), torch.ones(1, 2, 1, 2))
    with pytest.raises(TypeError, match="camera_rules: expected amp_threshold to be a number"):
        camera_rules(d, a, amp_threshold=torch.tensor(1.0))


def test_phasor_from_depth_refuses_non_finite():
    nan = torch.full((1, 1, 2, 2), float("nan"))
    with pytest.raises(ValueError, match="phasor_from_depth: depth_m contains non-finite"):
        phasor_from_depth(1.0, nan, F)
    with pytest.raises(ValueError, match="phasor_from_depth: amplitude contains non-finite"):
        phasor_from_depth(nan, torch.ones(1, 1, 2, 2), F)
    with pytest.raises(ValueError, match="phasor_from_depth: expected a finite amplitude"):
        phasor_from_depth(float("inf"), torch.ones(1, 1, 2, 2), F)
    with pytest.raises(TypeError, match="phasor_from_depth: expected amplitude to be"):
        phasor_from_depth("1", torch.ones(1, 1, 2, 2), F)


@pytest.mark.parametrize("amp", [-100.0, torch.full((1, 1, 1, 1), -1.0)])
def test_negative_amplitude_is_refused(amp):
    # a negative magnitude is a phase shift of π: c/(4f) = 2.5 m of depth at 30 MHz, silently
    with pytest.raises(ValueError, match=r"phasor_from_depth: expected amplitude >= 0"):
        phasor_from_depth(amp, torch.full((1, 1, 1, 1), 1.5), 30e6)
