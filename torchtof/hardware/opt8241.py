"""TI OPT8241 ToF camera (OPT8241-CDK-EVM, "TintinCDK") over USB: registers and frames.

From the Voxel SDK (BSD) facts in ``domain-notes.md`` §5.3: USB VID 0x0451, PID 0x9105 is
the custom bulk device; frames arrive on bulk IN endpoint 0x82; registers are read and
written with vendor device control transfers. A 16-bit register address is
``slave << 8 | reg``; the request carries ``wValue = slave << shift`` and
``wIndex = reg << shift`` with per-slave request codes (read, write, shift, bytes):

====================  ============  ===========  =====  ======
slave                 read request  write req.   shift  bytes
====================  ============  ===========  =====  ======
0x58, 0x5C (ToF)      0x08          0x09         0      3
0x4B, 0x4E            0x0A          0x0B         0      2
0x2D, 0x52, 0x54      0x04          0x03         8      1
====================  ============  ===========  =====  ======

Per pixel the OPT9221 outputs 12-bit phase + 12-bit amplitude + 4-bit ambient + 4-bit flags
(Voxel ``ToFFrameGenerator``); depth = ``phase12 · c / (2f · 4096)`` (Eq. 1 with
``θ = 2π·phase12/4096``), then the camera rules of paper §2.2
(:func:`torchtof.sensor.camera_rules`).

**Not from TI documentation (to check on a device):** the register addresses in
:data:`REGISTERS` (modulation frequency, integration time, streaming enable) and their
units, the byte order of register values (little endian here), and the frame packet
header (:data:`HEADER`): the notes give only the per-pixel word. torchtof's frame packet is
a 32-byte header (magic ``b"TTOF"``, version, flags, frame id, timestamp, size, payload
length, CRC-32 of the payload) + one little-endian u32 per pixel
(``phase12 | amp12 << 12 | ambient4 << 24 | flags4 << 28``) + optionally the raw taps
as u16 ``(4, H, W)`` (Fig. 1 order). The simulator speaks exactly this format.
"""

from __future__ import annotations

import math
import struct
import time
import zlib
from dataclasses import dataclass

import numpy as np
import torch

from ..sensor import camera_rules, phase_to_depth, tap_amplitude, tap_phase
from .dlpc350 import find_device, translate_usb_error
from .errors import FrameError, FrameTimeoutError, HardwareError, ProtocolError
from .frames import Frame

__all__ = [
    "VID",
    "PID",
    "EP_FRAMES",
    "SLAVES",
    "REGISTERS",
    "HEADER",
    "CameraRules",
    "register_request",
    "encode_frame",
    "decode_frame",
    "OPT8241",
]

VID, PID = 0x0451, 0x9105
EP_FRAMES = 0x82
VENDOR_OUT, VENDOR_IN = 0x40, 0xC0  # bmRequestType: vendor, device, host->device / device->host

#: slave -> (read request, write request, shift, register bytes), domain-notes §5.3.
SLAVES: dict[int, tuple[int, int, int, int]] = {
    0x58: (0x08, 0x09, 0, 3),
    0x5C: (0x08, 0x09, 0, 3),
    0x4B: (0x0A, 0x0B, 0, 2),
    0x4E: (0x0A, 0x0B, 0, 2),
    0x2D: (0x04, 0x03, 8, 1),
    0x52: (0x04, 0x03, 8, 1),
    0x54: (0x04, 0x03, 8, 1),
}

#: Named registers (address = slave << 8 | reg). PLACEHOLDERS, not from TI's register map:
#: replace them with the OPT9221 addresses (Voxel DML files) before using a real camera.
REGISTERS: dict[str, int] = {
    "stream_enable": 0x5880,
    "mod_freq_khz": 0x5881,
    "intg_time_us": 0x5882,
    "frame_count": 0x5883,  # id of the next frame (wraps at 2^24)
}

HEADER = struct.Struct("<4sHHIQHHII")  # magic, version, flags, id, t_us, W, H, payload, crc32
MAGIC, VERSION = b"TTOF", 1
FLAG_TAPS = 1
_TWO_PI = 2.0 * math.pi


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
        >>> register_request(0x5881, write=True)
        (64, 9, 88, 129, 3)
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


def encode_frame(phase: np.ndarray, amplitude: np.ndarray, frame_id: int, timestamp_us: int,
                 ambient: np.ndarray | None = None, flags: np.ndarray | None = None,
                 taps: np.ndarray | None = None) -> bytes:
    """Encode one frame packet (module docstring). ``phase`` in radians, ``amplitude`` in ADC
    numbers (rounded and clipped to 12 bits), ``taps`` integer ADC numbers ``(4, H, W)``."""
    phase = np.asarray(phase, dtype=np.float64)
    h, w = phase.shape
    p12 = np.rint(np.mod(phase, _TWO_PI) * (4096 / _TWO_PI)).astype(np.uint32) % 4096
    a12 = np.clip(np.rint(np.asarray(amplitude, dtype=np.float64)), 0, 4095).astype(np.uint32)
    amb = np.zeros_like(p12) if ambient is None else np.asarray(ambient, np.uint32) & 0xF
    flg = np.zeros_like(p12) if flags is None else np.asarray(flags, np.uint32) & 0xF
    words = (p12 | a12 << 12 | amb << 24 | flg << 28).astype("<u4").tobytes()
    hdr_flags = 0
    if taps is not None:
        taps = np.asarray(taps)
        if taps.shape != (4, h, w) or (taps < 0).any() or (taps > 0xFFFF).any():
            raise ValueError(f"encode_frame: expected integer taps (4, {h}, {w}) in [0, 65535]")
        words += np.asarray(taps).astype("<u2").tobytes()
        hdr_flags |= FLAG_TAPS
    return HEADER.pack(MAGIC, VERSION, hdr_flags, frame_id & 0xFFFFFFFF, int(timestamp_us), w, h,
                       len(words), zlib.crc32(words)) + words


