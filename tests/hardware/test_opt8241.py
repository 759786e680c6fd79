"""OPT8241: register requests and named OPT9221 bit fields (Voxel SDK OPT9221.dml, written
out by hand below), the PLL and integration-time conversions, decoding of hand-built frames
in every documented layout, and the driver on the fake camera."""

import math
import struct

import numpy as np
import pytest
import torch

from torchtof.experiment import ExperimentConfig
from torchtof.hardware import opt8241 as opt
from torchtof.hardware.errors import FrameError, FrameTimeoutError, HardwareError, ProtocolError
from torchtof.hardware.simulated import SimulatedBench
from torchtof.sensor import (
    SPEED_OF_LIGHT,
    cw_tof_sensor,
    phasor_from_depth,
)


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


class Recorder:
    """A pyusb-like device that logs every control transfer and keeps 24-bit registers."""

    def __init__(self, regs=None):
        self.regs, self.log = dict(regs or {}), []

    def ctrl_transfer(self, rtype, req, wvalue, windex, data, timeout=None):
        slave = wvalue >> 8 if wvalue > 0xFF else wvalue
        reg = windex >> 8 if wvalue > 0xFF else windex
        address = slave << 8 | reg
        if rtype == 0x40:
            self.log.append((rtype, req, wvalue, windex, bytes(data)))
            self.regs[address] = int.from_bytes(bytes(data), "little")
            return len(data)
        self.log.append((rtype, req, wvalue, windex, data))
        return bytearray(self.regs.get(address, 0).to_bytes(data, "little"))


# name, value, wValue (slave), wIndex (register), the 3 bytes written (register initially 0):
# bank/address/lsb/msb from OPT9221.dml, bank 0 -> slave 0x58, bank 3 -> slave 0x5C
FIELDS = [
    ("mod_pll_update", 1, 0x58, 0x02, b"\x04\x00\x00"),  # reg 2 bit 2
    ("mod_m_frac1", 0xABCD, 0x58, 0x0C, b"\xcd\xab\x00"),  # reg 12 bits 0-15
    ("mod_m1", 15, 0x58, 0x0C, b"\x00\x00\x0f"),  # reg 12 bits 16-21
    ("mod_n1", 2, 0x58, 0x0F, b"\x02\x00\x00"),  # reg 15 bits 0-1
    ("mod_ps1", 2, 0x58, 0x0F, b"\x20\x00\x00"),  # reg 15 bits 4-6
    ("tg_dis", 1, 0x58, 0x80, b"\x01\x00\x00"),  # reg 128 bit 0
    ("slave_mode", 1, 0x58, 0x81, b"\x01\x00\x00"),  # reg 129 bit 0
    ("pix_cnt_max", 100000, 0x58, 0x82, b"\xa0\x86\x01"),  # reg 130 bits 0-21
    ("quad_cnt_max", 4, 0x58, 0x83, b"\x04\x00\x00"),  # reg 131 bits 0-3
    ("sub_frame_cnt_max", 4, 0x58, 0x83, b"\x40\x00\x00"),  # reg 131 bits 4-7
    ("output_mode", 15, 0x5C, 0x25, b"\x00\x0f\x00"),  # bank 3 reg 37 bits 8-11
    ("op_data_arrange_mode", 2, 0x5C, 0x25, b"\x00\x00\x08"),  # bits 18-19
    ("pixel_data_size", 4, 0x5C, 0x27, b"\x00\x20\x00"),  # bank 3 reg 39 bits 11-14
    ("debug_frame_number_en", 1, 0x5C, 0x39, b"\x00\x10\x00"),  # bank 3 reg 57 bit 12
    ("frm_header_en", 1, 0x5C, 0x3C, b"\x02\x00\x00"),  # bank 3 reg 60 bit 1
    ("blk_header_en", 1, 0x5C, 0x3C, b"\x04\x00\x00"),  # bit 2
    ("intg_duty_cycle", 20, 0x5C, 0x4C, b"\x14\x00\x00"),  # bank 3 reg 76 bits 0-5
    ("pix_cnt_max_set_failed", 1, 0x5C, 0x63, b"\x00\x00\x40"),  # bank 3 reg 99 bit 22
    ("intg_duty_cycle_set_failed", 1, 0x5C, 0x63, b"\x00\x00\x80"),  # bit 23
    ("op_overflow", 1, 0x5C, 0x63, b"\x00\x00\x10"),  # DML id 6378: bank 3 reg 99 bit 20
    ("dealias_en", 1, 0x5C, 0x02, b"\x00\x00\x80"),  # bank 3 reg 2 bit 23
    ("dealias_16bit_op_enable", 1, 0x5C, 0x28, b"\x00\x00\x80"),  # bank 3 reg 40 bit 23
    ("delay_fb_coeff_1", 1280, 0x5C, 0xB3, b"\x00\x05\x00"),  # bank 3 reg 179 bits 0-11
    ("tillum_slv_addr", 0x72, 0x5C, 0x2E, b"\x72\x00\x00"),  # bank 3 reg 46 bits 0-6
    ("op_clk_freq", 1, 0x5C, 0x39, b"\x02\x00\x00"),  # DML id 6136: bank 3 reg 57 bits 1-2
    ("frm_trailer_en", 1, 0x5C, 0x3C, b"\x08\x00\x00"),  # id 6360: reg 60 bit 3
    ("dealiased_ph_mask", 5, 0x5C, 0x03, b"\x00\x28\x00"),  # id 991: reg 3 bits 11-14
    ("sync_mode", 1, 0x58, 0x81, b"\x00\x10\x00"),  # id 637: bank 0 reg 129 bit 12
    ("normal_frm_intg_scale", 3, 0x5C, 0x4D, b"\xc0\x00\x00"),  # id 9980: reg 77 bits 6-8
    ("bin_row_count", 240, 0x5C, 0x2F, b"\x00\x00\x3c"),  # id 2011: reg 47 bits 14-23
    ("bin_col_count", 320, 0x5C, 0x30, b"\x00\x00\x50"),  # id 2012: reg 48 bits 14-23
    ("row_start", 5, 0x58, 0x1F, b"\x05\x00\x00"),  # id 13: bank 0 reg 31 bits 0-7
    ("row_end", 239, 0x58, 0x1F, b"\x00\x00\xef"),  # id 536: reg 31 bits 16-23
    ("col_start", 2, 0x58, 0x20, b"\x10\x00\x00"),  # id 534: reg 32 bits 3-7
    ("col_end", 19, 0x58, 0x21, b"\x98\x00\x00"),  # id 538: reg 33 bits 3-7
    ("binning_en", 1, 0x5C, 0x2F, b"\x00\x10\x00"),  # id 2006: bank 3 reg 47 bit 12
    ("rows_to_merge", 1, 0x5C, 0x2F, b"\x01\x00\x00"),  # id 2008: reg 47 bits 0-9
    ("cols_to_merge", 1, 0x5C, 0x30, b"\x01\x00\x00"),  # id 2009: reg 48 bits 0-9
    # PLL 2: ids 7064, 7065 (bank 0 reg 13 bits 0-15, 16-21), 7079 (reg 15 bits 2-3), 7081
    # (reg 15 bits 7-9); sscg_en id 8665 (reg 14 bit 3)
    ("mod_m_frac2", 0xABCD, 0x58, 0x0D, b"\xcd\xab\x00"),
    ("mod_m2", 20, 0x58, 0x0D, b"\x00\x00\x14"),
    ("mod_n2", 2, 0x58, 0x0F, b"\x08\x00\x00"),
    ("mod_ps2", 5, 0x58, 0x0F, b"\x80\x02\x00"),  # 5 << 7 = 0x280
    ("sscg_en", 1, 0x58, 0x0E, b"\x08\x00\x00"),
    # phase calibration: ids 2091, 2095 (bank 3 regs 55, 56 bits 4-15, 12-bit signed: 0xFFF
    # is -1), 2098, 2099 (reg 81 bits 16, 17), 9981 (reg 182 bit 19), 8801 (reg 128 bit 0)
    ("phase_corr_1", 0xFFF, 0x5C, 0x37, b"\xf0\xff\x00"),
    ("phase_corr_2", 0x123, 0x5C, 0x38, b"\x30\x12\x00"),
    ("disable_offset_corr", 1, 0x5C, 0x51, b"\x00\x00\x01"),
    ("disable_temp_corr", 1, 0x5C, 0x51, b"\x00\x00\x02"),
    ("filt_en", 1, 0x5C, 0xB6, b"\x00\x00\x08"),
    ("phase_lin_corr_en", 1, 0x5C, 0x80, b"\x01\x00\x00"),
    ("hdr_scale", 3, 0x5C, 0x4C, b"\xc0\x00\x00"),  # id 6377: reg 76 bits 6-8
    ("padding_en", 1, 0x5C, 0x3C, b"\x01\x00\x00"),  # id 6146: reg 60 bit 0
]


