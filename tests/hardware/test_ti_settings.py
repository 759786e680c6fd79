"""The settings TI's own code makes and torchtof now makes too, checked byte for byte against
values written out by hand from TI's sources (never from torchtof's output):

* Voxel SDK (``3dtof/voxelsdk``): ``TI3DToF/OPT9221.dml`` (register, bits), ToFTintinCamera.cpp
  (``TintinVCOFrequency::get``/``set``, ``TintinModulationFrequencyParameter::set``,
  ``ToFTintinCamera::_applyCalibrationParams``), TintinCDKCameraCommon.h (the 39-60 MHz band),
  TintinCDKCameraNoCalibration.conf (``mod_freq2 = mod_freq1``, ``dealias_en = 0``);
* TI's DLPC350 API ``dlpc350_api.cpp``: ``DLPC350_SetTrigOutConfig`` (0x1A1D, ``[invert,
  rising, falling]``, 0xBB = 0 µs), ``DLPC350_GetInputSource`` (0x1A00), ``DLPC350_GetVideo
  SignalStatus`` (0x071C, 28 bytes), ``DLPC350_isSourceLocked`` (status & 3 == 2),
  ``DLPC350_Read`` (length 0 is a NACK), ``DLPC350_AddToPatLut`` (PatNum ≤ 24),
  ``DLPC350_SetMode`` (912 × 1140 pattern images, video up to 120 Hz).
"""

import math

import numpy as np
import pytest

from torchtof.experiment import ExperimentConfig
from torchtof.hardware import dlpc350 as dlp
from torchtof.hardware import opt8241 as opt
from torchtof.hardware import video
from torchtof.hardware.errors import HardwareError, NackError, ProtocolError, usb_exceptions
from torchtof.hardware.simulated import Faults, SimulatedBench
from torchtof.sensor import SPEED_OF_LIGHT


class Recorder:
    """A pyusb-like camera that logs every control transfer and keeps 24-bit registers."""

    def __init__(self, regs=None):
        self.regs, self.log = dict(regs or {}), []

    def ctrl_transfer(self, rtype, req, wvalue, windex, data, timeout=None):
        address = wvalue << 8 | windex  # the 3-byte OPT9221 slaves: no shift
        if rtype == 0x40:
            self.log.append((wvalue, windex, bytes(data)))
            self.regs[address] = int.from_bytes(bytes(data), "little")
            return len(data)
        return bytearray(self.regs.get(address, 0).to_bytes(data, "little"))

    def writes_to(self, address):
        return [d for (s, r, d) in self.log if s << 8 | r == address]


#: bin_row_count 240 / bin_col_count 320 (0x5C2F / 0x5C30 bits 14-23): the QVGA frame
QVGA = {0x5C2F: 240 << 14, 0x5C30: 320 << 14}

#: What TI's default CDK profile leaves (unambiguous_range 8, TintinUnambiguousRangeParameter::
#: set with modPS1 = 1, modPS2 = 0 and the 39-60 MHz band): quad_cnt_max 6 (0x5883 bits 0-3,
#: sub_frame_cnt_max 2 in bits 4-7), vco1 = 480 MHz -> mod_m1 = 480·4/96 = 20 (0x580C bits
#: 16-21), mod_n1 = 2, mod_ps1 = 1 (0x580F bits 0-1, 4-6): 40 MHz; vco2 = 360 MHz -> mod_m2 = 15
#: (0x580D bits 16-21), mod_n2 = 2, mod_ps2 = 0 (0x580F bits 2-3, 7-9): 60 MHz; dealias_en = 1
#: (0x5C02 bit 23); frame_rate 30 (TintinCDKCameraLongRange.conf) -> pix_cnt_max =
#: ⌊48 MHz / (30 · 6 · 2)⌋ = 133333 (0x5882, ToFCamera::_setFrameRate).
TI_PROFILE = {0x5883: 0x26, 0x580C: 20 << 16, 0x580D: 15 << 16,
              0x580F: 2 | 2 << 2 | 1 << 4 | 0 << 7, 0x5C02: 1 << 23, 0x5882: 133333}


# -- 1. the modulation frequency -----------------------------------------------------------------


