"""Tests of the DMD -> sensor area-overlap map (mixed pixels) and the phasor blur."""

import math

import pytest
import torch

from torchtof.sensor import (
    CWToFSensor,
    DMDToSensor,
    area_overlap_matrix,
    blur_phasor,
    dmd_to_sensor,
)
from torchtof.sensor.functional import SPEED_OF_LIGHT, phasor_from_depth

F = 30e6


def _x(b=1, c=1, h=4, w=4, dtype=torch.complex128, seed=0):
    return torch.randn(b, c, h, w, dtype=dtype, generator=torch.Generator().manual_seed(seed))


@pytest.mark.parametrize(
    ("n_in", "n_out"), [(4, 4), (4, 8), (4, 6), (5, 3), (32, 64), (32, 45), (1, 3)]
)
def test_overlap_rows_sum_to_one(n_in, n_out):
    k = area_overlap_matrix(n_in, n_out, torch.float64)
    assert k.shape == (n_out, n_in) and bool((k >= 0).all())
    torch.testing.assert_close(k.sum(1), torch.ones(n_out, dtype=torch.float64))
    # columns: each input pixel contributes the same total area n_out/n_in
    torch.testing.assert_close(k.sum(0), torch.full((n_in,), n_out / n_in, dtype=torch.float64))


def test_overlap_known_answer_and_copy():
    expected = torch.tensor([[1.0, 0.0], [0.5, 0.5], [0.0, 1.0]])
    torch.testing.assert_close(area_overlap_matrix(2, 3), expected)
    k = area_overlap_matrix(2, 3, torch.float64)
    k.zero_()  # mutating the result must not corrupt the cache
    torch.testing.assert_close(area_overlap_matrix(2, 3), expected)


def test_integer_ratio_is_block_replication():
    x = _x(2, 1, 4, 4)
    out = dmd_to_sensor(x, (8, 12))
    ref = x.repeat_interleave(2, dim=-2).repeat_interleave(3, dim=-1)
    assert torch.equal(out, ref)


def test_non_integer_ratio_mixes_neighbours():
    x = torch.tensor([[1.0, 2.0, 3.0, 4.0]], dtype=torch.float64).view(1, 1, 1, 4)
    out = dmd_to_sensor(x, (1, 6)).flatten()
    # sensor pixel p covers [p·4/6, (p+1)·4/6): weights (1), (.5,.5), (1), (1), (.5,.5), (1)
    torch.testing.assert_close(
        out, torch.tensor([1.0, 1.5, 2.0, 3.0, 3.5, 4.0], dtype=torch.float64)
    )


def test_downsampling_is_block_average():
    x = _x(1, 2, 4, 4)
    ref = x.view(1, 2, 2, 2, 2, 2).mean(dim=(3, 5))
    torch.testing.assert_close(dmd_to_sensor(x, 2), ref)


def test_flying_pixel_depth_between_edges():
    # DMD pixels at 1.5 m and 3.0 m; 3 sensor pixels: the middle one mixes both phasors
    d = torch.tensor([1.5, 3.0], dtype=torch.float64).view(1, 1, 1, 2)
    p = phasor_from_depth(100.0, d, F)
    s = dmd_to_sensor(p, (1, 3))
    mixed = 0.5 * (p[..., 0] + p[..., 1])
    torch.testing.assert_close(s[..., 1], mixed)
    depth = CWToFSensor(shot=None, adc_bits=None)(s).depth.flatten()
    expected_mid = (mixed.angle() % (2 * math.pi)) * SPEED_OF_LIGHT / (4 * math.pi * F)
    torch.testing.assert_close(
        depth, torch.stack([d.flatten()[0], expected_mid.flatten()[0], d.flatten()[1]])
    )
    assert 1.5 < float(depth[1]) < 3.0


def test_linearity():
    x, y = _x(seed=1), _x(seed=2)
    a, b = 0.3 - 1.2j, 2.0 + 0.5j
    torch.testing.assert_close(
        dmd_to_sensor(a * x + b * y, 6), a * dmd_to_sensor(x, 6) + b * dmd_to_sensor(y, 6)
    )


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64, torch.complex64, torch.complex128])
def test_module_equals_function_dtype(dtype):
    x = _x(3, 1, 4, 4, dtype)
    x0 = x.clone()
    m = DMDToSensor(4, (6, 7))
    out = m(x)
    assert out.dtype == dtype and out.shape == (3, 1, 6, 7)
    torch.testing.assert_close(out, dmd_to_sensor(x, (6, 7)))
    torch.testing.assert_close(out, torch.cat([m(x[i : i + 1]) for i in range(3)]))
    assert torch.equal(x, x0)
    assert m.state_dict() == {}  # non-persistent buffers


