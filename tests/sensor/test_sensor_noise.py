"""Tests of the ToF pixel noise: shot (Poisson / Gaussian), read noise, full well, ADC."""

import pytest
import torch

from torchtof.sensor.noise import ToFNoise, adc_quantize, read_noise, shot_noise, tof_noise

DTYPES = [torch.float32, torch.float64]
MEANS = torch.tensor([10.0, 50.0, 100.0, 400.0])


def _gen(seed=0):
    return torch.Generator().manual_seed(seed)


def _const_taps(h=64, w=64, dtype=torch.float64):
    return MEANS.to(dtype).view(1, 4, 1, 1).expand(1, 4, h, w).clone()


@pytest.mark.parametrize("mode", ["poisson", "gaussian"])
def test_shot_noise_statistics(mode):
    x = _const_taps()
    y = shot_noise(x, mode, _gen(1))
    mean = y.mean(dim=(0, 2, 3))
    var = y.var(dim=(0, 2, 3))
    # 4096 samples per tap: mean within ~4 sigma, variance within 10 %
    assert torch.allclose(mean, MEANS.double(), atol=float(4 * (MEANS.max() / 4096) ** 0.5))
    torch.testing.assert_close(var, MEANS.double(), rtol=0.1, atol=0)
    if mode == "poisson":
        assert torch.equal(y, y.round()) and bool((y >= 0).all())


@pytest.mark.parametrize("mode", ["poisson", "gaussian"])
def test_shot_noise_seeded_reproducible(mode):
    x = _const_taps(4, 4)
    assert torch.equal(shot_noise(x, mode, _gen(7)), shot_noise(x, mode, _gen(7)))
    assert not torch.equal(shot_noise(x, mode, _gen(7)), shot_noise(x, mode, _gen(8)))


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("mode", ["poisson", "gaussian"])
def test_shot_noise_dtype_shape_noinplace(dtype, mode):
    for b in (1, 3):
        x = torch.full((b, 4, 2, 3), 20.0, dtype=dtype)
        x0 = x.clone()
        y = shot_noise(x, mode, _gen())
        assert y.dtype == dtype and y.shape == (b, 4, 2, 3)
        assert torch.equal(x, x0)


def test_shot_noise_zero_and_negative_taps():
    x = torch.tensor([0.0, -3.0, 0.0, 0.0]).view(1, 4, 1, 1)
    assert shot_noise(x, "poisson", _gen()).flatten().tolist() == [0.0, 0.0, 0.0, 0.0]
    assert shot_noise(x, "gaussian", _gen()).flatten().tolist() == [0.0, 0.0, 0.0, 0.0]


def test_poisson_straight_through_gradient():
    x = torch.full((1, 4, 2, 2), 30.0, dtype=torch.float64, requires_grad=True)
    shot_noise(x, "poisson", _gen()).sum().backward()
    assert bool((x.grad == 1).all())


def test_gaussian_shot_gradcheck_and_zero_gradient():
    x = (torch.rand(1, 4, 2, 2, dtype=torch.float64, generator=_gen(2)) * 50 + 5).requires_grad_()
    assert torch.autograd.gradcheck(lambda t: shot_noise(t, "gaussian", _gen(3)), (x,))
    z = torch.zeros(1, 4, 1, 1, dtype=torch.float64, requires_grad=True)
    shot_noise(z, "gaussian", _gen()).sum().backward()
    assert torch.isfinite(z.grad).all()


def test_read_noise_statistics_and_identity():
    x = torch.full((1, 4, 64, 64), 100.0, dtype=torch.float64)
    y = read_noise(x, 3.0, _gen(4))
    assert abs(float(y.mean()) - 100.0) < 0.1
    assert abs(float(y.std()) - 3.0) < 0.1
    assert torch.equal(read_noise(x, 0.0, _gen()), x)


