"""Tests of the CW-ToF sensor (paper §2.1-2.2): noise-free recovery, camera rules, noise."""

import math

import pytest
import torch

from torchtof.sensor import CWToFSensor, ToFFrame, cw_tof_sensor
from torchtof.sensor.functional import SPEED_OF_LIGHT, phasor_from_depth

F = 30e6
R = SPEED_OF_LIGHT / (2 * F)
CLEAN = dict(shot=None, read_noise_e=0.0, adc_bits=None)
OPEN = dict(min_m=0.0, max_m=10.0)  # camera rules out of the way


def _scene(b=1, h=4, w=5, dtype=torch.float64, seed=0):
    g = torch.Generator().manual_seed(seed)
    d = (1.2 + 3.5 * torch.rand(b, 1, h, w, generator=g, dtype=torch.float64)).to(dtype)
    a = (50 + 100 * torch.rand(b, 1, h, w, generator=g, dtype=torch.float64)).to(dtype)
    return phasor_from_depth(a, d, F), a, d


def test_noise_free_recovers_whole_range_float64():
    depth = torch.linspace(0, R, 129, dtype=torch.float64)[:-1]
    amp = torch.tensor([1e-2, 1.0, 80.0, 3e3], dtype=torch.float64)
    d = depth.view(1, 1, -1, 1).expand(1, 1, -1, 4)
    a = amp.view(1, 1, 1, -1).expand_as(d)
    frame = cw_tof_sensor(phasor_from_depth(a, d, F), freq_hz=F, ambient_e=10.0, **CLEAN, **OPEN)
    assert isinstance(frame, ToFFrame)
    torch.testing.assert_close(frame.phase, 4 * math.pi * F * d / SPEED_OF_LIGHT, rtol=0, atol=1e-6)
    torch.testing.assert_close(frame.amplitude, a / 2, rtol=0, atol=1e-6)
    torch.testing.assert_close(frame.depth, d, rtol=0, atol=1e-6)


def test_taps_layout_and_offset():
    p = torch.full((1, 1, 1, 1), 4.0j, dtype=torch.complex128)  # θ = π/2, |P| = 4
    frame = cw_tof_sensor(p, ambient_e=1.0, **CLEAN)
    # offset = ambient + |P|/2 = 3; fig1 order (0, π, π/2, 3π/2): 2·(cos) -> (0, 0, -2, 2)
    assert frame.taps.flatten().tolist() == [3.0, 3.0, 1.0, 5.0]
    intensity = torch.full((1, 1, 1, 1), 10.0, dtype=torch.float64)
    frame = cw_tof_sensor(p, intensity, ambient_e=1.0, **CLEAN)
    assert frame.taps.flatten().tolist() == [11.0, 11.0, 9.0, 13.0]
    assert frame.phase.item() == pytest.approx(math.pi / 2)


def test_camera_rules_applied():
    f = 20e6  # range 7.49 m, so a depth beyond 5 m exists
    d = torch.tensor([0.4, 2.1, 6.0, 3.0], dtype=torch.float64).view(1, 1, 1, 4)
    a = torch.tensor([100.0, 100.0, 100.0, 0.0], dtype=torch.float64).view_as(d)
    frame = cw_tof_sensor(phasor_from_depth(a, d, f), freq_hz=f, step_m=0.25, **CLEAN)
    assert frame.depth.flatten().tolist() == [1.0, 2.0, 5.0, 5.0]


def test_text_order_sensor_degenerates():
    p, _, _ = _scene(h=6, w=6)
    ph = cw_tof_sensor(p, order="text", **CLEAN).phase
    near = torch.minimum((ph - math.pi / 4).abs(), (ph - 5 * math.pi / 4).abs())
    assert float(near.max()) < 1e-9


def test_shot_noise_depth_std_matches_theory():
    # σ_θ = sqrt(2B)/a for 4 taps with Poisson variance B (Lange & Seitz 2001)
    a, ambient, d0 = 200.0, 200.0, R / 2
    p = phasor_from_depth(a, torch.full((1, 1, 64, 64), d0, dtype=torch.float64), F)
    frame = cw_tof_sensor(
        p,
        ambient_e=ambient,
        shot="poisson",
        adc_bits=None,
        generator=torch.Generator().manual_seed(0),
        **OPEN,
    )
    sigma_d = R / (2 * math.pi) * math.sqrt(2 * (ambient + a / 2)) / a
    assert float(frame.depth.std()) == pytest.approx(sigma_d, rel=0.1)
    assert float(frame.depth.mean()) == pytest.approx(d0, abs=0.01)


def test_default_sensor_noisy_seeded():
    p, _, _ = _scene(2, 8, 8, torch.float32)
    sensor = CWToFSensor(ambient_e=50.0, read_noise_e=3.0)
    f1 = sensor(p, generator=torch.Generator().manual_seed(1))
    f2 = sensor(p, generator=torch.Generator().manual_seed(1))
    f3 = sensor(p, generator=torch.Generator().manual_seed(2))
    assert all(torch.equal(x, y) for x, y in zip(f1, f2, strict=True))
    assert not torch.equal(f1.taps, f3.taps)
    assert torch.equal(f1.taps, f1.taps.round())  # 12-bit ADC
    assert float(f1.taps.max()) <= 4095 and float(f1.taps.min()) >= 0
    assert bool(((f1.depth >= 1) & (f1.depth <= 5)).all())