#: bin_row_count = 240 (0x5C2F) and bin_col_count = 320 (0x5C30) at bits 14-23: the QVGA frame
#: the driver decodes by default (DML defaults of ids 2011, 2012)
QVGA = {0x5C2F: 240 << 14, 0x5C30: 320 << 14}


def test_every_named_register_has_a_byte_exact_test():
    assert {f[0] for f in FIELDS} == set(opt.REGISTERS)


@pytest.mark.parametrize("name,value,slave,reg,data", FIELDS)
def test_named_register_requests_byte_exact(name, value, slave, reg, data):
    dev = Recorder()
    cam = opt.OPT8241(dev)
    cam.write_field(name, value)
    # read-modify-write: read the 3-byte register, write it back with the field set
    assert dev.log == [(0xC0, 0x08, slave, reg, 3), (0x40, 0x09, slave, reg, data)]
    assert cam.read_field(name) == value


def test_write_field_keeps_the_other_bits_and_checks_the_width():
    dev = Recorder({0x580F: 0xFFFFFF})
    cam = opt.OPT8241(dev)
    cam.write_field("mod_ps1", 2)
    assert dev.regs[0x580F] == 0xFFFFAF  # bits 4-6 = 010, all others untouched
    with pytest.raises(ValueError, match="mod_ps1=8 does not fit bits 4..6"):
        cam.write_field("mod_ps1", 8)
    with pytest.raises(TypeError, match="integer"):
        cam.write_field("tg_dis", True)
    with pytest.raises(ValueError, match="unknown register field"):
        cam.read_field("stream_enable")


def test_pll_settings_match_the_sdk_and_the_dml_defaults():
    # 48 MHz (the SDK default) gives the DML reset values mod_m1=16, mod_n1=2, mod_ps1=1
    assert opt.pll_settings(48e6) == {"mod_ps1": 1, "mod_n1": 2, "mod_m1": 16, "mod_m_frac1": 0}
    assert opt.pll_frequency_hz(16, 0, 2, 1, 4) == 48e6
    # 30 MHz: ps = floor(300/4/30) = 2, vco = 3*4*30 = 360 MHz, M = 360*2/48 = 15
    assert opt.pll_settings(30e6) == {"mod_ps1": 2, "mod_n1": 2, "mod_m1": 15, "mod_m_frac1": 0}
    # 20 MHz: ps = 3, vco = 320 MHz, M·= 13.333…: frac = floor(0.3333… · 65536) = 21845
    s = opt.pll_settings(20e6)
    assert s == {"mod_ps1": 3, "mod_n1": 2, "mod_m1": 13, "mod_m_frac1": 21845}
    f = opt.pll_frequency_hz(s["mod_m1"], s["mod_m_frac1"], 2, 3, 4)
    assert f == pytest.approx(48e6 * (13 + 21845 / 65536) / 32) and abs(f - 20e6) < 10.0
    for bad in (9e6, 151e6, float("nan")):  # 37.5/4 … 600/4 MHz
        with pytest.raises(ValueError, match="freq_hz"):
            opt.pll_settings(bad)