def test_configure_programs_the_modulation_frequency_over_ti_s_profile():
    """TI's profile leaves 40 MHz (PLL 1) and 60 MHz (PLL 2); configure programs 30 MHz in both:
    mod_ps = ⌊300/4/30⌋ = 2, vco = 3·4·30 = 360 MHz, mod_m = 360·4/(2·48) = 15, frac 0, n = 2."""
    dev = Recorder({**QVGA, **TI_PROFILE})
    cam = opt.OPT8241(dev)
    assert cam.freq_hz == pytest.approx(40e6) and cam.pll2_freq_hz == pytest.approx(60e6)
    cam.configure()
    assert dev.regs[0x580C] == 15 << 16 and dev.regs[0x580D] == 15 << 16
    assert dev.regs[0x580F] == 2 | 2 << 2 | 2 << 4 | 2 << 7
    assert dev.regs[0x5883] & 0xF == 4 and dev.regs[0x5C02] >> 23 & 1 == 0  # dealias_en off
    assert dev.regs[0x5CB3] & 0xFFF == 1280  # delay_fb_coeff_1 = 30·1024/24 (DML id 10019)
    assert cam.freq_hz == 30e6 and cam.pll2_freq_hz == 30e6
    assert cam.unambiguous_range_m == pytest.approx(SPEED_OF_LIGHT / 60e6)
    # 6 quads, 2 sub-frames -> 4 quads, 1 sub-frame at the profile's 30 frames/s (no period):
    # pix_cnt_max = 133333 · 6 · 2 / 4 = 399999
    assert dev.regs[0x5882] == 399999 and cam.frame_time_us == pytest.approx(1e6 / 30, abs=0.1)


def test_quads_6_program_the_same_frequency():
    """quad_cnt_max 6: mod_ps = ⌊300/6/30⌋ = 1, vco = 2·6·30 = 360 MHz, mod_m = 15."""
    dev = Recorder({**QVGA, **TI_PROFILE})
    cam = opt.OPT8241(dev, quads=6)
    cam.configure()
    assert dev.regs[0x580F] == 2 | 2 << 2 | 1 << 4 | 1 << 7 and dev.regs[0x580C] == 15 << 16
    assert cam.freq_hz == 30e6 and cam.pll2_freq_hz == 30e6


def test_a_frequency_whose_range_is_shorter_than_max_m_is_refused_before_any_write():
    dev = Recorder({**QVGA, **TI_PROFILE})
    cam = opt.OPT8241(dev, mod_freq_hz=40e6)  # TI's band: c/(2f) = 3.747 m < 5 m
    with pytest.raises(ValueError, match=r"OPT8241.configure: mod_freq_hz = 40 MHz gives an "
                                         r"unambiguous range c/\(2f\) = 3.747 m, shorter than "
                                         r"the camera rules' max_m = 5 m"):
        cam.configure()
    assert dev.log == []
    # with the rules' range inside 3.747 m it is accepted
    ok = opt.OPT8241(Recorder({**QVGA, **TI_PROFILE}), mod_freq_hz=40e6,
                     rules=opt.CameraRules(max_m=3.7))
    ok.configure()
    assert abs(ok.freq_hz - 40e6) < 100  # mod_m1 = 13 + 21845/2^16: 39.99998 MHz
    # 30 MHz gives 4.9965 m: the paper's "5 m" (c = 3e8 m/s), accepted; 30.01 MHz is not
    assert SPEED_OF_LIGHT / 60e6 < 5.0
    opt.check_unambiguous_range(30e6, 5.0, "t")
    with pytest.raises(ValueError, match="t: mod_freq_hz = 30.01 MHz"):
        opt.check_unambiguous_range(30.01e6, 5.0, "t")


def test_bad_modulation_frequencies_name_the_argument():
    with pytest.raises(TypeError, match="OPT8241: expected mod_freq_hz a number"):
        opt.OPT8241(Recorder(), mod_freq_hz="30")
    with pytest.raises(ValueError, match="OPT8241: mod_freq_hz 5000000.0 cannot be programmed"):
        opt.OPT8241(Recorder(), mod_freq_hz=5e6)  # below 37.5/4 MHz: mod_ps1 > 7


