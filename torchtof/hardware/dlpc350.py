"""DLP LightCrafter 4500 (DLPC350 controller) over USB HID: message codec and driver.

Implemented from TI's command tables (DLPU010, DLPC350 programmer's guide) and checked
against pyCrafter4500 (``pycrafter4500.py``: ``dlpc350.command`` for the report layout, one
method per command for the codes and payloads, ``pattern_mode`` for the video-mode order);
no GPL code.

**Message** (one or more 64-byte HID reports, OUT endpoint 0x01, IN endpoint 0x81)::

    byte 0   flags: bit7 read, bit6 reply wanted (ack), bit5 NACK (set by the device), bits2:0 dest
    byte 1   sequence number (u8)
    byte 2-3 length (u16 LE) = 2 + payload length  (reply: length of the reply data)
    byte 4-5 command word (u16 LE) = CMD2 << 8 | CMD3, i.e. CMD3 first, then CMD2
    byte 6.. payload

A message longer than 64 bytes is cut into 64-byte reports: the first carries the header,
the command and 58 payload bytes, each continuation report carries the next 64 raw bytes;
the device acknowledges the last one. A read request has flags ``0xC0`` and length 2; its
reply carries the data from byte 4. Example (start the pattern sequence, sequence number
``SS``): ``40 SS 03 00 24 1A 02``.
"""

from __future__ import annotations

import struct
import time
import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .._optional import require
from .errors import (
    DeviceBusyError,
    DeviceLostError,
    DeviceNotFoundError,
    HardwareError,
    NackError,
    ProtocolError,
    TransientError,
    usb_exceptions,
)

__all__ = [
    "VID",
    "PID",
    "EP_OUT",
    "EP_IN",
    "REPORT_SIZE",
    "COMMANDS",
    "TRIGGER_MODES",
    "Message",
    "encode",
    "decode",
    "decode_reply",
    "Assembler",
    "lut_entry",
    "pack_pattern_lut",
    "pack_image_lut",
    "pack_bitplanes",
    "lut_valid_errors",
    "LightCrafter4500",
    "VideoPort",
    "patterns_per_vsync",
    "pattern_times_us",
    "check_video_hz",
    "payload_trig_out1",
    "decode_source_sel",
    "decode_video_status",
    "encode_video_status",
    "MAX_VIDEO_HZ",
    "DMD_SHAPE",
]

VID, PID = 0x0451, 0x6401
EP_OUT, EP_IN = 0x01, 0x81
REPORT_SIZE = 64
_HEADER = 4  # flags, seq, length (u16)

FLAG_READ, FLAG_REPLY, FLAG_NACK = 0x80, 0x40, 0x20

#: name -> (CMD2, CMD3, payload length or None for variable) (DLPU010; pyCrafter4500 methods).
COMMANDS: dict[str, tuple[int, int, int | None]] = {
    "POWER_CONTROL": (0x02, 0x00, 1),
    "GET_VERSION": (0x02, 0x05, 0),
    "DISP_MODE": (0x1A, 0x1B, 1),
    "PAT_DISP_MODE": (0x1A, 0x22, 1),
    "PAT_TRIG_MODE": (0x1A, 0x23, 1),
    "PAT_START_STOP": (0x1A, 0x24, 1),
    "PAT_EXPO_PRD": (0x1A, 0x29, 8),
    "PAT_CONFIG": (0x1A, 0x31, 4),
    "MBOX_ADDRESS": (0x1A, 0x32, 1),
    "MBOX_CONTROL": (0x1A, 0x33, 1),
    "MBOX_DATA": (0x1A, 0x34, None),
    "LUT_VALID": (0x1A, 0x1A, 1),
    "STATUS_HW": (0x1A, 0x0A, 0),
    "STATUS_SYS": (0x1A, 0x0B, 0),
    "STATUS_MAIN": (0x1A, 0x0C, 0),
    # TI's DLPC350 API (dlpc350_api.cpp CmdList; DLPC350_SetTrigOutConfig,
    # DLPC350_GetInputSource, DLPC350_GetVideoSignalStatus): a 3-byte write, a 1-byte and a
    # 28-byte read
    "TRIG_OUT1_CTL": (0x1A, 0x1D, 3),
    "SOURCE_SEL": (0x1A, 0x00, 1),
    "VID_SIG_STAT": (0x07, 0x1C, 0),
}
_BY_WORD = {(c2 << 8) | c3: name for name, (c2, c3, _) in COMMANDS.items()}

#: PAT_TRIG_MODE values.
TRIGGER_MODES = {"vsync": 0, "internal": 1, "external": 1, "trig_in_pairs": 2}
_START_STOP = {"stop": 0, "pause": 1, "start": 2}
_SOURCE = {"video": 0, "flash": 3}
_MBOX = {"close": 0, "image": 1, "pattern": 2, "var_exposure": 3}
#: ``LUT_VALID`` status bits (TI's ``DLPC350_StartPatLutValidate`` documentation,
#: dlpc350_api.cpp): bits 0 and 1 invalid settings, bits 2-4 warnings.
_LUT_ERRORS = {
    0: "exposure or period out of range",
    1: "pattern numbers out of range",
    2: "TrigOut1 continuous or overlapping black sectors (warning)",
    3: "post vector not inserted before an externally triggered vector (warning)",
    4: "period - exposure < 230 us (warning)",
}
#: The ``LUT_VALID`` bits that reject the sequence; the others are TI's warnings.
LUT_FATAL_BITS = 0x03
MIN_DARK_US = 230  # PAT_EXPO_PRD: exposure == period or exposure <= period - 230 us
#: (rows, columns) of the LightCrafter 4500's DMD: pattern display mode "Assumes a 1-bit
#: through 8-bit image with a pixel resolution of 912 x 1140" (TI's DLPC350 API,
#: dlpc350_api.cpp, documentation of DLPC350_SetMode).
DMD_SHAPE = (1140, 912)
#: Highest video input rate: "Video Display mode ... up to 1280 x 800 up to 120 Hz" (TI's
#: DLPC350 API, dlpc350_api.cpp, documentation of DLPC350_SetMode; its text for pattern
#: display mode, used here, gives no rate, so the video mode's cap is taken; the LightCrafter
#: 4500 user's guide DLPU011 was not available where this was written).
MAX_VIDEO_HZ = 120.0
#: TRIG_OUT1 edge delay codes (DLPC350_SetTrigOutConfig, dlpc350_api.cpp): "Each bit adds
#: 107.2 ns, 0x00 = -20.05 µs, ... 0xBB = 0.00 µs, ..., 0xD5 = +2.787 µs".
TRIG_OUT_ZERO_DELAY, TRIG_OUT_MAX_DELAY, TRIG_OUT_DELAY_STEP_NS = 0xBB, 0xD5, 107.2
#: SOURCE_SEL source field (bits 2:0) and parallel port width field (bits 7:3)
#: (DLPC350_SetInputSource / DLPC350_GetInputSource, dlpc350_api.cpp).
SOURCES = {0: "parallel", 1: "internal test pattern", 2: "flash", 3: "FPD-link"}
PORT_WIDTHS = {0: 30, 1: 24, 2: 20, 3: 16, 4: 10, 5: 8}
#: VID_SIG_STAT status bits that mean "locked" (DLPC350_isSourceLocked: ``(Status &
#: SOURCE_LOCK_MASK) == SOURCE_LOCKED``, mask 0x03, locked 0x02; dlpc350_api.cpp).
SOURCE_LOCK_MASK, SOURCE_LOCKED = 0x03, 0x02
#: Units the VID_SIG_STAT vertical frequency word may be in (Hz per count): TI's API returns
#: the raw word (DLPC350_GetVideoSignalStatus) and its unit is not in TI's code; 0.01 Hz fits
#: a 16-bit word at every rate, 1 Hz is the plain reading. Both are accepted (device-only).
VFREQ_UNITS_HZ = (0.01, 1.0)
#: Relative difference allowed between the video input's measured rate and ``video_hz``.
VIDEO_HZ_TOLERANCE = 0.01