def test_gradcheck():
    x = _x(1, 1, 3, 3).requires_grad_()
    assert torch.autograd.gradcheck(lambda t: dmd_to_sensor(t, (5, 4)), (x,))


def test_errors():
    with pytest.raises(ValueError, match="dmd_to_sensor: expected x of rank 4"):
        dmd_to_sensor(torch.ones(4, 4), 8)
    with pytest.raises(ValueError, match="dmd_to_sensor: expected out_hw >= 1"):
        dmd_to_sensor(torch.ones(1, 1, 4, 4), (0, 8))
    with pytest.raises(TypeError, match="dmd_to_sensor: expected out_hw to be an int"):
        dmd_to_sensor(torch.ones(1, 1, 4, 4), 8.0)
    with pytest.raises(ValueError, match=r"DMDToSensor: expected x of shape \(B, C, 4, 4\)"):
        DMDToSensor(4, 8)(torch.ones(1, 1, 5, 4))
    with pytest.raises(ValueError, match="area_overlap_matrix: expected n_in >= 1"):
        area_overlap_matrix(0, 3)
    with pytest.raises(TypeError, match="dmd_to_sensor: expected x to be a floating-point"):
        dmd_to_sensor(torch.ones(1, 1, 2, 2, dtype=torch.int64), 4)


# ---------------------------------------------------------------- blur_phasor
def test_blur_constant_unchanged_and_linear():
    p = torch.full((2, 1, 8, 8), 2.0 - 1.0j, dtype=torch.complex128)
    torch.testing.assert_close(blur_phasor(p, 1.5), p)
    x, y = _x(1, 1, 6, 6, seed=3), _x(1, 1, 6, 6, seed=4)
    torch.testing.assert_close(
        blur_phasor(x + 2j * y, 1.0), blur_phasor(x, 1.0) + 2j * blur_phasor(y, 1.0)
    )
    # real and imaginary parts blur independently
    torch.testing.assert_close(blur_phasor(x, 1.0).real, blur_phasor(x.real.contiguous(), 1.0))


@pytest.mark.parametrize("dtype", [torch.float32, torch.complex64, torch.complex128])
def test_blur_dtype_tiny_image(dtype):
    x = _x(1, 1, 2, 3, dtype)
    out = blur_phasor(x, 5.0)  # kernel clipped to the image
    assert (
        out.dtype == dtype
        and out.shape == x.shape
        and torch.isfinite(torch.view_as_real(out) if out.is_complex() else out).all()
    )


def test_blur_impulse_response_is_the_sampled_normalised_gaussian():
    # written from the kernel's arithmetic: an impulse far from the borders returns the
    # outer product g gᵀ, g_k = exp(−k²/2σ²) / Σ_j exp(−j²/2σ²), k = −⌈3σ⌉ … ⌈3σ⌉
    sigma, r = 1.3, 4
    x = torch.zeros(1, 1, 15, 15, dtype=torch.float64)
    x[..., 7, 7] = 1.0
    k = torch.arange(-r, r + 1, dtype=torch.float64)
    g = torch.exp(-k**2 / (2 * sigma**2))
    g = g / g.sum()
    want = torch.zeros_like(x)
    want[0, 0, 7 - r : 8 + r, 7 - r : 8 + r] = g[:, None] * g[None, :]
    torch.testing.assert_close(blur_phasor(x, sigma), want, rtol=0, atol=1e-15)


@pytest.mark.parametrize("shape, sigma", [((2, 3, 9, 13), 1.3), ((1, 2, 6, 6), 5.0)])
def test_blur_equals_kornia_reflect_gaussian(shape, sigma):
    # the same filter as kornia.filters.gaussian_blur2d with reflect borders (radius clipped)
    kornia = pytest.importorskip("kornia")
    x = _x(*shape, dtype=torch.float64)
    r = min(math.ceil(3 * sigma), min(shape[-2:]) - 1)
    want = kornia.filters.gaussian_blur2d(x, (2 * r + 1,) * 2, (sigma, sigma),
                                          border_type="reflect")
    torch.testing.assert_close(blur_phasor(x, sigma), want, rtol=0, atol=1e-14)


def test_blur_errors():
    with pytest.raises(ValueError, match="blur_phasor: expected sigma_px > 0"):
        blur_phasor(torch.ones(1, 1, 4, 4), 0.0)
