"""The simulated devices parse the real bytes: malformed messages are NACKed, state is kept,
and a frame of the fake camera is the sensor model's frame of the displayed pattern."""

import struct

import numpy as np
import pytest
import torch

from torchtof.experiment import ExperimentConfig, simulate_frames
from torchtof.hardware import dlpc350 as dlp
from torchtof.hardware import opt8241 as opt
from torchtof.hardware.frames import FrameSource
from torchtof.hardware.simulated import Faults, SimulatedBench

CFG = ExperimentConfig(n=8, roi_px=8, srs=(0.25,), shot=None, read_noise_e=0.0)


def _exchange(dev, reports):
    for r in reports:
        dev.write(dlp.EP_OUT, r)
    return bytes(dev.read(dlp.EP_IN, 64))


@pytest.mark.parametrize("raw", [
    struct.pack("<BBHBB", 0x40, 1, 4, 0x24, 0x1A) + b"\x02\x00",  # start with a 2-byte payload
    struct.pack("<BBHBB", 0x40, 1, 3, 0x99, 0x1A) + b"\x00",  # unknown command word 1A 99
    struct.pack("<BBHBB", 0x40, 1, 3, 0x1B, 0x1A) + b"\x05",  # DISP_MODE 5: out of range
    struct.pack("<BBHBB", 0x40, 1, 5, 0x34, 0x1A) + b"\x01\x02\x03",  # MBOX_DATA, mailbox closed
    struct.pack("<BBH", 0x40, 1, 1) + b"\x24",  # length 1: no room for a command word
])
def test_malformed_messages_are_nacked(raw):
    dev = SimulatedBench(CFG).lightcrafter_usb
    reply = _exchange(dev, [raw.ljust(64, b"\x00")])
    assert reply[0] & dlp.FLAG_NACK
    # the device keeps working afterwards
    ok = _exchange(dev, dlp.encode("DISP_MODE", b"\x01", seq=2))
    assert not ok[0] & dlp.FLAG_NACK and dev.state["pattern_mode"]


def test_short_report_is_nacked_and_wrong_endpoint_fails():
    import usb.core

    dev = SimulatedBench(CFG).lightcrafter_usb
    assert _exchange(dev, [b"\x40\x01\x03\x00"])[0] & dlp.FLAG_NACK
    with pytest.raises(usb.core.USBError):
        dev.write(0x02, bytes(64))
    with pytest.raises(usb.core.USBTimeoutError):
        dev.read(dlp.EP_IN, 64)  # nothing to answer


def test_multi_report_lut_is_reassembled_into_state():
    bench = SimulatedBench(CFG)
    lcr = bench.lightcrafter()
    entries = [dlp.lut_entry(k % 24, trig="internal") for k in range(40)]  # 2 reports
    assert len(dlp.encode("MBOX_DATA", dlp.pack_pattern_lut(entries))) == 2
    lcr.load_pattern_lut(entries)
    assert bench.lightcrafter_usb.pattern_lut == entries


def test_camera_frame_is_the_sensor_model_of_the_displayed_pattern():
    bench = SimulatedBench(CFG)
    lcr, cam = bench.lightcrafter(), bench.camera()
    assert isinstance(cam, FrameSource)
    cam.start()
    pat = (np.arange(64).reshape(8, 8) % 3 == 0).astype(np.uint8)
    lcr.show_sequence(pat[None], exposure_us=1000)
    frame = cam.grab(0.1)
    ref = simulate_frames(bench.scene, torch.from_numpy(pat.astype(np.float32))[None], CFG,
                          bench.noise_generator(pat), None, bench.stray)
    # row 0 is the dark guard row above the sensor ROI; quad samples are signed: the
    # simulator sends a model tap c as c - QUAD_OFFSET
    off = opt.QUAD_OFFSET
    assert torch.equal(frame.taps[:, 1:], ref.taps[0] - off)
    assert (frame.taps[:, 0] == -off).all()
    assert torch.equal(frame.depth[1:], ref.depth[0, 0])


