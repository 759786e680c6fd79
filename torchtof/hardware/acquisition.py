"""Acquisition: show each DMD pattern, grab its ToF frame, form the buckets, record safely.

For each ±1 Hadamard row the DMD shows the pair ``φ⁺ = (1+h)/2``, ``φ⁻ = (1−h)/2`` (DESIGN
§2, :class:`~torchtof.operators.DMDSplit`, acquisition order ``φ⁺₁, φ⁻₁, φ⁺₂, …``). Patterns
are loaded in sequences of at most 24 (one 24-bit video frame of bit planes); the DMD paces
the sequence and its TRIG_OUT1 triggers the camera, one frame per pattern.

**Frame ids and checks** (``frame_ids``). The OPT8241's frames carry no header; two modes:

* ``"device"`` (default): the acquisition switches on the OPT9221's
  ``debug_frame_number_en`` (:mod:`.opt8241`: byte 0 of every frame is the device's 8-bit
  frame number; that sample of pixel (0, 0) is not a measurement, so the bucket ROI leaves
  row 0 out). Each frame is checked as it arrives — id = previous + 1 (mod 256): good, record
  it at once; same id and same bytes: a duplicated transfer, dropped; same id with other
  bytes, or a gap (a lost frame): re-acquire from that frame's pattern pair — and recorded
  before the next grab, so a killed run loses at most the frame in flight. The counter's
  start value is unknown, so after the camera starts and after every retry the first frame
  is an *anchor*: the first pattern pair is acquired as a sequence of its own, recorded as it
  arrives but marked provisional (``frames_ok`` 2) until its count check passes (a pair is
  re-acquired as a whole on resume anyway). As a second check every sequence ends with the
  count check: no frame may follow the last pattern within 50 ms (a spurious frame the camera
  makes itself gets the next number and is seen only here; the whole sequence is then
  re-acquired — if the run is killed in between, that sequence's frames after the spurious
  one stay recorded shifted: the one case device ids cannot make kill-safe).
* ``"count"`` (cameras or firmware without the counter): the host numbers frames as TI's SDK
  does, so a lost frame is seen only by the *count*: the frames of a sequence (≤ 24) are held
  in memory until all of them (one per pattern) have arrived and no extra frame follows within
  50 ms, and only then recorded — a killed run loses up to the sequence in flight (≤ 24
  frames). A frame byte-identical to its predecessor is dropped. Blind to a lost *and* an
  extra frame in the same sequence, and to a repeated frame that is not byte-identical.

Any fault (missing, extra or out-of-order frame, timeout, NACK, corrupt frame) re-acquires
(``retries`` times per sequence, then a clear error). Buckets per frame over the ROI ``roi``
(paper Eq. 10, §3.1, DESIGN §2): depth ``Σ d``, gated depth ``Σ gate(d)``, intensity
``Σ a`` and the four tap sums (NaN unless the camera sends raw quads).

**Recording** (zarr v3, :func:`acquire`): every frame (its ROI) and its buckets are written
as they are accepted (arrays ``frames_depth``, ``frames_amplitude``, ``frames_phase``,
``frames_taps``, ``frames_id`` (device number 0-255, or host count), ``frames_timestamp``,
``buckets_depth``, ``buckets_gated``, ``buckets_intensity``, ``buckets_taps`` — frame axis
last for buckets ``(1, C, 2M)``, first for frames, chunked per pattern sequence of ≤ 24
frames) and then marked in ``frames_ok`` (1 recorded, 2 provisional, 0 not yet). zarr's
local store replaces each chunk file atomically, so a killed run keeps every frame recorded
before the kill;
``resume=True`` continues at the first pattern pair not completely recorded. Needs zarr ≥ 3
(Python ≥ 3.11): :func:`require_zarr3`. Patterns, order, timing, ROI, frame-id mode, camera
settings and package versions are store attributes.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch

from ..bucket import PAPER_GATE_M, depth_bucket, intensity_bucket, tap_buckets
from ..operators import DMDSplit, Hadamard
from ..operators.split import combine_split
from .errors import (
    DeviceLostError,
    FrameIdError,
    FrameSequenceError,
    FrameTimeoutError,
    HardwareError,
    TransientError,
)

__all__ = ["AcquisitionResult", "acquire", "load_buckets", "load_run", "require_zarr3",
           "MAX_SEQUENCE"]

MAX_SEQUENCE = 24  # 1-bit patterns per 24-bit video frame (DLPC350 video-port bit planes)
_KINDS = ("depth", "gated", "intensity", "taps")
_FRAME_IDS = ("device", "count")
_ANCHOR = 2  # frames acquired (and provisional) after a start or retry: one pattern pair
_FORMAT = "torchtof.acquisition/1"


@dataclass
class AcquisitionResult:
    """Summary of :func:`acquire`: the store, how many ±1 patterns (pairs) were acquired,
    whether ``stop`` ended the run early, and the faults that were handled."""

    path: str
    m_acquired: int
    m_planned: int
    stopped_early: bool
    retries: int
    duplicates: int
    resumed_from: int


def _versions() -> dict[str, str]:
    import importlib.metadata as md

    out = {}
    for pkg in ("torchtof", "torch", "numpy", "zarr", "pyusb"):
        try:
            out[pkg] = md.version(pkg)
        except md.PackageNotFoundError:
            out[pkg] = "not installed"
    import torchtof

    out["torchtof"] = torchtof.__version__
    return out


def _signed(buf: dict[str, torch.Tensor], frames: int) -> dict[str, torch.Tensor]:
    """Signed Hadamard buckets ``y = y⁺ − y⁻`` ``(1, C, m)`` of the first ``frames`` frames,
    and their pair sums ``y⁺ + y⁻`` as ``"<kind>_sum"`` (the free noise estimate of
    :func:`torchtof.adaptive.noise_from_pair_sums`)."""
    # combine_split / pair_sums with n = 1: the hook's contract is y± sums, not divided by n
    from ..adaptive.noise import pair_sums

    out = {}
    for k in ("depth", "gated", "intensity"):
        raw = buf[k][..., :frames].reshape(1, 1, -1)
        out[k], out[f"{k}_sum"] = combine_split(raw, 1), pair_sums(raw, 1)
    return out


def _frame_buckets(frame, gate_m: float) -> dict[str, torch.Tensor]:
    d = frame.depth[None, None]  # (1, 1, H, W): one frame on the frame axis
    if frame.taps is None:  # a frame without raw taps: NaN tap buckets, never made-up numbers
        taps = torch.full((1, 4, 1), float("nan"))
    else:
        taps = tap_buckets(frame.taps[None, None])  # DESIGN §2 per-tap buckets
    return {
        "depth": depth_bucket(d),  # Eq. 10
        "gated": depth_bucket(d, gate_m=gate_m),  # §3.1 "low-pass filter"
        "intensity": intensity_bucket(frame.amplitude[None, None]),  # S_i of Eq. 9
        "taps": taps,
    }


def _crop(frame, roi: tuple[int, int, int, int]):
    """The frame's ROI ``(row, col, height, width)`` (a view, no copy)."""
    y, x, h, w = roi
    cut = (..., slice(y, y + h), slice(x, x + w))
    return replace(frame, phase=frame.phase[cut], amplitude=frame.amplitude[cut],
                   depth=frame.depth[cut], taps=None if frame.taps is None else frame.taps[cut])