def test_set_modulation_frequency_request_sequence():
    dev = Recorder({0x5883: 0x44})  # quad_cnt_max = 4, sub_frame_cnt_max = 4
    cam = opt.OPT8241(dev)
    assert cam.set_modulation_frequency(30e6) == 30e6
    writes = [(w, d) for (t, _, _, w, d) in dev.log if t == 0x40]
    assert writes == [
        (0x02, b"\x04\x00\x00"),  # mod_pll_update = 1
        (0x0C, b"\x00\x00\x0f"),  # mod_m1 = 15
        (0x0F, b"\x02\x00\x00"),  # mod_n1 = 2
        (0x0C, b"\x00\x00\x0f"),  # mod_m_frac1 = 0
        (0x0F, b"\x22\x00\x00"),  # mod_ps1 = 2
        # PLL 2 as PLL 1 (TintinCDKCameraNoCalibration.conf: mod_freq2 = mod_freq1):
        (0x0D, b"\x00\x00\x0f"),  # mod_m2 = 15 (reg 13 bits 16-21)
        (0x0F, b"\x2a\x00\x00"),  # mod_n2 = 2 (reg 15 bits 2-3), PLL 1's bits kept
        (0x0D, b"\x00\x00\x0f"),  # mod_m_frac2 = 0 (reg 13 bits 0-15)
        (0x0F, b"\x2a\x01\x00"),  # mod_ps2 = 2 (reg 15 bits 7-9: 0x100)
        (0x02, b"\x00\x00\x00"),  # mod_pll_update = 0 (TintinVCOFrequency::set's window)
        # DML id 7984: "After updating the PLL registers, set this register to 1 and then back
        # to 0" (the last two writes of ToFTintinCamera::_init)
        (0x02, b"\x04\x00\x00"),  # mod_pll_update = 1
        (0x02, b"\x00\x00\x00"),  # mod_pll_update = 0
        (0xB3, b"\x00\x05\x00"),  # delay_fb_coeff_1 = 30 · 1024 / 24 = 1280 (DML id 10019)
    ]
    assert cam.freq_hz == 30e6 and cam.pll2_freq_hz == 30e6


def test_integration_time_conversion():
    dev = Recorder({0x5882: 100000, 0x5883: 0x44, 0x5C4C: 6})  # DML defaults
    cam = opt.OPT8241(dev)
    frame_us = 100000 * 4 * 4 / 48  # pix_cnt_max · quads · sub-frames / 48 MHz
    assert cam.frame_time_us == pytest.approx(frame_us)
    # DML: integration time = intg_duty_cycle · 100/64 percent
    assert cam.integration_time_us == pytest.approx(6 * 100 / 64 / 100 * frame_us)
    got = cam.set_integration_time(1000)  # (uint)(1000 / 33333.3 · 64 + 0.5) = 2
    assert dev.regs[0x5C4C] == 2 and got == pytest.approx(2 / 64 * frame_us)
    cam.set_integration_time(20 / 64 * frame_us)  # the board's cap, 20
    assert dev.regs[0x5C4C] == 20
    for bad in (-1, 21 / 64 * frame_us, float("nan"), True):
        with pytest.raises(ValueError, match="integration time"):
            cam.set_integration_time(bad)


def test_set_failed_flags_are_read_back_and_raise():
    dev = Recorder({0x5882: 100000, 0x5883: 0x44, 0x5C63: 1 << 23})
    cam = opt.OPT8241(dev)
    with pytest.raises(HardwareError, match="intg_duty_cycle_set_failed"):
        cam.set_integration_time(1000)
    dev = Recorder({0x5882: 100000, 0x5883: 0x14, 0x5C63: 1 << 22})
    with pytest.raises(HardwareError, match="pix_cnt_max_set_failed"):
        opt.OPT8241(dev).set_frame_time(9500)


def test_frame_time_is_programmed_to_fit_the_pattern_period():
    dev = Recorder({0x5882: 100000, 0x5883: 0x44})  # power-up: 33.3 ms
    cam = opt.OPT8241(dev)
    got = cam.set_frame_time(9500)  # pix = floor(9500 · 48 / (4 · 1)) = 114000
    assert dev.regs[0x5882] == 114000 and opt.REGISTERS["sub_frame_cnt_max"].get(
        dev.regs[0x5883]) == 1
    assert got == pytest.approx(9500) and got <= 9500
    with pytest.raises(ValueError, match="pix_cnt_max = 48000 < 50000"):
        cam.set_frame_time(4000)  # 4000 · 48 / 4 = 48000: below the board's limit
    with pytest.raises(ValueError, match="sub_frames"):
        cam.set_frame_time(9500, sub_frames=3)


def test_uninitialised_board_is_refused():
    with pytest.raises(HardwareError, match="tillum_slv_addr reads 0x71.*Voxel Viewer"):
        opt.OPT8241(Recorder({0x5C2E: 0x71})).check_initialised()
    opt.OPT8241(Recorder({0x5C2E: 0x72})).check_initialised()


# -- frame decoding on hand-built bytes ------------------------------------------------------
WIDE = opt.CameraRules(min_m=0.0, max_m=100.0, step_m=None)


def test_decode_depth_continuous():
    # pixel 0: amplitude 0x123, ambient 4, phase 0x800 (π), flags 1; pixel 1: all zero
    raw = bytes([0x23, 0x41, 0x00, 0x18, 0, 0, 0, 0])
    fr = opt.decode_frame(raw, 2, 1, 30e6, "depth", WIDE, frame_id=5, timestamp=1.5)
    assert fr.amplitude.tolist() == [[0x123, 0]]
    assert fr.ambient.tolist() == [[4, 0]] and fr.flags.tolist() == [[1, 0]]
    assert fr.phase[0, 0].item() == pytest.approx(math.pi)
    # θ = π at 30 MHz: c / (4 f) (Eq. 1)
    assert fr.depth[0, 0].item() == pytest.approx(SPEED_OF_LIGHT / (4 * 30e6), rel=1e-6)
    assert (fr.frame_id, fr.timestamp, fr.taps) == (5, 1.5, None)


