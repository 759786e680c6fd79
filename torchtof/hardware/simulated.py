"""Simulated LightCrafter 4500 and OPT8241 behind the same pyusb-level interface.

:class:`FakeLightCrafter` (``write``/``read`` of 64-byte HID reports) parses the real
DLPC350 byte protocol (:mod:`~torchtof.hardware.dlpc350`): it reassembles multi-report
messages, NACKs malformed ones (unknown command, wrong payload length, out-of-range values),
keeps the display/trigger/timing/mailbox/LUT/TRIG_OUT1/input-source state, answers LUT_VALID
(with its error bits), status, version, SOURCE_SEL and VID_SIG_STAT reads (a locked 912 × 1140
input at the bench's ``video_hz``; :attr:`FakeLightCrafter.video_signal` changes it), and
when a sequence starts it shows each LUT entry's bit plane of
the current video frame (or flash image) and raises TRIG_OUT1. :class:`FakeOPT8241`
(``ctrl_transfer``/``read``) keeps its registers behind the vendor control transfers of
:mod:`~torchtof.hardware.opt8241`; on each trigger it renders one frame of the chosen scene
through the displayed pattern with the torchtof sensor model
(:func:`torchtof.experiment.simulate_frames`, the same code and configuration as
:class:`~torchtof.experiment.PaperExperiment`) and queues the encoded packet on bulk IN.
The simulated frame is the ``roi_px × roi_px`` sensor ROI below one dark guard row (row 0,
all taps 0: the camera sees more than the DMD image, and row 0 is where the OPT9221 writes
its frame number). With ``debug_frame_number_en`` set, byte 0 of every packet is the low byte
of a counter that advances once per frame the camera outputs — delivered, dropped or
spurious — starting at ``frame_number_start`` (:mod:`.opt8241` on what is assumed).

Each frame's noise comes from a generator seeded from ``seed`` and the displayed pattern
(:meth:`SimulatedBench.noise_generator`), so a retried or resumed frame is the frame the
uninterrupted run recorded; a noise-free acquisition equals ``PaperExperiment``'s depth,
gated and intensity buckets bucket for bucket. Its tap buckets are sums of signed 12-bit
samples (the simulator's convention :data:`~torchtof.hardware.opt8241.QUAD_OFFSET`: a model
tap ``c`` is sent as ``c − 2048``; the offset a real OPT9221 removes is undocumented), so
they sit 2048 per pixel per frame below ``PaperExperiment``'s (a constant that cancels in
``y⁺ − y⁻``).

Fault injection (:class:`Faults`): frame-level faults are keyed by the camera's frame
ordinal (0 = first frame rendered), command faults by the command's occurrence count.
"""

from __future__ import annotations

import hashlib
import math
import os
import struct
import threading
import time
from collections import deque
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import torch

from ..experiment import ExperimentConfig, simulate_frames, stray_light
from ..scenes import get_scene
from ..sensor import dust_map
from . import dlpc350 as dlp
from . import opt8241 as opt
from .dlpc350 import LightCrafter4500, VideoPort
from .errors import usb_exceptions
from .opt8241 import OPT8241, CameraRules

__all__ = ["Faults", "FakeLightCrafter", "FakeOPT8241", "SimulatedBench", "rules_from_config"]


def _usb_error(msg: str, errno: int):
    """pyusb's ``USBError``, or its stand-in without pyusb (the simulator needs no USB)."""
    return usb_exceptions()[0](msg, errno=errno)


def _usb_timeout(msg: str = "Operation timed out"):
    return usb_exceptions()[1](msg, errno=110)