def _check_roi(roi, h: int, w: int, device: bool) -> tuple[int, int, int, int]:
    if roi is None:
        if h < 2:
            raise ValueError(f"acquire: a {w}x{h} px frame has no rows below row 0 for the "
                             "default roi; pass roi=(row, col, height, width)")
        return (1, 0, h - 1, w)  # row 0 left out: its first pixel carries the frame number
    try:
        y, x, rh, rw = (int(v) for v in roi)
    except (TypeError, ValueError):
        raise TypeError(f"acquire: expected roi as (row, col, height, width), got {roi!r}") \
            from None
    if rh < 1 or rw < 1 or y < 0 or x < 0 or y + rh > h or x + rw > w:
        raise ValueError(f"acquire: roi {roi!r} does not fit the {w}x{h} px frame")
    if device and y == 0 and x == 0:
        raise ValueError(f"acquire: roi {roi!r} contains pixel (0, 0), whose first byte is the "
                         "device frame number with frame_ids='device'; start it at row 1 or "
                         "column 1, or use frame_ids='count'")
    return (y, x, rh, rw)


def _recorded(ok: np.ndarray) -> int:
    """Frames recorded without a gap from the start (``frames_ok == 1``)."""
    bad = np.flatnonzero(ok != 1)
    return int(bad[0]) if bad.size else int(ok.shape[0])


