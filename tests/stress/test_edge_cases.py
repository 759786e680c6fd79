"""Direct checks of the numerical stress edge cases (one function per edge-case family).

The matrix (``test_matrix.py``) runs every module × dtype × edge case; these tests pin the
expected *values* where the physics or the math gives them.

=====================================  ======================================================
edge case                              expectation
=====================================  ======================================================
all pixels "no photon"                 depth exactly 5 m, amplitude 0, phase 0; depth bucket
                                       5 m × pixels; gated bucket 0 (float32 and float64)
saturated taps                         every tap at full scale: c₁ = c₂, c₃ = c₄ → no photon
phase exactly at the wrap-around       phase in [0, 2π) in every dtype; depth reads 0 or R
zero buckets                           every reconstructor: all-zero image or a clear error
half precision                         TVAL3, BP and DIP raise a TypeError naming the dtype;
                                       phasor_from_depth as well (no complex32 polar kernel)
extreme noise (SNR < 0 dB)             finite depth inside the camera's [1, 5] m, finite images
ill-conditioned patterns (κ ≈ 5e4)     A⁺ y in float32 within 1e-2 of float64
amplitude at 1e±30                     phase and depth independent of the amplitude scale
=====================================  ======================================================
"""

import math

import pytest
import torch

from torchtof.bucket import depth_bucket
from torchtof.operators import DMDSplit, Hadamard, PatternOperator
from torchtof.sensor import (
    correlation_taps,
    cw_tof_sensor,
    phasor_from_depth,
    tap_phase,
    unambiguous_range,
)
from torchtof.testing.stability import BP_FAST, DIP_FAST, illcond_patterns, scene

F32, F64 = torch.float32, torch.float64
HALF = (torch.float16, torch.bfloat16)


def _reconstructors(A, S):
    from torchtof.recon import registry

    opts = {"BasisPursuit": BP_FAST, "UnrolledTVAL3": {"pretrained": False}, "DIP": DIP_FAST}
    names = ("CGI", "TGI", "DGI", "PseudoInverse", "TVAL3", "BasisPursuit", "UnrolledTVAL3", "DIP")
    specs = {k: registry.get(k) for k in names}
    return {k: (s.module(op, **opts.get(k, {})), op)
            for k, s in specs.items() for op in [S if s.operator == "split" else A]}


@pytest.mark.parametrize("dtype", [F32, F64])
def test_all_pixels_no_photon_read_5m(dtype):
    p = torch.zeros(3, 1, 64, 64, dtype=torch.complex64 if dtype == F32 else torch.complex128)
    f = cw_tof_sensor(p, shot=None, adc_bits=None)
    assert torch.equal(f.depth, torch.full_like(f.depth, 5.0))
    assert not f.amplitude.any() and not f.phase.any()
    frames = f.depth.view(1, 3, 64, 64)
    assert torch.equal(depth_bucket(frames), torch.full((1, 1, 3), 5.0 * 64 * 64, dtype=dtype))
    assert not depth_bucket(frames, gate_m=3.0).any()


@pytest.mark.parametrize("dtype", [F32, F64])
def test_saturated_taps_read_no_photon(dtype):
    p = phasor_from_depth(100.0, torch.full((2, 1, 4, 4), 2.0, dtype=dtype), 30e6)
    f = cw_tof_sensor(p, shot=None, ambient_e=1e7, adc_bits=12)  # every tap clips at 4095 DN
    assert torch.equal(f.taps, torch.full_like(f.taps, 4095.0))
    assert torch.equal(f.depth, torch.full_like(f.depth, 5.0))


@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16, F32, F64])
def test_phase_at_the_wrap_stays_in_half_open_interval(dtype):
    # c₁ − c₂ = 4 and c₄ − c₃ ∈ {0, −tiny, −4ε}: θ = −ε + 2π rounds to 2π and must wrap to 0
    eps, tiny = torch.finfo(dtype).eps, torch.finfo(dtype).tiny
    q = torch.tensor([0.0, -tiny, -4 * eps], dtype=F64)
    taps = torch.stack([torch.full_like(q, 5.0), torch.ones_like(q), torch.zeros_like(q), q])
    theta = tap_phase(taps.to(dtype).view(1, 4, 1, 3))
    assert theta.dtype == dtype
    assert bool((theta >= 0).all()) and bool((theta.double() < 2 * math.pi).all())
    assert bool((torch.minimum(theta.double(), 2 * math.pi - theta.double()) < 1e-2).all())
    r = unambiguous_range(30e6)
    if dtype in (F32, F64):  # a return exactly at c/2f reads 0 (wrapped) or R, nothing between
        p = phasor_from_depth(100.0, torch.full((1, 1, 2, 2), r, dtype=dtype), 30e6)
        d = cw_tof_sensor(p, shot=None, adc_bits=None, min_m=0.0).depth.double()
        assert bool((torch.minimum(d, (d - r).abs()) < 1e-3).all())