@dataclass
class Faults:
    """Faults to inject. Frame ordinals count every frame the camera renders (from 0).

    Attributes:
        frame_timeout: triggers the camera misses: no frame and no frame number (the host
            waits for it in vain: a frame timeout).
        drop: frames rendered but never delivered (a frame-id gap).
        duplicate: frames delivered twice.
        extra: frames followed by one spurious, different frame (its words in reverse order),
            made by the camera itself: it takes the next frame number.
        corrupt: frames delivered 2 bytes short (a transfer of the wrong size: the only
            damage the format can show, since the SDK ignores the top 4 bits of a quad word).
        split: frames delivered as two bulk transfers (each of the wrong size).
        stall: frames whose bulk read fails with a stalled endpoint (EPIPE); the frame is lost.
        ctrl_fail: control-transfer ordinals (from 0) that fail once with EPIPE.
        op_overflow: frames during whose output the OPT9221 sets ``op_overflow`` (OPT9221.dml
            id 6378: the output data rate is too low); the frame itself is delivered whole,
            so only the flag shows it.
        late_reply: ``{command: {occurrence}}``: the LightCrafter answers too late: the first
            read times out and the reply is the next one read (stale, its sequence number the
            old command's).
        set_failed: OPT9221 failure flags forced to 1 (``"pix_cnt_max_set_failed"``,
            ``"intg_duty_cycle_set_failed"``).
        nack: ``{command: {occurrence, ...}}``: the LightCrafter NACKs these writes
            (occurrence counts from 0 per command).
        reply_timeout: ``{command: {occurrence}}``: the LightCrafter does not answer.
        vanish_after_frames: both devices disappear (ENODEV) once the camera has delivered
            this many frames (the next bulk read fails).
        hang_at_frame: on rendering this frame the camera touches ``hang_file`` and stalls
            for ``hang_s`` (a test kills the process meanwhile).
        hang_at_read: the same on the bulk read that would deliver this many-th frame (0 =
            first): every earlier frame has reached the host.
        no_seq_echo: the LightCrafter answers with sequence byte 0 instead of the request's
            (whether a DLPC350 echoes it is device-only; pyCrafter4500 always sends 0).
        empty_reply: ``{command: {occurrence}}``: the LightCrafter answers these reads with
            no data (length 0), which TI's ``DLPC350_Read`` counts as a NACK.
    """

    frame_timeout: set[int] = field(default_factory=set)
    drop: set[int] = field(default_factory=set)
    duplicate: set[int] = field(default_factory=set)
    extra: set[int] = field(default_factory=set)
    corrupt: set[int] = field(default_factory=set)
    nack: dict[str, set[int]] = field(default_factory=dict)
    reply_timeout: dict[str, set[int]] = field(default_factory=dict)
    split: set[int] = field(default_factory=set)
    stall: set[int] = field(default_factory=set)
    ctrl_fail: set[int] = field(default_factory=set)
    late_reply: dict[str, set[int]] = field(default_factory=dict)
    set_failed: set[str] = field(default_factory=set)
    vanish_after_frames: int | None = None
    hang_at_frame: int | None = None
    hang_at_read: int | None = None
    hang_file: str | None = None
    hang_s: float = 60.0
    no_seq_echo: bool = False
    empty_reply: dict[str, set[int]] = field(default_factory=dict)
    op_overflow: set[int] = field(default_factory=set)

    #: fields holding frame or control-transfer ordinals (lists of non-negative ints)
    _ORDINALS = ("frame_timeout", "drop", "duplicate", "extra", "corrupt", "split", "stall",
                 "ctrl_fail", "op_overflow")
    #: fields ``{command: [occurrence, ...]}``, commands of :data:`~.dlpc350.COMMANDS`
    _COMMANDS = ("nack", "reply_timeout", "late_reply", "empty_reply")
    #: fields holding one ordinal or ``None``
    _ORDINAL = ("vanish_after_frames", "hang_at_frame", "hang_at_read")

    @classmethod
    def from_dict(cls, d: dict) -> Faults:
        """A fault plan from a JSON object (``torchtof acquire --sim-faults``): ordinal sets as
        lists of non-negative ints, ``{command: [occurrence, ...]}`` for ``nack``,
        ``reply_timeout``, ``late_reply`` and ``empty_reply`` (commands of
        :data:`~.dlpc350.COMMANDS`),
        ``set_failed`` a list of the two OPT9221 failure flags, ``vanish_after_frames``,
        ``hang_at_frame`` and ``hang_at_read`` a non-negative int or null, ``hang_file`` a
        path or null, ``hang_s`` a non-negative number of seconds, ``no_seq_echo`` a bool.

        Raises:
            ValueError: not a dict, an unknown field, or a field's value of the wrong type or
                out of range (the message names the field).
        """
        if not isinstance(d, dict):
            raise ValueError(f"Faults: expected a JSON object of faults, got {d!r}")
        return cls(**cls._checked(d))

    def __post_init__(self) -> None:
        # the constructor checks what from_dict checks: a bad plan was accepted and injected
        # nothing, or failed much later as a fake USB error
        for k, v in self._checked({k: getattr(self, k)
                                   for k in self.__dataclass_fields__}).items():
            setattr(self, k, v)

    @classmethod
    def _checked(cls, d: dict) -> dict:
        """The fields of ``d`` checked and normalised (sets of ints); a ValueError naming the
        field otherwise."""
        kw = {}
        for k, v in d.items():
            if k in cls._ORDINALS:
                kw[k] = _ordinals(repr(k), v, "frame" if k != "ctrl_fail" else "control-transfer")
            elif k in cls._COMMANDS:
                if not isinstance(v, dict):
                    raise ValueError(f"Faults: expected {k!r} an object {{command: [occurrence, "
                                     f"...]}}, got {v!r}")
                for c in v:
                    if c not in dlp.COMMANDS:
                        raise ValueError(f"Faults: unknown command {c!r} in {k!r}; expected one "
                                         f"of {sorted(dlp.COMMANDS)}")
                kw[k] = {c: _ordinals(f"{k!r} (command {c!r})", o, "occurrence")
                         for c, o in v.items()}
            elif k == "set_failed":
                flags = FakeOPT8241._READ_ONLY
                if not isinstance(v, (list, tuple, set, frozenset)) or any(
                        f not in flags for f in v):
                    raise ValueError(f"Faults: expected 'set_failed' a list of {flags}, "
                                     f"got {v!r}")
                kw[k] = set(v)
            elif k in cls._ORDINAL:
                if v is not None and not _is_ordinal(v):
                    raise ValueError(f"Faults: expected {k!r} a non-negative int (a frame "
                                     f"count) or null, got {v!r}")
                kw[k] = None if v is None else int(v)
            elif k == "hang_file":
                if v is not None and not isinstance(v, (str, os.PathLike)):
                    raise ValueError(f"Faults: expected 'hang_file' a path (a string) or null, "
                                     f"got {v!r}")
                kw[k] = None if v is None else os.fspath(v)
            elif k == "hang_s":
                if isinstance(v, bool) or not isinstance(v, (int, float)) or \
                        not (math.isfinite(v) and v >= 0):
                    raise ValueError(f"Faults: expected 'hang_s' a non-negative number of "
                                     f"seconds, got {v!r}")
                kw[k] = float(v)
            elif k == "no_seq_echo":
                if not isinstance(v, bool):
                    raise ValueError(f"Faults: expected 'no_seq_echo' true or false, got {v!r}")
                kw[k] = v
            else:
                raise ValueError(f"Faults: unknown fault {k!r}; expected one of "
                                 f"{sorted(cls.__dataclass_fields__)}")
        return kw


def _is_ordinal(v) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v >= 0


def _ordinals(name: str, v, what: str) -> set[int]:
    """``v`` (a list of non-negative ints) as a set; a ValueError naming ``name`` (quoted)
    otherwise."""
    items = None if isinstance(v, (str, bytes, dict)) or not hasattr(v, "__iter__") else list(v)
    if items is None or not all(_is_ordinal(o) for o in items):
        raise ValueError(f"Faults: expected {name} a list of {what} ordinals (non-negative "
                         f"ints), got {v!r}")
    return {int(o) for o in items}


def rules_from_config(cfg: ExperimentConfig) -> CameraRules:
    """The camera rules of the simulated set-up, with the threshold in ADC numbers (as
    :func:`~torchtof.experiment.simulate_frames` applies them)."""
    g = cfg.gain() if cfg.adc_bits is not None else 1.0
    return CameraRules(min_m=cfg.min_m, max_m=cfg.max_m, step_m=cfg.step_m,
                       amp_threshold=cfg.amp_threshold_e / g, no_photon_m=cfg.max_m)


class _Gone:
    """Mixin: once ``bench.vanished`` every USB call fails with ENODEV, as pyusb does."""

    bench: SimulatedBench

    def _alive(self) -> None:
        if self.bench.vanished:
            raise _usb_error("No such device (it may have been disconnected)", 19)