def test_decode_depth_rearranged_in_chunks_of_8():
    amp = [0x100 + k for k in range(8)]
    phase = [0x200 * k | (k % 4) << 12 for k in range(8)]  # flags k % 4
    raw = struct.pack("<16H", *amp, *phase)  # 8 amplitude words, then 8 phase words
    fr = opt.decode_frame(raw, 8, 1, 30e6, "depth8", WIDE)
    assert fr.amplitude[0].tolist() == amp
    assert fr.flags[0].tolist() == [k % 4 for k in range(8)]
    np.testing.assert_allclose(fr.phase[0].numpy(), [2 * math.pi * 0x200 * k / 4096
                                                     for k in range(8)], rtol=1e-6)
    assert opt.pack_depth(np.array([[0x200 * k for k in range(8)]]), np.array([amp]),
                          flags=np.array([[k % 4 for k in range(8)]]), arrange=2) == raw
    with pytest.raises(ValueError, match="divisible by 8"):
        opt.decode_frame(bytes(24), 6, 1, 30e6, "depth8")


def test_decode_depth2():
    fr = opt.decode_frame(struct.pack("<H", 0xA800), 1, 1, 30e6, "depth2", WIDE)
    assert fr.amplitude.item() == 0xA00 and fr.phase.item() == pytest.approx(math.pi)


def test_decode_iq_follows_eqs_7_and_8():
    raw = struct.pack("<hh", 3, -4)  # I = 3, Q = -4
    fr = opt.decode_frame(raw, 1, 1, 30e6, "iq", WIDE)
    assert fr.amplitude.item() == 2.5  # |3 - 4j| / 2 (Eq. 8)
    assert fr.phase.item() == pytest.approx(math.atan2(-4, 3) + 2 * math.pi)


def _sdk_words(theta, amp, quads, offset=0):
    """Raw-quad words of one row of pixels written from the SDK's arithmetic (not the
    decoder's): sample k of a pixel with phase θ is round(offset + A cos(θ − 2πk/N)), so that
    I = Σ d_k cos(2πk/N) = (N/2) A cos θ and Q = Σ d_k sin(2πk/N) = (N/2) A sin θ; each sample
    is sent as its 16-bit two's complement."""
    words = []
    for t in theta:
        for k in range(quads):
            d = round(offset + amp * math.cos(t - 2 * math.pi * k / quads))
            words.append(d & 0xFFFF)
    return struct.pack(f"<{len(words)}H", *words)


@pytest.mark.parametrize("quads", [4, 6])
def test_quad_decoding_recovers_the_phase_from_sdk_style_frames(quads):
    theta = [0.3 + 0.1 * k for k in range(57)]  # 0.3 … 5.9 rad
    raw = _sdk_words(theta, 1500, quads, offset=-300)
    fr = opt.decode_frame(raw, len(theta), 1, 30e6, "quad", WIDE, quads=quads)
    got = fr.phase[0].double()
    assert torch.allclose(got, torch.tensor(theta, dtype=torch.float64), atol=1e-3, rtol=0)
    # amplitude: Eq. 8's, 2|I + jQ| / N = A
    assert torch.allclose(fr.amplitude[0].double(), torch.full((57,), 1500.0, dtype=torch.float64),
                          atol=2.0)


def test_quad_samples_are_signed_12_bit_and_the_top_nibble_ignored():
    # 0x0F00 and 0xFF00: low 12 bits 0xF00, sign-extended: -256 (ToFFrameGenerator.cpp)
    words = np.array([[[0x0F00, 0xFF00, 0x0100, 0x7005]]], dtype=np.uint16)
    d, i, q = opt.sdk_quad_iq(words, 4)
    assert d.tolist() == [[[-256, -256, 256, 5]]]
    assert i[0, 0] == pytest.approx(-256 - 256) and q[0, 0] == pytest.approx(-256 - 5)
    fr = opt.decode_frame(words.tobytes(), 1, 1, 30e6, "quad", WIDE)  # no reserved-bit error
    assert fr.taps.view(-1).tolist() == [-256, 256, 5, -256]  # c1..c4 = d0, d2, d3, d1
    assert fr.phase.item() == pytest.approx(math.atan2(-261, -512) + 2 * math.pi, abs=1e-6)
    assert len(opt.pack_quads(np.zeros((6, 2, 3), dtype=np.int64))) == \
        opt.frame_bytes(3, 2, "quad", quads=6) == 3 * 2 * 6 * 2


def test_encode_frame_and_pack_reject_bad_input():
    with pytest.raises(ValueError, match="taps"):
        opt.encode_frame("quad", np.ones((3, 2, 2)))
    with pytest.raises(ValueError, match="unknown mode"):
        opt.encode_frame("tof", np.ones((4, 2, 2), dtype=np.int64))
    with pytest.raises(ValueError, match="phase12"):
        opt.pack_depth(np.full((1, 2), 4096), np.zeros((1, 2)))


def _sensor_frame():
    g = torch.Generator().manual_seed(0)
    depth = 1.0 + 3.0 * torch.rand(1, 1, 6, 8, generator=g)
    kw = dict(freq_hz=30e6, ambient_e=300.0, shot="poisson", read_noise_e=3.0, adc_bits=12,
              gain_e_per_dn=1.0, min_m=1.0, max_m=5.0, amp_threshold=20.0, step_m=0.25)
    return cw_tof_sensor(phasor_from_depth(800.0, depth, 30e6), generator=g, **kw)


@pytest.mark.parametrize("mode", ["quad", "iq"])
def test_quad_and_iq_frames_equal_the_sensor_model_bit_for_bit(mode):
    fr = _sensor_frame()
    raw = opt.encode_frame(mode, fr.taps[0].numpy().astype(np.int64))
    out = opt.decode_frame(raw, 8, 6, 30e6, mode, opt.CameraRules(1.0, 5.0, 0.25, 20.0, 5.0))
    assert torch.equal(out.depth, fr.depth[0, 0])
    assert torch.equal(out.amplitude, fr.amplitude[0, 0])
    assert torch.equal(out.phase, fr.phase[0, 0])
    assert (out.taps is not None) == (mode == "quad")


