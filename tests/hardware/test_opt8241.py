"""OPT8241: register requests (Voxel SDK table, domain-notes §5.3), frame packets, decoding
to depth with the camera rules, and the driver on the fake camera."""

import math

import numpy as np
import pytest
import torch

from torchtof.experiment import ExperimentConfig
from torchtof.hardware import opt8241 as opt
from torchtof.hardware.errors import FrameError, FrameTimeoutError, ProtocolError
from torchtof.hardware.simulated import SimulatedBench
from torchtof.sensor import SPEED_OF_LIGHT, cw_tof_sensor, phasor_from_depth


@pytest.mark.parametrize("address,write,expected", [
    (0x5881, True, (0x40, 0x09, 0x58, 0x81, 3)),
    (0x5881, False, (0xC0, 0x08, 0x58, 0x81, 3)),
    (0x5C10, True, (0x40, 0x09, 0x5C, 0x10, 3)),
    (0x4B02, False, (0xC0, 0x0A, 0x4B, 0x02, 2)),
    (0x4E7F, True, (0x40, 0x0B, 0x4E, 0x7F, 2)),
    (0x2D10, False, (0xC0, 0x04, 0x2D00, 0x1000, 1)),  # shift 8 for the 1-byte slaves
    (0x5201, True, (0x40, 0x03, 0x5200, 0x0100, 1)),
    (0x54FF, True, (0x40, 0x03, 0x5400, 0xFF00, 1)),
])
def test_register_request_table(address, write, expected):
    assert opt.register_request(address, write) == expected


def test_register_request_bad_slave():
    with pytest.raises(ValueError, match="unknown slave 0x12"):
        opt.register_request(0x1234, True)
    with pytest.raises(ValueError, match="16-bit"):
        opt.register_request(0x12345, True)


def _camera(**kw):
    cfg = ExperimentConfig(n=8, roi_px=8, srs=(0.25,), **kw)
    bench = SimulatedBench(cfg)
    return bench, bench.camera()


def test_register_round_trip_on_fake():
    bench, cam = _camera()
    cam.set_modulation_frequency(48e6)
    assert cam.freq_hz == 48e6 and bench.camera_usb.regs[0x5881] == 48000
    cam.set_integration_time(700)
    assert cam.integration_time_us == 700
    cam.write_register(0x2D10, 0xAB)  # a 1-byte slave, shifted request fields
    assert cam.read_register(0x2D10) == 0xAB
    with pytest.raises(ValueError, match="does not fit"):
        cam.write_register(0x2D10, 256)
    with pytest.raises(ValueError, match="freq_hz"):
        cam.set_modulation_frequency(5e6)
    with pytest.raises(ValueError, match="unknown register"):
        cam.read_register("nope")


def test_fake_camera_stalls_on_malformed_requests():
    import usb.core

    bench, _ = _camera()
    dev = bench.camera_usb
    with pytest.raises(usb.core.USBError, match="Pipe error"):
        dev.ctrl_transfer(0x40, 0x09, 0x58, 0x81, b"\x01\x02")  # 2 bytes to a 3-byte register
    with pytest.raises(usb.core.USBError, match="Pipe error"):
        dev.ctrl_transfer(0x40, 0x08, 0x58, 0x81, b"\x01\x02\x03")  # read code with OUT type
    with pytest.raises(usb.core.USBError, match="Pipe error"):
        dev.ctrl_transfer(0xC0, 0x08, 0x11, 0x00, 3)  # unknown slave


def test_frame_packet_round_trip_phase_path():
    rng = np.random.default_rng(0)
    p12 = rng.integers(0, 4096, size=(3, 5))
    phase = p12 * (2 * math.pi / 4096)
    amp = rng.integers(0, 4096, size=(3, 5)).astype(float)
    raw = opt.encode_frame(phase, amp, frame_id=77, timestamp_us=1500, ambient=np.full((3, 5), 3),
                           flags=np.eye(3, 5, dtype=np.uint32))
    assert len(raw) == opt.HEADER.size + 4 * 15
    word = int.from_bytes(raw[32:36], "little")  # pixel (0, 0): phase | amp << 12 | ...
    assert word == int(p12[0, 0]) | int(amp[0, 0]) << 12 | 3 << 24 | 1 << 28
    f = 30e6
    rules = opt.CameraRules(min_m=0.0, max_m=10.0, step_m=None)
    fr = opt.decode_frame(raw, f, rules)
    assert fr.frame_id == 77 and fr.timestamp == pytest.approx(1.5e-3) and fr.taps is None
    np.testing.assert_array_equal(fr.amplitude.numpy(), amp.astype(np.float32))
    # depth_m = phase12 · c / (2 f 4096) (domain-notes §5.3)
    np.testing.assert_allclose(fr.depth.numpy(), p12 * SPEED_OF_LIGHT / (2 * f * 4096),
                               rtol=1e-6)
    assert fr.ambient.unique().tolist() == [3] and fr.flags.sum() == 3