def require_zarr3():
    """The ``zarr`` module, version 3 or later (the recorder uses the v3 API).

    Raises:
        ImportError: zarr is missing or older than 3, naming the requirement (zarr 3 needs
            Python ≥ 3.11).
    """
    import sys

    hint = ("torchtof acquire/reconstruct record runs with zarr>=3, which needs Python>=3.11 "
            f"(this is Python {sys.version_info.major}.{sys.version_info.minor}): "
            "pip install 'torchtof[hardware]'")
    try:
        import zarr
    except ImportError as exc:
        raise ImportError(f"zarr is not installed; {hint}") from exc
    version = str(getattr(zarr, "__version__", "0"))
    try:
        major = int(version.split(".")[0])
    except ValueError:
        major = 0
    if major < 3:
        raise ImportError(f"zarr {version} is installed; {hint}")
    return zarr


def _open_store(path, patterns: np.ndarray, attrs: dict, shape_hw: tuple[int, int], chunk: int,
                resume: bool):
    zarr = require_zarr3()

    path = Path(path)
    f = patterns.shape[0]
    h, w = shape_hw
    if (path / "zarr.json").exists():
        group = zarr.open_group(str(path), mode="a")
        if group.attrs.get("format") != _FORMAT:
            raise FileExistsError(f"acquire: {path} exists and is not a torchtof acquisition")
        if not resume:
            raise FileExistsError(f"acquire: {path} exists; pass resume=True (--resume) to "
                                  "continue it or choose a new path")
        old = group.attrs
        for key in ("n", "m", "order", "frames", "roi"):
            if old.get(key) != attrs[key]:
                raise ValueError(f"acquire: cannot resume {path}: it was recorded with "
                                 f"{key}={old.get(key)!r}, this run has {key}={attrs[key]!r}")
        if not np.array_equal(group["patterns"][:], patterns):
            raise ValueError(f"acquire: cannot resume {path}: its patterns differ")
        if tuple(group["frames_depth"].shape[1:]) != (h, w):
            old_hw = tuple(group["frames_depth"].shape[1:])
            raise ValueError(f"acquire: cannot resume {path}: frames of {old_hw} px, this "
                             f"ROI has {(h, w)}")
        return group, True
    group = zarr.open_group(str(path), mode="w")
    group.create_array("patterns", data=patterns, chunks=(min(f, 256), *patterns.shape[1:]))

    def arr(name, shape, dtype, chunks, fill):
        group.create_array(name, shape=shape, dtype=dtype, chunks=chunks, fill_value=fill)

    nan = float("nan")
    arr("frames_ok", (f,), "uint8", (chunk,), 0)
    arr("frames_id", (f,), "int64", (chunk,), -1)
    arr("frames_timestamp", (f,), "float64", (chunk,), nan)
    for name in ("frames_depth", "frames_amplitude", "frames_phase"):
        arr(name, (f, h, w), "float32", (chunk, h, w), nan)
    arr("frames_taps", (f, 4, h, w), "float32", (chunk, 4, h, w), nan)
    for k in ("depth", "gated", "intensity"):
        arr(f"buckets_{k}", (1, 1, f), "float32", (1, 1, chunk), nan)
    arr("buckets_taps", (1, 4, f), "float32", (1, 4, chunk), nan)
    group.attrs.update({**attrs, "status": "running", "m_acquired": 0})
    return group, False


