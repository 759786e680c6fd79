"""TI OPT8241 ToF camera (OPT8241-CDK-EVM, "TintinCDK", OPT9221 controller) over USB.

Every fact below was read from TI's Voxel SDK (``3dtof/voxelsdk``, BSD-3) — facts only, no
code; file and function are named at each. **None of it was verified against a physical
camera here** (README "Real hardware" lists what only a device can confirm).

**USB** (``TI3DToF/boards/TintinCDK/TintinCDKCamera.cpp``, the slave table of
``TintinCDKCamera::_init``; ``Voxel/USBIO.cpp``): VID 0x0451, PID 0x9105 is the bulk device
(``TINTIN_CDK_PRODUCT_BULK``, TintinCDKCamera.h; 0x9106 is TI's UVC firmware, which torchtof
does not drive); the SDK only opens the device and claims interface 0 (``USBIO``), so
:meth:`OPT8241.open` sets a configuration only when none is active; registers are read and
written with vendor device control transfers, ``wValue = slave << shift``, ``wIndex = reg
<< shift``, the value little endian in ``nbytes`` bytes:

====================  ============  ===========  =====  ======
slave                 read request  write req.   shift  bytes
====================  ============  ===========  =====  ======
0x58, 0x5C (OPT9221)  0x08          0x09         0      3
0x4B, 0x4E            0x0A          0x0B         0      2
0x2D, 0x52, 0x54      0x04          0x03         8      1
====================  ============  ===========  =====  ======

**Register map** (``TI3DToF/OPT9221.dml``; bank 0 "TG" → slave 0x58, bank 3 "DE" → slave
0x5C, address ``slave << 8 | register`` as ``ToFTintinCamera::_init`` remaps them). A named
parameter is a bit field of one 24-bit register (:data:`REGISTERS`), written by
read-modify-write.

* Modulation frequency (system clock 48 MHz, ``ToFTintinCamera::_getSystemClockFrequency``),
  read back as the SDK does (``TintinVCOFrequency::get``,
  ``TintinModulationFrequencyParameter::get``)::

      f_vco = 2 · 48 MHz · (mod_m1 + mod_m_frac1 / 2^16) / 2^mod_n1
      f_mod = f_vco / ((1 + mod_ps1) · quad_cnt_max)

  (the DML description of ``mod_m1`` divides by ``mod_n1`` instead of ``2^mod_n1 / 2``: the
  two agree only for ``mod_n1`` = 1 or 2, so :func:`pll_frequency_hz` refuses any other),
  programmed as ``TintinModulationFrequencyParameter`` / ``TintinVCOFrequency`` do
  (ToFTintinCamera.cpp): ``mod_ps1 = ⌊300 / quad_cnt_max / f_MHz⌋``, ``mod_n1 = 2``,
  ``mod_m1``/``mod_m_frac1`` from ``f_vco · 2 / 48``, framed by ``mod_pll_update`` 1 … 0 with
  10 ms between the last PLL write and releasing ``mod_pll_update`` (``TintinVCOFrequency::set``
  sleeps 10 ms there), then one more bare pulse ``mod_pll_update`` 1 → 0 after all the PLL
  writes (DML id 7984: "After updating the PLL registers, set this register to 1 and then back
  to 0 to update the PLL frequency"; ``ToFTintinCamera::_init`` ends with that pulse); then
  ``delay_fb_coeff_1 = f·1024/24 MHz`` (DML id 10019; the one-frequency branch of
  ``TintinUnambiguousRangeParameter::set`` writes it right after setting the frequency —
  ``TintinModulationFrequencyParameter::set`` itself does not write it).
  :meth:`OPT8241.configure` programs :attr:`OPT8241.mod_freq_hz` (default 30 MHz, the
  paper's) into PLL 1 **and PLL 2** (``mod_m2``, ``mod_m_frac2``, ``mod_n2``, ``mod_ps2``), as
  TI's one-frequency profile asks (TintinCDKCameraNoCalibration.conf: ``mod_freq1 = mod_freq2
  = 48``, ``dealias_en = 0``); TI's Lens Only, Short Range, High Ambient (``unambiguous_range
  = 4``) and Long Range (8, the default profile 130) profiles leave 40 MHz in PLL 1 and 60 MHz
  in PLL 2 with de-aliasing on (``TintinUnambiguousRangeParameter::set``, ``modPS1 = 1``,
  ``modPS2 = 0`` from ``TintinCDKUnambiguousRangeParameter``); Extra Long Range
  (TintinCDKCameraExtraLongRange.conf) lists ``mod_freq1 = 25.5``, ``mod_freq2 = 34`` MHz. It
  refuses a frequency whose unambiguous range ``c/(2f)`` is shorter than the camera rules'
  ``max_m`` (:func:`check_unambiguous_range`). TI's optimal band is 39-60 MHz
  (``TintinCDKModulationFrequencyParameter``, TintinCDKCameraCommon.h): 30 MHz lies below it
  (docs/hardware.md, "Modulation frequency").
* Phase calibration off: TI's profile calibrates the phase for its defining parameters
  (``ToFCamera::_init``: ``unambiguous_range``, ``frame_rate``, ``sub_frame_cnt_max``,
  ``quad_cnt_max``, ``mix_volt``, ``intg_time``), which torchtof changes, so
  :meth:`OPT8241.configure` writes what ``ToFTintinCamera::_applyCalibrationParams`` writes
  with the calibration disabled (:attr:`OPT8241.CALIBRATION_OFF`): ``disable_offset_corr =
  1``, ``phase_corr_1 = phase_corr_2 = 0``, ``disable_temp_corr = 1``, ``filt_en = 0``,
  ``phase_lin_corr_en = 0``. It also writes ``hdr_scale = 0`` (DML id 6377: integration time
  ``>> hdr_scale`` on alternate frames) and ``padding_en = 0`` (DML id 6146: zeros after a
  frame's last packet); ``sscg_en`` (DML id 8665, no description; TI's CDK profiles set it) is
  read and recorded, not written.
* Frame time: ``pix_cnt_max · quad_cnt_max · sub_frame_cnt_max`` cycles at 48 MHz (DML
  description of ``pix_cnt_max``; ``ToFCamera::_getFrameRate``), 33.3 ms at the DML defaults;
  ``ToFCamera::_setFrameRate`` sets ``pix_cnt_max`` and reads ``pix_cnt_max_set_failed``. The
  TintinCDK board limits ``pix_cnt_max`` ≥ 50000 and ``intg_duty_cycle`` ≤ 20
  (``TintinCDKCamera::_init``). ``quad_cnt_max`` takes 4 or 6, ``sub_frame_cnt_max`` 1, 2, 4 or
  8 (DML descriptions).
* Integration time: ``intg_duty_cycle · 100/64`` percent (DML description;
  ``IntegrationTimeParameter``, ToFCamera.cpp, which reads ``intg_duty_cycle_set_failed``
  after each write), right-shifted by ``normal_frm_intg_scale`` (DML id 9980: "integration
  time (scaled) = integration time >> normal_frm_intg_scale"; 0 at power-up, the DML default;
  no SDK code writes it: torchtof reads it and never writes it). The µs value torchtof
  reports is that share of the frame time (the SDK gives only the percentage).
* Output bandwidth: the OPT9221 sends one byte per output clock, ``24 MHz >> op_clk_freq``
  (DML id 6136: "it is the host's responsibility to ensure that the rate is sufficient to attain
  the required frame-rate without dropping any data"); the SDK's highest frame rate is
  ``0.8 · clock / (pixel_data_size · width · height)`` (``TintinCDKCamera::_getMaximumFrameRate``;
  its comment says 90 %, its code 0.8). In ``"quad"`` mode it still counts ``pixel_data_size``
  (4) although the transfer carries ``2 · quad_cnt_max`` bytes per pixel
  (``_setStreamerFrameSize``): torchtof counts the bytes actually sent (:func:`frame_bytes`),
  stricter than the SDK — a QVGA ``"quad"`` frame with N = 4 is 614 400 bytes, 32 ms at
  24 MHz, at most 31 frames/s where the SDK's formula gives 62. Which formula is right only a
  device can say (README "Real hardware"). :meth:`OPT8241.configure` refuses a trigger spacing
  shorter than a frame's output time (:meth:`OPT8241.output_time_us`); TI's profiles run 8–50
  frames/s. At run time the camera reports it: ``op_overflow`` (DML id 6378, bank 3 reg 99 bit
  20: "Indicates that the output data rate is too low. Write a '0' to reset the state") is
  cleared by :meth:`OPT8241.start` and read after each pattern sequence
  (:meth:`OPT8241.check_output_overflow`, called by ``acquire``): set, the sequence is
  discarded and shown again (a :class:`FrameError`).
* Frame size: ``bin_col_count`` × ``bin_row_count`` (DML ids 2012, 2011; read by
  ``ToFCamera::_getFrameSize``); :meth:`OPT8241.configure` checks that they match the
  ``width`` × ``height`` the frames are decoded with.
* De-aliasing off for one frequency: ``dealias_en = 0``, ``dealias_16bit_op_enable = 0``,
  ``dealiased_ph_mask = 0`` (``TintinUnambiguousRangeParameter::set``).
* Layout registers written by :meth:`OPT8241.configure` whatever an earlier program left:
  ``frm_header_en = 0`` (DML id 6145: a 12-byte header per frame), ``frm_trailer_en = 0`` (DML
  id 6360: a 12-byte trailer), ``blk_header_en = 0`` (``TintinCDKCamera::_init`` writes it
  false for the bulk device), ``pixel_data_size`` (4 in ``"quad"`` mode: the DML default), and
  ``sync_mode = 0`` (DML id 637: "If both slave_mode and sync_mode are enabled, sync_mode takes
  higher priority").
* Streaming: ``tg_dis`` (``0x5880`` bit 0), DML: "'1': TFC stops all processing. Streaming
  comes to a halt … '0': TFC is in normal operation"; the SDK writes 1 while configuring and 0
  to run (``ToFTintinCamera::_init``, ``_initStartParams``). ``slave_mode`` (``0x5881`` bit
  0, DML: "waits for external sync through VD_IN pin for the start of frames") gives one
  frame per DMD trigger.
* Board initialisation (potentiometer, illumination driver, current monitors, profile) is
  TI's (``TintinCDKCamera::_init`` and the profile's parameters); torchtof requires it to have
  run and checks ``tillum_slv_addr`` (DML default 0x71, written 0x72 by TintinCDKCamera::_init).
* **Device frame numbers.** DML property 6363 ``debug_frame_number_en`` (bank 3 register 57
  → ``0x5C39``, bit 12): "Debug. Replaces first byte of each frame with the current frame
  number when set to '1'." With ``frame_ids=True`` :meth:`OPT8241.configure` sets it and
  :meth:`OPT8241.grab` takes byte 0 of the transfer as the frame's id and sets that byte to 0
  (:func:`split_frame_id`): the low byte of the first word of pixel (0, 0), which is then no
  measurement (the acquisition leaves row 0 out of the bucket ROI). **Assumed:** an 8-bit
  counter advancing once per output frame, in byte 0 of the transfer (no header enabled).

**Frames** (``Voxel/USBBulkStreamer.cpp``, ``ToFFrameGenerator.cpp``,
``TintinCDKCamera::_setStreamerFrameSize``): one bulk IN transfer on endpoint 0x82 is one
frame — no header, id, timestamp or checksum; the SDK asks for 255 extra bytes, drops a
transfer of another size, reads on its own capture thread (200 ms transfer timeout,
``USBBulkStreamerPrivate``; torchtof keeps it in master mode and waits longer in slave mode:
:attr:`OPT8241.SLAVE_READ_TIMEOUT_S`), resets
the endpoint at start and after three failed transfers, and drops the oldest buffer when the
consumer is slow (``USBBulkStreamer::USBBulkStreamerPrivate::putBuffer``, at most
``MAX_BUFFER_COUNT`` = 2 buffers). :class:`OPT8241` does the same on a reader
thread, but reports dropped and wrong-sized transfers instead of hiding them. Layouts,
little-endian 16-bit words, row-major (:data:`FRAME_MODES`):

* ``"depth"`` (``output_mode`` 0, ``pixel_data_size`` 4, ``op_data_arrange_mode`` 0): per
  pixel ``amplitude12 | ambient4 << 12`` then ``phase12 | flags4 << 12``;
* ``"depth8"`` (``op_data_arrange_mode`` 2, the DML default): per row, per group of 8 pixels,
  8 amplitude/ambient words then 8 phase/flags words;
* ``"depth2"`` (``pixel_data_size`` 2): ``phase12 | amplitude_msb4 << 12``;
* ``"iq"`` (``output_mode`` 1): int16 ``I`` then int16 ``Q``; phase ``arg(I + jQ)``;
* ``"quad"`` (``output_mode`` 15, ``ToFFrameGenerator::_generateToFRawIQFrame``):
  ``quad_cnt_max`` words per pixel (the transfer is ``2 · quad_cnt_max`` bytes per pixel,
  ``_setStreamerFrameSize``), each a **signed** 12-bit sample (``(int16)(w << 4) >> 4``), word
  ``k`` at phase ``2πk/N``: ``I = Σ d_k cos(2πk/N)``, ``Q = Σ d_k sin(2πk/N)``, phase
  ``arg(I + jQ)`` (:func:`sdk_quad_iq`, :func:`decode_frame`).

12-bit phase to depth: ``θ = 2π · phase12 / 4096``, ``depth = θ · c / (4π f)`` (Eq. 1), then
the camera rules of paper §2.2 (:func:`torchtof.sensor.camera_rules`).

**Corrupt frames**: without a checksum only the size can be checked; a flipped bit inside a
word is undetectable (USB's packet CRC protects the wire).
"""