@pytest.mark.parametrize("mode", ["depth", "depth8"])
def test_depth_frames_agree_to_the_12_bit_quantum(mode):
    fr = _sensor_frame()
    raw = opt.encode_frame(mode, fr.taps[0].numpy().astype(np.int64))
    out = opt.decode_frame(raw, 8, 6, 30e6, mode, WIDE)
    dphi = (out.phase - fr.phase[0, 0]).abs()
    assert float(torch.minimum(dphi, 2 * math.pi - dphi).max()) <= math.pi / 4096 + 1e-6
    assert float((out.amplitude - fr.amplitude[0, 0]).abs().max()) <= 0.5


# -- the driver on the fake camera ------------------------------------------------------------
def _camera(**kw):
    cfg = ExperimentConfig(n=8, roi_px=8, srs=(0.25,))
    bench = SimulatedBench(cfg)
    return bench, bench.camera(**kw)


def test_fake_camera_registers_through_the_driver():
    bench, cam = _camera()
    assert cam.freq_hz == 30e6  # the fake's PLL is set for the configuration
    assert cam.set_modulation_frequency(48e6) == 48e6
    assert bench.camera_usb.regs[0x580C] == 16 << 16 and bench.camera_usb.freq_hz == 48e6
    cam.write_register(0x2D10, 0xAB)  # a 1-byte slave, shifted request fields
    assert cam.read_register(0x2D10) == 0xAB
    with pytest.raises(ValueError, match="does not fit"):
        cam.write_register(0x2D10, 256)


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


def test_grab_timeout_names_the_pattern():
    _, cam = _camera()
    cam.start()
    cam.pattern_index = 17
    with pytest.raises(FrameTimeoutError, match="pattern 17 within 0.01 s"):
        cam.grab(0.01)
    assert cam.flush(0.001) == 0


@pytest.mark.parametrize("mode", list(opt.FRAME_MODES))
def test_fake_camera_streams_the_mode_the_registers_select(mode):
    bench, cam = _camera(mode=mode)
    pat = np.ones((8, 8), dtype=np.uint8)
    bench.camera_usb.trigger(pat, 0.0)  # tg_dis = 1: not streaming, ignored
    assert bench.camera_usb.rendered == 0
    cam.start()
    assert bench.camera_usb.mode == mode and bench.camera_usb.field("blk_header_en") == 0
    assert bench.camera_usb.field("slave_mode") == 1
    frame_s = 100000 * 4 * 4 / 48e6  # power-up frame time, 33.3 ms
    bench.camera_usb.trigger(pat, 0.0)
    bench.camera_usb.trigger(pat, 0.010)  # during the first frame: missed
    bench.camera_usb.trigger(pat, 1.0)
    assert bench.camera_usb.missed_triggers == 1
    a, b = cam.grab(0.5), cam.grab(0.5)
    # no header: W·H·bytes per pixel (8 x 9: the ROI below the simulator's guard row)
    assert len(a.raw) == opt.frame_bytes(8, 9, mode) == 8 * 9 * (8 if mode == "quad" else
                                                                 opt.FRAME_MODES[mode][1])
    assert (a.frame_id, b.frame_id) == (0, 1) and cam.frame_counter() == 2  # host-side ids
    assert (a.timestamp, b.timestamp) == (pytest.approx(frame_s), pytest.approx(1 + frame_s))
    assert a.depth.shape == (9, 8) and (a.taps is not None) == (mode == "quad")
    cam.stop()
    assert bench.camera_usb.field("tg_dis") == 1


def test_oversized_transfer_is_a_usb_error():
    bench, cam = _camera()
    cam.start()
    bench.camera_usb._fifo.append((9, bytes(10_000), 0.0))  # > frame + 255 bytes: overflow
    with pytest.raises(ProtocolError, match="bulk read: USB error.*Overflow"):
        cam.grab(1.0)
    cam.start()  # a failed bulk read ends the reader: restart it
    bench.camera_usb._fifo.append((9, bytes(100), 0.0))  # a short transfer: not a frame
    with pytest.raises(FrameError, match="100 bytes, a 8x9 'quad' frame has 576"):
        cam.grab(1.0)
    assert cam.frame_counter() == 0  # neither was numbered


def test_driver_rejects_bad_modes_and_sizes():
    with pytest.raises(ValueError, match="unknown mode 'tof'"):
        opt.OPT8241(Recorder(), mode="tof")
    with pytest.raises(ValueError, match="bad frame size 12x8 for mode 'depth8'"):
        opt.OPT8241(Recorder(), width=12, height=8, mode="depth8")


# -- device frame numbers (OPT9221.dml debug_frame_number_en, bank 3 reg 57 bit 12) ------------
def test_configure_with_frame_ids_writes_the_counter_bit_byte_exact():
    """Read-modify-write of 0x5C39: bit 12 set, the register's other bits kept
    (op_serial_width, bit 10, set here); blk_header_en, frm_header_en, frm_trailer_en and
    padding_en (0x5C3C bits 2, 1, 3, 0) cleared."""
    dev = Recorder({0x5C39: 0x000400, 0x5C3C: 0x00000F, 0x5883: 0x04, **QVGA})
    opt.OPT8241(dev, frame_ids=True).configure()
    writes = [e for e in dev.log if e[0] == 0x40]
    assert (0x40, 0x09, 0x5C, 0x39, b"\x00\x14\x00") in writes
    hdr = [e[4] for e in writes if e[2:4] == (0x5C, 0x3C)]
    # blk_header_en, then frm_header_en, then frm_trailer_en, then padding_en
    assert hdr == [b"\x0b\x00\x00", b"\x09\x00\x00", b"\x01\x00\x00", b"\x00\x00\x00"]
    assert dev.regs[0x5C3C] == 0 and dev.regs[0x5C39] == 0x001400
    dev = Recorder({0x5C39: 0x001400, 0x5883: 0x04, **QVGA})
    opt.OPT8241(dev, frame_ids=False).configure()
    assert (0x40, 0x09, 0x5C, 0x39, b"\x00\x04\x00") in dev.log  # cleared again


@pytest.mark.parametrize("mode,first_word", [("quad", 0), ("iq", 0), ("depth", 0),
                                             ("depth8", 0), ("depth2", 0)])