def test_pll_read_back_uses_the_sdk_formula_and_refuses_other_dividers():
    """TintinVCOFrequency::get: vco = 2·48·(M + frac/2^16)/2^N; the DML's 48·M/N agrees for N = 1
    and 2 only. N = 1, M = 8: vco 384 MHz, /(2·4) = 48 MHz; N = 2, M = 16: the same."""
    assert opt.pll_frequency_hz(8, 0, 1, 1, 4) == 48e6
    assert opt.pll_frequency_hz(16, 0, 2, 1, 4) == 48e6
    for n in (0, 3):
        with pytest.raises(ProtocolError, match=f"mod_n1={n}.*agree only for mod_n1 = 1 or 2"):
            opt.pll_frequency_hz(16, 0, n, 1, 4)


def test_the_simulated_run_records_the_frequency_and_what_configure_set(tmp_path):
    zarr = pytest.importorskip("zarr", minversion="3")
    from torchtof.hardware import acquire

    bench = SimulatedBench(ExperimentConfig(n=8, roi_px=8, srs=(0.25,), shot=None,
                                            read_noise_e=0.0))
    cam = bench.camera()
    assert bench.camera_usb.field("sscg_en") == 1  # as TI's profile left it
    acquire(tmp_path / "r.zarr", bench.lightcrafter(timeout_ms=100), cam, n=8, sr=0.125,
            progress=False)
    c = zarr.open_group(str(tmp_path / "r.zarr"), mode="r").attrs["camera"]
    assert c["freq_hz"] == 30e6 and c["pll2_freq_hz"] == 30e6
    assert c["mod_freq_hz_requested"] == 30e6
    assert c["unambiguous_range_m"] == pytest.approx(SPEED_OF_LIGHT / 60e6)
    assert (c["phase_calibration"], c["hdr_scale"], c["sscg_en"]) == ("off", 0, 1)


def test_cli_exposes_the_frequency_and_refuses_a_range_below_5_m(tmp_path, capsys):
    pytest.importorskip("zarr", minversion="3")
    from torchtof.cli import main

    with pytest.raises(SystemExit):
        main(["acquire", "--help"])
    assert "--mod-freq-mhz" in capsys.readouterr().out
    out = tmp_path / "x.zarr"
    with pytest.raises(SystemExit) as exc:
        main(["acquire", "--simulated", "--n", "8", "--mod-freq-mhz", "40", "-o", str(out)])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "argument --mod-freq-mhz: --mod-freq-mhz = 40 MHz" in err
    assert "3.747 m" in err and not out.exists()
    with pytest.raises(SystemExit) as exc:
        main(["acquire", "--simulated", "--n", "8", "--mod-freq-mhz", "5", "-o", str(out)])
    assert exc.value.code == 2 and "PLL cannot make 5 MHz" in capsys.readouterr().err


# -- 2. TI's phase calibration ------------------------------------------------------------------


def test_configure_writes_what_the_sdk_writes_with_the_calibration_disabled():
    """ToFTintinCamera::_applyCalibrationParams, disabled branches, in order: disable_offset_corr
    (0x5C51 bit 16) = 1, phase_corr_1 (0x5C37 bits 4-15) = 0, phase_corr_2 (0x5C38 bits 4-15)
    = 0, disable_temp_corr (0x5C51 bit 17) = 1, filt_en (0x5CB6 bit 19) = 0, phase_lin_corr_en
    (0x5C80 bit 0) = 0; every other bit of those registers kept. Start: a calibrated profile
    (TintinCDKCameraExtraLongRange.conf: phase_corr_1 = 1309, phase_corr_2 = 1653,
    tillum_calib = 61, tsensor_calib = 56; calib_prec = 1 at 0x5C51 bit 20)."""
    dev = Recorder({**QVGA, 0x5883: 0x04, 0x5C51: 1 << 20 | 56 << 8 | 61,
                    0x5C37: 1309 << 4 | 0x5, 0x5C38: 1653 << 4, 0x5CB6: 1 << 19 | 0x1234,
                    0x5C80: 0x101})
    opt.OPT8241(dev).configure()
    assert dev.writes_to(0x5C51) == [b"\x3d\x38\x11", b"\x3d\x38\x13"]
    assert dev.writes_to(0x5C37) == [b"\x05\x00\x00"]
    assert dev.writes_to(0x5C38) == [b"\x00\x00\x00"]
    assert dev.writes_to(0x5CB6) == [b"\x34\x12\x00"]
    assert dev.writes_to(0x5C80) == [b"\x00\x01\x00"]
    order = [(s << 8 | r) for (s, r, _) in dev.log if (s << 8 | r) in
             (0x5C51, 0x5C37, 0x5C38, 0x5CB6, 0x5C80)]
    assert order == [0x5C51, 0x5C37, 0x5C38, 0x5C51, 0x5CB6, 0x5C80]