from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import dataclass, replace

import numpy as np
import torch

from ..sensor import SPEED_OF_LIGHT, camera_rules, phase_to_depth, tap_amplitude, tap_phase
from .dlpc350 import ensure_configuration, find_device, translate_usb_error
from .errors import (
    FrameError,
    FrameTimeoutError,
    HardwareError,
    ProtocolError,
    usb_exceptions,
)
from .frames import Frame

__all__ = [
    "VID",
    "PID",
    "EP_FRAMES",
    "SLAVES",
    "SYSCLK_MHZ",
    "Field",
    "REGISTERS",
    "FRAME_MODES",
    "CameraRules",
    "register_request",
    "pll_settings",
    "pll_frequency_hz",
    "DEFAULT_MOD_FREQ_HZ",
    "unambiguous_range_m",
    "check_unambiguous_range",
    "pack_depth",
    "pack_depth2",
    "pack_iq",
    "pack_quads",
    "encode_frame",
    "frame_bytes",
    "decode_frame",
    "FRAME_ID_BYTE",
    "split_frame_id",
    "OPT8241",
]

VID, PID = 0x0451, 0x9105
EP_FRAMES = 0x82
BULK_EXTRA = 255  # extra bytes asked per frame transfer (Voxel/USBBulkStreamer.cpp)
VENDOR_OUT, VENDOR_IN = 0x40, 0xC0  # bmRequestType: vendor, device, host->device / device->host
SYSCLK_MHZ = 48  # ToFTintinCamera::_getSystemClockFrequency

#: slave -> (read request, write request, shift, register bytes) (TintinCDKCamera.cpp).
SLAVES: dict[int, tuple[int, int, int, int]] = {
    0x58: (0x08, 0x09, 0, 3),
    0x5C: (0x08, 0x09, 0, 3),
    0x4B: (0x0A, 0x0B, 0, 2),
    0x4E: (0x0A, 0x0B, 0, 2),
    0x2D: (0x04, 0x03, 8, 1),
    0x52: (0x04, 0x03, 8, 1),
    0x54: (0x04, 0x03, 8, 1),
}


@dataclass(frozen=True)
class Field:
    """A bit field ``[lsb, msb]`` of the 24-bit register at ``address`` (OPT9221.dml)."""

    address: int
    lsb: int
    msb: int

    @property
    def mask(self) -> int:
        return ((1 << (self.msb - self.lsb + 1)) - 1) << self.lsb

    def get(self, register: int) -> int:
        return (register & self.mask) >> self.lsb

    def put(self, register: int, value: int) -> int:
        width = self.msb - self.lsb + 1
        if not 0 <= int(value) < 1 << width:
            raise ValueError(f"Field: value {value} does not fit {width} bits")
        return (register & ~self.mask) | (int(value) << self.lsb)


#: Named OPT9221 parameters: DML name -> bit field (``TI3DToF/OPT9221.dml``: bank, register
#: address, lsb, msb; bank 0 -> slave 0x58, bank 3 -> slave 0x5C).
REGISTERS: dict[str, Field] = {
    "mod_pll_update": Field(0x5802, 2, 2),  # bank 0 reg 2
    "mod_m_frac1": Field(0x580C, 0, 15),  # bank 0 reg 12
    "mod_m1": Field(0x580C, 16, 21),
    "mod_n1": Field(0x580F, 0, 1),  # bank 0 reg 15
    "mod_ps1": Field(0x580F, 4, 6),
    "tg_dis": Field(0x5880, 0, 0),  # bank 0 reg 128
    "slave_mode": Field(0x5881, 0, 0),  # bank 0 reg 129
    "pix_cnt_max": Field(0x5882, 0, 21),  # bank 0 reg 130
    "quad_cnt_max": Field(0x5883, 0, 3),  # bank 0 reg 131
    "sub_frame_cnt_max": Field(0x5883, 4, 7),
    "output_mode": Field(0x5C25, 8, 11),  # bank 3 reg 37
    "op_data_arrange_mode": Field(0x5C25, 18, 19),
    "pixel_data_size": Field(0x5C27, 11, 14),  # bank 3 reg 39
    "debug_frame_number_en": Field(0x5C39, 12, 12),  # bank 3 reg 57
    "frm_header_en": Field(0x5C3C, 1, 1),  # bank 3 reg 60
    "blk_header_en": Field(0x5C3C, 2, 2),
    "intg_duty_cycle": Field(0x5C4C, 0, 5),  # bank 3 reg 76
    # read-only failure flags, bank 3 reg 99 (DML ids 6369 and 2124; read back after a write
    # by ToFCamera::_setFrameRate and IntegrationTimeParameter::set, ToFCamera.cpp)
    "pix_cnt_max_set_failed": Field(0x5C63, 22, 22),
    "intg_duty_cycle_set_failed": Field(0x5C63, 23, 23),
    # output overflow, DML id 6378, bank 3 reg 99 bit 20: "Indicates that the output data rate
    # is too low. Write a '0' to reset the state" (sticky): cleared by start(), read after each
    # sequence (check_output_overflow)
    "op_overflow": Field(0x5C63, 20, 20),
    # de-aliasing, switched off for one frequency (TintinUnambiguousRangeParameter::set,
    # ToFTintinCamera.cpp): dealias_en bank 3 reg 2 bit 23, dealias_16bit_op_enable reg 40 bit 23
    "dealias_en": Field(0x5C02, 23, 23),
    "dealias_16bit_op_enable": Field(0x5C28, 23, 23),
    # illumination-delay coefficient: DML id 10019 "delay_fb_coeff_1 = f1·1024/24MHz", bank 3
    # reg 179 bits 0-11; TI writes it only in TintinUnambiguousRangeParameter::set (right after
    # the frequency in its one-frequency branch), torchtof after each frequency change it makes
    "delay_fb_coeff_1": Field(0x5CB3, 0, 11),
    # second temperature-sensor slave address, bank 3 reg 46 bits 0-6: DML default 113 (0x71);
    # TintinCDKCamera::_init writes 0x72 (TILLUM_SLAVE_ADDR): the board-initialised marker
    "tillum_slv_addr": Field(0x5C2E, 0, 6),
    # output clock 24 MHz >> op_clk_freq, DML id 6136, bank 3 reg 57 bits 1-2
    "op_clk_freq": Field(0x5C39, 1, 2),
    # 12-byte debug trailer, DML id 6360, bank 3 reg 60 bit 3
    "frm_trailer_en": Field(0x5C3C, 3, 3),
    # dealiased phase mask (4-bit signed), DML id 991, bank 3 reg 3 bits 11-14; zeroed for one
    # frequency by TintinUnambiguousRangeParameter::set
    "dealiased_ph_mask": Field(0x5C03, 11, 14),
    # TG sync mode (priority over slave_mode), DML id 637, bank 0 reg 129 bit 12
    "sync_mode": Field(0x5881, 12, 12),
    # integration time >> normal_frm_intg_scale, DML id 9980, bank 3 reg 77 bits 6-8
    "normal_frm_intg_scale": Field(0x5C4D, 6, 8),
    # output frame size (ToFCamera::_getFrameSize): DML ids 2011/2012, bank 3 regs 47/48
    "bin_row_count": Field(0x5C2F, 14, 23),
    "bin_col_count": Field(0x5C30, 14, 23),
    # sensor region of interest (ToFTintinCamera::_setROI): DML ids 13, 536 (bank 0 reg 31),
    # 534 (reg 32), 538 (reg 33); "col_start = (start address) >> 4", likewise col_end
    "row_start": Field(0x581F, 0, 7),
    "row_end": Field(0x581F, 16, 23),
    "col_start": Field(0x5820, 3, 7),
    "col_end": Field(0x5821, 3, 7),
    # binning (ToFCamera::_setBinning, written by _setROI with 1 × 1): DML ids 2006, 2008, 2009
    "binning_en": Field(0x5C2F, 12, 12),
    "rows_to_merge": Field(0x5C2F, 0, 9),
    "cols_to_merge": Field(0x5C30, 0, 9),
    # PLL 2 (DML ids 7065, 7064, 7079, 7081: bank 0 reg 13 bits 16-21 / 0-15, reg 15 bits 2-3
    # / 7-9), programmed as PLL 1 for one frequency (TintinCDKCameraNoCalibration.conf:
    # mod_freq2 = mod_freq1, dealias_en = 0; TintinCDKModulationFrequencyParameter for
    # MOD_FREQ2, TintinCDKCamera.cpp)
    "mod_m_frac2": Field(0x580D, 0, 15),
    "mod_m2": Field(0x580D, 16, 21),
    "mod_n2": Field(0x580F, 2, 3),
    "mod_ps2": Field(0x580F, 7, 9),
    # spread-spectrum clock, DML id 8665 (bank 0 reg 14 bit 3; no DML description): read and
    # recorded, never written (TI's CDK profiles set sscg_en = true)
    "sscg_en": Field(0x580E, 3, 3),
    # phase calibration, written as ToFTintinCamera::_applyCalibrationParams writes it with the
    # calibration disabled: DML ids 2091, 2095 (bank 3 regs 55, 56 bits 4-15, signed), 2098,
    # 2099 (reg 81 bits 16, 17), 9981 (reg 182 bit 19, CROSS_TALK_EN), 8801 (reg 128 bit 0,
    # NONLINEARITY_ENABLE; ToFTintinCamera.h)
    "phase_corr_1": Field(0x5C37, 4, 15),
    "phase_corr_2": Field(0x5C38, 4, 15),
    "disable_offset_corr": Field(0x5C51, 16, 16),
    "disable_temp_corr": Field(0x5C51, 17, 17),
    "filt_en": Field(0x5CB6, 19, 19),
    "phase_lin_corr_en": Field(0x5C80, 0, 0),
    # integration time >> hdr_scale on alternate frames, DML id 6377 (bank 3 reg 76 bits 6-8)
    "hdr_scale": Field(0x5C4C, 6, 8),
    # zero padding of a frame's last packet to the block size, DML id 6146 (reg 60 bit 0)
    "padding_en": Field(0x5C3C, 0, 0),
}
#: The sensor (DML defaults of ``row_end`` 239 and ``col_end`` 19: 320 columns in blocks of 16).
SENSOR_ROWS, SENSOR_COLS, ROI_COL_STEP = 240, 320, 16