@pytest.mark.parametrize("b", [1, 3])
def test_shapes(b):
    p, _, _ = _scene(b, 3, 4, torch.float32)
    frame = CWToFSensor()(p, generator=torch.Generator().manual_seed(0))
    assert frame.taps.shape == (b, 4, 3, 4)
    for t in (frame.amplitude, frame.phase, frame.depth):
        assert t.shape == (b, 1, 3, 4)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_dtype_preserved(dtype):
    p, _, _ = _scene(dtype=dtype)
    frame = cw_tof_sensor(p, generator=torch.Generator().manual_seed(0))
    assert all(t.dtype == dtype for t in frame)


def test_module_equals_function_batched_equals_singles_no_inplace():
    p, _, _ = _scene(3)
    p0 = p.clone()
    kw = dict(freq_hz=F, ambient_e=5.0, step_m=0.25, amp_threshold=1.0, **CLEAN)
    out = CWToFSensor(**kw)(p)
    ref = cw_tof_sensor(p, **kw)
    assert all(torch.equal(x, y) for x, y in zip(out, ref, strict=True))
    singles = [cw_tof_sensor(p[i : i + 1], **kw) for i in range(3)]
    for k in range(4):
        torch.testing.assert_close(out[k], torch.cat([s[k] for s in singles]))
    assert torch.equal(p, p0)


def test_module_config_attributes():
    s = CWToFSensor(freq_hz=20e6, amp_threshold=3.0)
    assert s.freq_hz == 20e6 and s.config["amp_threshold"] == 3.0
    s.amp_threshold = 0.5
    assert s.config["amp_threshold"] == 0.5 and "freq_hz=20000000.0" in repr(s)


def test_gradcheck_noise_free():
    p, _, _ = _scene(1, 2, 2)
    p.requires_grad_()

    def f(x):
        fr = cw_tof_sensor(x, ambient_e=1.0, **CLEAN, **OPEN)
        return fr.depth, fr.amplitude

    assert torch.autograd.gradcheck(f, (p,))


def test_gradient_flows_through_noisy_sensor():
    p, _, _ = _scene(1, 3, 3, torch.float32)
    p.requires_grad_()
    fr = CWToFSensor(ambient_e=20.0, shot="gaussian")(p, generator=torch.Generator().manual_seed(0))
    (fr.depth.sum() + fr.amplitude.sum()).backward()
    assert torch.isfinite(torch.view_as_real(p.grad)).all() and float(p.grad.abs().sum()) > 0


def test_errors():
    p, _, _ = _scene()
    with pytest.raises(TypeError, match="cw_tof_sensor: expected phasor to be a complex tensor"):
        cw_tof_sensor(p.abs())
    with pytest.raises(ValueError, match="cw_tof_sensor: expected phasor of rank 4"):
        cw_tof_sensor(p[0])
    with pytest.raises(ValueError, match=r"cw_tof_sensor: expected phasor of shape \(\*, 1"):
        cw_tof_sensor(torch.cat([p, p], dim=1))
    with pytest.raises(ValueError, match="cw_tof_sensor: expected freq_hz > 0"):
        cw_tof_sensor(p, freq_hz=-30e6)
    with pytest.raises(ValueError, match="CWToFSensor: expected freq_hz > 0"):
        CWToFSensor(freq_hz=0.0)
    with pytest.raises(ValueError, match="CWToFSensor: expected order in"):
        CWToFSensor(order="abcd")
    with pytest.raises(ValueError, match="CWToFSensor: expected shot in"):
        CWToFSensor(shot="poison")
    with pytest.raises(ValueError, match="CWToFSensor: expected max_m > min_m"):
        CWToFSensor(min_m=5.0, max_m=1.0)
    with pytest.raises(ValueError, match="CWToFSensor: expected ambient_e >= 0"):
        CWToFSensor(ambient_e=-1.0)
    with pytest.raises(ValueError, match="cw_tof_sensor: expected intensity of shape"):
        cw_tof_sensor(p, p.abs()[..., :2])
    with pytest.raises(TypeError, match="cw_tof_sensor: expected intensity to be a real"):
        cw_tof_sensor(p, p)


def test_extremely_bright_return_keeps_its_depth():
    # a 1e30 e⁻ return from 2 m with Poisson shot noise (no ADC): relative noise 1e-15, so
    # the phase and depth are those of 2 m, not the 5 m of a dark pixel
    p = phasor_from_depth(1e30, torch.full((1, 1, 2, 2), 2.0, dtype=torch.float64), 30e6)
    frame = cw_tof_sensor(p, adc_bits=None, generator=torch.Generator().manual_seed(0))
    torch.testing.assert_close(frame.depth, torch.full_like(frame.depth, 2.0), rtol=0, atol=1e-6)
    torch.testing.assert_close(frame.amplitude, torch.full_like(frame.amplitude, 5e29),
                               rtol=1e-9, atol=0)


@pytest.mark.parametrize("taps, kw, msg", [
    (torch.ones(1, 4, 2, 2), {"freq_hz": 0.0}, "camera_readout: expected freq_hz > 0"),
    (torch.ones(1, 3, 1, 1), {}, r"camera_readout: expected taps of shape \(\*, 4, \*, \*\)"),
])
def test_camera_readout_errors_name_camera_readout(taps, kw, msg):
    # they named phase_to_depth and tap_amplitude, which the caller never called
    from torchtof.sensor.readout import camera_readout
    with pytest.raises(ValueError, match=msg):
        camera_readout(taps, **kw)