@dataclass(frozen=True)
class Message:
    """A decoded DLPC350 message (request or reply)."""

    flags: int
    seq: int
    command: str | None  # None for replies (they carry no command word)
    payload: bytes

    @property
    def read(self) -> bool:
        return bool(self.flags & FLAG_READ)

    @property
    def reply_wanted(self) -> bool:
        return bool(self.flags & FLAG_REPLY)

    @property
    def nack(self) -> bool:
        return bool(self.flags & FLAG_NACK)


def _command(name: str) -> tuple[int, int, int | None]:
    if name not in COMMANDS:
        raise ValueError(f"dlpc350: unknown command {name!r}; expected one of {sorted(COMMANDS)}")
    return COMMANDS[name]


def encode(name: str, payload: bytes = b"", seq: int = 0, read: bool = False,
           reply: bool = True) -> list[bytes]:
    """Encode one command as 64-byte HID reports (module docstring for the layout).

    Args:
        name: a key of :data:`COMMANDS`.
        payload: the command's data (a read request sends none).
        seq: sequence number, ``0..255``.
        read: build a read request (flags ``0xC0``, no payload).
        reply: ask the device for an acknowledgement (write only; reads always reply).

    Returns:
        The reports, each exactly 64 bytes, zero padded.

    Raises:
        ValueError: on an unknown command, a payload of the wrong length or a bad ``seq``.

    Example:
        >>> encode("PAT_START_STOP", b"\\x02", seq=5)[0][:7].hex(" ")
        '40 05 03 00 24 1a 02'
    """
    cmd2, cmd3, size = _command(name)
    payload = bytes(payload)
    if not 0 <= int(seq) <= 255:
        raise ValueError(f"dlpc350.encode: expected seq in [0, 255], got {seq}")
    if read:
        if payload:
            raise ValueError(f"dlpc350.encode: a read of {name} takes no payload, got {payload!r}")
        flags = FLAG_READ | FLAG_REPLY
    else:
        if size is not None and len(payload) != size:
            raise ValueError(f"dlpc350.encode: {name} expects a {size}-byte payload, "
                             f"got {len(payload)}")
        if size is None and not payload:
            raise ValueError(f"dlpc350.encode: {name} expects a non-empty payload")
        flags = FLAG_REPLY if reply else 0
    if len(payload) + 2 > 0xFFFF:
        raise ValueError(f"dlpc350.encode: payload of {len(payload)} bytes is too long")
    msg = struct.pack("<BBHBB", flags, seq, len(payload) + 2, cmd3, cmd2) + payload
    reports = [msg[i : i + REPORT_SIZE] for i in range(0, len(msg), REPORT_SIZE)]
    return [r.ljust(REPORT_SIZE, b"\x00") for r in reports]


def _header(report: bytes) -> tuple[int, int, int]:
    if len(report) < _HEADER:
        raise ProtocolError("dlpc350", f"report of {len(report)} bytes is shorter than the header")
    flags, seq, length = struct.unpack_from("<BBH", report)
    return flags, seq, length


class Assembler:
    """Reassemble a request from 64-byte reports (the device side; used by the simulator).

    ``feed(report)`` returns ``None`` until the message is complete, then the
    :class:`Message`. Raises :class:`ProtocolError` on a report that is not 64 bytes or a
    length field below 2.
    """

    def __init__(self) -> None:
        self._buf = b""
        self._need = 0

    @property
    def pending(self) -> bool:
        return bool(self._buf)

    def feed(self, report: bytes) -> Message | None:
        report = bytes(report)
        if len(report) != REPORT_SIZE:
            self._buf = b""
            raise ProtocolError("dlpc350",
                                f"expected a {REPORT_SIZE}-byte report, got {len(report)}")
        if not self._buf:
            flags, seq, length = _header(report)
            if length < 2:
                raise ProtocolError("dlpc350", f"length field {length} < 2 (no command word)")
            self._need = _HEADER + length
        self._buf += report
        if len(self._buf) < self._need:
            return None
        msg, self._buf = self._buf[: self._need], b""
        flags, seq, length = _header(msg)
        word = msg[4] | (msg[5] << 8)
        return Message(flags, seq, _BY_WORD.get(word, f"0x{word:04x}"), msg[6:])


def decode(reports: Sequence[bytes]) -> Message:
    """Decode a complete request (one or more reports) into a :class:`Message`.

    Raises:
        ProtocolError: if the reports end before the message does or carry extra reports.

    Example:
        >>> decode(encode("PAT_START_STOP", b"\\x02", seq=1)).payload
        b'\\x02'
    """
    asm = Assembler()
    for i, r in enumerate(reports):
        msg = asm.feed(r)
        if msg is not None:
            if i != len(reports) - 1:
                raise ProtocolError(msg.command or "dlpc350",
                                    f"{len(reports) - 1 - i} extra report(s) after the message")
            return msg
    raise ProtocolError("dlpc350", f"message incomplete after {len(reports)} report(s)")


def decode_reply(report: bytes, command: str, seq: int | None = None) -> Message:
    """Decode a device reply (one IN report): flags, sequence, length and the data from byte 4.

    Raises:
        NackError: if the device set the NACK flag.
        ProtocolError: on a wrong sequence number or a length beyond the report.
    """
    report = bytes(report)
    flags, rseq, length = _header(report)
    if flags & FLAG_NACK:
        raise NackError(command)
    if seq is not None and rseq != seq:
        raise ProtocolError(command, f"reply has sequence number {rseq}, expected {seq}")
    if _HEADER + length > len(report):
        raise ProtocolError(command, f"reply length {length} exceeds the {len(report)}-byte report")
    return Message(flags, rseq, None, report[_HEADER : _HEADER + length])