def acquire(
    store: str | Path,
    lightcrafter,
    camera,
    *,
    n: int = 32,
    sr: float | None = 0.25,
    m: int | None = None,
    order: str = "cake_cutting",
    exposure_us: int = 10_000,
    period_us: int | None = None,
    block: int = 12,
    stop: Callable[[dict[str, torch.Tensor]], bool] | None = None,
    resume: bool = False,
    retries: int = 3,
    gate_m: float = PAPER_GATE_M,
    frame_timeout_s: float = 2.0,
    progress: bool = True,
    metadata: dict | None = None,
    on_frame: Callable[[int], None] | None = None,
    frame_ids: str = "device",
    roi: tuple[int, int, int, int] | None = None,
) -> AcquisitionResult:
    """Acquire the DMD-split Hadamard buckets of a scene into a zarr store (module docstring).

    Args:
        store: path of the zarr v3 store (a directory).
        lightcrafter: a :class:`~torchtof.hardware.dlpc350.LightCrafter4500` (with a video port).
        camera: an :class:`~torchtof.hardware.opt8241.OPT8241` (any object with its methods).
        n: DMD pattern size ``n × n`` (a power of two).
        sr, m: sampling rate ``m / n²`` or the number of ±1 patterns ``m`` (``m`` wins).
        order: Hadamard order (:mod:`torchtof.operators.patterns`).
        exposure_us, period_us: DMD exposure and period per pattern (µs).
        block: ±1 patterns (pairs) per block; ``stop`` is asked after each block but the last.
        stop: optional ``stop(y) -> bool`` called after each block with the signed buckets
            measured so far, ``{"depth", "gated", "intensity"}`` each ``y⁺ − y⁻`` of shape
            ``(1, 1, m_so_far)`` in pattern order (not divided by ``n``), and
            ``"<kind>_sum"`` the pair sums ``y⁺ + y⁻`` (noise level); ``True`` ends the
            acquisition, the store records ``m_acquired`` and ``stopped_early``.
        resume: continue an interrupted store (same patterns and settings).
        retries: re-acquisitions allowed per pattern sequence for transient faults.
        gate_m: depth gate of the gated buckets (paper §3.1: 3 m).
        frame_timeout_s: frame timeout.
        progress: show a tqdm progress bar.
        metadata: extra JSON-able store attributes (e.g. the simulated set-up).
        on_frame: called with the frame index after each frame is recorded.
        frame_ids: ``"device"`` (OPT9221 frame numbers, each frame checked and recorded as it
            arrives) or ``"count"`` (host numbering, frames recorded per complete sequence;
            weaker, module docstring).
        roi: ``(row, col, height, width)`` of the frame that forms the buckets and is
            recorded; default the whole frame below row 0 (pixel (0, 0) carries the device
            frame number and is refused in ``"device"`` mode).

    Returns:
        :class:`AcquisitionResult`.

    Raises:
        FileExistsError: the store exists and ``resume`` is false.
        ValueError: bad arguments or a store that does not match this run.
        FrameTimeoutError, FrameError, FrameSequenceError, ProtocolError: a transient fault
            that persisted after ``retries`` attempts (names the pattern index / command).
        DeviceLostError: a device disappeared (resume later with ``resume=True``).
    """
    if isinstance(block, bool) or not isinstance(block, int) or block < 1:
        raise ValueError(f"acquire: expected block a positive int, got {block!r}")
    if isinstance(retries, bool) or not isinstance(retries, int) or retries < 0:
        raise ValueError(f"acquire: expected retries a non-negative int, got {retries!r}")
    if stop is not None and not callable(stop):
        raise TypeError(f"acquire: expected stop to be callable or None, got {type(stop).__name__}")
    if frame_ids not in _FRAME_IDS:
        raise ValueError(f"acquire: expected frame_ids in {_FRAME_IDS}, got {frame_ids!r}")
    device = frame_ids == "device"
    if device and not hasattr(camera, "frame_ids"):
        raise TypeError(f"acquire: frame_ids='device' needs a camera with device frame "
                        f"numbers (OPT8241); {type(camera).__name__} has none: use "
                        "frame_ids='count'")
    if sr is not None and m is not None:
        sr = None
    hadamard = Hadamard(n, sr=sr, m=m, order=order)
    pats = DMDSplit(hadamard).patterns(torch.float32).to(torch.uint8).numpy()  # (2M, n, n)
    n_frames, m_total = pats.shape[0], hadamard.m
    seq = min(MAX_SEQUENCE, 2 * block)
    roi = _check_roi(roi, camera.height, camera.width, device)
    h, w = roi[2], roi[3]
    if hasattr(camera, "frame_ids"):
        camera.frame_ids = device  # written to debug_frame_number_en by camera.start()
    period_us = exposure_us if period_us is None else period_us
    attrs = {
        "format": _FORMAT, "n": n, "m": m_total, "sr": m_total / (n * n), "order": order,
        "frames": n_frames, "frame_order": "interleaved phi+, phi- (DMDSplit)", "block": block,
        "sequence": seq, "gate_m": gate_m, "roi": list(roi), "frame_ids": frame_ids,
        "dmd": {"exposure_us": exposure_us, "period_us": period_us, "trigger": "internal",
                "source": "video", "bitplanes_per_frame": MAX_SEQUENCE},
        "camera": {"freq_hz": camera.freq_hz, "integration_time_us": camera.integration_time_us,
                   "width": camera.width, "height": camera.height,
                   "rules": vars(camera.rules).copy(),
                   "mode": getattr(camera, "mode", None)},
        "versions": _versions(), "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        **(metadata or {}),
    }
    group, resumed = _open_store(store, pats, attrs, (h, w), seq, resume)
    done = _recorded(group["frames_ok"][:])
    done -= done % 2  # restart at a pair boundary: y⁺ and y⁻ taken back to back
    buf = {k: torch.from_numpy(group[f"buckets_{k}"][:]) for k in _KINDS}
    if group.attrs.get("status") == "complete":
        return AcquisitionResult(str(store), int(group.attrs["m_acquired"]), m_total,
                                 bool(group.attrs.get("stopped_early", False)), 0, 0, done)
    stats = {"retries": int(group.attrs.get("retries", 0)),
             "duplicates": int(group.attrs.get("duplicates", 0))}
    bar = None
    if progress:
        from .._optional import progress_bar as tqdm

        bar = tqdm(total=n_frames, initial=done, desc="acquiring ToF frames", unit="frame")

    arrays = {name: group[name] for name in (
        "frames_depth", "frames_amplitude", "frames_phase", "frames_taps", "frames_id",
        "frames_timestamp", "frames_ok", *(f"buckets_{k}" for k in _KINDS))}

    def commit(k: int, frame, ok: int = 1) -> None:
        frame = _crop(frame, roi)
        b = _frame_buckets(frame, gate_m)
        arrays["frames_depth"][k] = frame.depth.numpy()
        arrays["frames_amplitude"][k] = frame.amplitude.numpy()
        arrays["frames_phase"][k] = frame.phase.numpy()
        if frame.taps is not None:
            arrays["frames_taps"][k] = frame.taps.numpy()
        arrays["frames_id"][k] = frame.frame_id
        arrays["frames_timestamp"][k] = frame.timestamp
        for kind in _KINDS:
            arrays[f"buckets_{kind}"][..., k] = b[kind][..., 0].numpy()
            buf[kind][..., k] = b[kind][..., 0]
        arrays["frames_ok"][k] = ok  # last: the frame counts only once everything is written
        if bar is not None and ok == 1:
            bar.update(1)
        if on_frame is not None:
            on_frame(k)

    stopped = False
    start_block = done // (2 * block)
    dev = _DeviceIds(lightcrafter, camera, pats, seq, exposure_us, period_us, retries,
                     frame_timeout_s, commit, stats, arrays, bar)
    try:
        camera.start()
        for b0 in range(start_block * 2 * block, n_frames, 2 * block):
            b1 = min(b0 + 2 * block, n_frames)
            s0 = max(b0, done)
            while s0 < b1:
                if device:
                    s0 = dev.sequence(s0, b1)
                else:
                    _acquire_sequence(lightcrafter, camera, pats, s0, min(s0 + seq, b1),
                                      exposure_us, period_us, retries, frame_timeout_s, commit,
                                      stats)
                    s0 = min(s0 + seq, b1)
            done = b1
            if stop is not None and b1 < n_frames and stop(_signed(buf, b1)):
                stopped = True
                break
        camera.stop()
    except (HardwareError, KeyboardInterrupt):  # the recorded frames stay valid: resume
        group.attrs.update({"status": "interrupted", **stats})
        raise
    finally:
        if bar is not None:
            bar.close()
    group.attrs.update({"status": "complete", "m_acquired": done // 2, "stopped_early": stopped,
                        **stats})
    return AcquisitionResult(str(store), done // 2, m_total, stopped, stats["retries"],
                             stats["duplicates"], 0)