def test_split_frame_id_restores_a_defined_first_byte(mode, first_word):
    taps = np.full((4, 2, 8), 0x0ABC, dtype=np.int64)
    taps[1] = 0x0123
    raw = bytearray(opt.encode_frame(mode, taps))
    sent_hi = raw[1]
    raw[0] = 0x2A  # what the OPT9221 sends with debug_frame_number_en = 1
    fid, data = opt.split_frame_id(bytes(raw))
    assert fid == 0x2A and data[0] == 0 and data[1] == sent_hi and data[2:] == bytes(raw[2:])
    out = opt.decode_frame(data, 8, 2, 30e6, mode, WIDE)
    ref = opt.decode_frame(opt.encode_frame(mode, taps), 8, 2, 30e6, mode, WIDE)
    same = torch.ones(2, 8, dtype=torch.bool)
    same[0, 0] = False  # only pixel (0, 0) differs
    assert torch.equal(out.depth[same], ref.depth[same])
    assert torch.equal(out.amplitude[same], ref.amplitude[same])
    if mode == "quad":  # sample d0 = tap c1 of pixel (0, 0): high byte as sent, low byte 0
        hi = sent_hi << 8
        assert float(out.taps[0, 0, 0]) == (hi & 0xFFF) - (hi & 0x800) * 2
        assert torch.equal(out.taps[1:], ref.taps[1:])
    with pytest.raises(FrameError, match="empty transfer"):
        opt.split_frame_id(b"")


def test_driver_takes_the_device_number_from_byte_zero():
    bench = SimulatedBench(ExperimentConfig(n=8, roi_px=8, srs=(0.25,)), frame_number_start=254)
    cam = bench.camera(frame_ids=True)
    cam.start()
    assert bench.camera_usb.field("debug_frame_number_en") == 1
    pat = np.ones((8, 8), dtype=np.uint8)
    for t in range(3):
        bench.camera_usb.trigger(pat, float(t))
    frames = [cam.grab(0.5) for _ in range(3)]
    assert [f.frame_id for f in frames] == [254, 255, 0]  # 8 bits: wraps
    assert [f.raw[0] for f in frames] == [254, 255, 0]  # Frame.raw: the bytes as received
    # guard row: sample -2048 = 0xF800, its low byte 0 restored
    assert all(float(f.taps[0, 0, 0]) == -opt.QUAD_OFFSET for f in frames)


# -- output bandwidth, frame size, integration scale, PLL settle, layout registers ----------


def test_output_time_is_the_frame_bytes_at_80_percent_of_the_output_clock():
    """TintinCDKCamera::_getMaximumFrameRate: 0.8 · (24 MHz >> op_clk_freq) bytes per second.
    A QVGA quad frame, N = 4: 320 · 240 · 8 = 614400 bytes / 19.2 MB/s = 32 ms; depth mode:
    307200 bytes, 16 ms; op_clk_freq = 1 (12 MHz) doubles both."""
    cam = opt.OPT8241(Recorder(dict(QVGA)), mode="quad")
    assert cam.output_time_us() == pytest.approx(32_000.0)
    assert opt.OPT8241(Recorder(dict(QVGA)), mode="depth").output_time_us() == \
        pytest.approx(16_000.0)
    slow = opt.OPT8241(Recorder({**QVGA, 0x5C39: 1 << 1}), mode="quad", quads=6)
    assert slow.output_time_us() == pytest.approx(320 * 240 * 12 / 9.6e6 * 1e6)


def test_configure_refuses_a_pattern_period_shorter_than_the_output_time():
    regs = {**QVGA, 0x5882: 100000, 0x5883: 0x44}
    cam = opt.OPT8241(Recorder(dict(regs)), mode="quad")
    with pytest.raises(ValueError, match=r"614400 bytes\) takes 32\.0 ms to send at 24 MHz.*"
                                         r"16\.7 ms between patterns"):
        cam.configure(period_us=16_667)
    cam.configure(period_us=33_000)  # fits: frame time programmed, no error
    assert cam.frame_time_us <= 32_500
    opt.OPT8241(Recorder(dict(regs)), mode="depth").configure(period_us=16_667)


def test_configure_checks_the_frame_size_the_camera_sends():
    cam = opt.OPT8241(Recorder({0x5C2F: 120 << 14, 0x5C30: 160 << 14}))
    with pytest.raises(HardwareError, match=r"sends 160x120 frames .* decodes 320x240; "
                                            r"construct it with width=160, height=120"):
        cam.configure()
    opt.OPT8241(Recorder({0x5C2F: 120 << 14, 0x5C30: 160 << 14, 0x5883: 0x04}), width=160,
                height=120).configure()


def test_configure_clears_what_an_earlier_program_may_have_left():
    """Header, trailer, sync mode, dealiased phase mask, pixel_data_size 2 (a depth2 run)."""
    dev = Recorder({**QVGA, 0x5C3C: 0b1110, 0x5881: 1 << 12, 0x5C03: 5 << 11,
                    0x5C27: 2 << 11, 0x5883: 0x04})
    cam = opt.OPT8241(dev, mode="quad")
    cam.configure()
    for name in ("frm_header_en", "frm_trailer_en", "blk_header_en", "sync_mode",
                 "dealiased_ph_mask"):
        assert cam.read_field(name) == 0, name
    assert cam.read_field("pixel_data_size") == 4 and cam.read_field("slave_mode") == 1


def test_integration_time_follows_normal_frm_intg_scale():
    """DML id 9980: integration time (scaled) = integration time >> normal_frm_intg_scale."""
    regs = {0x5882: 100000, 0x5883: 0x44, 0x5C4C: 6}  # 33.3 ms frame, duty 6/64
    plain = opt.OPT8241(Recorder(dict(regs)))
    halved = opt.OPT8241(Recorder({**regs, 0x5C4D: 1 << 6}))
    assert plain.integration_time_us == pytest.approx(6 / 64 * 100000 * 16 / 48)
    assert halved.integration_time_us == pytest.approx(plain.integration_time_us / 2)
    halved.set_integration_time(plain.integration_time_us / 2)  # the same duty cycle
    assert halved.read_field("intg_duty_cycle") == 6


