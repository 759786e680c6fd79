"""Tests of two-path multipath interference (the returns add as phasors)."""

import math

import pytest
import torch

from torchtof.sensor import CWToFSensor, Multipath, add_multipath
from torchtof.sensor.functional import SPEED_OF_LIGHT, phasor_from_depth

F = 30e6


def _p(b=1, h=4, w=4, dtype=torch.complex128, seed=0):
    return torch.randn(b, 1, h, w, dtype=dtype, generator=torch.Generator().manual_seed(seed))


def test_strength_zero_is_identity():
    p = _p(2)
    assert torch.equal(add_multipath(p, 0.0, 1.3, F), p)
    assert torch.equal(add_multipath(p, 0.0, 1.3, F, blur_sigma=1.0), p)
    assert torch.equal(Multipath(0.0, 0.7)(p), p)


def test_two_path_known_answer():
    d = torch.full((1, 1, 2, 2), 2.0, dtype=torch.float64)
    direct = phasor_from_depth(100.0, d, F)
    s, extra = 0.4, 0.8
    out = add_multipath(direct, s, extra, F)
    expected = direct + phasor_from_depth(100.0 * s, d + extra, F)
    torch.testing.assert_close(out, expected)
    # the camera reads the depth of arg(P1 + P2)
    depth = CWToFSensor(shot=None, adc_bits=None, min_m=0.0, max_m=10.0)(out).depth
    mixed = (expected.angle() % (2 * math.pi)) * SPEED_OF_LIGHT / (4 * math.pi * F)
    torch.testing.assert_close(depth, mixed)
    assert bool(((depth > 2.0) & (depth < 2.8)).all())  # biased towards the stronger return


def test_blur_spreads_indirect_light():
    p = torch.zeros(1, 1, 7, 7, dtype=torch.complex128)
    p[0, 0, 3, 3] = 10.0
    out = add_multipath(p, 0.5, 0.3, F, blur_sigma=1.0)
    assert out[0, 0, 3, 4].abs() > 0 and out[0, 0, 0, 0].abs() < out[0, 0, 3, 4].abs()
    const = torch.full((1, 1, 6, 6), 1.0 + 0.0j, dtype=torch.complex128)
    torch.testing.assert_close(
        add_multipath(const, 0.5, 0.3, F, 1.0), add_multipath(const, 0.5, 0.3, F)
    )


def test_tensor_strength_map():
    p = _p()
    strength = torch.zeros(1, 1, 4, 4, dtype=torch.float64)
    strength[..., :2] = 0.3
    out = add_multipath(p, strength, 0.5, F)
    torch.testing.assert_close(out[..., 2:], p[..., 2:])
    torch.testing.assert_close(out[..., :2], add_multipath(p, 0.3, 0.5, F)[..., :2])


@pytest.mark.parametrize("dtype", [torch.complex64, torch.complex128])
@pytest.mark.parametrize("b", [1, 3])
def test_module_equals_function_dtype_shapes(dtype, b):
    p = _p(b, 5, 5, dtype)
    p0 = p.clone()
    out = Multipath(0.3, 0.5, F, blur_sigma=1.0)(p)
    assert out.dtype == dtype and out.shape == (b, 1, 5, 5)
    torch.testing.assert_close(out, add_multipath(p, 0.3, 0.5, F, 1.0))
    singles = [add_multipath(p[i : i + 1], 0.3, 0.5, F, 1.0) for i in range(b)]
    torch.testing.assert_close(out, torch.cat(singles))
    assert torch.equal(p, p0)


def test_gradcheck():
    p = _p(1, 3, 3).requires_grad_()
    s = torch.rand(1, 1, 3, 3, dtype=torch.float64, requires_grad=True)
    e = torch.tensor(0.6, dtype=torch.float64, requires_grad=True)
    fn = lambda p, s, e: add_multipath(p, s, e, F, 1.0)  # noqa: E731
    assert torch.autograd.gradcheck(fn, (p, s, e), fast_mode=True)
    assert torch.autograd.gradcheck(lambda p: add_multipath(p, 0.4, 0.6, F), (p,))


def test_errors():
    p = _p()
    with pytest.raises(TypeError, match="add_multipath: expected phasor to be a complex tensor"):
        add_multipath(p.real, 0.1, 0.5, F)
    with pytest.raises(ValueError, match="add_multipath: expected phasor of rank 4"):
        add_multipath(p[0], 0.1, 0.5, F)
    with pytest.raises(ValueError, match="add_multipath: expected strength >= 0"):
        add_multipath(p, -0.1, 0.5, F)
    with pytest.raises(ValueError, match="add_multipath: expected freq_hz > 0"):
        add_multipath(p, 0.1, 0.5, -F)
    with pytest.raises(ValueError, match="Multipath: expected blur_sigma > 0"):
        Multipath(0.1, 0.5, F, blur_sigma=0.0)
    with pytest.raises(TypeError, match="add_multipath: expected strength to be a real"):
        add_multipath(p, p, 0.5, F)