class _DeviceIds:
    """``frame_ids="device"``: check each frame's device number as it arrives and record it
    at once (module docstring)."""

    def __init__(self, lcr, camera, pats, seq, exposure_us, period_us, retries, timeout_s,
                 commit, stats, arrays, bar) -> None:
        self.lcr, self.camera, self.pats, self.seq = lcr, camera, pats, seq
        self.exposure_us, self.period_us = exposure_us, period_us
        self.retries, self.timeout_s, self.commit, self.stats = retries, timeout_s, commit, stats
        self.arrays, self.bar = arrays, bar
        self.expected: int | None = None  # next device frame number; None: not anchored

    def sequence(self, s0: int, b1: int) -> int:
        """Acquire from pattern ``s0`` (a pair boundary) up to at most ``b1``: one DMD
        sequence, or the anchor pair when not anchored; returns the next pattern index."""
        attempt, start = 0, s0
        while True:
            anchored = self.expected is not None
            s1 = min(start + (self.seq if anchored else _ANCHOR), b1)
            k = start
            try:
                self.camera.pattern_index = start
                self.lcr.show_sequence(self.pats[start:s1], self.exposure_us, self.period_us,
                                       trigger="internal")
                last = None
                while k < s1:
                    self.camera.pattern_index = k
                    frame = self.camera.grab(self.timeout_s)
                    fid = int(frame.frame_id)
                    if last is not None and fid == last.frame_id:
                        if _same_bytes(frame, last):  # a duplicated transfer
                            self.stats["duplicates"] += 1
                            continue
                        raise FrameIdError(k, int(self.expected), fid,
                                           "repeated id on a different frame")
                    if self.expected is not None and fid != self.expected:
                        raise FrameIdError(k, self.expected, fid)
                    self.commit(k, frame, 1 if anchored else 2)
                    last, self.expected, k = frame, (fid + 1) % 256, k + 1
                self.camera.pattern_index = None
                while True:  # second check: no frame may follow the sequence's last pattern
                    try:
                        frame = self.camera.grab(min(self.timeout_s, 0.05))
                    except FrameTimeoutError:
                        break
                    if frame.frame_id == last.frame_id and _same_bytes(frame, last):
                        self.stats["duplicates"] += 1
                        continue
                    k = start  # a spurious frame before it may have shifted them all
                    raise FrameSequenceError(s1 - start, s1 - start + 1, start)
                if not anchored:  # the count confirms the anchor: the pair is recorded
                    self.arrays["frames_ok"][start:s1] = 1
                    if self.bar is not None:
                        self.bar.update(s1 - start)
                return s1
            except DeviceLostError:
                raise
            except TransientError:
                attempt += 1
                self.stats["retries"] += 1
                if attempt > self.retries:
                    raise
                try:
                    self.lcr.stop()
                except TransientError:
                    pass
                self.camera.flush()
                self.expected = None  # re-anchor after the retry
                start = k - k % 2  # the pair of the failed frame: y+ and y- back to back