def test_pll_update_is_released_10_ms_after_the_last_pll_write(monkeypatch):
    dev = Recorder({0x5883: 0x04})
    cam = opt.OPT8241(dev)
    events = []
    monkeypatch.setattr(opt.time, "sleep", lambda s: events.append(("sleep", s, len(dev.log))))
    cam.set_modulation_frequency(30e6)
    (_, s, at), = events
    assert s == 0.010
    after = [e for e in dev.log[at:] if e[0] == 0x40]
    assert after[0][2:] == (0x58, 0x02, b"\x00\x00\x00")  # then mod_pll_update = 0


def test_iq_words_are_int16_beyond_12_bits():
    """From six signed 12-bit samples |I| = |Σ d_k cos(2πk/6)| reaches 4 · 2048 = 8192: the SDK
    reads the words as plain int16 (_generateToFRawIQFrame), so do we."""
    fr = opt.decode_frame(struct.pack("<hh", 8000, -6000), 1, 1, 30e6, "iq", WIDE)
    assert fr.amplitude.item() == 5000.0  # |8000 - 6000j| / 2 (Eq. 8)


def test_throughput_tool_paces_patterns_at_the_camera_output_time():
    """A 320x240 quad frame takes 32 ms to send: the throughput tool's patterns are 32 ms
    apart on the internal trigger (the VSYNC pace of 16.7 ms would be refused); a small
    depth frame keeps 10 ms on the VSYNC trigger."""
    from torchtof.hardware.throughput import measure

    big = measure("quad", n=8, sr=0.125)
    assert (big["exposure_us"], big["trigger"], big["frames"]) == (32_000, "internal", 16)
    small = measure("depth", n=8, sr=0.125, width=64, height=48)
    assert (small["exposure_us"], small["trigger"]) == (10_000, "vsync")


def test_acquire_checks_the_output_time_against_the_vsync_spacing(tmp_path):
    """On the VSYNC trigger at 60 Hz, 10 ms patterns are 16.7 ms apart: a 320x240 depth frame
    (16.0 ms to send) fits, a quad frame (32 ms) is refused naming that spacing; the frame
    time still fits the 10 ms pattern."""
    from torchtof.hardware.acquisition import acquire
    from torchtof.hardware.throughput import ReplayCamera

    for mode in ("depth", "quad"):
        bench = SimulatedBench(ExperimentConfig(n=8, roi_px=8, srs=(0.125,)))
        bench.camera_usb = ReplayCamera(bench, 320, 240)
        cam = opt.OPT8241(bench.camera_usb, width=320, height=240, mode=mode,
                          clock=lambda b=bench: b.camera_usb.time_s)
        kw = dict(n=8, sr=0.125, progress=False, exposure_us=10_000, trigger="vsync")
        if mode == "depth":
            res = acquire(tmp_path / "depth.zarr", bench.lightcrafter(), cam, **kw)
            assert res.m_acquired == 8 and cam.frame_time_us <= 9_500
        else:
            with pytest.raises(ValueError, match=r"32\.0 ms to send .* 16\.7 ms between"):
                acquire(tmp_path / "quad.zarr", bench.lightcrafter(), cam, **kw)



def test_set_roi_writes_the_sdk_registers_and_shrinks_the_frame():
    """ToFTintinCamera::_setROI: rows 40..104, columns 64..127 -> col_start 64/16 = 4,
    col_end (64 + 64)/16 - 1 = 7; binning 1 x 1 with the region's size. A 64 x 65 quad frame
    (N = 4) is 33 280 bytes: 1.733 ms at 19.2 MB/s."""
    dev = Recorder(dict(QVGA))
    cam = opt.OPT8241(dev, mode="quad")
    cam.set_roi(40, 64, 65, 64)
    got = {k: cam.read_field(k) for k in ("row_start", "row_end", "col_start", "col_end",
                                          "rows_to_merge", "cols_to_merge", "bin_row_count",
                                          "bin_col_count", "binning_en")}
    assert got == {"row_start": 40, "row_end": 104, "col_start": 4, "col_end": 7,
                   "rows_to_merge": 1, "cols_to_merge": 1, "bin_row_count": 65,
                   "bin_col_count": 64, "binning_en": 1}
    assert (cam.width, cam.height) == (64, 65)
    assert cam.output_time_us() == pytest.approx(64 * 65 * 8 / 19.2e6 * 1e6)
    cam.check_frame_size()
    with pytest.raises(ValueError, match="multiples of 16"):
        cam.set_roi(0, 8, 10, 32)
    with pytest.raises(ValueError, match="beyond the 320x240 sensor"):
        cam.set_roi(200, 0, 65, 64)
    with pytest.raises(TypeError, match="integers"):
        cam.set_roi(0, 0, 10.0, 32)


def test_camera_roi_frames_are_that_region_of_the_full_frame():
    """The simulated camera reads out the region the ROI registers select: the same pattern
    (the same noise draw) gives the full frame's rows 4..13, columns 16..31."""
    cfg = ExperimentConfig(n=8, roi_px=32, srs=(0.25,))
    pat = (np.arange(64).reshape(8, 8) % 3 == 0).astype(np.uint8)
    frames = []
    for roi in (None, (4, 16, 10, 16)):
        bench = SimulatedBench(cfg)
        lcr, cam = bench.lightcrafter(), bench.camera()
        if roi:
            cam.set_roi(*roi)
        cam.start()
        lcr.show_sequence(pat[None], exposure_us=1000)
        frames.append(cam.grab(0.1))
    full, part = frames
    assert part.taps.shape == (4, 10, 16)
    assert torch.equal(part.taps, full.taps[:, 4:14, 16:32])


def test_a_camera_roi_lets_quad_frames_keep_the_vsync_pace(tmp_path):
    """A 320 x 240 quad frame (32 ms) cannot follow 10 ms patterns 16.7 ms apart; a 64 x 65
    region of it (1.7 ms) can."""
    from torchtof.hardware.acquisition import acquire
    from torchtof.hardware.throughput import ReplayCamera

    bench = SimulatedBench(ExperimentConfig(n=8, roi_px=8, srs=(0.125,)))
    bench.camera_usb = ReplayCamera(bench, 320, 240)
    cam = opt.OPT8241(bench.camera_usb, width=320, height=240, mode="quad",
                      clock=lambda: bench.camera_usb.time_s)
    cam.set_roi(0, 0, 65, 64)
    res = acquire(tmp_path / "roi.zarr", bench.lightcrafter(), cam, n=8, sr=0.125,
                  progress=False, exposure_us=10_000, trigger="vsync")
    assert res.m_acquired == 8 and (cam.width, cam.height) == (64, 65)