def test_header_and_trailer_left_on_by_another_program_are_cleared_by_start():
    """The fake camera adds 12 bytes before and after each frame while frm_header_en /
    frm_trailer_en are set (OPT9221.dml ids 6145, 6360); start() configures them off, so the
    frames have their size again."""
    bench = SimulatedBench(CFG)
    fake = bench.camera_usb
    fake._set("frm_header_en", 1)
    fake._set("frm_trailer_en", 1)
    fake._set("tg_dis", 0)
    pat = np.ones((8, 8), dtype=np.uint8)
    fake.trigger(pat)
    want = opt.frame_bytes(CFG.roi_px, CFG.roi_px + 1, fake.mode)  # the power-up depth8
    assert len(fake.read(opt.EP_FRAMES, want + 1000)) == want + 24
    bench = SimulatedBench(CFG)  # a fresh camera (the frame above keeps this one busy)
    bench.camera_usb._set("frm_header_en", 1)
    bench.camera_usb._set("frm_trailer_en", 1)
    lcr, cam = bench.lightcrafter(), bench.camera()
    cam.start()
    lcr.show_sequence(pat[None], exposure_us=1000)
    assert cam.grab(0.1).taps.shape == (4, CFG.roi_px + 1, CFG.roi_px)


def test_fault_plan_from_json_dict():
    f = Faults.from_dict({"drop": [1, 2], "nack": {"PAT_CONFIG": [0]}, "hang_s": 1.0})
    assert f.drop == {1, 2} and f.nack == {"PAT_CONFIG": {0}} and f.hang_s == 1.0
    with pytest.raises(ValueError, match="unknown fault 'explode'"):
        Faults.from_dict({"explode": 1})


def test_bench_rejects_a_camera_without_adc():
    with pytest.raises(ValueError, match="adc_bits"):
        SimulatedBench(ExperimentConfig(n=8, roi_px=8, srs=(0.25,), adc_bits=None))


def test_vanished_devices_raise_enodev():
    import usb.core

    bench = SimulatedBench(CFG)
    bench.vanished = True
    with pytest.raises(usb.core.USBError) as err:
        bench.lightcrafter_usb.write(dlp.EP_OUT, bytes(64))
    assert err.value.errno == 19


@pytest.mark.parametrize("kw, msg", [
    (dict(drop=5), "'drop' a list of frame ordinals"),
    (dict(drop=[-1]), "'drop' a list of frame ordinals"),
    (dict(nack={"NOPE": {0}}), "unknown command 'NOPE' in 'nack'"),
    (dict(set_failed={"bogus"}), "'set_failed' a list of"),
    (dict(hang_s=-1), "'hang_s' a non-negative number"),
])
def test_faults_constructor_checks_the_plan(kw, msg):
    # the Python constructor accepted these (injecting nothing) or failed later as a fake
    # USB error; it now checks what Faults.from_dict (--sim-faults) checks
    from torchtof.hardware.simulated import Faults
    with pytest.raises(ValueError, match=msg):
        Faults(**kw)


@pytest.mark.parametrize("kw, err, msg", [
    (dict(config="sky"), TypeError, "expected config an ExperimentConfig"),
    (dict(faults={"drop": [3]}), TypeError, "expected faults a Faults"),
    (dict(video_hz=0), ValueError, "expected video_hz a finite number > 0"),
    (dict(video_hz=-60), ValueError, "expected video_hz"),
    (dict(video_hz="60"), ValueError, "expected video_hz"),
    (dict(mode_latency_s=float("nan")), ValueError, "expected mode_latency_s"),
    (dict(frame_number_start=2.7), ValueError, "expected frame_number_start an int"),
])
def test_simulated_bench_checks_its_arguments(kw, err, msg):
    # these failed later as fake USB or hardware errors (a 'extend the desktop onto the
    # LightCrafter' message on a simulated bench) or were silently truncated
    from torchtof.hardware.simulated import SimulatedBench
    with pytest.raises(err, match=f"SimulatedBench: {msg}"):
        SimulatedBench(**kw)


def test_faults_hang_file_takes_a_path_object(tmp_path):
    from torchtof.hardware.simulated import Faults
    f = Faults(hang_at_frame=3, hang_file=tmp_path / "h")
    assert f.hang_file == str(tmp_path / "h")