def test_adc_saturation_and_rounding():
    x = torch.tensor([-5.0, 0.4, 0.6, 2.5, 4094.6, 4095.0, 5000.0, 1e9]).view(1, 4, 1, 2)
    out = adc_quantize(x, bits=12).flatten().tolist()
    assert out == [0.0, 0.0, 1.0, 2.0, 4095.0, 4095.0, 4095.0, 4095.0]
    # gain 10 e-/DN, 8 bits: 123 e- -> 12 DN; 3000 e- -> 255 (saturated)
    x = torch.tensor([0.0, 123.0, 127.0, 3000.0]).view(1, 4, 1, 1)
    assert adc_quantize(x, bits=8, gain_e_per_dn=10.0).flatten().tolist() == [
        0.0,
        12.0,
        13.0,
        255.0,
    ]


def test_adc_straight_through_gradient():
    x = torch.tensor([-1.0, 12.3, 40.6, 1e6], dtype=torch.float64).view(1, 4, 1, 1).requires_grad_()
    adc_quantize(x, bits=12, gain_e_per_dn=2.0).sum().backward()
    assert x.grad.flatten().tolist() == [0.0, 0.5, 0.5, 0.0]


@pytest.mark.parametrize("dtype", DTYPES)
def test_adc_dtype(dtype):
    assert adc_quantize(torch.ones(3, 4, 2, 2, dtype=dtype) * 7.7).dtype == dtype


def test_tof_noise_noise_free_identity():
    x = torch.rand(3, 4, 5, 5, generator=_gen()) * 100
    assert torch.equal(tof_noise(x, shot=None, read_noise_e=0.0, adc_bits=None), x)


def test_tof_noise_full_well_and_order():
    x = torch.tensor([10.0, 500.0, 2000.0, 9000.0]).view(1, 4, 1, 1)
    out = tof_noise(x, shot=None, full_well_e=1000.0, adc_bits=12, gain_e_per_dn=0.5)
    assert out.flatten().tolist() == [20.0, 1000.0, 2000.0, 2000.0]  # well clips before ADC


def test_tof_noise_saturated_pixel_keeps_the_read_noise():
    # The well clips the collected charge; the readout adds its noise afterwards (EMVA 1288
    # linear model). A pixel far above the well W therefore reads W + σ_r·N(0, 1): mean W,
    # variance σ_r² (clipping after the read noise would give variance 0).
    w, sigma_r, n = 1000.0, 5.0, 200_000
    x = torch.full((n, 4, 1, 1), 50_000.0, dtype=torch.float64)
    out = tof_noise(x, shot="poisson", read_noise_e=sigma_r, full_well_e=w, adc_bits=None,
                    generator=_gen(3))
    se_mean = sigma_r / (4 * n) ** 0.5
    assert abs(out.mean().item() - w) < 5 * se_mean
    var = out.var().item()
    assert abs(var - sigma_r**2) < 5 * sigma_r**2 * (2 / (4 * n - 1)) ** 0.5
    # below the well nothing is clipped: Poisson(c) + σ_r² has variance c + σ_r²
    c = 400.0
    out = tof_noise(torch.full((n, 4, 1, 1), c, dtype=torch.float64), shot="poisson",
                    read_noise_e=sigma_r, full_well_e=w, adc_bits=None, generator=_gen(4))
    assert abs(out.var().item() - (c + sigma_r**2)) < 5 * (c + sigma_r**2) * (2 / (4 * n)) ** 0.5


def test_tof_noise_seeded_and_module_equals_function():
    x = _const_taps(8, 8, torch.float32)
    kw = dict(shot="poisson", read_noise_e=2.0, full_well_e=None, adc_bits=12, gain_e_per_dn=1.0)
    a = tof_noise(x, **kw, generator=_gen(5))
    b = ToFNoise(**kw)(x, _gen(5))
    assert torch.equal(a, b) and a.dtype == torch.float32
    assert torch.equal(a, a.round())  # ADC output is integer DN