def test_a_failed_set_roi_writes_the_previous_region_back():
    """A write that fails half-way (col_start stalls) puts every written register back, and
    the frame-size check still agrees with the registers."""
    dev = Recorder(dict(QVGA))
    cam = opt.OPT8241(dev, mode="quad")
    cam.set_roi(0, 0, 65, 64)
    before = dict(dev.regs)
    real = dev.ctrl_transfer

    def stall_col_start(rtype, req, wvalue, windex, data, timeout=None):
        if rtype == 0x40 and (wvalue, windex) == (0x58, 0x20) and bytes(data) != b"\x00\x00\x00":
            raise ProtocolError("write register 0x5820", "stalled")
        return real(rtype, req, wvalue, windex, data, timeout)

    dev.ctrl_transfer = stall_col_start
    with pytest.raises(ProtocolError):
        cam.set_roi(16, 32, 33, 32)
    assert dev.regs == before and cam.roi == (0, 0, 65, 64) and (cam.width, cam.height) == (64, 65)
    cam.check_frame_size()


def test_a_failed_restore_write_does_not_stop_the_others():
    """The region write fails at bin_col_count and putting row_start/row_end back fails too:
    every other register is still written back."""
    dev = Recorder(dict(QVGA))
    cam = opt.OPT8241(dev, mode="quad")
    cam.set_roi(0, 0, 65, 64)
    before = dict(dev.regs)
    real, rows_writes = dev.ctrl_transfer, []

    def flaky(rtype, req, wvalue, windex, data, timeout=None):
        if rtype == 0x40 and (wvalue, windex) == (0x58, 0x1F):
            rows_writes.append(bytes(data))
            if len(rows_writes) > 2:  # the two writes of the region pass, the restores fail
                raise ProtocolError("write register 0x581F", "stalled")
        if rtype == 0x40 and (wvalue, windex) == (0x5C, 0x30) and \
                opt.REGISTERS["bin_col_count"].get(int.from_bytes(bytes(data), "little")) == 32:
            raise ProtocolError("write register 0x5C30", "stalled")
        return real(rtype, req, wvalue, windex, data, timeout)

    dev.ctrl_transfer = flaky
    with pytest.raises(ProtocolError, match="0x5C30"):
        cam.set_roi(16, 32, 33, 32)
    assert len(rows_writes) == 4  # row_start and row_end each tried once more
    changed = {a for a in set(before) | set(dev.regs) if before.get(a) != dev.regs.get(a)}
    assert changed == {0x581F}  # only the register whose restore failed


def test_check_frame_size_rounds_the_binned_size_down_as_the_register_map_says():
    """OPT9221.dml id 2011: bin_row_count "must be programmed to floor(total_rows /
    rows_to_merge)": 65 selected rows merged by 2 are 32 rows, not 32.5 or 33."""
    dev = Recorder(dict(QVGA))
    cam = opt.OPT8241(dev, mode="quad", width=32, height=32)
    for name, value in (("row_start", 0), ("row_end", 64), ("col_start", 0), ("col_end", 3),
                        ("rows_to_merge", 2), ("cols_to_merge", 2), ("bin_row_count", 32),
                        ("bin_col_count", 32), ("binning_en", 1)):
        cam.write_field(name, value)
    cam.check_frame_size()
    cam.height = 33
    cam.write_field("bin_row_count", 33)
    with pytest.raises(HardwareError, match="ROI registers select 64x65 pixels"):
        cam.check_frame_size()


def test_check_frame_size_catches_roi_registers_that_disagree_with_the_bin_counts():
    dev = Recorder(dict(QVGA))
    cam = opt.OPT8241(dev, mode="quad")
    cam.set_roi(0, 0, 65, 64)
    cam.write_field("row_end", 8)  # as a half-written region left by another program
    with pytest.raises(HardwareError, match="ROI registers select 64x9 pixels but the bin "
                                            "counts give 64x65 frames"):
        cam.check_frame_size()


def test_a_simulated_sensor_larger_than_the_roi_fields_streams_whole():
    """row_end is 8 bits: a 257-row simulated sensor (roi_px = 256, the default of
    ``acquire --simulated --n 128``) cannot be selected by the default registers and is read
    whole until a region is written."""
    bench = SimulatedBench(ExperimentConfig(n=8, roi_px=256, srs=(0.25,)))
    lcr, cam = bench.lightcrafter(), bench.camera()
    assert (cam.width, cam.height) == (256, 257)
    cam.start()
    lcr.show_sequence(np.ones((1, 8, 8), dtype=np.uint8), exposure_us=1000)
    assert cam.grab(0.1).taps.shape == (4, 257, 256)
    cam.stop()


def test_the_simulated_camera_refuses_a_region_beyond_its_sensor():
    bench = SimulatedBench(ExperimentConfig(n=8, roi_px=16, srs=(0.25,)))
    cam = bench.camera()
    with pytest.raises(ProtocolError, match="stalled"):
        cam.set_roi(0, 0, 65, 64)  # valid on the 320 x 240 device, not on a 17 x 16 sensor
    assert (cam.width, cam.height) == (16, 17) and cam.roi is None
    assert not bench.camera_usb.field("binning_en")
    lcr = bench.lightcrafter()  # the sensor still streams its whole frame
    cam.start()
    lcr.show_sequence(np.ones((1, 8, 8), dtype=np.uint8), exposure_us=1000)
    assert cam.grab(0.1).taps.shape == (4, 17, 16)
    cam.stop()
    narrow = SimulatedBench(ExperimentConfig(n=8, roi_px=8, srs=(0.25,))).camera()
    with pytest.raises(ProtocolError, match="stalled"):  # 16 columns on an 8-column sensor
        narrow.set_roi(0, 0, 9, 16)
    assert (narrow.width, narrow.height) == (8, 9)