#: Limits of the TintinCDK board (``TintinCDKCamera::_init``, TintinCDKCamera.cpp):
#: ``pix_cnt_max`` lower limit 50000, ``intg_duty_cycle`` upper limit 20.
PIX_CNT_MAX_MIN = 50_000
INTG_DUTY_CYCLE_MAX = 20
#: Wait between the last PLL write and releasing ``mod_pll_update`` (``TintinVCOFrequency::set``
#: sleeps 10 ms there, ToFTintinCamera.cpp).
VCO_SETTLE_S = 0.010
#: ``tillum_slv_addr`` after TI's board initialisation (TintinCDKCamera::_init).
TILLUM_SLAVE_ADDR_INIT = 0x72
#: Valid ``quad_cnt_max`` and ``sub_frame_cnt_max`` (OPT9221.dml descriptions of ids 82, 83).
QUAD_COUNTS = (4, 6)
SUB_FRAME_COUNTS = (1, 2, 4, 8)
#: The modulation frequency :meth:`OPT8241.configure` programs by default: the paper's 30 MHz
#: (unambiguous range c/2f = 4.997 m, the paper's "5 m"). TI's optimal band for this board is
#: 39-60 MHz (``TintinCDKModulationFrequencyParameter::getOptimalMinimum``/``Maximum``,
#: TintinCDKCameraCommon.h): 30 MHz lies below it (docs/hardware.md, "Modulation frequency").
DEFAULT_MOD_FREQ_HZ = 30e6
#: TI's optimal modulation band of the TintinCDK board, Hz (TintinCDKCameraCommon.h).
TI_OPTIMAL_MOD_FREQ_HZ = (39e6, 60e6)
#: The paper's "5 m at 30 MHz" takes c as 3·10^8 m/s (exactly, c/2f = 4.9965 m): the range
#: check (:func:`check_unambiguous_range`) allows that rounding and no more.
PAPER_C = 3e8

#: frame mode -> (output_mode, pixel_data_size, op_data_arrange_mode) (module docstring).
#: ``pixel_data_size`` defines only 2 and 4 (OPT9221.dml id 1067); in ``"quad"`` mode the SDK
#: never writes it and sizes the transfer as ``quad_cnt_max · 2`` bytes per pixel
#: (``TintinCDKCamera::_setStreamerFrameSize``); torchtof writes the DML default 4 there, so
#: that a 2 left by a ``"depth2"`` run does not stay (whether quad mode reads it at all is
#: device-only, README "Real hardware").
FRAME_MODES: dict[str, tuple[int, int, int]] = {
    "depth": (0, 4, 0),
    "depth8": (0, 4, 2),
    "depth2": (0, 2, 0),
    "iq": (1, 4, 0),
    "quad": (15, 4, 0),
}
_TWO_PI = 2.0 * math.pi
#: The output clock at ``op_clk_freq = 0`` (OPT9221.dml id 6136: 24, 12, 6, 3 MHz).
OP_CLK_HZ = 24e6
#: Share of the output clock the SDK counts on (``TintinCDKCamera::_getMaximumFrameRate``).
OP_CLK_USABLE = 0.8


@dataclass(frozen=True)
class CameraRules:
    """The camera's output rules (paper §2.2, :func:`torchtof.sensor.camera_rules`);
    ``amp_threshold`` in ADC numbers."""

    min_m: float = 1.0
    max_m: float = 5.0
    step_m: float | None = 0.25
    amp_threshold: float = 0.0
    no_photon_m: float = 5.0

    def apply(self, depth: torch.Tensor, amplitude: torch.Tensor) -> torch.Tensor:
        return camera_rules(depth, amplitude, self.min_m, self.max_m, self.amp_threshold,
                            self.no_photon_m, self.step_m)


def register_request(address: int, write: bool) -> tuple[int, int, int, int, int]:
    """``(bmRequestType, bRequest, wValue, wIndex, nbytes)`` of a register access.

    Example:
        >>> register_request(0x580C, write=True)
        (64, 9, 88, 12, 3)
        >>> register_request(0x2D10, write=False)
        (192, 4, 11520, 4096, 1)
    """
    if not 0 <= int(address) <= 0xFFFF:
        raise ValueError(f"register_request: expected a 16-bit address, got {address!r}")
    slave, reg = address >> 8, address & 0xFF
    if slave not in SLAVES:
        raise ValueError(f"register_request: unknown slave 0x{slave:02x} in address "
                         f"0x{address:04x}; expected one of {[hex(s) for s in SLAVES]}")
    rd, wr, shift, nbytes = SLAVES[slave]
    return (VENDOR_OUT if write else VENDOR_IN, wr if write else rd, slave << shift,
            reg << shift, nbytes)


def pll_settings(freq_hz: float, quad_cnt_max: int = 4) -> dict[str, int]:
    """PLL fields for a modulation frequency, as ``ToFTintinCamera.cpp`` computes them
    (module docstring): ``{"mod_ps1", "mod_n1", "mod_m1", "mod_m_frac1"}``.

    Example:
        >>> pll_settings(30e6)
        {'mod_ps1': 2, 'mod_n1': 2, 'mod_m1': 15, 'mod_m_frac1': 0}
    """
    if isinstance(quad_cnt_max, bool) or not 1 <= int(quad_cnt_max) <= 15:
        raise ValueError(f"pll_settings: expected quad_cnt_max in [1, 15], got {quad_cnt_max!r}")
    f_mhz = float(freq_hz) / 1e6
    lo, hi = 37.5 / quad_cnt_max, 600.0 / quad_cnt_max
    if not math.isfinite(f_mhz) or not lo <= f_mhz <= hi:
        raise ValueError(f"pll_settings: expected freq_hz in [{lo * 1e6:g}, {hi * 1e6:g}] for "
                         f"quad_cnt_max={quad_cnt_max}, got {freq_hz!r}")
    ps = int(300.0 / quad_cnt_max / f_mhz)
    if ps > 7:
        raise ValueError(f"pll_settings: freq_hz {freq_hz!r} needs mod_ps1={ps} > 7")
    vco = (ps + 1) * quad_cnt_max * f_mhz
    n = 2
    m_f = vco * n / SYSCLK_MHZ
    m = int(m_f)
    return {"mod_ps1": ps, "mod_n1": n, "mod_m1": m, "mod_m_frac1": int((m_f - m) * (1 << 16))}


def unambiguous_range_m(freq_hz: float) -> float:
    """``c / (2 f)``: the depth at which the phase of one modulation frequency wraps (Eq. 1).

    Example:
        >>> round(unambiguous_range_m(30e6), 4)
        4.9965
    """
    return SPEED_OF_LIGHT / (2.0 * float(freq_hz))


def check_unambiguous_range(freq_hz: float, max_m: float, where: str,
                            option: str = "mod_freq_hz", scale: float = 1e6,
                            unit: str = "MHz") -> None:
    """Refuse a modulation frequency whose unambiguous range ``c/(2f)`` is shorter than the
    camera rules' ``max_m`` (a target beyond it would wrap to a near depth instead of being
    clipped to ``max_m``). The paper's 30 MHz for 5 m takes c as 3·10^8 m/s: the check allows
    ``f ≤ 3·10^8 / (2 max_m)`` (30 MHz for 5 m).

    Raises:
        ValueError: naming ``where`` and ``option`` (its value shown as ``freq_hz / scale``
            ``unit``), the range, ``max_m`` and the highest frequency allowed.

    Example:
        >>> check_unambiguous_range(30e6, 5.0, "f")  # 4.9965 m: the paper's "5 m"
        >>> check_unambiguous_range(40e6, 3.7, "f")  # TI's band: 3.747 m
    """
    top = PAPER_C / (2.0 * float(max_m))
    if float(freq_hz) > top * (1 + 1e-12):
        raise ValueError(
            f"{where}: {option} = {float(freq_hz) / scale:g} {unit} gives an unambiguous range "
            f"c/(2f) = {unambiguous_range_m(freq_hz):.3f} m, shorter than the camera rules' "
            f"max_m = {float(max_m):g} m (a target beyond {unambiguous_range_m(freq_hz):.3f} m "
            f"would wrap to a near depth, not be clipped to {float(max_m):g} m): choose at most "
            f"{top / scale:g} {unit} (c rounded to 3e8 m/s, as the paper's 5 m at 30 MHz), or "
            f"lower max_m")


def pll_frequency_hz(mod_m1: int, mod_m_frac1: int, mod_n1: int, mod_ps1: int,
                     quad_cnt_max: int) -> float:
    """Modulation frequency of a PLL in Hz as the SDK reads it back: ``f_vco = 2 · 48 MHz ·
    (M + M_frac/2^16) / 2^N`` (``TintinVCOFrequency::get``, ToFTintinCamera.cpp), ``f_mod =
    f_vco / (quad_cnt_max · (1 + PS))`` (``TintinModulationFrequencyParameter::get``).

    The DML description of ``mod_m1`` gives ``f_vco = 48 MHz · (M + M_frac/2^16) / N``; the two
    agree only for ``N`` = 1 and 2 (the SDK always writes 2, ``TintinVCOFrequency::set``), so
    another ``N`` is refused rather than read with either formula.

    Raises:
        ProtocolError: ``mod_n1`` not 1 or 2, or ``quad_cnt_max`` 0 (the PLL was not set up
            as the SDK sets it).
    """
    if mod_n1 not in (1, 2) or quad_cnt_max == 0:
        raise ProtocolError("read modulation frequency",
                            f"mod_n1={mod_n1}, quad_cnt_max={quad_cnt_max}: the SDK's read-back "
                            "(TintinVCOFrequency::get, 2·48 MHz·M/2^N) and the DML's (48 MHz·M/N) "
                            "agree only for mod_n1 = 1 or 2, and the SDK writes 2; program the "
                            "PLL with set_modulation_frequency (OPT8241.configure does)")
    vco_mhz = 2 * SYSCLK_MHZ * (mod_m1 + mod_m_frac1 / 65536.0) / (1 << mod_n1)
    return vco_mhz / ((1 + mod_ps1) * quad_cnt_max) * 1e6


# -- frame packing (what the OPT9221 sends; the simulator and tests use these) -------------
def _u12(a, name: str) -> np.ndarray:
    a = np.asarray(a)
    if a.ndim != 2 or (a < 0).any() or (a > 0xFFF).any():
        raise ValueError(f"pack: expected {name} as a 2-D array of integers in [0, 4095]")
    return a.astype(np.uint16)


def _u4(a, like: np.ndarray, name: str) -> np.ndarray:
    if a is None:
        return np.zeros_like(like)
    a = np.asarray(a)
    if a.shape != like.shape or (a < 0).any() or (a > 0xF).any():
        raise ValueError(f"pack: expected {name} {like.shape} in [0, 15]")
    return a.astype(np.uint16)