def decode_frame(raw: bytes, freq_hz: float, rules: CameraRules = CameraRules(),
                 use_taps: bool = True) -> Frame:
    """Decode a frame packet into a :class:`Frame` (depth in metres with the camera rules).

    With raw taps in the packet and ``use_taps`` (default) the phase, amplitude and depth
    are computed from the taps exactly as :func:`torchtof.sensor.cw_tof_sensor` does
    (Eqs. 7, 8, 1 and §2.2); otherwise from the 12-bit phase and amplitude words.

    Raises:
        FrameError: short packet, wrong magic/version, size mismatch or CRC mismatch.
    """
    raw = bytes(raw)
    if len(raw) < HEADER.size:
        raise FrameError(f"{len(raw)} bytes, shorter than the {HEADER.size}-byte header")
    magic, version, hflags, fid, t_us, w, h, n, crc = HEADER.unpack_from(raw)
    if magic != MAGIC or version != VERSION:
        raise FrameError(f"bad magic/version {magic!r}/{version}")
    body = raw[HEADER.size :]
    expect = 4 * w * h + (8 * w * h if hflags & FLAG_TAPS else 0)
    if n != expect or len(body) != n:
        raise FrameError(f"payload of {len(body)} bytes (header says {n}, a {w}x{h} frame "
                         f"needs {expect})")
    if zlib.crc32(body) != crc:
        raise FrameError("CRC-32 mismatch (bytes corrupted in transfer)")
    words = np.frombuffer(body, dtype="<u4", count=w * h).reshape(h, w)
    p12 = (words & 0xFFF).astype(np.float32)
    amp = torch.from_numpy(((words >> 12) & 0xFFF).astype(np.float32))
    ambient = torch.from_numpy(((words >> 24) & 0xF).astype(np.uint8))
    flags = torch.from_numpy(((words >> 28) & 0xF).astype(np.uint8))
    taps = None
    if hflags & FLAG_TAPS:
        t = np.frombuffer(body, dtype="<u2", offset=4 * w * h).reshape(4, h, w)
        taps = torch.from_numpy(t.astype(np.float32))
    if taps is not None and use_taps:
        t4 = taps[None]
        amp4, phase4 = tap_amplitude(t4), tap_phase(t4)  # Eqs. 8 and 7
    else:
        amp4 = amp[None, None]
        phase4 = torch.from_numpy(p12 * np.float32(_TWO_PI / 4096))[None, None]
    depth4 = rules.apply(phase_to_depth(phase4, freq_hz), amp4)  # Eq. 1 + §2.2
    return Frame(phase=phase4[0, 0], amplitude=amp4[0, 0], depth=depth4[0, 0],
                 timestamp=t_us * 1e-6, frame_id=fid, taps=taps, ambient=ambient, flags=flags)