def _depth_bench(mode="depth", **kw):
    cfg = ExperimentConfig(n=8, roi_px=8, srs=(0.25,), shot=None, read_noise_e=0.0,
                           multipath_strength=0.0, stray_e=0.0)
    bench = SimulatedBench(cfg, **kw)
    return bench, bench.camera(mode=mode)


def test_the_simulator_records_the_calibration_writes_and_drops_the_phase_offset():
    """A phase_corr_1 of 100 left on (disable_offset_corr 0) shifts the fake's depth-mode phase
    by 100/4096 of a turn; after configure the fake holds TI's disabled-calibration values and
    the frame equals the one of a camera that never had the offset."""
    bench, cam = _depth_bench()
    ref_bench, ref = _depth_bench()
    fake = bench.camera_usb
    fake._set("phase_corr_1", 100)
    fake._set("filt_en", 1)
    fake._set("phase_lin_corr_en", 1)
    assert fake.phase_correction() == 100
    cam.start()
    ref.start()
    got = {a: v for a, v in fake.writes}
    assert got[0x5C51] >> 16 & 3 == 3 and got[0x5C37] == 0 and got[0x5C38] == 0
    assert got[0x5CB6] >> 19 & 1 == 0 and got[0x5C80] & 1 == 0
    assert fake.phase_correction() == 0
    pat = np.ones((8, 8), dtype=np.uint8)
    fake.trigger(pat, 0.0)
    ref_bench.camera_usb.trigger(pat, 0.0)
    assert cam.grab(0.5).raw == ref.grab(0.5).raw


def test_the_simulated_phase_offset_is_subtracted_in_12_bit_units():
    taps = np.zeros((4, 1, 8), dtype=np.int64)
    taps[0], taps[1] = 1000, 0  # I = 1000, Q = 0: phase 0
    plain = np.frombuffer(opt.encode_frame("depth", taps), "<u2")[1::2] & 0xFFF
    shifted = np.frombuffer(opt.encode_frame("depth", taps, phase_corr=100), "<u2")[1::2] & 0xFFF
    assert plain.tolist() == [0] * 8 and shifted.tolist() == [4096 - 100] * 8


# -- 3. PLL 2 ----------------------------------------------------------------------------------


def test_the_simulated_pll_2_starts_as_ti_s_profile_left_it_and_ends_as_pll_1():
    bench, cam = _depth_bench()
    fake = bench.camera_usb
    assert (fake.field("mod_m2"), fake.field("mod_ps2")) == (15, 0)  # vco2 360 MHz, ps2 0
    cam.configure()
    for k in ("mod_m", "mod_m_frac", "mod_n", "mod_ps"):
        assert fake.field(k + "2") == fake.field(k + "1"), k
    assert cam.pll2_freq_hz == cam.freq_hz == 30e6


# -- 4. hdr_scale, padding_en, sscg_en ------------------------------------------------------------


def test_configure_clears_hdr_scale_and_padding_keeping_the_neighbours():
    """hdr_scale: 0x5C4C bits 6-8 beside intg_duty_cycle (bits 0-5); padding_en: 0x5C3C
    bit 0 beside blk_size (bits 4-23, 1024 here, never written by torchtof)."""
    dev = Recorder({**QVGA, 0x5883: 0x04, 0x5C4C: 2 << 6 | 6, 0x5C3C: 1024 << 4 | 1})
    opt.OPT8241(dev).configure()
    assert dev.writes_to(0x5C4C) == [b"\x06\x00\x00"]
    assert dev.regs[0x5C3C] == 1024 << 4