class FakeLightCrafter(_Gone):
    """A DLPC350 that speaks the HID report protocol (module docstring)."""

    def __init__(self, bench: SimulatedBench) -> None:
        self.bench = bench
        self._asm = dlp.Assembler()
        self._replies: deque[bytes] = deque()
        self._late: list[bytes] = []
        self._mode_at = 0.0  # simulated time the last display-mode switch completes
        self._prev_mode = False
        self.counts: dict[str, int] = {}
        self.log: list[dlp.Message] = []
        self.video_frame: np.ndarray | None = None
        self.flash: dict[int, np.ndarray] = {}
        self.state = {"standby": False, "pattern_mode": False, "source": None, "config": None,
                      "trigger": None, "exposure_us": None, "period_us": None, "running": False,
                      "mbox": 0, "mbox_addr": 0, "validated": False,
                      # TRIG_OUT1_CTL as written (invert, rising, falling); None: never written
                      "trig_out1": None,
                      # SOURCE_SEL: parallel port, 24 bits (source 0 | width 1 << 3)
                      "source_sel": 0x08}
        #: what VID_SIG_STAT reports (dlpc350.decode_video_status fields): a locked 912 x 1140
        #: input at the bench's video rate; the units of the clock and frequency words are
        #: simulator choices (v_freq in 0.01 Hz, h_freq in 10 Hz, pix_clock in Hz)
        rows, cols = dlp.DMD_SHAPE
        tot_pix, tot_lines = cols + 160, rows + 45
        self.video_signal = {
            "status": dlp.SOURCE_LOCKED, "h_res": cols, "v_res": rows, "hsync_pol": 1,
            "vsync_pol": 1, "pix_clock": round(tot_pix * tot_lines * bench.video_hz),
            "h_freq": round(tot_lines * bench.video_hz / 10),
            "v_freq": round(bench.video_hz * 100), "total_pixels_per_line": tot_pix,
            "total_lines_per_frame": tot_lines, "active_pixels_per_line": cols,
            "active_lines_per_frame": rows, "first_active_pixel": 0, "first_active_line": 0}
        self.pattern_lut: list[int] = []
        self.image_lut: list[int] = []
        self.lut_status = 0
        self._busy_reads = 0
        self.shown: list[np.ndarray] = []  # every pattern displayed (for tests)
        self._next = 0  # next LUT entry for external triggers

    # -- pyusb surface -----------------------------------------------------------------------
    def write(self, endpoint: int, data, timeout: int | None = None) -> int:
        self._alive()
        if endpoint != dlp.EP_OUT:
            raise _usb_error(f"invalid endpoint 0x{endpoint:02x}", 22)
        data = bytes(data)
        try:
            msg = self._asm.feed(data)
        except dlp.ProtocolError:
            self._replies.append(struct.pack("<BBH", dlp.FLAG_NACK | dlp.FLAG_REPLY, 0, 0)
                                 .ljust(dlp.REPORT_SIZE, b"\x00"))
            return len(data)
        if msg is not None:
            self._handle(msg)
        return len(data)

    def read(self, endpoint: int, size: int, timeout: int | None = None):
        self._alive()
        if endpoint != dlp.EP_IN:
            raise _usb_error(f"invalid endpoint 0x{endpoint:02x}", 22)
        if self._late:  # a reply that comes too late: this read times out, the next gets it
            self._replies.extendleft(reversed(self._late))
            self._late.clear()
            raise _usb_timeout()
        if not self._replies:
            raise _usb_timeout()
        reply = self._replies.popleft()
        if self.bench.faults.no_seq_echo:
            reply = reply[:1] + b"\x00" + reply[2:]
        return bytearray(reply[:size])

    # -- protocol ----------------------------------------------------------------------------
    def _handle(self, msg: dlp.Message) -> None:
        self.log.append(msg)
        name = msg.command
        occ = self.counts.get(name, 0)
        self.counts[name] = occ + 1
        if occ in self.bench.faults.reply_timeout.get(name, ()):
            return
        if occ in self.bench.faults.late_reply.get(name, ()):
            n = len(self._replies)
            self._handle_now(msg, name)
            self._late.extend(self._replies.pop() for _ in range(len(self._replies) - n))
            return
        self._handle_now(msg, name)

    def _handle_now(self, msg: dlp.Message, name: str) -> None:
        occ = self.counts[name] - 1
        if occ in self.bench.faults.nack.get(name, ()) or name not in dlp.COMMANDS:
            self._replies.append(dlp.encode_reply(msg, nack=True))
            return
        size = dlp.COMMANDS[name][2]
        if msg.read:
            data = self._read(name) if not msg.payload else None
            if data is not None and occ in self.bench.faults.empty_reply.get(name, ()):
                data = b""  # an answer without data (length 0)
            self._replies.append(dlp.encode_reply(msg, data or b"", nack=data is None))
            return
        ok = (size is None and len(msg.payload) > 0) or len(msg.payload) == size
        ok = ok and self._apply(name, msg.payload)
        if msg.reply_wanted or not ok:
            self._replies.append(dlp.encode_reply(msg, nack=not ok))

    def _read(self, name: str) -> bytes | None:
        if name == "LUT_VALID":
            if self._busy_reads:
                self._busy_reads -= 1
                return bytes([0x80])
            return bytes([self.lut_status])
        if name == "STATUS_HW":
            return b"\x01"  # initialisation done, no error
        if name == "STATUS_SYS":
            return b"\x01"  # internal memory test passed
        if name == "STATUS_MAIN":
            return bytes([0x01 | (0x02 if self.state["running"] else 0)])  # DMD parked? running
        if name == "DISP_MODE":  # the old mode until the switch completes
            switched = self.bench.now() >= self._mode_at
            return bytes([int(self.state["pattern_mode"] if switched else self._prev_mode)])
        if name == "GET_VERSION":
            return struct.pack("<IIII", 0x03000000, 0x00010000, 0, 0)
        if name == "SOURCE_SEL":
            return bytes([self.state["source_sel"]])
        if name == "VID_SIG_STAT":
            return dlp.encode_video_status(**self.video_signal)
        if name == "TRIG_OUT1_CTL":  # DLPC350_GetTrigOutConfig: invert, rising, falling
            return bytes(self.state["trig_out1"] or (0, dlp.TRIG_OUT_ZERO_DELAY,
                                                     dlp.TRIG_OUT_ZERO_DELAY))
        return None

    def _apply(self, name: str, p: bytes) -> bool:
        s = self.state
        if name == "POWER_CONTROL":
            if p[0] > 2:
                return False
            s["standby"] = p[0] == 1
        elif name == "DISP_MODE":
            if p[0] > 1:
                return False
            self._prev_mode = s["pattern_mode"]
            if s["pattern_mode"] != (p[0] == 1):
                self._mode_at = self.bench.now() + self.bench.mode_latency_s
                if not self.bench.realtime:
                    self.bench.sim_time = self._mode_at
            s["pattern_mode"] = p[0] == 1
        elif name == "PAT_DISP_MODE":
            if p[0] not in (0, 3):
                return False
            s["source"] = {0: "video", 3: "flash"}[p[0]]
        elif name == "PAT_TRIG_MODE":
            if p[0] > 4:
                return False
            s["trigger"] = p[0]
        elif name == "PAT_EXPO_PRD":
            s["exposure_us"], s["period_us"] = struct.unpack("<II", p)
        elif name == "TRIG_OUT1_CTL":  # DLPC350_SetTrigOutConfig: invert 0/1, delays <= 0xD5
            if p[0] > 1 or max(p[1], p[2]) > dlp.TRIG_OUT_MAX_DELAY:
                return False
            s["trig_out1"] = tuple(p)
            s["validated"] = False  # TI: validate again after it
        elif name == "SOURCE_SEL":  # DLPC350_SetInputSource: source 0-3, width 0-5
            if p[0] & 0x07 > 3 or p[0] >> 3 > 5:
                return False
            s["source_sel"] = p[0]
        elif name == "VID_SIG_STAT":  # a status: read only
            return False
        elif name == "PAT_CONFIG":
            s["config"] = tuple(p)
        elif name == "MBOX_CONTROL":
            if p[0] > 3:
                return False
            s["mbox"], s["mbox_addr"] = p[0], 0
            if p[0] == 2:
                self.pattern_lut = []
            elif p[0] == 1:
                self.image_lut = []
            s["validated"] = False
        elif name == "MBOX_ADDRESS":
            if p[0] > 127:
                return False
            s["mbox_addr"] = p[0]
        elif name == "MBOX_DATA":
            if s["mbox"] == 2:
                if len(p) % 3:
                    return False
                self.pattern_lut += [int.from_bytes(p[i : i + 3], "little")
                                     for i in range(0, len(p), 3)]
            elif s["mbox"] == 1:
                idx = list(p)
                self.image_lut += idx[::-1] if len(idx) == 2 else idx
            else:
                return False  # mailbox closed
        elif name == "LUT_VALID":
            self.lut_status = self._validate()
            # bits 0-1 are errors, 2-4 warnings (TI's DLPC350_StartPatLutValidate); written
            # here from TI's table, not from the driver's constant, so that a test can tell
            s["validated"] = not self.lut_status & 0x03
            self._busy_reads = 1  # the first poll reads busy
        elif name == "PAT_START_STOP":
            if p[0] > 2:
                return False
            if p[0] == 2:
                if not (s["validated"] and s["pattern_mode"]):
                    return False
                s["running"] = True
                self._next = 0
                if (s["trigger"] == 1 and self._internal()) or s["trigger"] == 0:
                    self._play_all()
            else:
                s["running"] = False
                self.bench.camera_usb.cancel_triggers_after(self.bench.now())
        return True

    def _internal(self) -> bool:
        trig = {dlp.unpack_lut_entry(e)["trig"] for e in self.pattern_lut}
        return trig <= {0, 3}

    def _validate(self) -> int:
        s, status = self.state, 0
        e, per = s["exposure_us"], s["period_us"]
        if e is None or per is None or not (e == per or e <= per - dlp.MIN_DARK_US):
            status |= 0x01 | (0x10 if e is not None and per is not None and e < per else 0)
        cfg = s["config"]
        entries = [dlp.unpack_lut_entry(v) for v in self.pattern_lut]
        if s["trigger"] == 0 and per is not None:  # exposures within one input frame
            runs, k = [], 0
            for x in entries:
                k = 1 if x["trig"] != 3 else k + 1
                runs.append(k)
            if runs and max(runs) * per > 1e6 / self.bench.video_hz:
                status |= 0x01
        if (cfg is None or not entries or cfg[0] + 1 != len(entries)
                or any(x["pattern"] > 23 or x["bit_depth"] != 1 for x in entries)):
            status |= 0x02
        if s["source"] == "video" and self.video_frame is None:
            status |= 0x02
        if s["source"] == "flash" and any(i not in self.flash for i in self.image_lut):
            status |= 0x02
        return status

    def _pattern(self, k: int) -> np.ndarray:
        entries = [dlp.unpack_lut_entry(v) for v in self.pattern_lut]
        e = entries[k]
        if self.state["source"] == "video":
            frame = self.video_frame
        else:
            img = sum(x["buffer_swap"] for x in entries[1 : k + 1])
            frame = self.flash[self.image_lut[img]]
        plane = dlp.unpack_bitplane(frame, e["pattern"])
        return 1 - plane if e["invert"] else plane

    def _times(self) -> list[float]:
        """Start time (simulated s) of each LUT entry: every ``period`` on the internal
        trigger; in VSYNC mode an entry with trigger type 1 waits for the next VSYNC of the
        ``video_hz`` source and one with type 3 follows its predecessor (pyCrafter4500
        ``pattern_mode``)."""
        per = (self.state["period_us"] or 0) * 1e-6
        t0 = self.bench.now()
        entries = [dlp.unpack_lut_entry(v) for v in self.pattern_lut]
        if self.state["trigger"] != 0:
            return [t0 + k * per for k in range(len(entries))]
        frame = 1.0 / self.bench.video_hz
        times, t, vsync = [], t0, math.ceil(t0 / frame - 1e-9) * frame
        for e in entries:
            if e["trig"] != 3:
                vsync = max(vsync, math.ceil(t / frame - 1e-9) * frame)
                t = vsync
                vsync += frame
            times.append(t)
            t += per
        return times

    def _play_all(self) -> None:
        times = self._times()
        for k, t in enumerate(times):
            self._show(k, t)
        if not self.bench.realtime and times:
            per = (self.state["period_us"] or 0) * 1e-6
            self.bench.sim_time = times[-1] + per
        self.state["running"] = False

    def _show(self, k: int, t: float | None = None) -> None:
        pat = self._pattern(k)
        self.shown.append(pat)
        self.bench.camera_usb.trigger(pat, t)

    def trigger_in(self, t: float | None = None) -> None:
        """A TRIG_IN edge at simulated time ``t`` (external trigger mode): show the next
        pattern."""
        if self.state["running"] and self._next < len(self.pattern_lut):
            t = self.bench.now() if t is None else float(t)
            self._show(self._next, t)
            self._next += 1
            if not self.bench.realtime:
                self.bench.sim_time = t + (self.state["period_us"] or 0) * 1e-6