def encode_reply(request: Message, data: bytes = b"", nack: bool = False) -> bytes:
    """The device's reply to ``request`` (one report): used by the simulator and the tests."""
    flags = (request.flags & (FLAG_READ | FLAG_REPLY)) | (FLAG_NACK if nack else 0)
    body = struct.pack("<BBH", flags, request.seq, len(data)) + bytes(data)
    return body.ljust(REPORT_SIZE, b"\x00")[:REPORT_SIZE]


# ---------------------------------------------------------------------------------------------
# payload encoders (one per command)


def _u8(value: int, name: str, lo: int, hi: int) -> bytes:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not lo <= value <= hi:
        raise ValueError(f"dlpc350: expected {name} in [{lo}, {hi}], got {value!r}")
    return bytes([int(value)])


def payload_power(standby: bool) -> bytes:
    return b"\x01" if standby else b"\x00"


def payload_display_mode(pattern: bool = True) -> bytes:
    return b"\x01" if pattern else b"\x00"


def payload_pattern_source(source: str) -> bytes:
    if source not in _SOURCE:
        raise ValueError(f"dlpc350: expected source in {tuple(_SOURCE)}, got {source!r}")
    return bytes([_SOURCE[source]])


def payload_trigger_mode(trigger: str | int) -> bytes:
    if isinstance(trigger, str):
        if trigger not in TRIGGER_MODES:
            raise ValueError(f"dlpc350: expected trigger in {tuple(TRIGGER_MODES)}, "
                             f"got {trigger!r}")
        return bytes([TRIGGER_MODES[trigger]])
    return _u8(trigger, "trigger mode", 0, 4)


def payload_start_stop(action: str) -> bytes:
    if action not in _START_STOP:
        raise ValueError(f"dlpc350: expected action in {tuple(_START_STOP)}, got {action!r}")
    return bytes([_START_STOP[action]])