def test_left_over_padding_and_hdr_scale_would_corrupt_the_frames():
    """The fake models both (OPT9221.dml ids 6146, 6377): a camera configured and then given
    padding_en = 1 pads each 8x9 quad frame (576 bytes) to blk_size 1024; hdr_scale = 1 halves
    every other frame's taps. configure() clears both."""
    bench, cam = _depth_bench("quad")
    cam.configure()
    cam._configured = True
    fake = bench.camera_usb
    fake._set("padding_en", 1)
    cam.start()  # configure skipped: the leftover stays
    fake.trigger(np.ones((8, 8), dtype=np.uint8), 0.0)
    assert len(fake._fifo[0][1]) == 1024  # 576 bytes and 448 zeros
    with pytest.raises(ProtocolError, match="Overflow"):  # more than the 576 + 255 asked for
        cam.grab(0.5)
    cam.stop()
    fake._set("hdr_scale", 1)
    cam.start()  # configure runs: both cleared
    assert fake.field("padding_en") == 0 and fake.field("hdr_scale") == 0
    pat = np.ones((8, 8), dtype=np.uint8)
    fake.trigger(pat, 10.0)
    fake.trigger(pat, 11.0)
    a, b = cam.grab(0.5), cam.grab(0.5)
    assert a.raw == b.raw  # same pattern, no noise, no alternate-frame scaling


def test_the_simulated_hdr_scale_divides_alternate_frames():
    bench, cam = _depth_bench("quad")
    cam.configure()
    cam._configured = True
    bench.camera_usb._set("hdr_scale", 1)
    cam.start()
    pat = np.ones((8, 8), dtype=np.uint8)
    for t in (0.0, 1.0):
        bench.camera_usb.trigger(pat, t)
    a, b = cam.grab(0.5), cam.grab(0.5)
    ta, tb = a.taps + opt.QUAD_OFFSET, b.taps + opt.QUAD_OFFSET  # the model taps
    assert float(ta.sum()) > 0 and np.array_equal(np.floor(ta.numpy() / 2), tb.numpy())


# -- 5. DLPC350 trigger output and video input --------------------------------------------------


def test_trig_out1_payload_and_its_limits():
    assert dlp.payload_trig_out1() == bytes([0x00, 0xBB, 0xBB])
    with pytest.raises(ValueError, match="payload_trig_out1 rising"):
        dlp.payload_trig_out1(False, 0xD6)  # beyond +2.787 us (0xD5)
    with pytest.raises(TypeError, match="payload_trig_out1: expected invert a bool"):
        dlp.payload_trig_out1(2)


def test_the_fake_nacks_a_trig_out1_beyond_ti_s_range():
    bench = SimulatedBench(ExperimentConfig(n=8, roi_px=8, srs=(0.25,)))
    lcr = bench.lightcrafter()
    with pytest.raises(NackError, match="TRIG_OUT1_CTL"):
        lcr.write("TRIG_OUT1_CTL", bytes([0x02, 0xBB, 0xBB]))
    with pytest.raises(NackError, match="TRIG_OUT1_CTL"):
        lcr.write("TRIG_OUT1_CTL", bytes([0x00, 0xD6, 0xBB]))
    lcr.write("TRIG_OUT1_CTL", bytes([0x01, 0x00, 0xD5]))
    assert bench.lightcrafter_usb.state["trig_out1"] == (1, 0x00, 0xD5)
    assert lcr.read("TRIG_OUT1_CTL") == bytes([0x01, 0x00, 0xD5])


#: A VID_SIG_STAT reply laid out byte by byte as DLPC350_GetVideoSignalStatus reads it: status
#: data[0] & 3, HRes data[1..2], VRes data[3..4], RSVD data[5], HSyncPol data[6], VSyncPol
#: data[7], PixClock data[8..11], HFreq data[12..13], VFreq data[14..15], TotPixPerLine
#: data[16..17], TotLinPerFrame data[18..19], ActvPixPerLine data[20..21], ActvLinePerFrame
#: data[22..23], FirstActvPix data[24..25], FirstActvLine data[26..27].
VID_BYTES = bytes([0x06,  # status 2 (locked) in bits 1:0, a stray bit 2
                   0x90, 0x03, 0x74, 0x04,  # HRes 912, VRes 1140
                   0x00, 0x01, 0x00,  # reserved, HSync +, VSync -
                   0x40, 0x42, 0x0F, 0x00,  # pixel clock 1 000 000
                   0x34, 0x12,  # HFreq 0x1234
                   0x70, 0x17,  # VFreq 6000
                   0x30, 0x04, 0xA1, 0x04,  # total 1072 x 1185
                   0x90, 0x03, 0x74, 0x04,  # active 912 x 1140
                   0x05, 0x00, 0x07, 0x00])  # first active pixel 5, line 7


