"""Tests of the scattering medium: depth domain (paper Eq. 15) and phasor domain."""

import math

import pytest
import torch

from torchtof.sensor import (
    CWToFSensor,
    ScatteringMedium,
    dust_map,
    scatter_depth,
    scatter_phasor,
    scattering_medium,
)
from torchtof.sensor.functional import phasor_from_depth

F = 30e6


def _d(b=1, h=4, w=4, dtype=torch.float64, seed=0):
    return 1 + 4 * torch.rand(
        b, 1, h, w, generator=torch.Generator().manual_seed(seed), dtype=dtype
    )


def _p(b=1, h=4, w=4, dtype=torch.complex128, seed=0):
    return torch.randn(b, 1, h, w, dtype=dtype, generator=torch.Generator().manual_seed(seed))


@pytest.mark.parametrize("alpha", [0.0, -0.1, 1.5, float("nan")])
def test_alpha_out_of_range_raises(alpha):
    with pytest.raises(ValueError, match=r"scatter_depth: expected alpha in \(0.0, 1.0\]"):
        scatter_depth(_d(), alpha)
    with pytest.raises(ValueError, match=r"scatter_phasor: expected alpha in \(0.0, 1.0\]"):
        scatter_phasor(_p(), alpha)
    with pytest.raises(ValueError, match="ScatteringMedium: expected alpha"):
        ScatteringMedium(alpha)


def test_identity_at_alpha_one():
    d, p = _d(2), _p(2)
    assert torch.equal(scatter_depth(d, 1.0, 0.0), d)
    assert torch.equal(scatter_phasor(p, 1.0), p)
    assert torch.equal(ScatteringMedium(1.0, "depth", depth_s=0.0, size=4)(d), d)
    assert torch.equal(ScatteringMedium(1.0, "phasor", blur_sigma=None, size=4)(p), p)


def test_eq15_known_answer():
    d = _d(2)
    ds = torch.linspace(0, 1, 16, dtype=torch.float64).view(1, 1, 4, 4)
    torch.testing.assert_close(scatter_depth(d, 0.6, ds), 0.6 * d + ds)
    torch.testing.assert_close(scatter_depth(d, 0.6, 0.7), 0.6 * d + 0.7)


def test_phasor_known_answer_backscatter_depth():
    sheet = 0.5
    p = torch.zeros(1, 1, 3, 3, dtype=torch.complex128)
    p[..., 1, 1] = phasor_from_depth(200.0, torch.tensor(2.0, dtype=torch.float64), F)
    out = scatter_phasor(p, 0.6, None, 10.0, sheet, F)
    bs = phasor_from_depth(10.0, torch.tensor(sheet, dtype=torch.float64), F)
    torch.testing.assert_close(out, 0.6 * p + bs)
    # a pixel with only backscatter reads the sheet's distance (before the 1 m clip)
    depth = CWToFSensor(shot=None, adc_bits=None, min_m=0.0, max_m=10.0)(out).depth
    assert float(depth[0, 0, 0, 0]) == pytest.approx(sheet, abs=1e-9)
    assert 0.5 < float(depth[0, 0, 1, 1]) < 2.0  # the object pixel is pulled towards the sheet


def test_forward_scatter_blur():
    p = torch.zeros(1, 1, 9, 9, dtype=torch.complex128)
    p[0, 0, 4, 4] = 1.0
    out = scatter_phasor(p, 1.0, blur_sigma=1.0)
    assert float(out[0, 0, 4, 4].abs()) < 1.0 and float(out[0, 0, 4, 5].abs()) > 0
    torch.testing.assert_close(
        out.sum(), p.sum(), atol=1e-6, rtol=0
    )  # energy kept away from borders


def test_dust_map_properties():
    m1 = dust_map((16, 12), 2.0, torch.Generator().manual_seed(0), dtype=torch.float64)
    m2 = dust_map((16, 12), 2.0, torch.Generator().manual_seed(0), dtype=torch.float64)
    m3 = dust_map((16, 12), 2.0, torch.Generator().manual_seed(1), dtype=torch.float64)
    assert m1.shape == (1, 1, 16, 12) and torch.equal(m1, m2) and not torch.equal(m1, m3)
    assert float(m1.min()) == 0.0 and float(m1.max()) == 1.0
    # smooth: neighbour differences far below those of min-max scaled white noise (~0.25)
    assert float((m1[..., 1:] - m1[..., :-1]).abs().mean()) < 0.1
    assert dust_map(4).dtype == torch.get_default_dtype()
    assert torch.equal(dust_map(1), torch.zeros(1, 1, 1, 1))