def payload_exposure_period(exposure_us: int, period_us: int) -> bytes:
    """``PAT_EXPO_PRD``: u32 exposure and u32 period in µs (LE); the DLPC350 needs
    ``exposure == period`` or ``exposure <= period - 230 µs``."""
    for name, v in (("exposure_us", exposure_us), ("period_us", period_us)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 0 < v < 2**32:
            raise ValueError(f"dlpc350: expected {name} a positive 32-bit integer, got {v!r}")
    if not (exposure_us == period_us or exposure_us <= period_us - MIN_DARK_US):
        raise ValueError(f"dlpc350: expected exposure_us == period_us or exposure_us <= period_us"
                         f" - {MIN_DARK_US}, got exposure_us={exposure_us}, period_us={period_us}")
    return struct.pack("<II", int(exposure_us), int(period_us))


def payload_pattern_config(n_lut: int, repeat: bool, n_trig_out2: int, n_images: int) -> bytes:
    """``PAT_CONFIG``: ``[nLUT − 1, repeat, nTrigOut2 − 1, nImages − 1]``."""
    return (_u8(n_lut - 1, "n_lut - 1", 0, 127) + (b"\x01" if repeat else b"\x00")
            + _u8(n_trig_out2 - 1, "n_trig_out2 - 1", 0, 127)
            + _u8(n_images - 1, "n_images - 1", 0, 63))


def payload_mailbox_control(mode: str) -> bytes:
    if mode not in _MBOX:
        raise ValueError(f"dlpc350: expected mailbox mode in {tuple(_MBOX)}, got {mode!r}")
    return bytes([_MBOX[mode]])


def lut_entry(pattern: int, bit_depth: int = 1, leds: str = "RGB", trig: str = "internal",
              invert: bool = False, insert_black: bool = False, buffer_swap: bool = False,
              trig_out_prev: bool = False) -> int:
    """One 24-bit pattern LUT entry (pyCrafter4500 ``send_pattern_lut``: byte 0 trigger type
    and pattern number, byte 1 bit depth and LEDs, byte 2 flags).

    bits 1:0 trigger type (0 internal, 1 external +, 2 external −, 3 none/continue),
    bits 7:2 pattern number (bit plane, 0–24), bits 11:8 bit depth (1–8),
    bits 14:12 LEDs (b0 R, b1 G, b2 B), bit 16 invert, bit 17 insert black, bit 18 buffer
    swap, bit 19 trigger-out with the previous pattern.

    The pattern number follows TI's code: ``DLPC350_AddToPatLut`` (dlpc350_api.cpp) returns
    -1 for ``PatNum > 24``, although its comment (and pyCrafter4500's ``send_pattern_lut``)
    describes 25 as a white fill.

    Raises:
        ValueError: a pattern outside 0–24, a bit depth outside 1–8, unknown LEDs or trigger.
    """
    trigs = {"internal": 0, "external+": 1, "external-": 2, "none": 3}
    if trig not in trigs:
        raise ValueError(f"lut_entry: expected trig in {tuple(trigs)}, got {trig!r}")
    if isinstance(pattern, bool) or not isinstance(pattern, (int, np.integer)) or \
            not 0 <= pattern <= 24:
        raise ValueError(f"lut_entry: expected pattern in [0, 24] (TI's DLPC350_AddToPatLut "
                         f"returns -1 for PatNum > 24), got {pattern!r}")
    _u8(bit_depth, "bit_depth", 1, 8)
    if not leds or set(leds) - set("RGB"):
        raise ValueError(f"lut_entry: expected leds a non-empty subset of 'RGB', got {leds!r}")
    led = ("R" in leds) | ("G" in leds) << 1 | ("B" in leds) << 2
    return (trigs[trig] | pattern << 2 | (bit_depth & 0xF) << 8 | led << 12 | int(invert) << 16
            | int(insert_black) << 17 | int(buffer_swap) << 18 | int(trig_out_prev) << 19)


def pack_pattern_lut(entries: Sequence[int]) -> bytes:
    """Pattern LUT entries as the ``MBOX_DATA`` payload: 3 bytes each, little endian."""
    if not 1 <= len(entries) <= 128:
        raise ValueError(f"pack_pattern_lut: expected 1 to 128 entries, got {len(entries)}")
    return b"".join(int(e).to_bytes(3, "little") for e in entries)


def pack_image_lut(indices: Sequence[int]) -> bytes:
    """Flash image indices as the image-LUT ``MBOX_DATA`` payload (one byte each); TI's API
    sends a 2-entry table swapped."""
    idx = [int(_u8(i, "image index", 0, 255)[0]) for i in indices]
    if not 1 <= len(idx) <= 64:
        raise ValueError(f"pack_image_lut: expected 1 to 64 images, got {len(idx)}")
    if len(idx) == 2:
        idx = idx[::-1]
    return bytes(idx)


def unpack_lut_entry(value: int) -> dict:
    """Inverse of :func:`lut_entry` (the simulator reads the LUT back with it)."""
    return {"trig": value & 3, "pattern": (value >> 2) & 0x3F, "bit_depth": (value >> 8) & 0xF,
            "leds": (value >> 12) & 7, "invert": bool(value >> 16 & 1),
            "insert_black": bool(value >> 17 & 1), "buffer_swap": bool(value >> 18 & 1),
            "trig_out_prev": bool(value >> 19 & 1)}


#: Bit plane ``k`` (the pattern number of a 1-bit LUT entry) of a 24-bit video frame: the
#: DLPC350 numbers bit planes G0–G7, R0–R7, B0–B7 (check on a device: TI's GUI lists them so).
BITPLANE_CHANNELS = (1, 0, 2)  # G, R, B as indices into an RGB frame


def pack_bitplanes(patterns: np.ndarray) -> np.ndarray:
    """Pack up to 24 binary patterns ``(K, H, W)`` into one 24-bit RGB frame ``(H, W, 3)``
    uint8: pattern ``k`` is bit ``k % 8`` of channel ``BITPLANE_CHANNELS[k // 8]``."""
    pats = np.asarray(patterns)
    if pats.ndim != 3 or not 1 <= pats.shape[0] <= 24:
        raise ValueError(f"pack_bitplanes: expected patterns of shape (K<=24, H, W), "
                         f"got {pats.shape}")
    if not np.isin(pats, (0, 1)).all():
        raise ValueError("pack_bitplanes: expected binary (0/1) patterns")
    frame = np.zeros((*pats.shape[1:], 3), dtype=np.uint8)
    for k in range(pats.shape[0]):  # at most 24 bit planes, not a pixel loop
        ch = BITPLANE_CHANNELS[k // 8]
        frame[..., ch] |= (pats[k].astype(np.uint8) << (k % 8))
    return frame


def unpack_bitplane(frame: np.ndarray, k: int) -> np.ndarray:
    """Bit plane ``k`` of a 24-bit RGB frame ``(H, W, 3)`` as a 0/1 uint8 ``(H, W)``."""
    return (frame[..., BITPLANE_CHANNELS[k // 8]] >> (k % 8)) & 1


def check_video_hz(video_hz: float, where: str, option: str = "video_hz") -> float:
    """``video_hz`` as a float in ``(0, 120]`` Hz (:data:`MAX_VIDEO_HZ`: video display mode runs
    "up to 120 Hz", DLPC350_SetMode's documentation in TI's dlpc350_api.cpp; its text for
    pattern display mode states no rate).

    Raises:
        ValueError: naming ``where`` and ``option``.
    """
    if isinstance(video_hz, bool) or not isinstance(video_hz, (int, float, np.integer,
                                                              np.floating)) or \
            not 0 < float(video_hz) <= MAX_VIDEO_HZ:
        raise ValueError(f"{where}: expected {option} in (0, {MAX_VIDEO_HZ:g}] Hz (the DLPC350's "
                         f"video input runs up to {MAX_VIDEO_HZ:g} Hz, DLPC350_SetMode), got "
                         f"{video_hz!r}")
    return float(video_hz)


def payload_trig_out1(invert: bool = False, rising: int = TRIG_OUT_ZERO_DELAY,
                      falling: int = TRIG_OUT_ZERO_DELAY) -> bytes:
    """``TRIG_OUT1_CTL``: ``[invert, rising delay, falling delay]`` as
    ``DLPC350_SetTrigOutConfig(1, invert, rising, falling)`` sends them (dlpc350_api.cpp):
    invert 0 = active high; delays in steps of 107.2 ns, ``0xBB`` = 0 µs, at most ``0xD5``
    (+2.787 µs). The default, a non-inverted pulse without delay, is what :meth:`LightCrafter4500.
    show_sequence` writes.

    Example:
        >>> payload_trig_out1().hex(" ")
        '00 bb bb'
    """
    if not isinstance(invert, (bool, np.bool_)):
        raise TypeError(f"dlpc350.payload_trig_out1: expected invert a bool, got {invert!r}")
    return (bytes([int(invert)]) + _u8(rising, "payload_trig_out1 rising", 0, TRIG_OUT_MAX_DELAY)
            + _u8(falling, "payload_trig_out1 falling", 0, TRIG_OUT_MAX_DELAY))


def decode_source_sel(data: bytes) -> dict:
    """The ``SOURCE_SEL`` read byte as ``DLPC350_GetInputSource`` decodes it: source = bits
    2:0 (0 parallel, 1 test pattern, 2 flash, 3 FPD-link), port width = bits 7:3 (0 = 30,
    1 = 24, 2 = 20, 3 = 16, 4 = 10, 5 = 8 bits).

    Example:
        >>> decode_source_sel(b"\\x08")
        {'source': 0, 'source_name': 'parallel', 'port_width': 1, 'port_bits': 24}
    """
    if len(data) < 1:
        raise ProtocolError("SOURCE_SEL", "empty reply")
    source, width = data[0] & 0x07, data[0] >> 3
    return {"source": source, "source_name": SOURCES.get(source, f"unknown ({source})"),
            "port_width": width, "port_bits": PORT_WIDTHS.get(width)}


_VID_SIG = struct.Struct("<BHHBBBIHHHHHHHH")  # 28 bytes, DLPC350_GetVideoSignalStatus
_VID_SIG_FIELDS = ("status", "h_res", "v_res", "reserved", "hsync_pol", "vsync_pol",
                   "pix_clock", "h_freq", "v_freq", "total_pixels_per_line",
                   "total_lines_per_frame", "active_pixels_per_line", "active_lines_per_frame",
                   "first_active_pixel", "first_active_line")


def decode_video_status(data: bytes) -> dict:
    """The 28 ``VID_SIG_STAT`` bytes as ``DLPC350_GetVideoSignalStatus`` (dlpc350_api.cpp)
    reads them: status (byte 0, bits 1:0), HRes, VRes (u16 LE at 1, 3), a reserved byte,
    HSync and VSync polarity, the pixel clock (u32 at 8), HFreq, VFreq, total pixels per
    line, total lines per frame, active pixels per line, active lines per frame, first active
    pixel, first active line (u16 each from byte 12). The units of the clock and frequency
    words are not in TI's code (device-only); they are returned raw.

    Raises:
        ProtocolError: fewer than 28 bytes.
    """
    if len(data) < _VID_SIG.size:
        raise ProtocolError("VID_SIG_STAT", f"expected {_VID_SIG.size} bytes, got {len(data)}")
    out = dict(zip(_VID_SIG_FIELDS, _VID_SIG.unpack_from(bytes(data)), strict=True))
    out["status"] &= SOURCE_LOCK_MASK
    return out


def encode_video_status(**fields) -> bytes:
    """Inverse of :func:`decode_video_status` (the simulator answers with it); missing
    fields are 0."""
    unknown = set(fields) - set(_VID_SIG_FIELDS)
    if unknown:
        raise ValueError(f"dlpc350.encode_video_status: unknown fields {sorted(unknown)}")
    return _VID_SIG.pack(*(int(fields.get(k, 0)) for k in _VID_SIG_FIELDS))


def patterns_per_vsync(exposure_us: int, period_us: int, video_hz: float) -> int:
    """Patterns shown per video input frame on the VSYNC trigger: ``⌊frame period /
    period⌋``; the exposures within one input frame cannot exceed the frame time (TI's
    DLPC350 programmer's guide, as pyCrafter4500's ``pattern_mode`` example keeps them).

    Raises:
        ValueError: a period longer than the video frame, or ``video_hz`` outside
            ``(0, 120]`` (:func:`check_video_hz`).
    """
    check_video_hz(video_hz, "dlpc350.patterns_per_vsync")
    frame_us = 1e6 / video_hz
    if max(exposure_us, period_us) > frame_us:
        raise ValueError(f"dlpc350: a {period_us} us pattern period does not fit one "
                         f"{frame_us:.0f} us video frame at {video_hz:g} Hz: the exposures "
                         "within one input frame cannot exceed the frame time (VSYNC trigger)")
    return max(1, int(frame_us // period_us))


def pattern_times_us(k: int, exposure_us: int, period_us: int, trigger: str = "vsync",
                     video_hz: float = 60.0) -> np.ndarray:
    """Start time (µs, from the first) of each of ``k`` patterns of a sequence: every
    ``period_us`` on the internal trigger; on the VSYNC trigger groups of
    :func:`patterns_per_vsync` patterns, each group starting at a VSYNC.

    Example:
        >>> pattern_times_us(3, 10_000, 10_000, "vsync", 50.0).tolist()
        [0.0, 10000.0, 20000.0]
        >>> pattern_times_us(3, 10_000, 10_000, "vsync", 60.0).round().tolist()
        [0.0, 16667.0, 33333.0]
    """
    payload_exposure_period(exposure_us, period_us)
    j = np.arange(int(k))
    if trigger != "vsync":
        return (j * float(period_us)).astype(np.float64)
    per = patterns_per_vsync(exposure_us, period_us, video_hz)
    return (j // per) * (1e6 / video_hz) + (j % per) * float(period_us)


def lut_valid_errors(status: int) -> list[str]:
    """Decode the ``LUT_VALID`` read byte into messages (bit 7 busy is not an error)."""
    return [msg for bit, msg in _LUT_ERRORS.items() if status >> bit & 1]


class VideoPort:
    """Protocol of the HDMI/DisplayPort output that feeds the LightCrafter's video port:
    ``show(frame)`` displays a 24-bit frame ``(H, W, 3)`` uint8 and returns once it is on the
    DMD. torchtof ships none for real hardware (any full-screen image viewer will do); the
    simulator provides one."""

    def show(self, frame: np.ndarray) -> None:  # pragma: no cover - protocol
        raise NotImplementedError


def _usb_errno(exc: BaseException) -> int | None:
    return getattr(exc, "errno", None) or getattr(exc, "backend_error_code", None)


def translate_usb_error(exc: BaseException, what: str, command: str) -> HardwareError:
    """Map a pyusb exception to the hardware errors (timeout → transient, ENODEV → lost)."""
    if isinstance(exc, usb_exceptions()[1]):  # pyusb's, or the simulator's without pyusb
        return _Timeout(command, str(exc))
    code = _usb_errno(exc)
    if code in (19, -4):  # ENODEV / LIBUSB_ERROR_NO_DEVICE
        return DeviceLostError(what, f"{command}: {exc}")
    if code in (16, -6):  # EBUSY / LIBUSB_ERROR_BUSY
        return DeviceBusyError(what, str(exc))
    return ProtocolError(command, f"USB error: {exc}")


class _Timeout(ProtocolError, TransientError):
    def __init__(self, command: str, detail: str) -> None:
        super().__init__(command, f"no reply in time ({detail})")


class LightCrafter4500:
    """Driver of a DLP LightCrafter 4500 over any pyusb-like device object.

    ``dev`` needs ``write(endpoint, data, timeout)`` and ``read(endpoint, size, timeout)``
    (a ``usb.core.Device`` after :meth:`open`, or :class:`~torchtof.hardware.simulated.
    FakeLightCrafter`). Every write asks for an acknowledgement and checks its NACK flag.

    Args:
        dev: the USB device.
        timeout_ms: per-transfer timeout.
        video: a :class:`VideoPort` for video-port (bit-plane) sequences.
        retries: times a command without a reply is sent again (late replies discarded).
    """

    what = "DLP LightCrafter 4500"

    def __init__(self, dev, timeout_ms: int = 1000, video: VideoPort | None = None,
                 retries: int = 2) -> None:
        self.dev, self.timeout_ms, self.video = dev, int(timeout_ms), video
        self.retries = int(retries)
        self.stale_replies = 0
        #: whether the device echoes the sequence byte: ``None`` until a reply shows it
        #: (:meth:`_transfer`)
        self.seq_echo: bool | None = None
        self._pending: set[int] = set()  # sequence bytes of commands that timed out
        self._seq = 0
        self.sent: list[tuple[str, bytes]] = []  # (command, payload) log, newest last

    # -- discovery -------------------------------------------------------------------------
    @classmethod
    def open(cls, **kwargs) -> LightCrafter4500:
        """Find the first LightCrafter 4500 (VID 0x0451, PID 0x6401), detach the kernel HID
        driver, select its configuration if none is active (:func:`ensure_configuration`),
        claim interface 0.

        Raises:
            DeviceNotFoundError: nothing attached (or no libusb backend), with the udev hint.
            DeviceBusyError: the interface is held by another program.
        """
        dev = find_device(VID, PID, cls.what)
        try:
            try:
                if dev.is_kernel_driver_active(0):
                    dev.detach_kernel_driver(0)
            except NotImplementedError:  # pragma: no cover - not on every OS
                pass
            ensure_configuration(dev)
            import usb.util

            usb.util.claim_interface(dev, 0)
        except Exception as exc:  # pyusb raises USBError subclasses
            raise translate_usb_error(exc, cls.what, "open") from exc
        return cls(dev, **kwargs)

    # -- transport ---------------------------------------------------------------------------
    def _next_seq(self) -> int:
        """1, 2, …, 255, 1, …: never 0, the byte a device without the echo answers with
        (pyCrafter4500 sends 0), so a reply can only match by echoing."""
        self._seq = self._seq % 255 + 1
        return self._seq

    #: commands that must not be re-sent blindly: MBOX_DATA appends at the mailbox's
    #: auto-incremented address (a repeat would add entries twice); the caller reloads the
    #: whole table instead (:meth:`show_sequence` is retried as a whole by the acquisition)
    _NOT_IDEMPOTENT = ("MBOX_DATA",)

    def _transfer(self, name: str, payload: bytes, read: bool) -> Message:
        """Send a command and return its reply. A reply whose sequence number is not this
        command's is a late reply to an earlier one (it arrived after the host gave up on
        it): discarded, and the read repeated. No reply in time: the command is sent again
        with a new sequence number (up to :attr:`retries` times; never ``MBOX_DATA``).
        pyCrafter4500 (``dlpc350.command``) and TI's ``DLPC350_USB_Write``/``DLPC350_USB_Read``
        (dlpc350_usb.cpp) read one report per command; the sequence byte is what tells replies
        apart. That the DLPC350 echoes it in its reply is device-only (TI's API never reads it
        back, pyCrafter4500 always sends 0; README "Real hardware"), so it is learnt. Replies
        already waiting are drained before the first command, and before each retry (unless
        the echo is known) the replies of the timed-out attempts. Our sequence bytes run
        1 … 255, never 0. While the echo is unknown, a reply with byte 0 is held (a later one
        replaces it), not taken: an echoing device's own reply may still follow it (the held
        one was then another program's, or late), and it is then discarded. When nothing else
        arrives before the deadline the command is sent once more (an echoing device's reply
        may just be slow; not for commands that must not be repeated), and only when that
        attempt too ends with a byte-0 reply and nothing after it does the driver conclude
        that the device does not echo (:attr:`seq_echo` ``False``, one
        :class:`RuntimeWarning`; the first command of such a device waits its timeout twice)
        and take the held reply. A reply with a
        non-zero byte that is not this command's proves the echo (:attr:`seq_echo` ``True``,
        also after order matching was concluded) and is discarded as late. A mismatched
        byte otherwise is a late or stray reply and is discarded; a match shows the echo
        (:attr:`seq_echo` ``True``)."""
        attempts = 1 if name in self._NOT_IDEMPOTENT else self.retries + 1
        zero_once = False  # a held byte-0 reply met the deadline once (then the command is resent)
        for attempt in range(attempts):
            if self.seq_echo is None and self._seq == 0 or self.seq_echo is not True and \
                    self._pending:
                self._drain()  # another program's leftovers, or late replies (no echo known)
            seq = self._next_seq()
            held = None  # a byte-0 reply while the echo is unknown
            try:
                for r in encode(name, payload, seq, read=read):
                    self.dev.write(EP_OUT, r, self.timeout_ms)
                deadline = time.monotonic() + self.timeout_ms / 1000
                while True:
                    left = max(1, int((deadline - time.monotonic()) * 1000))
                    try:
                        raw = bytes(self.dev.read(EP_IN, REPORT_SIZE, left))
                    except Exception as exc:
                        if held is None or not isinstance(
                                translate_usb_error(exc, self.what, name), _Timeout):
                            raise
                        if not zero_once and attempt < attempts - 1:
                            # an echoing device's own reply may just be slow: send again
                            zero_once = True
                            self.stale_replies += 1
                            raise
                        # byte 0 and nothing else before the deadline, twice: no echo
                        self.seq_echo = False
                        warnings.warn(
                            f"LightCrafter4500: the reply to {name} carries sequence byte 0, "
                            f"not {seq}, and no reply with {seq} followed: this device does "
                            "not echo it; replies are matched by their order",
                            RuntimeWarning, stacklevel=3)
                        return decode_reply(held, name, 0)
                    got = _header(raw)[1]
                    if got == seq:  # bytes are never 0: only an echo matches
                        self.seq_echo = True
                        self._pending.clear()
                        if held is not None:
                            self.stale_replies += 1
                        return decode_reply(raw, name, seq)
                    if self.seq_echo is False:
                        if got == 0:
                            return decode_reply(raw, name, got)
                        self.seq_echo = True  # a byte of ours, not this one: a late echo
                    elif self.seq_echo is None and got == 0:
                        if held is not None:
                            self.stale_replies += 1
                        held = raw  # wait for this command's own echo until the deadline
                        continue
                    elif self.seq_echo is None:  # a byte of ours, not this one: the echo
                        self.seq_echo = True
                        if held is not None:
                            self.stale_replies += 1
                            held = None
                    self.stale_replies += 1  # a late reply to an earlier command
            except HardwareError:
                raise
            except Exception as exc:
                err = translate_usb_error(exc, self.what, name)
                if not isinstance(err, _Timeout):
                    raise err from exc
                self._pending.add(seq)
                last = err
        raise last

    def _drain(self, timeout_ms: int = 20) -> int:
        """Read and discard the replies already waiting (late ones, or another program's)
        until a read times out; returns how many (counted in :attr:`stale_replies`). Forgets
        the unanswered commands (:meth:`_transfer`)."""
        n = 0
        while n < 64:
            try:
                self.dev.read(EP_IN, REPORT_SIZE, timeout_ms)
            except Exception:  # noqa: BLE001 - a timeout (or no device: the command will say)
                break
            n += 1
        self.stale_replies += n
        self._pending.clear()
        return n

    def write(self, name: str, payload: bytes = b"") -> None:
        """Send command ``name`` with ``payload`` and wait for the acknowledgement.

        Raises:
            NackError: the device rejected it (the error names the command).
        """
        self._transfer(name, bytes(payload), read=False)
        self.sent.append((name, bytes(payload)))

    def read(self, name: str) -> bytes:
        """Read command ``name``; returns the reply data.

        Raises:
            NackError: the device set the NACK flag, or answered with no data (length 0):
                TI's ``DLPC350_Read`` (dlpc350_api.cpp) returns -2, its NACK code, for
                ``head.flags.nack == 1 || head.length == 0``.
        """
        data = self._transfer(name, b"", read=True).payload
        if not data:
            raise NackError(name, "the reply carries no data (length 0), which TI's "
                            "DLPC350_Read counts as a NACK")
        return data

    def display_mode(self) -> str:
        """``"pattern"`` or ``"video"``, read back with ``DISP_MODE`` (DLPC350 command
        0x1A1B; pyCrafter4500 ``set_display_mode`` for the values)."""
        return "pattern" if self.read("DISP_MODE")[0] & 1 else "video"

    def set_display_mode(self, pattern: bool = True, timeout_s: float = 2.0,
                         poll_s: float = 0.01) -> None:
        """Switch the display mode only if it differs, then poll the read-back until the
        switch has taken effect (the controller needs time to change modes).

        Raises:
            ProtocolError: still in the old mode after ``timeout_s``.
        """
        want = "pattern" if pattern else "video"
        if self.display_mode() == want:
            return
        self.write("DISP_MODE", payload_display_mode(pattern))
        t0 = time.monotonic()
        while self.display_mode() != want:
            if time.monotonic() - t0 > timeout_s:
                raise ProtocolError("DISP_MODE", f"still not in {want} mode after {timeout_s:g} s")
            time.sleep(poll_s)

    def video_input(self) -> dict:
        """The video input as the controller reports it: ``SOURCE_SEL``
        (:func:`decode_source_sel`) and ``VID_SIG_STAT`` (:func:`decode_video_status`)."""
        return {**decode_source_sel(self.read("SOURCE_SEL")),
                **decode_video_status(self.read("VID_SIG_STAT"))}

    def check_video_input(self, video_hz: float, shape: tuple[int, int] = DMD_SHAPE) -> dict:
        """Check, before a run, that the bit planes can come from the video input: the input
        source is the parallel port (``SOURCE_SEL`` source 0, ``DLPC350_GetInputSource``), the
        video signal is locked (``DLPC350_isSourceLocked``), its active area is ``shape`` =
        (lines, pixels) — the DMD's 912 × 1140, which pattern display mode assumes
        (``DLPC350_SetMode``'s documentation) — and its vertical rate is within 1 % of
        ``video_hz`` (the raw ``VFreq`` word read in 0.01 Hz or in Hz, :data:`VFREQ_UNITS_HZ`).
        Returns what was read.

        Raises:
            ValueError: ``video_hz`` outside ``(0, 120]`` (:func:`check_video_hz`).
            HardwareError: any check fails; the message lists everything that was read.
            NackError, ProtocolError: from the reads.
        """
        video_hz = check_video_hz(video_hz, "LightCrafter4500.check_video_input")
        got = self.video_input()
        rows, cols = (int(v) for v in shape)
        rates = [got["v_freq"] * unit for unit in VFREQ_UNITS_HZ]
        problems = []
        if got["source"] != 0:
            problems.append(f"the input source is {got['source_name']} (SOURCE_SEL source "
                            f"{got['source']}), not the parallel port (source 0)")
        if got["status"] != SOURCE_LOCKED:
            problems.append(f"the video signal is not locked (VID_SIG_STAT status "
                            f"{got['status']}, locked is {SOURCE_LOCKED})")
        if (got["active_pixels_per_line"], got["active_lines_per_frame"]) != (cols, rows):
            problems.append(f"the active area is {got['active_pixels_per_line']}x"
                            f"{got['active_lines_per_frame']}, the DMD needs {cols}x{rows}")
        if not any(abs(r - video_hz) <= VIDEO_HZ_TOLERANCE * video_hz for r in rates):
            problems.append(f"the vertical rate word {got['v_freq']} is neither "
                            f"{rates[0]:g} Hz (0.01 Hz units) nor {rates[1]:g} Hz within "
                            f"{VIDEO_HZ_TOLERANCE:.0%} of video_hz = {video_hz:g}")
        if problems:
            read = ", ".join(f"{k}={v}" for k, v in got.items())
            raise HardwareError(
                f"{self.what}: the video input cannot carry the patterns: "
                + "; ".join(problems) + f". Read: {read}. Extend the desktop onto the "
                f"LightCrafter's HDMI input at {cols}x{rows}, {video_hz:g} Hz, no scaling "
                "(README 'Real hardware'), and select its video input (TI's LightCrafter 4500 "
                "GUI, or SOURCE_SEL 0x1A00)")
        return got

    # -- commands ----------------------------------------------------------------------------
    def start(self) -> None:
        self.write("PAT_START_STOP", payload_start_stop("start"))

    def stop(self) -> None:
        self.write("PAT_START_STOP", payload_start_stop("stop"))

    def pause(self) -> None:
        self.write("PAT_START_STOP", payload_start_stop("pause"))

    def standby(self, on: bool = True) -> None:
        self.write("POWER_CONTROL", payload_power(on))

    def status(self) -> dict[str, int]:
        """The hardware, system and main status bytes."""
        return {k: self.read(f"STATUS_{k.upper()}")[0] for k in ("hw", "sys", "main")}

    def version(self) -> dict[str, int]:
        """``GET_VERSION``: the reply's 32-bit words (application, API, config, sequence)."""
        data = self.read("GET_VERSION")
        n = len(data) // 4
        words = struct.unpack(f"<{n}I", data[: 4 * n])
        keys = ("app", "api", "config", "sequence")
        return {keys[i] if i < 4 else f"word{i}": w for i, w in enumerate(words)}

    def load_pattern_lut(self, entries: Sequence[int]) -> None:
        """Open mailbox 2 (pattern LUT) at address 0, send all entries, close it."""
        data = pack_pattern_lut(entries)
        self.write("MBOX_CONTROL", payload_mailbox_control("pattern"))
        self.write("MBOX_ADDRESS", _u8(0, "mailbox address", 0, 127))
        self.write("MBOX_DATA", data)
        self.write("MBOX_CONTROL", payload_mailbox_control("close"))

    def load_image_lut(self, indices: Sequence[int]) -> None:
        self.write("MBOX_CONTROL", payload_mailbox_control("image"))
        self.write("MBOX_ADDRESS", _u8(0, "mailbox address", 0, 127))
        self.write("MBOX_DATA", pack_image_lut(indices))
        self.write("MBOX_CONTROL", payload_mailbox_control("close"))

    def validate(self, timeout_s: float = 2.0, poll_s: float = 0.0) -> None:
        """Start LUT validation and poll until the busy bit clears.

        Bits 0-1 (invalid exposure/period or pattern numbers) reject the sequence; bits 2-4,
        which TI documents as warnings (``DLPC350_StartPatLutValidate``), are issued as a
        :class:`RuntimeWarning` naming them and the sequence is kept.

        Raises:
            ProtocolError: naming ``LUT_VALID`` and the decoded error bits, or on timeout.
        """
        self.write("LUT_VALID", b"\x00")
        t0 = time.monotonic()
        while True:
            status = self.read("LUT_VALID")[0]
            if not status & 0x80:
                break
            if time.monotonic() - t0 > timeout_s:
                raise ProtocolError("LUT_VALID", f"still busy after {timeout_s:g} s")
            if poll_s:
                time.sleep(poll_s)
        errors = lut_valid_errors(status)
        if status & LUT_FATAL_BITS:
            raise ProtocolError("LUT_VALID", f"sequence rejected (status 0x{status:02x}): "
                                + "; ".join(errors))
        if errors:
            warnings.warn(f"LightCrafter4500.validate: LUT_VALID status 0x{status:02x}, TI's "
                          f"warnings: {'; '.join(errors)}", RuntimeWarning, stacklevel=2)

    def show_sequence(self, patterns, exposure_us: int, period_us: int | None = None,
                      trigger: str = "vsync", source: str = "video", repeat: bool = False,
                      leds: str = "RGB", start: bool = True, video_hz: float = 60.0) -> None:
        """Load a 1-bit pattern sequence and (by default) start it.

        The order of pyCrafter4500's ``pattern_mode`` (stop → display mode → pattern source →
        pattern config → trigger mode → exposure/period → (image LUT) → pattern LUT →
        validate → start), with the display mode read back and switched only when it
        differs (:meth:`set_display_mode`), TRIG_OUT1 set active high with no delay after the
        exposure/period (``TRIG_OUT1_CTL``, :func:`payload_trig_out1`; TI's
        ``DLPC350_SetTrigOutConfig`` wants the sequence stopped and a validation after it),
        and LUT validation polled and its error bits decoded. Each pattern raises TRIG_OUT1
        while it is shown (the camera's trigger).

        ``trigger="vsync"`` (default): as in TI's and pyCrafter4500's video-mode examples the
        sequence is paced by the video input's VSYNC: ``⌊frame period / period⌋`` patterns
        per input frame, the first of each group with LUT trigger type 1 (it waits for the
        VSYNC), the others type 3 (continue) — the exposures within one input frame must not
        exceed the frame time (:func:`pattern_times_us`). The static 24-bit frame that
        carries the ≤ 24 bit planes is shown once by :attr:`video`.

        Args:
            patterns: ``source="video"``: binary array ``(K ≤ 24, H, W)``, packed into the bit
                planes of one 24-bit frame that :attr:`video` shows (``video.show``).
                ``source="flash"``: a sequence of ``(flash_image_index, bit_plane)`` pairs of
                images already stored in the controller's flash.
            exposure_us: exposure per pattern in µs.
            period_us: pattern period in µs (default: ``exposure_us``).
            trigger: ``"vsync"``, ``"internal"`` (the DMD paces the sequence) or
                ``"external"`` (each pattern waits for a TRIG_IN edge).
            repeat: loop the sequence.
            leds: LEDs lit for every pattern (subset of ``"RGB"``).
            start: send the start command.
            video_hz: the video input's frame rate (``"vsync"``).

        Raises:
            ValueError: bad patterns or timing; ProtocolError/NackError from the device.
        """
        period_us = exposure_us if period_us is None else period_us
        payload_exposure_period(exposure_us, period_us)  # validate before touching the device
        payload_trigger_mode(trigger)
        if source == "video":
            pats = np.asarray(patterns.detach().cpu() if hasattr(patterns, "detach") else patterns)
            frame = pack_bitplanes(pats)
            if self.video is None:
                raise ValueError("LightCrafter4500.show_sequence: source='video' needs a video "
                                 "port (LightCrafter4500(dev, video=...)) to show the bit planes")
            planes = list(range(pats.shape[0]))
            swaps = [False] * len(planes)
            images: list[int] = []
        elif source == "flash":
            pairs = [(int(i), int(b)) for i, b in patterns]
            if not 1 <= len(pairs) <= 128:
                raise ValueError(f"show_sequence: expected 1 to 128 flash patterns, "
                                 f"got {len(pairs)}")
            images = []
            swaps = []
            for img, _ in pairs:
                swaps.append(not images or images[-1] != img)
                if swaps[-1]:
                    images.append(img)
            swaps[0] = False
            planes = [b for _, b in pairs]
        else:
            raise ValueError(f"show_sequence: expected source in {tuple(_SOURCE)}, got {source!r}")
        if trigger == "vsync":
            per = patterns_per_vsync(exposure_us, period_us, video_hz)
            trigs = ["external+" if k % per == 0 else "none" for k in range(len(planes))]
        else:
            trigs = ["external+" if trigger == "external" else "internal"] * len(planes)
        entries = [lut_entry(p, 1, leds, t, buffer_swap=s)
                   for p, t, s in zip(planes, trigs, swaps)]
        self.stop()
        if source == "video":
            self.video.show(frame)
        self.set_display_mode(True)
        self.write("PAT_DISP_MODE", payload_pattern_source(source))
        self.write("PAT_CONFIG", payload_pattern_config(len(entries), repeat, len(entries),
                                                        max(1, len(images))))
        self.write("PAT_TRIG_MODE", payload_trigger_mode(trigger))
        self.write("PAT_EXPO_PRD", payload_exposure_period(exposure_us, period_us))
        # TRIG_OUT1 (the camera's trigger) active high, no delay: DLPC350_SetTrigOutConfig
        # asks for it while the sequence is stopped, before the validation
        self.write("TRIG_OUT1_CTL", payload_trig_out1())
        if images:
            self.load_image_lut(images)
        self.load_pattern_lut(entries)
        self.validate()
        if start:
            self.start()

    def close(self) -> None:
        try:
            import usb.util

            usb.util.dispose_resources(self.dev)
        except Exception:  # noqa: BLE001 - fake devices, already gone
            pass


def ensure_configuration(dev) -> None:
    """Select the device's first configuration only if none is active: re-selecting the active
    one makes libusb reset the device's USB state (TI's ``USBIO`` only opens the device and
    claims its interface, Voxel/USBIO.cpp)."""
    import usb.core

    try:
        active = dev.get_active_configuration()
    except usb.core.USBError:  # unconfigured (pyusb raises when the value is 0)
        active = None
    if active is None:
        dev.set_configuration()


def find_device(vid: int, pid: int, what: str):
    """``usb.core.find(idVendor=vid, idProduct=pid)`` with errors a user understands.

    Raises:
        DeviceNotFoundError: no such device, or pyusb has no libusb backend.
        ImportError: pyusb is not installed (naming the extra ``torchtof[hardware]``).
    """
    require("usb", f"opening the {what} over USB")
    import usb.core

    try:
        dev = usb.core.find(idVendor=vid, idProduct=pid)
    except usb.core.NoBackendError as exc:
        raise DeviceNotFoundError(
            what, vid, pid, "pyusb found no libusb backend: install libusb "
            "(apt install libusb-1.0-0, or pip install libusb-package)") from exc
    except usb.core.USBError as exc:
        raise translate_usb_error(exc, what, "usb.core.find") from exc
    if dev is None:
        raise DeviceNotFoundError(what, vid, pid)
    return dev