def test_video_status_and_source_decode_as_ti_s_api():
    v = dlp.decode_video_status(VID_BYTES)
    assert (v["status"], v["h_res"], v["v_res"], v["hsync_pol"], v["vsync_pol"]) == \
        (2, 912, 1140, 1, 0)
    assert (v["pix_clock"], v["h_freq"], v["v_freq"]) == (1_000_000, 0x1234, 6000)
    assert (v["total_pixels_per_line"], v["total_lines_per_frame"]) == (1072, 1185)
    assert (v["active_pixels_per_line"], v["active_lines_per_frame"]) == (912, 1140)
    assert (v["first_active_pixel"], v["first_active_line"]) == (5, 7)
    assert dlp.encode_video_status(**{**v, "status": 6}) == VID_BYTES
    with pytest.raises(ProtocolError, match="VID_SIG_STAT: expected 28 bytes, got 27"):
        dlp.decode_video_status(VID_BYTES[:27])
    # DLPC350_GetInputSource: source = bits 2:0, port width = bits 7:3 (1 = 24 bits)
    assert dlp.decode_source_sel(b"\x08") == {"source": 0, "source_name": "parallel",
                                              "port_width": 1, "port_bits": 24}
    assert dlp.decode_source_sel(b"\x02")["source_name"] == "flash"
    assert dlp.decode_source_sel(b"\x0b")["source_name"] == "FPD-link"


def _lcr(**kw):
    bench = SimulatedBench(ExperimentConfig(n=8, roi_px=8, srs=(0.25,)), **kw)
    return bench, bench.lightcrafter(timeout_ms=100)


def test_check_video_input_passes_a_locked_912x1140_input_at_the_rate():
    bench, lcr = _lcr()
    got = lcr.check_video_input(60.0)
    assert (got["source"], got["port_bits"], got["status"]) == (0, 24, 2)
    assert (got["active_pixels_per_line"], got["active_lines_per_frame"]) == (912, 1140)
    log = bench.lightcrafter_usb.log
    assert [(m.command, m.read) for m in log] == [("SOURCE_SEL", True), ("VID_SIG_STAT", True)]
    bench.lightcrafter_usb.video_signal["v_freq"] = 60  # the same rate read in whole Hz
    lcr.check_video_input(60.0)
    bench, lcr = _lcr(video_hz=50.0)
    lcr.check_video_input(50.0)


@pytest.mark.parametrize("change,match", [
    ({"source_sel": 0x02}, r"the input source is flash \(SOURCE_SEL source 2\)"),
    ({"status": 3}, r"not locked \(VID_SIG_STAT status 3, locked is 2\)"),
    ({"active_pixels_per_line": 1280, "active_lines_per_frame": 800},
     r"the active area is 1280x800, the DMD needs 912x1140"),
    ({"v_freq": 5000}, r"the vertical rate word 5000 is neither 50 Hz .* nor 5000 Hz within "
                       r"1% of video_hz = 60"),
])
def test_check_video_input_lists_what_was_read(change, match):
    bench, lcr = _lcr()
    fake = bench.lightcrafter_usb
    for k, v in change.items():
        (fake.state if k == "source_sel" else fake.video_signal)[k] = v
    with pytest.raises(HardwareError, match=match) as exc:
        lcr.check_video_input(60.0)
    assert "Read: source=" in str(exc.value) and "v_freq=" in str(exc.value)


def test_acquire_checks_the_video_input_before_creating_a_store(tmp_path):
    pytest.importorskip("zarr", minversion="3")
    from torchtof.hardware import acquire

    bench, lcr = _lcr()
    bench.lightcrafter_usb.video_signal["status"] = 3
    with pytest.raises(HardwareError, match="not locked"):
        acquire(tmp_path / "r.zarr", lcr, bench.camera(), n=8, sr=0.125, progress=False)
    assert not (tmp_path / "r.zarr").exists()
    bench, lcr = _lcr()  # a 60 Hz input, a run that assumes 50 Hz
    with pytest.raises(HardwareError, match="video_hz = 50"):
        acquire(tmp_path / "r.zarr", lcr, bench.camera(), n=8, sr=0.125, progress=False,
                video_hz=50.0, exposure_us=20_000)
    assert not (tmp_path / "r.zarr").exists()