class OPT8241:
    """OPT8241-CDK-EVM frame source over any pyusb-like device (``ctrl_transfer`` and
    ``read``), e.g. ``usb.core.Device`` (:meth:`open`) or the simulator's fake camera.

    Args:
        dev: the USB device.
        width, height: frame size in pixels (QVGA 320×240; smaller with an ROI).
        rules: the camera rules applied to the decoded depth.
        use_taps: compute phase/amplitude/depth from raw taps when frames carry them.
        timeout_s: default frame timeout.
        registers: register map (see the warning on :data:`REGISTERS`).
    """

    what = "TI OPT8241 ToF camera"

    def __init__(self, dev, width: int = 320, height: int = 240,
                 rules: CameraRules = CameraRules(), use_taps: bool = True,
                 timeout_s: float = 2.0, registers: dict[str, int] | None = None) -> None:
        self.dev, self.width, self.height = dev, int(width), int(height)
        self.rules, self.use_taps, self.timeout_s = rules, use_taps, float(timeout_s)
        self.registers = dict(REGISTERS if registers is None else registers)
        self.pattern_index: int | None = None  # set by acquire(): named in timeout errors

    @classmethod
    def open(cls, **kwargs) -> OPT8241:
        """Find the first OPT8241-CDK-EVM (VID 0x0451, PID 0x9105) and configure it.

        Raises:
            DeviceNotFoundError: nothing attached / no libusb backend (with the udev hint).
            DeviceBusyError: the interface is held by another program.
        """
        dev = find_device(VID, PID, cls.what)
        try:
            dev.set_configuration()
        except Exception as exc:
            raise translate_usb_error(exc, cls.what, "open") from exc
        return cls(dev, **kwargs)

    # -- registers ---------------------------------------------------------------------------
    def _address(self, reg: int | str) -> int:
        if isinstance(reg, str):
            if reg not in self.registers:
                raise ValueError(f"OPT8241: unknown register {reg!r}; "
                                 f"known {sorted(self.registers)}")
            return self.registers[reg]
        return int(reg)

    def write_register(self, reg: int | str, value: int) -> None:
        address = self._address(reg)
        rtype, req, wvalue, windex, nbytes = register_request(address, write=True)
        if not 0 <= int(value) < 1 << (8 * nbytes):
            raise ValueError(f"OPT8241.write_register: value {value} does not fit the "
                             f"{nbytes}-byte register 0x{address:04x}")
        data = int(value).to_bytes(nbytes, "little")
        name = f"write register 0x{address:04x}"
        try:
            n = self.dev.ctrl_transfer(rtype, req, wvalue, windex, data, 1000)
        except HardwareError:
            raise
        except Exception as exc:
            raise translate_usb_error(exc, self.what, name) from exc
        if n != nbytes:
            raise ProtocolError(name, f"device accepted {n} of {nbytes} bytes")

    def read_register(self, reg: int | str) -> int:
        address = self._address(reg)
        rtype, req, wvalue, windex, nbytes = register_request(address, write=False)
        name = f"read register 0x{address:04x}"
        try:
            data = bytes(self.dev.ctrl_transfer(rtype, req, wvalue, windex, nbytes, 1000))
        except HardwareError:
            raise
        except Exception as exc:
            raise translate_usb_error(exc, self.what, name) from exc
        if len(data) != nbytes:
            raise ProtocolError(name, f"expected {nbytes} bytes, got {len(data)}")
        return int.from_bytes(data, "little")

    @property
    def freq_hz(self) -> float:
        """Modulation frequency in Hz (read from the camera)."""
        return self.read_register("mod_freq_khz") * 1e3

    def set_modulation_frequency(self, freq_hz: float) -> None:
        """Set the modulation frequency (10–100 MHz, datasheet SBAS704B)."""
        if not 10e6 <= freq_hz <= 100e6:
            raise ValueError(f"OPT8241: expected freq_hz in [10e6, 100e6], got {freq_hz}")
        self.write_register("mod_freq_khz", round(freq_hz / 1e3))

    @property
    def integration_time_us(self) -> int:
        return self.read_register("intg_time_us")

    def frame_counter(self) -> int:
        """The id the next frame will carry (the camera's frame counter, 24 bits)."""
        return self.read_register("frame_count")

    def set_integration_time(self, us: int) -> None:
        if isinstance(us, bool) or not isinstance(us, int) or not 1 <= us < 1 << 24:
            raise ValueError(f"OPT8241: expected integration time in [1, 2^24) us, got {us!r}")
        self.write_register("intg_time_us", us)

    # -- streaming ---------------------------------------------------------------------------
    def start(self) -> None:
        self._freq = self.freq_hz
        self.write_register("stream_enable", 1)

    def stop(self) -> None:
        self.write_register("stream_enable", 0)

    def _max_packet(self) -> int:
        return HEADER.size + 12 * self.width * self.height

    def grab(self, timeout_s: float | None = None) -> Frame:
        """Read and decode the next frame from bulk endpoint 0x82.

        Raises:
            FrameTimeoutError: nothing arrived (names :attr:`pattern_index` when set).
            FrameError: the bytes do not decode.
            DeviceLostError: the camera disappeared.
        """
        import usb.core

        timeout = self.timeout_s if timeout_s is None else float(timeout_s)
        try:
            raw = self.dev.read(EP_FRAMES, self._max_packet(), max(1, int(timeout * 1000)))
        except usb.core.USBTimeoutError as exc:
            raise FrameTimeoutError(self.pattern_index, timeout) from exc
        except HardwareError:
            raise
        except Exception as exc:
            raise translate_usb_error(exc, self.what, "bulk read") from exc
        freq = getattr(self, "_freq", None) or self.freq_hz
        try:
            return decode_frame(bytes(raw), freq, self.rules, self.use_taps)
        except FrameError as exc:
            raise FrameError(str(exc).removeprefix("corrupt frame: "), self.pattern_index) from exc

    def flush(self, timeout_s: float = 0.05) -> int:
        """Discard queued frames until none arrives within ``timeout_s``; returns the count."""
        import usb.core

        n, t0 = 0, time.monotonic()
        while time.monotonic() - t0 < 10.0:
            try:
                self.dev.read(EP_FRAMES, self._max_packet(), max(1, int(timeout_s * 1000)))
            except usb.core.USBTimeoutError:
                return n
            except Exception as exc:
                raise translate_usb_error(exc, self.what, "flush") from exc
            n += 1
        raise ProtocolError("flush", "camera keeps sending frames after 10 s")