def test_medium_dust_fixed_at_construction():
    a, b = ScatteringMedium(0.6, size=(8, 8), seed=3), ScatteringMedium(0.6, size=(8, 8), seed=3)
    d = _d(1, 8, 8)
    assert torch.equal(a(d), b(d)) and torch.equal(a(d), a(d))
    torch.testing.assert_close(a(d), 0.6 * d + 1.0 * a.dust)
    assert not torch.equal(a(d), ScatteringMedium(0.6, size=(8, 8), seed=4)(d))


@pytest.mark.parametrize("b", [1, 3])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_module_equals_function_depth(b, dtype):
    d = _d(b, 6, 6, dtype)
    d0 = d.clone()
    m = ScatteringMedium(0.6, "depth", dust_m=2.0, size=6, seed=1)
    out = m(d)
    assert out.dtype == dtype and out.shape == (b, 1, 6, 6)
    ds = 2.0 * m.dust.to(dtype)
    torch.testing.assert_close(out, scattering_medium(d, 0.6, "depth", ds))
    torch.testing.assert_close(out, torch.cat([m(d[i : i + 1]) for i in range(b)]))
    assert torch.equal(d, d0)


@pytest.mark.parametrize("b", [1, 3])
@pytest.mark.parametrize("dtype", [torch.complex64, torch.complex128])
def test_module_equals_function_phasor(b, dtype):
    p = _p(b, 6, 6, dtype)
    m = ScatteringMedium(0.5, "phasor", size=6, blur_sigma=1.0, backscatter_e=3.0, sheet_m=0.4)
    out = m(p)
    assert out.dtype == dtype and out.shape == (b, 1, 6, 6)
    bs = 3.0 * m.dust.to(p.real.dtype)
    torch.testing.assert_close(out, scattering_medium(p, 0.5, "phasor", 0.0, 1.0, bs, 0.4, F))
    torch.testing.assert_close(out, torch.cat([m(p[i : i + 1]) for i in range(b)]))


def test_medium_tensor_depth_s():
    ds = torch.full((1, 1, 4, 4), 0.25)
    m = ScatteringMedium(0.5, depth_s=ds, size=4)
    ds.fill_(9.0)  # the module keeps its own copy
    torch.testing.assert_close(m(torch.full((2, 1, 4, 4), 2.0)), torch.full((2, 1, 4, 4), 1.25))


def test_gradcheck():
    d = _d(1, 3, 3).requires_grad_()
    ds = torch.rand(1, 1, 3, 3, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda d, s: scatter_depth(d, 0.6, s), (d, ds))
    p = _p(1, 3, 3).requires_grad_()
    b = torch.rand(1, 1, 3, 3, dtype=torch.float64, requires_grad=True)
    fn = lambda p, b: scatter_phasor(p, 0.7, 1.0, b, 0.5, F)  # noqa: E731
    assert torch.autograd.gradcheck(fn, (p, b), fast_mode=True)


def test_errors():
    with pytest.raises(ValueError, match="scatter_depth: expected depth_s broadcastable"):
        scatter_depth(_d(1, 4, 4), 0.6, torch.ones(1, 1, 3, 3, dtype=torch.float64))
    with pytest.raises(ValueError, match="scatter_depth: expected depth of rank 4"):
        scatter_depth(torch.ones(4, 4), 0.6)
    with pytest.raises(TypeError, match="scatter_depth: expected depth to be a real"):
        scatter_depth(_p(), 0.6)
    with pytest.raises(TypeError, match="scatter_phasor: expected phasor to be a complex"):
        scatter_phasor(_d(), 0.6)
    with pytest.raises(ValueError, match="scatter_phasor: expected freq_hz > 0"):
        scatter_phasor(_p(), 0.6, freq_hz=-1.0)
    with pytest.raises(ValueError, match="scattering_medium: expected mode in"):
        scattering_medium(_d(), 0.6, mode="fog")
    with pytest.raises(ValueError, match="ScatteringMedium: expected mode in"):
        ScatteringMedium(0.6, mode="fog")
    with pytest.raises(ValueError, match=r"ScatteringMedium: expected x of spatial size \(8, 8\)"):
        ScatteringMedium(0.6, size=8)(_d(1, 4, 4))
    with pytest.raises(ValueError, match="dust_map: expected sigma_px > 0"):
        dust_map(4, 0.0)


def test_scattering_lowers_depth_contrast():
    # object at 2 m on a dark (5 m) background: Eq. 15 with alpha < 1 shrinks the contrast
    d = torch.full((1, 1, 8, 8), 5.0, dtype=torch.float64)
    d[..., 2:6, 2:6] = 2.0
    out = scatter_depth(d, 0.6, 0.5)
    assert math.isclose(float(out.max() - out.min()), 0.6 * 3.0)


def test_dust_map_refuses_an_integer_dtype():
    from torchtof.sensor import dust_map
    with pytest.raises(TypeError, match=r"dust_map: expected dtype"):
        dust_map(8, dtype=torch.int64)