#: What the fake camera puts in the 12-byte frame header / trailer when they are enabled.
HEADER_BYTES = bytes(range(12))
TRAILER_BYTES = b"\xa5" * 12


class FakeOPT8241(_Gone):
    """An OPT8241-CDK-EVM: 24-bit OPT9221 registers (and the 1/2-byte board slaves) behind
    the vendor control transfers, frames on bulk IN in the format its registers select
    (``output_mode``, ``pixel_data_size``, ``op_data_arrange_mode``, ``quad_cnt_max``,
    :mod:`.opt8241`): raw bytes; byte 0 the frame number when ``debug_frame_number_en`` is set
    (module docstring); 12 more bytes before or after the frame while ``frm_header_en`` or
    ``frm_trailer_en`` is set; ``bin_col_count`` × ``bin_row_count`` read the frame size
    (``roi_px`` × ``roi_px + 1``). Registers start at the OPT9221.dml
    defaults (frame time 100000 · 4 · 4 / 48 MHz = 33.3 ms) with PLL 1 set for the
    configuration's modulation frequency and ``tillum_slv_addr`` = 0x72 when the bench says
    TI's SDK initialised the board.

    Like a device it: rejects (stalls) writes of values the register map calls invalid
    (``quad_cnt_max`` ∉ {4, 6}, ``sub_frame_cnt_max`` ∉ {1, 2, 4, 8}, ``pixel_data_size`` ∉
    {2, 4}) and keeps its read-only flags; sets ``pix_cnt_max_set_failed`` below
    ``pix_cnt_max`` 50000 and ``intg_duty_cycle_set_failed`` above duty cycle 20 (simulator
    choices: the board's limits, TintinCDKCamera.cpp); keeps ``op_overflow`` (OPT9221.dml id
    6378, set by :attr:`Faults.op_overflow`) until a 0 is written to it ("Write a '0' to reset
    the state"; a written 1 leaves it as it was: a simulator choice); takes one frame time per
    frame and ignores a trigger that comes while a frame is still being taken (a missed trigger: no
    frame, no number); reads out the region the ROI registers select once they are written
    (:meth:`crop`); and, with ``bench.realtime``, delivers each frame only once its frame
    time has passed on the wall clock and holds at most ``bench.fifo_frames`` undelivered
    frames (a full FIFO drops the newest frame after numbering it: a frame-id gap).

    It also models what TI's profile may leave and :meth:`.OPT8241.configure` now clears: an
    active ``phase_corr_1`` shifts the depth modes' phase (:meth:`phase_correction`),
    ``hdr_scale`` divides the taps of every other frame by ``2^hdr_scale``, ``padding_en``
    pads each transfer with zeros to a multiple of ``blk_size`` (1024, the DML default); with
    ``bench.sdk_initialised`` PLL 2 and ``sscg_en`` start as TI's default profile leaves them.
    Every register write is logged in :attr:`writes`.
    """

    _VALID = {"quad_cnt_max": (4, 6), "sub_frame_cnt_max": (1, 2, 4, 8),
              "pixel_data_size": (2, 4)}
    _READ_ONLY = ("pix_cnt_max_set_failed", "intg_duty_cycle_set_failed")
    _ROI_ADDRESSES = {opt.REGISTERS[k].address for k in ("row_start", "col_start", "col_end")}
    #: ``blk_size`` (OPT9221.dml id 6133, bank 3 reg 60 bits 4-23, default 1024: "Each frame is
    #: sent to the host in blocks of this size in terms of the number of output clock cycles"),
    #: the packet size ``padding_en`` pads to; torchtof neither reads nor writes it
    BLK_SIZE = opt.Field(0x5C3C, 4, 23)

    def __init__(self, bench: SimulatedBench) -> None:
        self.bench = bench
        self.regs: dict[int, int] = {}
        defaults = {"mod_n1": 2, "mod_ps1": 1, "mod_m1": 16, "quad_cnt_max": 4,
                    "sub_frame_cnt_max": 4, "pix_cnt_max": 100000, "intg_duty_cycle": 6,
                    "op_data_arrange_mode": 2, "pixel_data_size": 4, "tg_dis": 1,
                    "delay_fb_coeff_1": 2048, "op_clk_freq": 0,
                    "tillum_slv_addr": 0x72 if bench.sdk_initialised else 0x71}
        defaults.update(opt.pll_settings(bench.config.freq_hz, 4))
        if bench.sdk_initialised:  # what TI's default profile (Long Range, id 130) leaves:
            # PLL 2 at vco 360 MHz with mod_ps2 = 0 (60 MHz at its quad_cnt_max 6) for
            # de-aliasing (TintinUnambiguousRangeParameter::set), sscg_en = true (its .conf)
            defaults.update(mod_m2=15, mod_m_frac2=0, mod_n2=2, mod_ps2=0, sscg_en=1)
        else:  # OPT9221.dml defaults of PLL 2 (48 MHz at quad_cnt_max 4)
            defaults.update(mod_m2=16, mod_m_frac2=0, mod_n2=2, mod_ps2=1)
        for name, value in defaults.items():
            self._set(name, value)
        self.regs[self.BLK_SIZE.address] = self.BLK_SIZE.put(
            self.regs.get(self.BLK_SIZE.address, 0), 1024)
        #: every register write as ``(address, 24-bit value)``, oldest first (for tests)
        self.writes: list[tuple[int, int]] = []
        #: (rows, columns) of the simulated sensor: the guard row and the ROI of the render
        self.sensor = (bench.config.roi_px + 1, bench.config.roi_px)
        self.select_whole_sensor()
        self._fifo: deque[tuple[int, bytes]] = deque()
        # (ready time, pattern, trigger time) of frames being taken
        self._pending: deque[tuple[float, np.ndarray, float]] = deque()
        self._lock = threading.RLock()
        self._cond = threading.Condition(self._lock)
        self.rendered = 0
        self.delivered = 0
        self.missed_triggers = 0
        self.fifo_dropped = 0
        self.ctrl_count = 0
        self.busy_until = -1.0
        self.time_s = 0.0  # host arrival time of the last delivered frame (simulated clock)
        self.frame_number = int(bench.frame_number_start)  # OPT9221 output frame counter
        self.roi_set = False  # read whole until the ROI registers are written

    def select_whole_sensor(self) -> None:
        """Registers for the whole :attr:`sensor`: the frame size (``bin_col_count`` ×
        ``bin_row_count``) and, where the fields can say so, the region (OPT9221.dml's defaults
        select the whole 320 × 240 one: ``row_end`` 239, ``col_end`` 19, columns in blocks of
        16); a larger simulated sensor is read whole until a region is written (:meth:`crop`).
        Not a control transfer: the state at power-up."""
        rows, cols = self.sensor
        for name, value in (("bin_col_count", cols), ("bin_row_count", rows), ("row_start", 0),
                            ("row_end", min(rows - 1, 255)), ("col_start", 0),
                            ("col_end", min(-(-cols // 16) - 1, 31))):
            self._set(name, value)

    def _set(self, name: str, value: int) -> None:
        f = opt.REGISTERS[name]
        self.regs[f.address] = f.put(self.regs.get(f.address, 0), value)

    def field(self, name: str) -> int:
        f = opt.REGISTERS[name]
        return f.get(self.regs.get(f.address, 0))

    @property
    def frame_time_s(self) -> float:
        """``pix_cnt_max · quad_cnt_max · sub_frame_cnt_max / 48 MHz``."""
        return (self.field("pix_cnt_max") * self.field("quad_cnt_max")
                * self.field("sub_frame_cnt_max")) / (opt.SYSCLK_MHZ * 1e6)

    def ctrl_transfer(self, bmRequestType: int, bRequest: int, wValue: int = 0, wIndex: int = 0,
                      data_or_wLength=None, timeout: int | None = None):
        self._alive()
        stall = _usb_error("Pipe error (request stalled)", 32)
        ordinal, self.ctrl_count = self.ctrl_count, self.ctrl_count + 1
        if ordinal in self.bench.faults.ctrl_fail:
            raise stall
        for slave, (rd, wr, shift, _) in opt.SLAVES.items():
            if wValue == slave << shift and bRequest in (rd, wr):
                break
        else:
            raise stall
        nbytes = opt.SLAVES[slave][3]
        write = bmRequestType == opt.VENDOR_OUT
        if bRequest != (wr if write else rd) or bmRequestType not in (opt.VENDOR_OUT,
                                                                        opt.VENDOR_IN):
            raise stall
        address = slave << 8 | (wIndex >> shift)
        if write:
            data = bytes(data_or_wLength)
            if len(data) != nbytes:
                raise stall
            value = int.from_bytes(data, "little")
            for name, valid in self._VALID.items():
                f = opt.REGISTERS[name]
                if f.address == address and f.get(value) not in valid:
                    raise stall  # a value the register map calls invalid
            if self._beyond_sensor(address, value):
                raise stall  # a region beyond this simulated sensor
            old = self.regs.get(address, 0)
            for name in self._READ_ONLY:
                f = opt.REGISTERS[name]
                if f.address == address:
                    value = f.put(value, f.get(old))
            f = opt.REGISTERS["op_overflow"]
            if f.address == address:  # only a written 0 resets it (OPT9221.dml id 6378)
                value = f.put(value, f.get(old) & f.get(value))
            self.regs[address] = value
            self.writes.append((address, value))
            if address in self._ROI_ADDRESSES:
                self.roi_set = True
            self._update_flags()
            with self._cond:  # a read waiting on a camera just halted returns (read())
                self._cond.notify_all()
            return len(data)
        if int(data_or_wLength) != nbytes:
            raise stall
        return bytearray(self.regs.get(address, 0).to_bytes(nbytes, "little"))

    def _update_flags(self) -> None:
        forced = self.bench.faults.set_failed
        self._set("pix_cnt_max_set_failed", int(self.field("pix_cnt_max") < 50_000
                                                 or "pix_cnt_max_set_failed" in forced))
        self._set("intg_duty_cycle_set_failed", int(self.field("intg_duty_cycle") > 20
                                                     or "intg_duty_cycle_set_failed" in forced))

    def clear_halt(self, endpoint: int) -> None:
        self._alive()
        if endpoint != opt.EP_FRAMES:
            raise _usb_error(f"invalid endpoint 0x{endpoint:02x}", 22)

    @property
    def mode(self) -> str:
        if self.field("output_mode") == 15:
            return "quad"
        key = (self.field("output_mode"), self.field("pixel_data_size"),
               self.field("op_data_arrange_mode"))
        for name, value in opt.FRAME_MODES.items():
            if value == key:
                return name
        raise ValueError(f"FakeOPT8241: unsupported output format {key}")

    def read(self, endpoint: int, size: int, timeout: int | None = None):
        self._alive()
        if endpoint != opt.EP_FRAMES:
            raise _usb_error(f"invalid endpoint 0x{endpoint:02x}", 22)
        deadline = time.monotonic() + (timeout or 1000) / 1000
        with self._cond:
            while True:
                self._complete(self.bench.now() if self.bench.realtime else math.inf)
                if self._fifo:
                    break
                left = deadline - time.monotonic()
                if left <= 0:
                    raise _usb_timeout()
                if self._halted():  # nothing can come: the timeout passes in simulated time
                    self._cond.wait(min(left, 0.002))  # (a short wall wait: no busy loop)
                    raise _usb_timeout()
                if self._pending and self.bench.realtime:
                    left = min(left, max(0.0, (self._pending[0][0] - self.bench.now())
                                         / self.bench.speed))
                self._cond.wait(left)
        f = self.bench.faults
        if f.vanish_after_frames is not None and self.delivered >= f.vanish_after_frames:
            self.bench.vanished = True
            self._alive()
        if f.hang_at_read is not None and self.delivered == f.hang_at_read:
            if f.hang_file:
                Path(f.hang_file).write_text(str(self.delivered))
            time.sleep(f.hang_s)
        with self._lock:
            ordinal, packet, stamp = self._fifo.popleft()
        if ordinal in f.stall:
            f.stall.discard(ordinal)
            raise _usb_error("Pipe error (endpoint stalled)", 32)
        if len(packet) > size:
            raise _usb_error("Overflow", 75)
        self.delivered += 1
        self.time_s = stamp
        return bytearray(packet)

    def phase_correction(self) -> int:
        """The phase the depth engine subtracts (12-bit units; :func:`.opt8241.encode_frame`):
        ``phase_corr_1`` (signed 12 bits, OPT9221.dml id 2091) unless ``disable_offset_corr``
        (id 2098: "Disables phase calibration completely"). The temperature, cross-talk and
        non-linearity corrections are not simulated (no temperatures, no optics)."""
        if self.field("disable_offset_corr"):
            return 0
        v = self.field("phase_corr_1")
        return v - 4096 if v & 0x800 else v

    def _halted(self) -> bool:
        """Streaming halted (``tg_dis``) with nothing queued or being taken, on the instant
        bench: no frame can arrive before the next register write."""
        return (not self.bench.realtime and bool(self.field("tg_dis")) and not self._fifo
                and not self._pending)

    @property
    def freq_hz(self) -> float:
        return opt.pll_frequency_hz(*(self.field(k) for k in (
            "mod_m1", "mod_m_frac1", "mod_n1", "mod_ps1", "quad_cnt_max")))

    def trigger(self, pattern: np.ndarray, t: float | None = None) -> None:
        """A trigger from the DMD's TRIG_OUT1 at simulated time ``t`` (s): start a frame if
        streaming and no frame is being taken; it is ready one frame time later."""
        if self.field("tg_dis"):
            return
        t = self.bench.now() if t is None else float(t)
        with self._lock:
            if t < self.busy_until - 1e-9:
                self.missed_triggers += 1
                return
            self.busy_until = t + self.frame_time_s
            self._pending.append((self.busy_until, pattern, t))
            if not self.bench.realtime:
                self._complete(math.inf)
            self._cond.notify_all()

    def _complete(self, now: float) -> None:
        while self._pending and self._pending[0][0] <= now:
            ready, pattern, _ = self._pending.popleft()
            self._output(pattern, ready)

    def cancel_triggers_after(self, t: float) -> None:
        """The DMD stopped at ``t``: triggers scheduled after it never come."""
        with self._lock:
            self._pending = deque(e for e in self._pending if e[2] <= t)
            if self._pending:
                self.busy_until = self._pending[-1][0]

    def _output(self, pattern: np.ndarray, ready: float) -> None:
        f = self.bench.faults
        ordinal = self.rendered
        self.rendered += 1
        if ordinal in f.frame_timeout:  # a missed trigger: no frame, no number
            self.missed_triggers += 1
            return
        if ordinal in f.op_overflow:  # the output fell behind (OPT9221.dml id 6378)
            self._set("op_overflow", 1)
        if f.hang_at_frame is not None and ordinal == f.hang_at_frame:
            if f.hang_file:
                Path(f.hang_file).write_text(str(ordinal))
            time.sleep(f.hang_s)
        frame = self.bench.render(pattern, self.freq_hz)
        taps = frame.taps[0].numpy()
        taps = self.crop(np.concatenate([np.zeros_like(taps[:, :1]), taps], axis=1))  # guard row 0
        hdr = self.field("hdr_scale")
        if hdr and self.frame_number % 2:  # OPT9221.dml id 6377: alternate frames integrate
            taps = np.floor(taps / (1 << hdr))  # >> hdr_scale (which ones: a simulator choice)
        # ambient / flags nibbles: simulator choices (TI does not document their meaning)
        sat = (taps >= 2 ** (self.bench.config.adc_bits or 12) - 1).any(axis=0)
        ambient = np.clip(0.5 * (taps[0] + taps[1]) / 256, 0, 15).astype(np.uint32)
        packet = opt.encode_frame(self.mode, taps.astype(np.int64), ambient=ambient,
                                  flags=sat.astype(np.uint32), quads=self.field("quad_cnt_max"),
                                  phase_corr=self.phase_correction())
        packet = self._numbered(packet)
        # the 12-byte frame header and debug trailer (OPT9221.dml ids 6145, 6360; contents
        # here: a simulator choice) when a register left them on
        packet = (HEADER_BYTES * self.field("frm_header_en") + packet
                  + TRAILER_BYTES * self.field("frm_trailer_en"))
        blk = self.BLK_SIZE.get(self.regs.get(self.BLK_SIZE.address, 0))
        if self.field("padding_en") and blk and len(packet) % blk:  # OPT9221.dml id 6146
            packet += bytes(blk - len(packet) % blk)
        cap = self.bench.fifo_frames if self.bench.realtime else None
        if cap is not None and len(self._fifo) >= cap:
            self.fifo_dropped += 1  # numbered, then lost: a frame-id gap
            return
        if ordinal in f.drop:
            return
        if ordinal in f.corrupt:
            self._fifo.append((ordinal, packet[:-2], ready))
        elif ordinal in f.split:
            half = len(packet) // 2
            self._fifo.append((ordinal, packet[:half], ready))
            self._fifo.append((ordinal, packet[half:], ready))
        else:
            self._fifo.append((ordinal, packet, ready))
        if ordinal in f.duplicate:
            self._fifo.append((ordinal, packet, ready))
        if ordinal in f.extra:
            spurious = np.frombuffer(packet, "<u2")[::-1].tobytes()
            self._fifo.append((ordinal, self._numbered(spurious), ready))

    def _beyond_sensor(self, address: int, value: int) -> bool:
        """A ``row_end`` / ``col_end`` write selecting rows or 16-column blocks beyond this
        simulated sensor (:attr:`sensor`; its columns rounded up to 16), or bin counts (the
        frame size) larger than it."""
        rows, cols = self.sensor
        limits = (("row_end", lambda v: v >= rows),
                  ("col_end", lambda v: 16 * (v + 1) > -(-cols // 16) * 16),
                  ("bin_row_count", lambda v: v > rows), ("bin_col_count", lambda v: v > cols))
        return any(opt.REGISTERS[k].address == address and beyond(opt.REGISTERS[k].get(value))
                   for k, beyond in limits)

    def crop(self, taps: np.ndarray) -> np.ndarray:
        """The region of the sensor the ROI registers select (``row_start`` … ``row_end``,
        columns ``16·col_start`` … ``16·(col_end + 1) − 1``); the whole simulated sensor
        (``roi_px + 1`` × ``roi_px``) until they are written (their defaults select it too,
        where its size fits the fields)."""
        if not self.roi_set:
            return taps
        r0, r1 = self.field("row_start"), self.field("row_end")
        c0, c1 = 16 * self.field("col_start"), 16 * (self.field("col_end") + 1)
        return taps[..., r0 : r1 + 1, c0:c1]

    def _numbered(self, packet: bytes) -> bytes:
        """One more frame out of the OPT9221: its number in byte 0 if enabled (OPT9221.dml
        ``debug_frame_number_en``)."""
        number, self.frame_number = self.frame_number, self.frame_number + 1
        if not self.field("debug_frame_number_en"):
            return packet
        return bytes([number & 0xFF]) + packet[1:]


class _SimVideo(VideoPort):
    def __init__(self, lcr: FakeLightCrafter) -> None:
        self.lcr = lcr

    def show(self, frame: np.ndarray) -> None:
        self.lcr.video_frame = np.array(frame, dtype=np.uint8, copy=True)


class SimulatedBench:
    """A LightCrafter 4500 and an OPT8241 looking at a simulated scene.

    Args:
        config: the simulated set-up (:class:`~torchtof.experiment.ExperimentConfig`); the
            camera frame is ``roi_px × roi_px``, the DMD pattern ``n × n``.
        seed: noise seed. Each frame's noise comes from its own generator, seeded from
            ``seed`` and the displayed pattern's bits (in a DMD-split Hadamard run every
            pattern is different, so this is the frame index), so a re-acquired or resumed
            frame gets the noise the uninterrupted run gave it.
        faults: faults to inject (:class:`Faults`).
        frame_number_start: the camera's frame counter at power-up (its real start value is
            not documented; tests move it to exercise the 8-bit wrap).
        realtime: frames take their frame time on the wall clock (scaled by ``speed``) and
            the camera's FIFO holds at most ``fifo_frames``; otherwise every frame is ready
            at once (fast tests) while frame times and missed triggers still follow the
            simulated clock, and a bulk read of a halted camera (``tg_dis``) times out at
            once instead of after its timeout.
        speed: how much faster than real time the realtime bench runs.
        fifo_frames: undelivered frames the camera holds (realtime only; a simulator choice).
        sdk_initialised: whether TI's SDK initialised the camera since power-up
            (``tillum_slv_addr`` reads 0x72, else 0x71).
        video_hz: video frame rate of the simulated video source (VSYNC trigger mode).
        mode_latency_s: simulated time the DLPC350 takes to switch display mode (a read of
            ``DISP_MODE`` shows the old mode until then).

    Example:
        >>> bench = SimulatedBench(ExperimentConfig(n=8, roi_px=8, srs=(0.25,)))
        >>> lcr, cam = bench.lightcrafter(), bench.camera()
        >>> lcr.status()["hw"]
        1
    """

    def __init__(self, config: ExperimentConfig | None = None, seed: int = 0,
                 faults: Faults | None = None, frame_number_start: int = 0,
                 realtime: bool = False, speed: float = 1.0, fifo_frames: int = 4,
                 sdk_initialised: bool = True, video_hz: float = 60.0,
                 mode_latency_s: float = 0.0) -> None:
        if config is not None and not isinstance(config, ExperimentConfig):
            raise TypeError(f"SimulatedBench: expected config an ExperimentConfig, got "
                            f"{type(config).__name__}")
        if not isinstance(faults, (Faults, type(None))):
            raise TypeError(f"SimulatedBench: expected faults a Faults (Faults.from_dict for "
                            f"a JSON plan), got {type(faults).__name__}")
        for name, v, lo in (("video_hz", video_hz, 0.0), ("mode_latency_s", mode_latency_s, None)):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
                    or (v <= lo if lo is not None else v < 0):
                raise ValueError(f"SimulatedBench: expected {name} a finite number "
                                 f"{'> 0' if lo is not None else '>= 0'}, got {v!r}")
        if isinstance(frame_number_start, bool) or not isinstance(frame_number_start,
                                                                  (int, np.integer)) \
                or frame_number_start < 0:
            raise ValueError(f"SimulatedBench: expected frame_number_start an int >= 0, got "
                             f"{frame_number_start!r}")
        cfg = (config or ExperimentConfig()).validate()
        if cfg.gain_e_per_dn is not None and not (isinstance(cfg.gain_e_per_dn, (int, float))
                                             and math.isfinite(cfg.gain_e_per_dn)
                                             and cfg.gain_e_per_dn > 0):
            raise ValueError(f"SimulatedBench: expected a positive finite gain_e_per_dn, got "
                             f"{cfg.gain_e_per_dn!r}")
        if isinstance(cfg.chunk_frames, bool) or not isinstance(cfg.chunk_frames, int) or \
                cfg.chunk_frames < 1:
            raise ValueError(f"SimulatedBench: expected chunk_frames a positive int, got "
                             f"{cfg.chunk_frames!r}")
        if cfg.adc_bits is None or cfg.adc_bits > 12:
            raise ValueError(f"SimulatedBench: the OPT8241 sends 12-bit samples: expected "
                             f"adc_bits in [1, 12], got {cfg.adc_bits}")
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
            raise TypeError(f"SimulatedBench: expected an integer seed, got {seed!r}")
        if not (isinstance(speed, (int, float)) and math.isfinite(speed) and speed > 0):
            raise ValueError(f"SimulatedBench: expected a positive speed, got {speed!r}")
        if isinstance(fifo_frames, bool) or not isinstance(fifo_frames, int) or fifo_frames < 1:
            raise ValueError(f"SimulatedBench: expected fifo_frames a positive int, got "
                             f"{fifo_frames!r}")
        self.config, self.seed = cfg, int(seed)
        self.faults = faults or Faults()
        self.frame_number_start = int(frame_number_start)
        self.realtime, self.speed, self.fifo_frames = bool(realtime), float(speed), fifo_frames
        self.sdk_initialised, self.video_hz = bool(sdk_initialised), float(video_hz)
        self.mode_latency_s = float(mode_latency_s)
        self.vanished = False
        self._t0 = time.monotonic()
        self.sim_time = 0.0  # the simulated clock when not realtime
        self.scene = get_scene(cfg.scene, cfg.n, cfg.object_m, dtype=torch.float32)
        self.dust = None
        if cfg.scattering:
            self.dust = dust_map(cfg.roi_px, cfg.dust_sigma_px,
                                 torch.Generator().manual_seed(cfg.dust_seed), dtype=torch.float32)
        self.stray = stray_light(cfg, torch.float32) if cfg.stray_e > 0 else None
        self.lightcrafter_usb = FakeLightCrafter(self)
        self.camera_usb = FakeOPT8241(self)
        self.video = _SimVideo(self.lightcrafter_usb)

    def now(self) -> float:
        """The simulated clock (s): wall time × ``speed`` when realtime, else the time the
        last simulated event set."""
        if self.realtime:
            return (time.monotonic() - self._t0) * self.speed
        return self.sim_time

    def noise_generator(self, pattern: np.ndarray) -> torch.Generator:
        """The generator of a frame showing ``pattern``: seeded from ``seed`` and the
        pattern's bits (BLAKE2b), independent of when or how often it is shown."""
        h = hashlib.blake2b(np.ascontiguousarray(pattern, dtype=np.uint8).tobytes(),
                            digest_size=8, key=self.seed.to_bytes(8, "little", signed=True))
        return torch.Generator().manual_seed(int.from_bytes(h.digest(), "little") >> 1)

    def render(self, pattern: np.ndarray, freq_hz: float):
        """One ToF frame of the scene through a 0/1 pattern ``(n, n)`` (simulate_frames)."""
        cfg = self.config
        if pattern.shape != (cfg.n, cfg.n):
            raise ValueError(f"SimulatedBench: the video frame is {pattern.shape}, the simulated "
                             f"DMD is {cfg.n}x{cfg.n}")
        if abs(freq_hz - cfg.freq_hz) > 0.5e3:
            cfg = replace(cfg, freq_hz=freq_hz)
        pats = torch.from_numpy(pattern.astype(np.float32))[None]
        return simulate_frames(self.scene, pats, cfg, self.noise_generator(pattern), self.dust,
                               self.stray)

    def lightcrafter(self, **kwargs) -> LightCrafter4500:
        """A :class:`LightCrafter4500` driver on the fake device with the simulated video port."""
        return LightCrafter4500(self.lightcrafter_usb, video=self.video, **kwargs)

    def camera(self, **kwargs) -> OPT8241:
        """An :class:`OPT8241` driver on the fake camera (``roi_px`` wide, ``roi_px + 1``
        high with the guard row 0, raw-quad mode so that the per-tap buckets exist, the
        simulated host clock, the configuration's modulation frequency)."""
        p = self.config.roi_px
        kw = {"width": p, "height": p + 1, "rules": rules_from_config(self.config), "mode": "quad",
              "clock": lambda: self.camera_usb.time_s, "mod_freq_hz": self.config.freq_hz,
              **kwargs}
        return OPT8241(self.camera_usb, **kw)