# -- 6. an empty read reply ----------------------------------------------------------------------


def test_an_empty_read_reply_is_a_nack_not_an_index_error():
    bench = SimulatedBench(ExperimentConfig(n=8, roi_px=8, srs=(0.25,)),
                           faults=Faults(empty_reply={"DISP_MODE": {0}, "LUT_VALID": {0}}))
    lcr = bench.lightcrafter(timeout_ms=100)
    with pytest.raises(NackError, match="DISP_MODE: device answered NACK: the reply carries no "
                                        "data"):
        lcr.display_mode()
    assert lcr.display_mode() == "video"  # the next read answers
    with pytest.raises(NackError, match="LUT_VALID"):
        lcr.read("LUT_VALID")
    assert Faults.from_dict({"empty_reply": {"STATUS_HW": [1]}}).empty_reply == {"STATUS_HW": {1}}


def test_an_empty_reply_on_the_wire():
    """The reply report ``c0 SS 00 00``: flags read|reply, the command's sequence byte, length
    0 (TI's DLPC350_Read returns -2 for it)."""

    class Dev:
        def __init__(self):
            self.seq = None

        def write(self, ep, data, timeout=None):
            self.seq = bytes(data)[1]
            return len(data)

        def read(self, ep, size, timeout=None):
            if self.seq is None:
                raise usb_exceptions()[1]("Operation timed out", errno=110)
            report, self.seq = bytes([0xC0, self.seq, 0x00, 0x00]).ljust(64, b"\0"), None
            return bytearray(report)

    with pytest.raises(NackError, match="STATUS_HW: device answered NACK"):
        dlp.LightCrafter4500(Dev(), timeout_ms=50).read("STATUS_HW")


# -- 7. the video rate cap ---------------------------------------------------------------------


def test_video_hz_is_capped_at_120():
    assert dlp.patterns_per_vsync(8000, 8000, 120.0) == 1
    with pytest.raises(ValueError, match=r"dlpc350.patterns_per_vsync: expected video_hz in "
                                         r"\(0, 120\] Hz"):
        dlp.patterns_per_vsync(5000, 5000, 121.0)
    with pytest.raises(ValueError, match="LightCrafter4500.check_video_input: expected video_hz"):
        _lcr()[1].check_video_input(144.0)


def test_cli_refuses_a_video_rate_above_120(tmp_path, capsys):
    pytest.importorskip("zarr", minversion="3")
    from torchtof.cli import main

    with pytest.raises(SystemExit) as exc:
        main(["acquire", "--simulated", "--n", "8", "--trigger", "internal", "--video-hz", "144",
              "-o", str(tmp_path / "x.zarr")])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "argument --video-hz: expected --video-hz in (0, 120]" in err


# -- 9. pattern numbers, 10. the DMD size --------------------------------------------------------


def test_lut_entry_takes_patterns_0_to_24_as_ti_s_code():
    # DLPC350_AddToPatLut: TrigType & 3 | PatNum << 2 | BitDepth << 8 | LEDSelect << 12
    assert dlp.lut_entry(24, 1, "RGB", "internal") == 0 | 24 << 2 | 1 << 8 | 7 << 12
    with pytest.raises(ValueError, match=r"lut_entry: expected pattern in \[0, 24\].*PatNum > 24"):
        dlp.lut_entry(25)


def test_the_dmd_shape_is_ti_s_pattern_mode_resolution():
    assert video.DMD_SHAPE == dlp.DMD_SHAPE == (1140, 912)  # DLPC350_SetMode: 912 x 1140


def test_the_optimal_band_and_the_default_frequency():
    lo, hi = opt.TI_OPTIMAL_MOD_FREQ_HZ
    assert (lo, hi) == (39e6, 60e6)  # TintinCDKModulationFrequencyParameter
    assert opt.DEFAULT_MOD_FREQ_HZ < lo  # the paper's 30 MHz lies below TI's band
    assert math.isclose(opt.unambiguous_range_m(lo), 3.843, abs_tol=1e-3)
    assert math.isclose(opt.unambiguous_range_m(hi), 2.498, abs_tol=1e-3)