def pack_depth(phase12, amplitude12, ambient=None, flags=None, arrange: int = 0) -> bytes:
    """A 4-byte-per-pixel depth frame (``output_mode`` 0): words
    ``amplitude | ambient << 12`` and ``phase | flags << 12`` per pixel (``arrange`` 0) or per
    8-pixel group (``arrange`` 2), ToFFrameGenerator.cpp."""
    p = _u12(phase12, "phase12")
    a = _u12(amplitude12, "amplitude12")
    if a.shape != p.shape:
        raise ValueError(f"pack_depth: amplitude12 {a.shape} != phase12 {p.shape}")
    w0 = a | _u4(ambient, a, "ambient") << 12
    w1 = p | _u4(flags, p, "flags") << 12
    h, w = p.shape
    if arrange == 0:
        words = np.stack([w0, w1], axis=-1)
    elif arrange == 2:
        if w % 8:
            raise ValueError(f"pack_depth: arrange 2 needs a width divisible by 8, got {w}")
        words = np.stack([w0.reshape(h, w // 8, 8), w1.reshape(h, w // 8, 8)], axis=2)
    else:
        raise ValueError(f"pack_depth: expected arrange 0 or 2, got {arrange!r}")
    return words.astype("<u2").tobytes()


def pack_depth2(phase12, amplitude12) -> bytes:
    """A 2-byte-per-pixel frame: ``phase12 | (amplitude12 >> 8) << 12`` (ToFFrameGenerator)."""
    p, a = _u12(phase12, "phase12"), _u12(amplitude12, "amplitude12")
    return (p | (a >> 8) << 12).astype("<u2").tobytes()


def pack_iq(i, q) -> bytes:
    """A raw-IQ frame (``output_mode`` 1): int16 ``I``, int16 ``Q`` per pixel."""
    i, q = np.asarray(i), np.asarray(q)
    if i.shape != q.shape or i.ndim != 2 or (np.abs(i) > 0x7FFF).any() or \
            (np.abs(q) > 0x7FFF).any():
        raise ValueError("pack_iq: expected equal 2-D integer arrays i, q within int16")
    return np.stack([i, q], axis=-1).astype("<i2").tobytes()


#: Simulator convention (not TI's): a 12-bit model tap ``c`` in ``[0, 4095]`` is sent as the
#: signed sample ``c − QUAD_OFFSET``; the offset a real OPT9221 removes is not documented.
QUAD_OFFSET = 2048


def pack_quads(samples) -> bytes:
    """A raw-quad frame (``output_mode`` 15) from signed samples ``(N, H, W)`` in the SDK's
    word order (word ``k`` at phase ``2πk/N``, ``ToFFrameGenerator::_generateToFRawIQFrame``):
    ``N`` little-endian 16-bit words per pixel, each the sample as an int16 (its low 12 bits
    are what the SDK reads, sign-extended).

    Example:
        >>> pack_quads(np.array([[[-256]], [[5]], [[0]], [[2047]]])).hex(" ")
        '00 ff 05 00 00 00 ff 07'
    """
    t = np.asarray(samples)
    if t.ndim != 3 or t.shape[0] < 1 or (t < -2048).any() or (t > 2047).any():
        raise ValueError(f"pack_quads: expected integer samples (N, H, W) in [-2048, 2047], got "
                         f"shape {t.shape}")
    return np.moveaxis(t, 0, -1).astype("<i2").tobytes()


def quads_from_taps(taps, quads: int = 4) -> np.ndarray:
    """Signed SDK-order samples ``(N, H, W)`` from integer model taps ``(4, H, W)`` in the
    Fig. 1 order (``τ = 0, π, π/2, 3π/2``), for the simulator.

    The SDK gives ``phase = arg(I + jQ)`` with ``I = Σ d_k cos(2πk/N)``, ``Q = Σ d_k
    sin(2πk/N)`` (ToFFrameGenerator.cpp), so word ``k`` is the correlation sample at delay
    ``−2πk/N``: for ``N = 4`` the words are ``c₁, c₄, c₂, c₃`` (``I = c₁ − c₂``, ``Q = c₄ − c₃``,
    Eq. 7); for another ``N`` torchtof synthesises ``m + (I cos φ_k + Q sin φ_k)/2`` (``m`` the
    taps' mean) rounded to integers. Each sample is then ``− QUAD_OFFSET``."""
    t = np.asarray(taps).astype(np.int64)
    if t.ndim != 3 or t.shape[0] != 4:
        raise ValueError(f"quads_from_taps: expected taps (4, H, W), got {t.shape}")
    quads = _check_quads(quads, "quads_from_taps")
    if quads == 4:
        d = t[[0, 3, 1, 2]]
    else:
        i, q, m = t[0] - t[1], t[3] - t[2], t.mean(axis=0)
        phi = 2 * np.pi * np.arange(quads) / quads
        d = np.rint(m[None] + 0.5 * (i[None] * np.cos(phi)[:, None, None]
                                     + q[None] * np.sin(phi)[:, None, None])).astype(np.int64)
    return np.clip(d - QUAD_OFFSET, -2048, 2047)


def sdk_quad_iq(words: np.ndarray, quads: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(samples, I, Q)`` of raw-quad words ``(H, W, N)`` as the SDK computes them
    (``ToFFrameGenerator::_generateToFRawIQFrame``, quad branch): each 16-bit word's low 12
    bits sign-extended (``(int16)(w << 4) >> 4``), ``I = Σ d_k cos(2πk/N)``, ``Q = Σ d_k
    sin(2πk/N)`` in float64 (the SDK's sine/cosine tables, ``ToFFrameGenerator::
    setParameters``). The top 4 bits are ignored, as the SDK ignores them."""
    w = np.ascontiguousarray(words, dtype=np.uint16)
    d = ((w << 4).view(np.int16) >> 4).astype(np.int32)
    phi = 2 * np.pi * np.arange(quads) / quads
    return d, d @ np.cos(phi), d @ np.sin(phi)


def encode_frame(mode: str, taps: np.ndarray, ambient=None, flags=None, quads: int = 4,
                 phase_corr: int = 0) -> bytes:
    """Encode one frame in ``mode`` from integer taps ``(4, H, W)`` (Fig. 1 order), as the
    camera would send it: phase and amplitude of Eqs. 7-8 rounded to 12 bits for the depth
    modes, ``I = c₁ − c₂``, ``Q = c₄ − c₃`` for ``"iq"``, ``quads`` signed SDK-order samples
    per pixel for ``"quad"`` (:func:`quads_from_taps`). ``phase_corr`` (the simulator's
    model of an active ``phase_corr_1``: DML id 2091, "This value is subtracted from the
    obtained phase", taken in 12-bit phase units) is subtracted modulo 4096 from the depth
    modes' phase; the raw ``"quad"`` and ``"iq"`` words are left alone."""
    t = np.asarray(taps)
    if t.ndim != 3 or t.shape[0] != 4:
        raise ValueError(f"encode_frame: expected taps (4, H, W), got {t.shape}")
    if mode == "quad":
        return pack_quads(quads_from_taps(t, quads))
    ti = t.astype(np.int64)
    i, q = ti[0] - ti[1], ti[3] - ti[2]
    if mode == "iq":
        return pack_iq(i, q)
    tt = torch.from_numpy(t.astype(np.float32))[None]
    phase = tap_phase(tt)[0, 0].double().numpy()  # Eq. 7
    amp = tap_amplitude(tt)[0, 0].double().numpy()  # Eq. 8
    p12 = (np.rint(phase * (4096 / _TWO_PI)).astype(np.int64) - int(phase_corr)) % 4096
    a12 = np.clip(np.rint(amp), 0, 4095).astype(np.int64)
    if mode in ("depth", "depth8"):
        return pack_depth(p12, a12, ambient, flags, FRAME_MODES[mode][2])
    if mode == "depth2":
        return pack_depth2(p12, a12)
    raise ValueError(f"encode_frame: unknown mode {mode!r}; expected one of {list(FRAME_MODES)}")


FRAME_ID_BYTE = 0  # byte of a transfer that debug_frame_number_en replaces (OPT9221.dml)


def split_frame_id(raw: bytes) -> tuple[int, bytes]:
    """``(frame number, bytes with the number's byte set to 0)`` of a transfer sent with
    ``debug_frame_number_en = 1`` (module docstring: byte 0 = low byte of pixel (0, 0)'s first
    word).

    Example:
        >>> split_frame_id(bytes([7, 0x0A, 0x34, 0x01]))
        (7, b'\\x00\\n4\\x01')
    """
    raw = bytes(raw)
    if not raw:
        raise FrameError("empty transfer: no frame number byte")
    return raw[FRAME_ID_BYTE], raw[:FRAME_ID_BYTE] + b"\x00" + raw[FRAME_ID_BYTE + 1 :]


def _check_quads(quads, where: str) -> int:
    if isinstance(quads, bool) or not isinstance(quads, (int, np.integer)) or \
            int(quads) not in QUAD_COUNTS:
        raise ValueError(f"{where}: expected quads (quad_cnt_max) in {QUAD_COUNTS} "
                         f"(OPT9221.dml), got {quads!r}")
    return int(quads)


def frame_bytes(width: int, height: int, mode: str, quads: int = 4) -> int:
    """Bytes of one frame: ``width · height · pixel_data_size``, or ``· 2 · quad_cnt_max`` in
    ``"quad"`` mode (``TintinCDKCamera::_setStreamerFrameSize``)."""
    if mode not in FRAME_MODES:
        raise ValueError(f"frame_bytes: unknown mode {mode!r}; expected one of "
                         f"{list(FRAME_MODES)}")
    per_pixel = 2 * _check_quads(quads, "frame_bytes") if mode == "quad" else FRAME_MODES[mode][1]
    return int(width) * int(height) * per_pixel


def decode_frame(raw: bytes, width: int, height: int, freq_hz: float, mode: str = "depth",
                 rules: CameraRules = CameraRules(), frame_id: int = 0,
                 timestamp: float = 0.0, quads: int = 4) -> Frame:
    """Decode one bulk transfer into a :class:`Frame` (module docstring for the layouts).

    ``"quad"``: ``quads`` signed 12-bit samples per pixel, ``I``/``Q`` as the SDK computes
    them (:func:`sdk_quad_iq`); ``Frame.taps`` are Fig. 1-order taps with the same ``I``/``Q``
    up to the factor ``N/4`` — for ``N = 4`` the samples themselves (``c₁, c₂, c₃, c₄ =
    d₀, d₂, d₃, d₁``), else ``m ± 2I/N``, ``m ∓ 2Q/N`` around the samples' mean ``m`` (linear
    in the light, so per-tap buckets stay linear) — and phase and amplitude follow Eqs. 7-8 on
    them, i.e. ``phase = arg(I + jQ)`` as in the SDK and amplitude ``2|I + jQ|/N``.
    ``"iq"``: phase and amplitude from ``I``/``Q`` (Eqs. 7, 8). Depth modes: the 12-bit words.
    Then Eq. 1 and the camera rules (§2.2). ``frame_id`` and ``timestamp`` come from the host.

    The SDK's amplitude in ``"quad"`` and ``"iq"`` modes is ``|I + jQ|`` in its raw processed
    frame (``ToFFrameGenerator::generate`` for raw I/Q frames) and ``|I + jQ|/4096`` in its
    depth frames (``ToFCamera::_getAmplitudeNormalizingFactor``); Eq. 8 gives ``2|I + jQ|/N``
    in ``"quad"`` mode (``/2`` for ``N = 4``, ``/3`` for ``N = 6``) and ``|I + jQ|/2`` in
    ``"iq"`` mode, so an ``amp_threshold`` read off TI's raw frames is 2 or 3 times torchtof's
    there (one read off its depth frames, 1/2048 or 1/1365 of it). The SDK then truncates I
    and Q to int16, the phase to a 12-bit code and the amplitude to an integer; torchtof keeps
    floats (the phase code's truncation is under one code, 1.2 mm at 30 MHz; in ``"quad"``
    mode the int16 truncation of I and Q adds up to ``√2/|I + jQ|`` rad). In the depth modes
    the amplitude is the camera's 12-bit word.
    ``"iq"`` words are plain int16 as the SDK reads them (``_generateToFRawIQFrame``), not
    range-checked: from six signed 12-bit samples ``|Σ d_k cos(2πk/6)|`` reaches
    ``4 · 2048 = 8192`` (four: 4095), and the firmware's scaling of them is device-only.

    Raises:
        FrameError: a transfer of the wrong size.
        ValueError: unknown mode, a bad ``quads``, or ``"depth8"`` with a width not divisible
            by 8.
    """
    raw = bytes(raw)
    h, w = int(height), int(width)
    need = frame_bytes(w, h, mode, quads)
    if len(raw) != need:
        raise FrameError(f"{len(raw)} bytes, a {w}x{h} {mode!r} frame has {need}")
    taps = ambient = flags = None
    if mode == "quad":
        n = int(quads)
        words = np.frombuffer(raw, dtype="<u2").reshape(h, w, n)
        if n == 4:  # the samples themselves: I = d0 - d2, Q = d1 - d3 exactly
            t = ((words << 4).view(np.int16) >> 4)[..., [0, 2, 3, 1]]
        else:
            d, i_sdk, q_sdk = sdk_quad_iq(words, n)
            m = d.mean(axis=-1)
            i4, q4 = i_sdk * (2.0 / n), q_sdk * (2.0 / n)
            t = np.stack([m + i4, m - i4, m - q4, m + q4], axis=-1)
        taps = torch.from_numpy(np.ascontiguousarray(np.moveaxis(t, -1, 0)).astype(np.float32))
        t4 = taps[None]
    elif mode == "iq":
        iq = np.frombuffer(raw, dtype="<i2").reshape(h, w, 2)
        t4 = torch.zeros(1, 4, h, w, dtype=torch.float32)
        t4[0, 0] = torch.from_numpy(iq[..., 0].astype(np.float32))  # c1 - c2 = I
        t4[0, 3] = torch.from_numpy(iq[..., 1].astype(np.float32))  # c4 - c3 = Q
    if mode in ("quad", "iq"):
        amp4, phase4 = tap_amplitude(t4), tap_phase(t4)  # Eqs. 8 and 7
    else:
        if mode == "depth2":
            words = np.frombuffer(raw, dtype="<u2").reshape(h, w)
            p12, a12 = words & 0xFFF, (words & 0xF000) >> 4
        else:
            if mode == "depth8":
                if w % 8:
                    raise ValueError(f"decode_frame: 'depth8' needs a width divisible by 8, "
                                     f"got {w}")
                g = np.frombuffer(raw, dtype="<u2").reshape(h, w // 8, 2, 8)
                w0, w1 = g[:, :, 0, :].reshape(h, w), g[:, :, 1, :].reshape(h, w)
            else:
                g = np.frombuffer(raw, dtype="<u2").reshape(h, w, 2)
                w0, w1 = g[..., 0], g[..., 1]
            a12, p12 = w0 & 0xFFF, w1 & 0xFFF
            ambient = torch.from_numpy((w0 >> 12).astype(np.uint8))
            flags = torch.from_numpy((w1 >> 12).astype(np.uint8))
        amp4 = torch.from_numpy(a12.astype(np.float32))[None, None]
        phase4 = torch.from_numpy(p12.astype(np.float32) * np.float32(_TWO_PI / 4096))[None, None]
    depth4 = rules.apply(phase_to_depth(phase4, freq_hz), amp4)  # Eq. 1 + §2.2
    return Frame(phase=phase4[0, 0], amplitude=amp4[0, 0], depth=depth4[0, 0],
                 timestamp=float(timestamp), frame_id=int(frame_id), taps=taps,
                 ambient=ambient, flags=flags, raw=raw)


class OPT8241:
    """OPT8241-CDK-EVM frame source over any pyusb-like device (``ctrl_transfer`` and
    ``read``), e.g. ``usb.core.Device`` (:meth:`open`) or the simulator's fake camera.

    **Precondition**: TI's SDK (Voxel Viewer, or ``voxelsdk``'s ``CameraSystem`` connecting
    to the camera) has initialised the board since it was powered (illumination driver,
    potentiometer, current monitors, profile: ``TintinCDKCamera::_init``,
    ``ToFTintinCamera::_init``). torchtof does not repeat that; :meth:`check_initialised`
    reads back ``tillum_slv_addr`` (0x71 at power-up, 0x72 after TI's initialisation) and
    refuses an uninitialised board. :meth:`start` calls it, and ``acquire`` and ``torchtof
    acquire`` call it first, before any register write (region, configuration) or store.

    Args:
        dev: the USB device.
        width, height: frame size in pixels (QVGA 320×240; smaller with an ROI).
        rules: the camera rules applied to the decoded depth.
        mode: frame mode (:data:`FRAME_MODES`); ``"quad"`` (raw samples) is needed for
            per-tap buckets.
        slave: put the OPT9221 in ``slave_mode`` (one frame per external VD_IN sync).
        timeout_s: default frame timeout.
        clock: host clock for the frame timestamps (seconds), as the SDK stamps frames.
        frame_ids: enable the OPT9221's ``debug_frame_number_en``: each frame's id is the
            device's 8-bit frame number from byte 0 (module docstring), else a host count.
        quads: ``quad_cnt_max`` written by :meth:`configure` (4 or 6, OPT9221.dml).
        sub_frames: ``sub_frame_cnt_max`` written by :meth:`set_frame_time` (1, 2, 4, 8).
        queue_frames: frames the reader thread may hold before it drops the oldest
            (``USBBulkStreamer::USBBulkStreamerPrivate::putBuffer`` does the same); each drop
            is counted in :attr:`stats` and reported by :meth:`grab` as a lost frame.
        mod_freq_hz: the modulation frequency :meth:`configure` programs into PLL 1 and PLL 2
            (default 30 MHz, the paper's; TI's CDK profiles leave 40 MHz in PLL 1 and 60 MHz in
            PLL 2, except No Calibration, 48/48, and Extra Long Range, 25.5/34: module
            docstring). :meth:`configure`
            refuses one whose unambiguous range ``c/(2f)`` is shorter than ``rules.max_m``
            (:func:`check_unambiguous_range`).
        check_overflow: read ``op_overflow`` after each sequence (:meth:`check_output_overflow`;
            default ``True``). That the flag is set by an output overrun and only then is
            device-only: ``False`` turns the check off (the flag is still cleared at start).
    """

    what = "TI OPT8241 ToF camera"

    def __init__(self, dev, width: int = 320, height: int = 240,
                 rules: CameraRules = CameraRules(), mode: str = "depth",
                 slave: bool = True, timeout_s: float = 2.0, clock=time.time,
                 frame_ids: bool = False, quads: int = 4, sub_frames: int = 1,
                 queue_frames: int = 64, mod_freq_hz: float = DEFAULT_MOD_FREQ_HZ,
                 check_overflow: bool = True) -> None:
        if mode not in FRAME_MODES:
            raise ValueError(f"OPT8241: unknown mode {mode!r}; expected one of "
                             f"{list(FRAME_MODES)}")
        if int(width) < 1 or int(height) < 1 or (mode == "depth8" and int(width) % 8):
            raise ValueError(f"OPT8241: bad frame size {width}x{height} for mode {mode!r}")
        if isinstance(sub_frames, bool) or sub_frames not in SUB_FRAME_COUNTS:
            raise ValueError(f"OPT8241: expected sub_frames in {SUB_FRAME_COUNTS} "
                             f"(OPT9221.dml sub_frame_cnt_max), got {sub_frames!r}")
        if isinstance(queue_frames, bool) or not isinstance(queue_frames, int) or \
                queue_frames < 1:
            raise ValueError(f"OPT8241: expected queue_frames a positive int, got "
                             f"{queue_frames!r}")
        if isinstance(mod_freq_hz, bool) or not isinstance(mod_freq_hz, (int, float)):
            raise TypeError(f"OPT8241: expected mod_freq_hz a number (Hz), got {mod_freq_hz!r}")
        try:
            pll_settings(mod_freq_hz, _check_quads(quads, "OPT8241"))
        except ValueError as exc:
            raise ValueError(f"OPT8241: mod_freq_hz {mod_freq_hz!r} cannot be programmed: "
                             f"{exc}") from None
        if not isinstance(check_overflow, bool):
            raise TypeError(f"OPT8241: expected check_overflow a bool, got {check_overflow!r}")
        self.mod_freq_hz = float(mod_freq_hz)
        self.check_overflow = check_overflow
        self.dev, self.width, self.height = dev, int(width), int(height)
        self.rules, self.mode = rules, mode
        self.slave, self.timeout_s, self.clock = bool(slave), float(timeout_s), clock
        self.frame_ids = bool(frame_ids)
        self.quads = _check_quads(quads, "OPT8241")
        self.sub_frames, self.queue_frames = int(sub_frames), int(queue_frames)
        self.registers = dict(REGISTERS)
        self.pattern_index: int | None = None  # set by acquire(): named in timeout errors
        #: ``(row, col, height, width)`` set by :meth:`set_roi` (``None``: not set here)
        self.roi: tuple[int, int, int, int] | None = None
        self._next_id = 0
        self._reader = None
        self.stats = {"frames": 0, "host_dropped": 0, "bad_size": 0, "endpoint_resets": 0,
                      "max_queued": 0, "op_overflow": 0}

    @classmethod
    def open(cls, **kwargs) -> OPT8241:
        """Find the first OPT8241-CDK-EVM (VID 0x0451, PID 0x9105), select its configuration
        if none is active and claim interface 0 (as TI's ``USBIO`` does).

        Raises:
            DeviceNotFoundError: nothing attached / no libusb backend (with the udev hint).
            DeviceBusyError: the interface is held by another program.
        """
        dev = find_device(VID, PID, cls.what)
        try:  # as TI's USBIO: open, claim interface 0 (Voxel/USBIO.cpp)
            ensure_configuration(dev)
            import usb.util

            usb.util.claim_interface(dev, 0)
        except Exception as exc:
            raise translate_usb_error(exc, cls.what, "open") from exc
        return cls(dev, **kwargs)

    def close(self) -> None:
        """Stop streaming (if it runs) and release the USB device; safe to call twice."""
        try:
            if self._reader is not None:
                self.stop()
        except HardwareError:
            pass
        finally:
            try:
                import usb.util

                usb.util.dispose_resources(self.dev)
            except Exception:  # noqa: BLE001 - fake devices, already gone
                pass

    # -- registers ---------------------------------------------------------------------------
    def write_register(self, address: int, value: int) -> None:
        """Write a whole register (``slave << 8 | reg``), little endian (VoxelUSBProgrammer)."""
        rtype, req, wvalue, windex, nbytes = register_request(int(address), write=True)
        if not 0 <= int(value) < 1 << (8 * nbytes):
            raise ValueError(f"OPT8241.write_register: value {value} does not fit the "
                             f"{nbytes}-byte register 0x{address:04x}")
        data = int(value).to_bytes(nbytes, "little")
        name = f"write register 0x{address:04x}"
        n = self._ctrl(name, rtype, req, wvalue, windex, data)
        if n != nbytes:
            raise ProtocolError(name, f"device accepted {n} of {nbytes} bytes")

    #: attempts of a control transfer that stalls (EPIPE); register reads and writes are
    #: idempotent, so a stalled one is simply repeated
    ctrl_attempts = 3

    def _ctrl(self, name: str, *request):
        for attempt in range(self.ctrl_attempts):
            try:
                return self.dev.ctrl_transfer(*request, 1000)
            except HardwareError:
                raise
            except Exception as exc:
                if getattr(exc, "errno", None) in (32, -9) and attempt + 1 < self.ctrl_attempts:
                    continue
                err = translate_usb_error(exc, self.what, name)
                if getattr(exc, "errno", None) in (32, -9):
                    err = ProtocolError(name, f"the device stalled the request "
                                        f"{self.ctrl_attempts} times (a value the register "
                                        f"map calls invalid?): {exc}")
                raise err from exc

    def read_register(self, address: int) -> int:
        """Read a whole register (``slave << 8 | reg``)."""
        rtype, req, wvalue, windex, nbytes = register_request(int(address), write=False)
        name = f"read register 0x{address:04x}"
        data = bytes(self._ctrl(name, rtype, req, wvalue, windex, nbytes))
        if len(data) != nbytes:
            raise ProtocolError(name, f"expected {nbytes} bytes, got {len(data)}")
        return int.from_bytes(data, "little")

    def _field(self, name: str) -> Field:
        if name not in self.registers:
            raise ValueError(f"OPT8241: unknown register field {name!r}; known "
                             f"{sorted(self.registers)}")
        return self.registers[name]

    def read_field(self, name: str) -> int:
        """A named parameter (:data:`REGISTERS`)."""
        f = self._field(name)
        return f.get(self.read_register(f.address))

    def write_field(self, name: str, value: int) -> None:
        """Set a named parameter by read-modify-write of its register."""
        f = self._field(name)
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
            raise TypeError(f"OPT8241.write_field: expected an integer for {name}, got "
                            f"{value!r}")
        try:
            new = f.put(self.read_register(f.address), int(value))
        except ValueError:
            raise ValueError(f"OPT8241.write_field: {name}={value} does not fit bits "
                             f"{f.lsb}..{f.msb}") from None
        self.write_register(f.address, new)

    # -- modulation frequency, frame time and integration time -------------------------------
    @property
    def freq_hz(self) -> float:
        """Modulation frequency in Hz from the PLL 1 registers (:func:`pll_frequency_hz`)."""
        return pll_frequency_hz(*(self.read_field(k) for k in (
            "mod_m1", "mod_m_frac1", "mod_n1", "mod_ps1", "quad_cnt_max")))

    @property
    def pll2_freq_hz(self) -> float:
        """The frequency PLL 2 makes, from its registers (``mod_m2``, ``mod_m_frac2``,
        ``mod_n2``, ``mod_ps2``; :func:`pll_frequency_hz`)."""
        return pll_frequency_hz(*(self.read_field(k) for k in (
            "mod_m2", "mod_m_frac2", "mod_n2", "mod_ps2", "quad_cnt_max")))

    def set_modulation_frequency(self, freq_hz: float) -> float:
        """Program PLL 1 and PLL 2 for ``freq_hz`` as the Voxel SDK programs one PLL
        (``TintinModulationFrequencyParameter::set``, ``TintinVCOFrequency::set``: module
        docstring), PLL 2 with PLL 1's values as TI's one-frequency profile asks
        (TintinCDKCameraNoCalibration.conf: ``mod_freq2 = mod_freq1``, ``dealias_en = 0``;
        TI's de-aliasing profiles leave PLL 2 at 60 MHz), all inside one ``mod_pll_update``
        1 … 0 (as ``TintinVCOFrequency::set`` and ``TintinModulationFrequencyParameter::set``
        frame their writes), then one bare pulse ``mod_pll_update`` 1 → 0 after the last PLL
        write: the DML (id 7984) asks for it "after updating the PLL registers", and
        ``ToFTintinCamera::_init`` ends with it; then the illumination-delay coefficient
        ``delay_fb_coeff_1 = ⌊f[MHz] · 1024 / 24⌋`` (DML id 10019). TI writes the coefficient
        only in ``TintinUnambiguousRangeParameter::set`` (ToFTintinCamera.cpp) — in its
        one-frequency branch right after ``TintinModulationFrequencyParameter::set``, which
        does not write it — so torchtof, which changes the frequency without that parameter,
        writes it here: the DML defines it from f1, and the delay correction scales with it
        (DML id 10005), so a profile's value for 40/60 MHz would be wrong at another
        frequency. Returns the frequency PLL 1 now gives.

        Raises:
            ValueError: a frequency the PLL or the 12-bit delay coefficient cannot take.
        """
        s = pll_settings(freq_hz, self.read_field("quad_cnt_max"))
        coeff = int(float(freq_hz) / 1e6 * 1024 / 24)
        if coeff > 4095:
            raise ValueError(f"OPT8241: freq_hz {freq_hz!r} gives delay_fb_coeff_1 = {coeff} > "
                             "4095 (12 bits, OPT9221.dml)")
        self.write_field("mod_pll_update", 1)
        try:
            for pll in ("1", "2"):
                for k in ("mod_m", "mod_n", "mod_m_frac", "mod_ps"):
                    self.write_field(k + pll, s[k + "1"])
            time.sleep(VCO_SETTLE_S)  # TintinVCOFrequency::set waits here before the release
        finally:
            self.write_field("mod_pll_update", 0)
        # OPT9221.dml id 7984: after the PLL registers are updated, 1 then back to 0 (as the
        # last two writes of ToFTintinCamera::_init)
        self.write_field("mod_pll_update", 1)
        self.write_field("mod_pll_update", 0)
        self.write_field("delay_fb_coeff_1", coeff)
        return self.freq_hz

    @property
    def unambiguous_range_m(self) -> float:
        """``c / (2 f)`` of the programmed PLL 1 frequency (:func:`unambiguous_range_m`)."""
        return unambiguous_range_m(self.freq_hz)

    #: What ``ToFTintinCamera::_applyCalibrationParams`` (ToFTintinCamera.cpp) writes when the
    #: profile's calibration is disabled, in its order: common phase offset off
    #: (``DISABLE_OFFSET_CORR`` true, ``PHASE_CORR_1``/``_2`` 0), temperature correction off
    #: (``DISABLE_TEMP_CORR`` true), cross-talk filter off (``CROSS_TALK_EN`` = ``filt_en``
    #: false), phase non-linearity correction off (``NONLINEARITY_ENABLE`` =
    #: ``phase_lin_corr_en`` false).
    CALIBRATION_OFF = (("disable_offset_corr", 1), ("phase_corr_1", 0), ("phase_corr_2", 0),
                       ("disable_temp_corr", 1), ("filt_en", 0), ("phase_lin_corr_en", 0))

    def disable_phase_calibration(self) -> None:
        """Switch TI's on-chip phase calibration off (:attr:`CALIBRATION_OFF`). TI calibrates
        for the profile's defining parameters — ``unambiguous_range``, ``frame_rate``,
        ``sub_frame_cnt_max``, ``quad_cnt_max``, ``mix_volt``, ``intg_time``
        (``ToFCamera::_init``, common phase offset and temperature sections) and
        ``op_clk_freq`` (``ToFTintinCamera::_init``, non-linearity) — all of which
        :meth:`configure` may change, so a profile's calibration would no longer hold."""
        for name, value in self.CALIBRATION_OFF:
            self.write_field(name, value)

    def _frame_cycles(self) -> int:
        return (self.read_field("pix_cnt_max") * self.read_field("quad_cnt_max")
                * self.read_field("sub_frame_cnt_max"))

    @property
    def frame_time_us(self) -> float:
        """``pix_cnt_max · quad_cnt_max · sub_frame_cnt_max`` system clock cycles at 48 MHz
        (DML description of ``pix_cnt_max``; ``ToFCamera::_getFrameRate``)."""
        return self._frame_cycles() / SYSCLK_MHZ

    def _check_flag(self, name: str, what: str) -> None:
        if self.read_field(name):
            raise HardwareError(f"{self.what}: the camera set {name} after {what} (OPT9221.dml: "
                                f"{_FLAG_MEANING[name]}); choose a longer frame or a shorter "
                                "integration time")

    def set_frame_time(self, max_us: float, sub_frames: int | None = None) -> float:
        """Program the frame time to at most ``max_us``: ``sub_frame_cnt_max`` (default
        :attr:`sub_frames`) and ``pix_cnt_max = ⌊max_us · 48 / (quad_cnt_max ·
        sub_frame_cnt_max)⌋`` as ``ToFCamera::_setFrameRate`` computes it, then the
        ``pix_cnt_max_set_failed`` flag is read back and ``intg_duty_cycle`` written again
        with the value it holds (:meth:`_rewrite_duty_cycle`), as ``_setFrameRate`` does after
        every ``pix_cnt_max`` write; returns the frame time (µs).

        Raises:
            ValueError: ``max_us`` needs ``pix_cnt_max`` below the board's limit 50000
                (``TintinCDKCamera::_init``). Beyond the register's 22 bits ``pix_cnt_max`` is
                clamped (the frame is then shorter than ``max_us``).
            HardwareError: the camera set ``pix_cnt_max_set_failed`` or
                ``intg_duty_cycle_set_failed``.
        """
        sub = self.sub_frames if sub_frames is None else sub_frames
        pix = self._pix_count(max_us, self.read_field("quad_cnt_max"), sub, "set_frame_time")
        self.write_field("sub_frame_cnt_max", sub)
        self.write_field("pix_cnt_max", pix)
        self._check_flag("pix_cnt_max_set_failed", f"pix_cnt_max = {pix}")
        self._rewrite_duty_cycle(f"pix_cnt_max = {pix}")
        return self.frame_time_us

    def _pix_count(self, max_us: float, quads: int, sub: int, func: str) -> int:
        """``pix_cnt_max`` for a frame of at most ``max_us`` with ``quads`` quads and ``sub``
        sub-frames (``ToFCamera::_setFrameRate``), checked against the board's limits; no I/O."""
        if isinstance(sub, bool) or sub not in SUB_FRAME_COUNTS:
            raise ValueError(f"OPT8241.{func}: expected sub_frames in "
                             f"{SUB_FRAME_COUNTS}, got {sub!r}")
        if isinstance(max_us, bool) or not isinstance(max_us, (int, float)) or \
                not math.isfinite(max_us) or max_us <= 0:
            raise ValueError(f"OPT8241.{func}: expected a positive max_us, got {max_us!r}")
        pix = int(max_us * SYSCLK_MHZ // (quads * sub))
        if pix < PIX_CNT_MAX_MIN:
            shortest = PIX_CNT_MAX_MIN * quads * sub / SYSCLK_MHZ
            raise ValueError(f"OPT8241.{func}: a frame of at most {max_us:g} us needs "
                             f"pix_cnt_max = {pix} < {PIX_CNT_MAX_MIN} (the board's limit, "
                             f"TintinCDKCamera.cpp); the shortest frame with {quads} quads and "
                             f"{sub} sub-frame(s) is {shortest:g} us")
        return min(pix, REGISTERS["pix_cnt_max"].mask >> REGISTERS["pix_cnt_max"].lsb)

    def _rewrite_duty_cycle(self, what: str) -> None:
        """Write ``intg_duty_cycle`` again with the value it holds, after a change of the
        frame's cycle count (``pix_cnt_max``, ``quad_cnt_max``), as ``ToFCamera::_setFrameRate``
        does (ToFCamera.cpp: it gets ``INTG_TIME`` and sets it back after setting
        ``PIX_CNT_MAX``; ``TintinUnambiguousRangeParameter::set`` calls it after setting
        ``QUAD_CNT_MAX``). ``INTG_TIME`` is ``intg_duty_cycle`` as a rounded percentage and
        back (``IntegrationTimeParameter::get``/``set``), which returns every duty cycle 0-63
        unchanged, so the value read is the value written. As there,
        ``intg_duty_cycle_set_failed`` is read before (``IntegrationTimeParameter::get`` fails
        on it) and after the write.

        Raises:
            HardwareError: ``intg_duty_cycle_set_failed`` set, naming ``what`` changed.
        """
        self._check_flag("intg_duty_cycle_set_failed", what)
        duty = self.read_field("intg_duty_cycle")
        self.write_field("intg_duty_cycle", duty)
        self._check_flag("intg_duty_cycle_set_failed",
                         f"{what} and intg_duty_cycle = {duty} written again")

    @property
    def integration_time_us(self) -> float:
        """``intg_duty_cycle · 100/64`` percent (DML description of ``intg_duty_cycle``,
        ``IntegrationTimeParameter::get`` in ToFCamera.cpp) of the frame time, right-shifted by
        ``normal_frm_intg_scale`` (DML id 9980) (torchtof's µs conversion: the SDK states only
        "percentage of total cycle time")."""
        shift = self.read_field("normal_frm_intg_scale")
        return self.read_field("intg_duty_cycle") / 64 * self.frame_time_us / (1 << shift)

    def set_integration_time(self, us: float) -> float:
        """Nearest ``intg_duty_cycle = round(us / frame time · 64 · 2^normal_frm_intg_scale)``
        (``IntegrationTimeParameter::set``; the scale as read, never written), at most 20 on
        this board (``TintinCDKCamera::_init``), then the
        ``intg_duty_cycle_set_failed`` flag read back; returns the integration time (µs).

        Raises:
            ValueError: beyond the duty-cycle limit 20 (31.25 % of the frame time, divided by
                ``2^normal_frm_intg_scale``).
            HardwareError: the camera set ``intg_duty_cycle_set_failed``.
        """
        frame_us = self.frame_time_us / (1 << self.read_field("normal_frm_intg_scale"))
        top = INTG_DUTY_CYCLE_MAX / 64 * frame_us
        if isinstance(us, bool) or not isinstance(us, (int, float)) or not math.isfinite(us) \
                or not 0 <= us:
            raise ValueError(f"OPT8241: expected a non-negative integration time in us, got "
                             f"{us!r}")
        duty = int(us / frame_us * 64 + 0.5)
        if duty > INTG_DUTY_CYCLE_MAX:
            raise ValueError(f"OPT8241: integration time {us:g} us needs intg_duty_cycle = "
                             f"{duty} > {INTG_DUTY_CYCLE_MAX} (the board's limit, "
                             f"TintinCDKCamera.cpp): at most {top:g} us at this frame time")
        self.write_field("intg_duty_cycle", duty)
        self._check_flag("intg_duty_cycle_set_failed", f"intg_duty_cycle = {duty}")
        return self.integration_time_us

    def frame_counter(self) -> int:
        """Frames received since :meth:`start` (host-side, as the SDK numbers frames)."""
        return self._next_id

    def check_initialised(self) -> None:
        """The class docstring's precondition: ``tillum_slv_addr`` reads 0x72.

        Raises:
            HardwareError: it reads anything else (the board was not initialised by TI's SDK).
        """
        got = self.read_field("tillum_slv_addr")
        if got != TILLUM_SLAVE_ADDR_INIT:
            raise HardwareError(
                f"{self.what}: tillum_slv_addr reads 0x{got:02x}, not 0x72: TI's board "
                "initialisation (illumination driver, potentiometer, current monitors, profile) "
                "has not run since the camera was powered. Connect to it once with TI's Voxel "
                "Viewer (or voxelsdk), choose a profile, disconnect, then run torchtof.")

    # -- streaming ---------------------------------------------------------------------------
    def output_time_us(self) -> float:
        """Time to send one frame of :attr:`mode` over the output interface: its bytes at
        80 % of ``24 MHz >> op_clk_freq`` (module docstring, "Output bandwidth";
        ``TintinCDKCamera::_getMaximumFrameRate``)."""
        rate = self._op_clock_hz() * OP_CLK_USABLE
        return frame_bytes(self.width, self.height, self.mode, self.quads) / rate * 1e6

    def _op_clock_hz(self) -> float:
        """The output clock, ``24 MHz >> op_clk_freq`` (OPT9221.dml id 6136)."""
        return OP_CLK_HZ / (1 << self.read_field("op_clk_freq"))

    def set_roi(self, row: int, col: int, height: int, width: int) -> None:
        """Read out only ``height × width`` sensor pixels from ``(row, col)``, as
        ``ToFTintinCamera::_setROI`` does: ``row_start``/``row_end``, ``col_start =
        col/16``/``col_end = (col + width)/16 − 1`` (columns in blocks of 16, OPT9221.dml), then
        binning 1 × 1 with ``bin_row_count``/``bin_col_count`` the region's size
        (``ToFCamera::_setBinning``). The frames then hold ``width · height`` pixels, so they
        take proportionally less time to send (:meth:`output_time_us`); :attr:`width` and
        :attr:`height` follow. Call it before :meth:`start` (the SDK refuses while streaming).

        The previous values are written back if a write fails. In ``frame_ids`` mode the
        frame number is byte 0 of the region's first pixel, so ``acquire`` leaves the region's
        row 0 out of the buckets.

        Raises:
            ValueError: ``col`` or ``width`` not a multiple of 16, a region beyond the
                320 × 240 sensor, or an empty one.
            HardwareError: while streaming.
        """
        vals = (row, col, height, width)
        if any(isinstance(v, bool) or not isinstance(v, (int, np.integer)) for v in vals):
            raise TypeError(f"OPT8241.set_roi: expected integers, got {vals!r}")
        row, col, height, width = (int(v) for v in vals)
        if col % ROI_COL_STEP or width % ROI_COL_STEP:
            raise ValueError(f"OPT8241.set_roi: col and width must be multiples of "
                             f"{ROI_COL_STEP} (OPT9221.dml col_start/col_end), got col={col}, "
                             f"width={width}")
        if height < 1 or width < ROI_COL_STEP or row < 0 or col < 0 or \
                row + height > SENSOR_ROWS or col + width > SENSOR_COLS:
            raise ValueError(f"OPT8241.set_roi: the region rows {row}..{row + height - 1}, "
                             f"columns {col}..{col + width - 1} is empty or beyond the "
                             f"{SENSOR_COLS}x{SENSOR_ROWS} sensor")
        if self._reader is not None:
            raise HardwareError(f"{self.what}: set_roi while streaming (stop() first)")
        writes = (("row_start", row), ("row_end", row + height - 1),
                  ("col_start", col // ROI_COL_STEP),
                  ("col_end", (col + width) // ROI_COL_STEP - 1),
                  ("rows_to_merge", 1), ("cols_to_merge", 1), ("bin_row_count", height),
                  ("bin_col_count", width), ("binning_en", 1))
        before = {name: self.read_field(name) for name, _ in writes}
        try:
            for name, value in writes:
                self.write_field(name, value)
        except BaseException:
            # put back what was written (a half-written region streams wrong frames), each
            # register on its own: one that fails does not keep the others from being restored
            for name, value in before.items():
                try:
                    self.write_field(name, value)
                except Exception:  # noqa: BLE001, PERF203 - the first error is the one to report
                    pass
            raise
        self.width, self.height = width, height
        self.roi = (row, col, height, width)

    def check_frame_size(self) -> None:
        """The frames the camera sends are ``bin_col_count`` × ``bin_row_count`` pixels
        (``ToFCamera::_getFrameSize``); they must be the ``width`` × ``height`` this object
        decodes. With binning on (a region from :meth:`set_roi`, or the SDK's), the bin counts
        must also be the ROI registers' size divided (rounded down) by the merge factors, as
        the register map requires (OPT9221.dml ids 2011/2012). With binning off the SDK reads
        only the bin counts, and so does this check.

        Raises:
            HardwareError: they differ.
        """
        cols, rows = self.read_field("bin_col_count"), self.read_field("bin_row_count")
        if (cols, rows) != (self.width, self.height):
            raise HardwareError(
                f"{self.what}: the camera sends {cols}x{rows} frames (bin_col_count x "
                f"bin_row_count) but this OPT8241 decodes {self.width}x{self.height}; construct "
                f"it with width={cols}, height={rows}, or set the region with set_roi (torchtof "
                f"acquire --camera-roi; the whole sensor: 0 0 240 320)")
        if self.read_field("binning_en"):  # a region set by set_roi: the registers agree
            sel_rows = self.read_field("row_end") - self.read_field("row_start") + 1
            sel_cols = ROI_COL_STEP * (self.read_field("col_end") - self.read_field("col_start")
                                       + 1)
            merge = (self.read_field("rows_to_merge"), self.read_field("cols_to_merge"))
            # OPT9221.dml ids 2011/2012: "must be programmed to floor(total_rows/rows_to_merge)"
            if min(merge) < 1 or (sel_rows // merge[0], sel_cols // merge[1]) != (rows, cols):
                raise HardwareError(
                    f"{self.what}: the ROI registers select {sel_cols}x{sel_rows} pixels but "
                    f"the bin counts give {cols}x{rows} frames: set the region again "
                    "(set_roi / --camera-roi)")

    def configure(self, period_us: float | None = None, margin_us: float = 500.0,
                  spacing_us: float | None = None) -> None:
        """Output format of :attr:`mode` with no frame header, trailer, block header or zero
        padding (bulk device), de-aliasing off, ``quad_cnt_max`` = :attr:`quads` (a change
        keeps the frame time, ``pix_cnt_max`` recomputed, or sets it from ``period_us``, as
        ``TintinUnambiguousRangeParameter::set`` calls ``_setFrameRate``; ``sub_frame_cnt_max``
        becomes :attr:`sub_frames`, where TI keeps the device's, so the frame time, not
        ``pix_cnt_max``, is TI's), PLL 1 and
        PLL 2 at :attr:`mod_freq_hz` (:meth:`set_modulation_frequency`), TI's phase
        calibration off (:meth:`disable_phase_calibration`), ``hdr_scale`` 0 (no alternate-
        frame integration scaling), slave mode with ``sync_mode`` off, device frame numbers
        on/off (:attr:`frame_ids`) — each written whatever an earlier program left (module
        docstring) — and the frame size checked (:meth:`check_frame_size`). With
        ``period_us`` (a pattern's period) the frame time is set to fit one period less
        ``margin_us`` (:meth:`set_frame_time`), after checking that the output interface can
        send a frame before the next trigger, ``spacing_us`` after this one (default
        ``period_us``; on the VSYNC trigger the patterns may be further apart than their
        period).

        Raises:
            ValueError: :attr:`mod_freq_hz` gives an unambiguous range ``c/(2f)`` shorter than
                ``rules.max_m`` (:func:`check_unambiguous_range`), or a frame takes longer than
                ``spacing_us`` to send (:meth:`output_time_us`), or the period's frame time
                or the one to keep at a new quad count needs ``pix_cnt_max`` below the
                board's limit; all before any write.
            HardwareError: the frame size differs (:meth:`check_frame_size`), or a flag of
                :meth:`set_frame_time`.
        """
        out, size, arrange = FRAME_MODES[self.mode]
        check_unambiguous_range(self.mod_freq_hz, self.rules.max_m, "OPT8241.configure",
                                "mod_freq_hz")
        self.check_frame_size()
        spacing = period_us if spacing_us is None else spacing_us
        if spacing is not None:
            need = self.output_time_us()
            if need > float(spacing):
                clock = self._op_clock_hz() / 1e6
                per_px = frame_bytes(1, 1, self.mode, self.quads)
                fewer = [m for m in ("depth", "depth2") if frame_bytes(1, 1, m) < per_px]
                raise ValueError(
                    f"OPT8241.configure: a {self.width}x{self.height} {self.mode!r} frame "
                    f"({frame_bytes(self.width, self.height, self.mode, self.quads)} bytes) takes "
                    f"{need / 1e3:.1f} ms to send at {clock:g} MHz (80 % usable, as "
                    f"TintinCDKCamera::_getMaximumFrameRate), longer than the "
                    f"{float(spacing) / 1e3:.1f} ms between patterns: lengthen the pattern "
                    "spacing or choose a smaller ROI"
                    + (f" or a mode with fewer bytes per pixel ({', '.join(map(repr, fewer))})"
                       if fewer else ""))
        target = None if period_us is None else float(period_us) - float(margin_us)
        new_quads = self.read_field("quad_cnt_max") != self.quads
        # TintinUnambiguousRangeParameter::set reads the frame rate, sets QUAD_CNT_MAX and sets
        # the frame rate back (_setFrameRate: PIX_CNT_MAX for the new quad count, then the duty
        # cycle written again): the frame time is kept, or set from the period. Either frame
        # time is checked before any write (one the board cannot hold is a ValueError).
        keep = target if target is not None else self.frame_time_us if new_quads else None
        if keep is not None:
            try:
                self._pix_count(keep, self.quads, self.sub_frames, "configure")
            except ValueError as exc:
                if target is not None:
                    raise
                raise ValueError(f"{exc} (keeping the frame time across the change to "
                                 f"{self.quads} quads; give the pattern period: "
                                 "configure(period_us=...))") from None
        self.write_field("tg_dis", 1)
        if new_quads:
            self.write_field("quad_cnt_max", self.quads)
            self.set_frame_time(keep)
        self.set_modulation_frequency(self.mod_freq_hz)  # PLL 1 and PLL 2, delay coefficient
        self.write_field("dealias_en", 0)
        self.write_field("dealias_16bit_op_enable", 0)
        self.write_field("dealiased_ph_mask", 0)
        self.disable_phase_calibration()
        self.write_field("hdr_scale", 0)  # alternate frames would integrate >> hdr_scale
        self.write_field("output_mode", out)
        self.write_field("pixel_data_size", size)  # 4 in quad mode: the default (FRAME_MODES)
        self.write_field("op_data_arrange_mode", arrange)
        self.write_field("blk_header_en", 0)
        self.write_field("frm_header_en", 0)  # frames are raw pixels (and byte 0 the number)
        self.write_field("frm_trailer_en", 0)
        self.write_field("padding_en", 0)  # zeros after the last packet would resize frames
        self.write_field("debug_frame_number_en", int(self.frame_ids))
        self.write_field("sync_mode", 0)  # it would override slave_mode (OPT9221.dml)
        self.write_field("slave_mode", int(self.slave))
        if target is not None and not new_quads:
            self.set_frame_time(target)

    def start(self) -> None:
        """Check the precondition, configure (unless :meth:`configure` ran since the last
        stop), clear ``op_overflow`` (:meth:`clear_output_overflow`), reset the bulk endpoint
        and start the reader thread (``USBBulkStreamer``: ``resetBulkEndPoint`` then a capture
        thread), then ``tg_dis = 0`` (OPT9221.dml: '0' normal operation, '1' TFC stops all
        processing)."""
        self.check_initialised()
        if not getattr(self, "_configured", False):
            self.configure()
        self._freq = self.freq_hz
        self._next_id = 0
        self.clear_output_overflow()
        self._reset_endpoint()
        self._start_reader()
        self.write_field("tg_dis", 0)
        self._configured = False

    def clear_output_overflow(self) -> None:
        """``op_overflow = 0`` (OPT9221.dml id 6378: "Write a '0' to reset the state")."""
        self.write_field("op_overflow", 0)

    def check_output_overflow(self) -> None:
        """Read ``op_overflow`` (OPT9221.dml id 6378: "Indicates that the output data rate is
        too low"), the camera's own report that its output did not keep up since it was last
        cleared; ``acquire`` calls this after each pattern sequence. Set, it is cleared (so
        that the next sequence starts clean), counted in :attr:`stats` and raised.

        Raises:
            FrameError: ``op_overflow`` was set: frames of the sequence may be incomplete or
                lost; a transient fault, so ``acquire`` shows the sequence again.
        """
        if not self.check_overflow or not self.read_field("op_overflow"):
            return
        self.clear_output_overflow()
        self.stats["op_overflow"] += 1
        raise FrameError(
            "the camera set op_overflow (OPT9221.dml: the output data rate is too low) during "
            f"the sequence: its output could not keep up with {self.mode!r} frames of "
            f"{self.width}x{self.height} at this trigger spacing (lengthen the pattern spacing, "
            "choose a smaller ROI or fewer bytes per pixel; if the flag fires on a healthy run, "
            "acquire --no-overflow-check / OPT8241(check_overflow=False) turns the check off)",
            self.pattern_index)

    def stop(self) -> None:
        """``tg_dis = 1`` (streaming halts), then the reader thread is stopped."""
        try:
            self.write_field("tg_dis", 1)
        finally:
            self._stop_reader()

    def _reset_endpoint(self) -> None:
        clear = getattr(self.dev, "clear_halt", None)
        if clear is None:
            return
        try:
            clear(EP_FRAMES)  # USBIO::resetBulkEndPoint: libusb_clear_halt
        except Exception as exc:
            raise translate_usb_error(exc, self.what, "reset bulk endpoint") from exc
        self.stats["endpoint_resets"] += 1

    @property
    def frame_size(self) -> int:
        return frame_bytes(self.width, self.height, self.mode, self.quads)

    def _read(self, timeout_s: float):
        return self.dev.read(EP_FRAMES, self.frame_size + BULK_EXTRA,
                             max(1, int(timeout_s * 1000)))

    #: Bulk-read timeout of the reader thread in master mode (free-running frames): TI's
    #: ``USBBulkStreamerPrivate`` reads with 200 ms (Voxel/USBBulkStreamer.cpp).
    MASTER_READ_TIMEOUT_S = 0.2
    #: Bulk-read timeout in slave mode. There the camera idles until the projector triggers
    #: it, so reads keep timing out between sequences, and a timed-out read loses what it
    #: had received (pyusb raises instead of returning the partial transfer; TI's
    #: ``USBIO::bulkTransfer`` keeps it but ``USBBulkStreamer`` then drops a transfer of the
    #: wrong size): a frame that starts less than its transfer time before a timeout is lost
    #: and its tail arrives as a short transfer (a retried sequence). The chance per sequence
    #: is about the transfer time over this timeout: a 320×240 quad frame (N = 4, 614 400
    #: bytes, 32 ms at 80 % of 24 MHz) straddles a 200 ms timeout 16 % of the time, a 1 s one
    #: 3 %. A longer wait delays :meth:`stop` (the reader notices the halt only when its read
    #: returns; pyusb cannot cancel a synchronous read), once per run; 1 s keeps that short.
    SLAVE_READ_TIMEOUT_S = 1.0

    @property
    def read_timeout_s(self) -> float:
        """The reader thread's bulk-read timeout: :attr:`SLAVE_READ_TIMEOUT_S` in slave mode,
        else TI's :attr:`MASTER_READ_TIMEOUT_S`."""
        return self.SLAVE_READ_TIMEOUT_S if self.slave else self.MASTER_READ_TIMEOUT_S

    # The reader thread: reads transfers continuously into a bounded queue (USBBulkStreamer:
    # a capture thread, oldest buffer dropped when the consumer is slow; read timeout
    # read_timeout_s). Items: (raw bytes, host time) or (exception, None); a drop puts a
    # marker first. It checks the halt event after every read, so it ends within one read
    # timeout of _stop_reader.
    def _start_reader(self) -> None:
        import threading

        self._stop_reader()
        self._items: deque = deque()
        self._queued = 0  # frames (not markers) in _items
        self._cond = threading.Condition()
        self._halt = threading.Event()
        self._reader = threading.Thread(target=self._read_loop, name="torchtof-opt8241-reader",
                                        daemon=True)
        self._reader.start()

    def _read_loop(self) -> None:
        usb_timeout = usb_exceptions()[1]  # pyusb's, or the simulator's without pyusb
        timeout = self.read_timeout_s

        while not self._halt.is_set():
            try:
                item = (bytes(self._read(timeout)), float(self.clock()))
            except usb_timeout:
                continue
            except Exception as exc:  # noqa: BLE001 - handed to grab() to translate
                item = (exc, None)
                if getattr(exc, "errno", None) in (32, -9):  # EPIPE: a stalled endpoint
                    try:  # USBBulkStreamer resets the endpoint and goes on
                        self._reset_endpoint()
                        item = (_Stalled(), None)
                    except HardwareError:
                        pass
            with self._cond:
                if isinstance(item[0], bytes):
                    if self._queued >= self.queue_frames:  # host too slow: drop the oldest
                        i = next(k for k, it in enumerate(self._items) if isinstance(it[0], bytes))
                        self._items[i] = (_Dropped(), None)
                        self._queued -= 1
                        self.stats["host_dropped"] += 1
                    self._queued += 1
                    self.stats["max_queued"] = max(self.stats["max_queued"], self._queued)
                self._items.append(item)
                self._cond.notify()
            if not isinstance(item[0], (bytes, _Stalled)):
                return

    def _stop_reader(self) -> None:
        t = getattr(self, "_reader", None)
        if t is not None:
            self._halt.set()
            if t is not threading_current():  # it ends when its read returns
                t.join(timeout=max(5.0, 2 * self.read_timeout_s))
        self._reader = None

    def _next_raw(self, timeout: float):
        if getattr(self, "_cond", None) is None:
            raise HardwareError(f"{self.what}: not streaming (call start() first)")
        with self._cond:
            if not self._cond.wait_for(lambda: bool(self._items), timeout=timeout):
                raise FrameTimeoutError(self.pattern_index, timeout)
            raw, stamp = self._items.popleft()
            if isinstance(raw, bytes):
                self._queued -= 1
        return raw, stamp

    def grab(self, timeout_s: float | None = None) -> Frame:
        """The next frame from the reader thread's queue, decoded; its id is the device's
        frame number (``frame_ids=True``, :func:`split_frame_id`) or the next host count, its
        timestamp the host time the transfer completed.

        Raises:
            FrameTimeoutError: nothing arrived (names :attr:`pattern_index` when set).
            FrameError: a transfer of the wrong size (the SDK drops those; torchtof reports
                them so that the sequence is re-acquired), or the host queue overflowed and
                dropped frames (``host_dropped`` in :attr:`stats`).
            DeviceLostError: the camera disappeared.
        """
        timeout = self.timeout_s if timeout_s is None else float(timeout_s)
        raw, stamp = self._next_raw(timeout)
        if isinstance(raw, _Dropped):
            raise FrameError("the host fell behind: the reader queue was full and dropped a "
                             f"frame (queue_frames={self.queue_frames})", self.pattern_index)
        if isinstance(raw, _Stalled):
            raise FrameError("the bulk endpoint stalled and was reset: a frame may be lost",
                             self.pattern_index)
        if isinstance(raw, BaseException):
            self._stop_reader()
            if isinstance(raw, HardwareError):
                raise raw
            if isinstance(raw, usb_exceptions()[1]):
                raise FrameTimeoutError(self.pattern_index, timeout) from raw
            raise translate_usb_error(raw, self.what, "bulk read") from raw
        freq = getattr(self, "_freq", None) or self.freq_hz
        try:
            fid, data = split_frame_id(raw) if self.frame_ids else (self._next_id, raw)
            frame = decode_frame(data, self.width, self.height, freq, self.mode,
                                 self.rules, fid, stamp, self.quads)
        except FrameError as exc:
            self.stats["bad_size"] += 1
            raise FrameError(str(exc).removeprefix("corrupt frame: "), self.pattern_index) from exc
        self._next_id += 1
        self.stats["frames"] += 1
        if self.frame_ids:
            frame = replace(frame, raw=raw)  # as received, number included (duplicate check)
        return frame

    def flush(self, timeout_s: float = 0.05) -> int:
        """Discard queued frames until none arrives within ``timeout_s``; returns the count."""
        n, t0 = 0, time.monotonic()
        while time.monotonic() - t0 < 10.0:
            try:
                raw, _ = self._next_raw(timeout_s)
            except FrameTimeoutError:
                return n
            if isinstance(raw, BaseException):
                self._stop_reader()
                if isinstance(raw, HardwareError):
                    raise raw
                raise translate_usb_error(raw, self.what, "flush") from raw
            n += isinstance(raw, bytes)
        raise ProtocolError("flush", "camera keeps sending frames after 10 s")


class _Dropped:
    """Queue marker: the reader dropped a frame here because the host queue was full."""


class _Stalled:
    """Queue marker: a bulk read failed with a stalled endpoint, which was reset."""


def threading_current():
    import threading

    return threading.current_thread()


_FLAG_MEANING = {
    "pix_cnt_max_set_failed": "indicates the pix_cnt_max setting is too low",
    "intg_duty_cycle_set_failed": "indicates that the integration duty cycle is too high",
}