def _acquire_sequence(lcr, camera, pats, s0, s1, exposure_us, period_us, retries, timeout_s,
                      commit, stats) -> None:
    """``frame_ids="count"``: frames ``s0 … s1−1``: load, start, grab all, check the count
    (module docstring), then commit; re-acquire the sequence on a transient fault."""
    attempt = 0
    while True:
        try:
            camera.pattern_index = s0
            lcr.show_sequence(pats[s0:s1], exposure_us, period_us, trigger="internal")
            frames: list = []
            while len(frames) < s1 - s0:
                camera.pattern_index = s0 + len(frames)
                frame = camera.grab(timeout_s)
                if frames and _same_bytes(frame, frames[-1]):  # a duplicated transfer
                    stats["duplicates"] += 1
                    continue
                frames.append(frame)
            extra = 0
            camera.pattern_index = None
            while True:  # no frame may follow the sequence's last pattern
                try:
                    frame = camera.grab(min(timeout_s, 0.05))
                except FrameTimeoutError:
                    break
                if _same_bytes(frame, frames[-1]):
                    stats["duplicates"] += 1
                else:
                    extra += 1
            if extra:
                raise FrameSequenceError(s1 - s0, s1 - s0 + extra, s0)
            for k, frame in enumerate(frames):
                commit(s0 + k, frame)
            return
        except DeviceLostError:
            raise
        except TransientError:
            attempt += 1
            stats["retries"] += 1
            if attempt > retries:
                raise
            try:
                lcr.stop()
            except TransientError:
                pass
            camera.flush()