def test_noise_errors():
    x = torch.ones(1, 4, 2, 2)
    with pytest.raises(ValueError, match="shot_noise: expected mode in"):
        shot_noise(x, "laplace")
    with pytest.raises(ValueError, match=r"shot_noise: expected taps of shape \(\*, 4"):
        shot_noise(torch.ones(1, 1, 2, 2))
    with pytest.raises(ValueError, match="shot_noise: expected taps of rank 4"):
        shot_noise(torch.ones(4, 2, 2))
    with pytest.raises(TypeError, match="shot_noise: expected taps to be a real"):
        shot_noise(x.to(torch.complex64))
    with pytest.raises(ValueError, match="read_noise: expected sigma_e >= 0"):
        read_noise(x, -1.0)
    with pytest.raises(ValueError, match=r"adc_quantize: expected bits in \[1, 32\]"):
        adc_quantize(x, bits=0)
    with pytest.raises(TypeError, match="adc_quantize: expected bits to be an int"):
        adc_quantize(x, bits=12.0)
    with pytest.raises(ValueError, match="adc_quantize: expected gain_e_per_dn > 0"):
        adc_quantize(x, gain_e_per_dn=0.0)
    with pytest.raises(ValueError, match="tof_noise: expected shot in"):
        tof_noise(x, shot="gauss")
    with pytest.raises(ValueError, match="ToFNoise: expected full_well_e > 0"):
        ToFNoise(full_well_e=0.0)
    with pytest.raises(ValueError, match="shot_noise: taps contains non-finite"):
        shot_noise(torch.full((1, 4, 1, 1), float("nan")))


def test_shot_noise_huge_means_are_counts_not_overflow():
    # torch.poisson wraps to −9.2e18 near 1e19; a Poisson count has mean c and variance c,
    # so at c = 1e20 the draws must sit at 1e20 ± a few 1e10, never negative.
    g = torch.Generator().manual_seed(0)
    taps = torch.full((2500, 4, 1, 1), 1e20, dtype=torch.float64)
    c = shot_noise(taps, generator=g)
    assert (c > 0).all()
    z = (c - 1e20) / 1e10
    assert abs(float(z.mean())) < 5 / 100  # 10000 draws: standard error of the mean 0.01
    assert abs(float(z.std()) - 1.0) < 0.05
    assert torch.equal(c, c.round())  # counts
    # float32 at 1e20 (the probe's case): finite and positive
    c32 = shot_noise(torch.full((1, 4, 2, 2), 1e20), generator=g)
    assert torch.isfinite(c32).all() and (c32 > 0).all()
    torch.testing.assert_close(c32, torch.full_like(c32, 1e20), rtol=1e-6, atol=0)


def test_shot_noise_small_means_keep_the_poisson_stream():
    # below the switch the draws are exactly torch.poisson's (seeded runs unchanged); in a
    # tensor that also holds a huge mean the small pixels stay non-negative integer counts
    taps = torch.rand(3, 4, 5, 5, generator=torch.Generator().manual_seed(1)) * 100
    got = shot_noise(taps, generator=torch.Generator().manual_seed(2))
    want = torch.poisson(taps, generator=torch.Generator().manual_seed(2))
    assert torch.equal(got, want)
    mixed = taps.clone()
    mixed[0, 0, 0, 0] = 1e25
    got = shot_noise(mixed, generator=torch.Generator().manual_seed(2))
    small = mixed < 1e12
    assert torch.equal(got[small], got[small].round()) and (got[small] >= 0).all()
    assert abs(float(got[small].mean() - mixed[small].mean())) < 2.0  # 299 draws, σ ≈ 7/√299
    assert got[0, 0, 0, 0] > 0


def test_noise_settings_take_numpy_scalars_and_generators_are_checked():
    import numpy as np
    t = torch.full((1, 4, 1, 1), 50.0)
    g = torch.Generator().manual_seed(0)
    want = tof_noise(t, adc_bits=12, read_noise_e=2.0, generator=g)
    g = torch.Generator().manual_seed(0)
    got = tof_noise(t, adc_bits=np.int64(12), read_noise_e=np.float32(2.0), generator=g)
    assert torch.equal(got, want)
    for f, kw in ((tof_noise, {}), (tof_noise, {"shot": None}), (read_noise, {"sigma_e": 1.0})):
        with pytest.raises(TypeError, match=rf"{f.__name__}: expected generator to be a torch"):
            f(t, generator=5, **kw)