@pytest.mark.parametrize("amp", [1e-30, 1e30])
def test_amplitude_scale_does_not_change_phase_or_depth(amp):
    depth = 1.0 + 3.9 * torch.rand(1, 1, 4, 4, generator=torch.Generator().manual_seed(0))
    ref = cw_tof_sensor(phasor_from_depth(100.0, depth, 30e6), shot=None, adc_bits=None)
    f = cw_tof_sensor(phasor_from_depth(amp, depth, 30e6), shot=None, adc_bits=None)
    assert bool(torch.isfinite(f.amplitude).all())
    torch.testing.assert_close(f.depth, ref.depth, rtol=0, atol=1e-4)
    torch.testing.assert_close(f.amplitude / amp, ref.amplitude / 100.0, rtol=1e-5, atol=0)


def test_zero_buckets_give_zero_image_or_clear_error():
    A = Hadamard(8, sr=0.5)
    S = DMDSplit(A)
    for name, (rec, op) in _reconstructors(A, S).items():
        y = torch.zeros(1, 1, op.m)
        try:
            x = rec(y).detach()
        except ValueError as e:
            assert str(e).split(":")[0] in ("fit_dip", "dip"), (name, e)
            continue
        assert x.shape == (1, 1, 8, 8) and x.dtype == F32, name
        assert not x.any(), f"{name}: zero buckets gave a non-zero image"


@pytest.mark.parametrize("dtype", HALF)
def test_half_precision_solvers_raise_clear_type_error(dtype):
    from torchtof.recon.bp import basis_pursuit
    from torchtof.recon.tval3 import tval3

    A = Hadamard(8, sr=0.5)
    y = A(scene(8)).to(dtype)
    name = str(dtype)
    with pytest.raises(TypeError, match=rf"^tval3: .*{name}"):
        tval3(y, A, return_result=True)
    with pytest.raises(TypeError, match=rf"^basis_pursuit: .*{name}"):
        basis_pursuit(y, A, return_result=True)


@pytest.mark.parametrize("dtype", HALF)
def test_half_precision_dip_raises_clear_type_error(dtype):
    from torchtof.recon.dip import dip

    A = Hadamard(8, sr=0.5)
    with pytest.raises(TypeError, match=rf"^(fit_dip|dip): .*{dtype}"):
        dip(A(scene(8)).to(dtype), A, max_iter=2)


@pytest.mark.filterwarnings("ignore:ComplexHalf support is experimental")
@pytest.mark.parametrize("dtype", HALF)
def test_half_precision_phasor_raises_clear_type_error(dtype):
    with pytest.raises(TypeError, match=rf"^phasor_from_depth: .*{dtype}"):
        phasor_from_depth(1.0, torch.ones(1, 1, 2, 2, dtype=dtype), 30e6)


def test_extreme_noise_stays_finite_and_in_range():
    g = torch.Generator().manual_seed(0)
    depth = torch.full((64, 1, 8, 8), 2.0)
    p = phasor_from_depth(4.0, depth, 30e6)  # 2 e⁻ correlation amplitude vs 20 e⁻ read noise
    f = cw_tof_sensor(p, ambient_e=50.0, read_noise_e=20.0, generator=g)
    signal = 2.0
    noise = float((f.taps - correlation_taps(p, 50.0 + 0.5 * p.abs())).std())
    assert 20 * math.log10(signal / noise) < 0  # SNR below 0 dB
    assert bool(torch.isfinite(f.depth).all()) and f.depth.min() >= 1 and f.depth.max() <= 5
    A = Hadamard(8, sr=0.5)
    y = A(scene(8))
    y = y + 2 * y.norm() / y.numel() ** 0.5 * torch.randn(y.shape, generator=g, dtype=F64)
    from torchtof.recon.tval3 import tval3

    assert bool(torch.isfinite(tval3(y, A)).all())


def test_ill_conditioned_pinv_float32_matches_float64():
    A = PatternOperator(illcond_patterns())
    s = torch.linalg.svdvals(A.matrix())
    assert 1e4 < float(s[0] / s[-1]) < 1e6  # κ(A) ≈ 5e4
    y = A(torch.rand(1, 1, 8, 8, generator=torch.Generator().manual_seed(5), dtype=F64))
    ref, out = A.pinv(y), A.pinv(y.float())
    assert float((out.double() - ref).norm() / ref.norm()) < 1e-2