def _same_bytes(a, b) -> bool:
    ra, rb = getattr(a, "raw", None), getattr(b, "raw", None)
    return ra is not None and ra == rb


def load_buckets(path: str | Path) -> tuple[dict[str, torch.Tensor], dict]:
    """Recorded interleaved buckets ``{"depth", "depth_gated", "intensity", "taps"}`` (each
    ``(1, C, 2·m_acquired)``) and the store attributes.

    Raises:
        ValueError: not a torchtof acquisition, or no complete pattern pair recorded.
    """
    zarr = require_zarr3()

    group = zarr.open_group(str(path), mode="r")
    attrs = dict(group.attrs)
    if attrs.get("format") != _FORMAT:
        raise ValueError(f"load_buckets: {path} is not a torchtof acquisition store")
    f = _recorded(group["frames_ok"][:])
    if attrs.get("status") == "complete":
        f = 2 * int(attrs["m_acquired"])
    f -= f % 2
    if f == 0:
        raise ValueError(f"load_buckets: {path} holds no complete pattern pair")
    names = {"depth": "depth", "depth_gated": "gated", "intensity": "intensity", "taps": "taps"}
    out = {k: torch.from_numpy(group[f"buckets_{v}"][..., :f]) for k, v in names.items()}
    attrs["frames_recorded"] = f
    return out, attrs


def load_run(path: str | Path):
    """A recorded run as :class:`~torchtof.experiment.ExperimentData` (one realisation), ready
    for :func:`torchtof.methods.build_method`; ``x`` is the simulated object when the run
    was simulated, zeros otherwise."""
    from ..experiment import ExperimentConfig, ExperimentData
    from ..scenes import get_scene

    buckets, attrs = load_buckets(path)
    n, m = int(attrs["n"]), attrs["frames_recorded"] // 2
    sim = attrs.get("simulation")
    fields = ExperimentConfig.__dataclass_fields__
    if sim is not None:
        kw = {k: (tuple(v) if isinstance(v, list) else v) for k, v in sim["config"].items()
              if k in fields}
    else:
        cam = attrs["camera"]
        kw = {"n": n, "freq_hz": cam["freq_hz"], "roi_px": max(n, cam["width"], cam["height"]),
              "gate_m": attrs["gate_m"]}
    kw.update(n=n, order=attrs["order"], srs=(m / (n * n),))
    cfg = ExperimentConfig(**kw)
    if sim is not None:
        scene = get_scene(cfg.scene, n, cfg.object_m, dtype=torch.float32)
        x, depth_m = scene.reflectance, scene.depth_m
    else:
        x = depth_m = torch.zeros(1, 1, n, n)
    empty = torch.zeros(0, 1, n, n)
    return ExperimentData(config=cfg, x=x, depth_m=depth_m, raw_tof=empty, raw_tof_image=empty,
                          buckets=buckets, hadamard=Hadamard(n, m=m, order=attrs["order"]))