def test_decode_applies_camera_rules():
    phase = np.array([[0.0, math.pi, 1.0]])
    amp = np.array([[100.0, 100.0, 2.0]])
    rules = opt.CameraRules(min_m=1.0, max_m=5.0, step_m=0.25, amp_threshold=5.0, no_photon_m=5.0)
    fr = opt.decode_frame(opt.encode_frame(phase, amp, 0, 0), 30e6, rules)
    # 0 m -> clipped to 1; π -> 2.498 m -> 2.5 on the 0.25 m grid; dark pixel -> 5
    assert fr.depth.tolist() == [[1.0, 2.5, 5.0]]


def test_taps_path_equals_the_sensor_model_bit_for_bit():
    g = torch.Generator().manual_seed(0)
    depth = 1.0 + 3.0 * torch.rand(1, 1, 6, 7, generator=g)
    kw = dict(freq_hz=30e6, ambient_e=300.0, shot="poisson", read_noise_e=3.0, adc_bits=12,
              gain_e_per_dn=1.0, min_m=1.0, max_m=5.0, amp_threshold=20.0, step_m=0.25)
    fr = cw_tof_sensor(phasor_from_depth(800.0, depth, 30e6), generator=g, **kw)
    raw = opt.encode_frame(fr.phase[0, 0].numpy(), fr.amplitude[0, 0].numpy(), 3, 0,
                           taps=fr.taps[0].numpy().astype(np.uint16))
    rules = opt.CameraRules(1.0, 5.0, 0.25, 20.0, 5.0)
    out = opt.decode_frame(raw, 30e6, rules)
    assert torch.equal(out.taps, fr.taps[0])
    assert torch.equal(out.depth, fr.depth[0, 0])
    assert torch.equal(out.amplitude, fr.amplitude[0, 0])
    assert torch.equal(out.phase, fr.phase[0, 0])
    # the 12-bit phase path agrees to the phase quantum (2π/4096)
    coarse = opt.decode_frame(raw, 30e6, opt.CameraRules(0.0, 10.0, None), use_taps=False)
    dphi = (coarse.phase - fr.phase[0, 0]).abs()
    assert float(torch.minimum(dphi, 2 * math.pi - dphi).max()) <= math.pi / 4096 + 1e-6


@pytest.mark.parametrize("mutate,match", [
    (lambda b: b[:20], "shorter than"),
    (lambda b: b"XXXX" + b[4:], "magic"),
    (lambda b: b[:-1], "payload of"),
    (lambda b: b[:40] + bytes([b[40] ^ 1]) + b[41:], "CRC-32"),
])
def test_corrupt_packets_raise(mutate, match):
    raw = opt.encode_frame(np.zeros((2, 3)), np.ones((2, 3)), 0, 0, taps=np.ones((4, 2, 3)))
    with pytest.raises(FrameError, match=match):
        opt.decode_frame(mutate(raw), 30e6)


def test_encode_frame_rejects_bad_taps():
    with pytest.raises(ValueError, match="taps"):
        opt.encode_frame(np.zeros((2, 3)), np.ones((2, 3)), 0, 0, taps=np.ones((4, 3, 2)))


def test_grab_timeout_names_the_pattern():
    _, cam = _camera()
    cam.start()
    cam.pattern_index = 17
    with pytest.raises(FrameTimeoutError, match="pattern 17 within 0.01 s"):
        cam.grab(0.01)
    assert cam.flush(0.001) == 0


def test_camera_renders_only_while_streaming_and_counts_frames():
    bench, cam = _camera()
    pat = np.ones((8, 8), dtype=np.uint8)
    bench.camera_usb.trigger(pat)  # not streaming: ignored
    assert cam.frame_counter() == 0
    cam.start()
    bench.camera_usb.trigger(pat)
    bench.camera_usb.trigger(pat)
    assert cam.frame_counter() == 2
    a, b = cam.grab(0.1), cam.grab(0.1)
    assert (a.frame_id, b.frame_id) == (0, 1) and a.depth.shape == (8, 8)
    assert a.taps.shape == (4, 8, 8)
    bench.camera_usb._fifo.append((9, bytes(10_000)))  # larger than a frame: USB overflow
    with pytest.raises(ProtocolError, match="bulk read: USB error.*Overflow"):
        cam.grab(0.1)
    cam.stop()
