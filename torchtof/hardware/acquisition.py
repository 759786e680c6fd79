"""Acquisition: show each DMD pattern, grab its ToF frame, form the buckets, record safely.

For each ±1 Hadamard row the DMD shows the pair ``φ⁺ = (1+h)/2``, ``φ⁻ = (1−h)/2``
(:class:`~torchtof.operators.DMDSplit`, acquisition order ``φ⁺₁, φ⁻₁, φ⁺₂, …``). Patterns are
loaded in sequences of at most 24 (the bit planes of one 24-bit video frame); the projector
paces them (VSYNC trigger by default) and its TRIG_OUT1 triggers the camera, one frame per
pattern. The camera's frame time is programmed to fit one pattern period first.

**A sequence is recorded only once all its checks pass** (:class:`_Sequences`): one frame
per pattern; byte-identical duplicates dropped; with ``frame_ids="device"`` (the OPT9221's
``debug_frame_number_en``, :mod:`.opt8241`) consecutive device frame numbers; with
``check_timing`` each frame's host arrival time on the pattern schedule (±40 % of the
pattern spacing: a spurious frame arrives too early, a lost one leaves a gap — the check
that sees a spurious *and* a lost frame in one sequence, whose device ids stay
consecutive); no frame after the last one; and, from an OPT8241, ``op_overflow`` clear
(the camera's output kept up, :meth:`~.opt8241.OPT8241.check_output_overflow`). Any failed
check, timeout, NACK or corrupt frame discards the whole sequence, stops the projector,
flushes the camera (and clears ``op_overflow``) and shows the sequence again (``retries``
times, then an error naming the pattern or command): no frame is ever recorded against the
wrong pattern. A killed run loses at most the sequence in flight (≤ 24 frames).

Buckets per frame over the ROI ``roi`` (paper Eq. 10, §3.1; per-tap buckets as
:func:`torchtof.bucket.tap_buckets`): depth ``Σ d``, gated depth ``Σ gate(d)``, intensity
``Σ a`` and the four tap sums (NaN unless the camera sends raw quads).

**Recording** (zarr ≥ 3.1.6, :func:`acquire`): a checked sequence is written with one write
per array (``frames_depth``, ``frames_amplitude``, ``frames_phase``, ``frames_taps``,
``frames_id`` (device number 0-255, or host count), ``frames_timestamp``, ``buckets_depth``,
``buckets_gated``, ``buckets_intensity``, ``buckets_taps`` — frame axis last for buckets
``(1, C, 2M)``, first for frames, chunked per sequence) and then marked in ``frames_ok``.
zarr 3.1.6's local store replaces each chunk file atomically and every chunk carries a
CRC-32C (zarr's ``crc32c`` codec), checked on every read. ``resume=True`` verifies the whole
store (:func:`_verify`), refuses one recorded with any other data-changing setting (naming
it), and continues at the first sequence not recorded. Patterns, order, timing, ROI,
frame-id mode, camera settings and package versions are store attributes.
"""

from __future__ import annotations

import math
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
    FrameTimingError,
    TransientError,
)

__all__ = ["AcquisitionResult", "StoreDamagedError", "acquire", "load_buckets", "load_run",
           "require_zarr3", "MAX_SEQUENCE"]

MAX_SEQUENCE = 24  # 1-bit patterns per 24-bit video frame (DLPC350 video-port bit planes)
_KINDS = ("depth", "gated", "intensity", "taps")
_FRAME_IDS = ("device", "count")
_FORMAT = "torchtof.acquisition/1"


@dataclass
class AcquisitionResult:
    """Summary of :func:`acquire`: the store, how many ±1 patterns (pairs) were acquired,
    whether ``stop`` ended the run early, the faults that were handled, and the pattern pairs
    the store already held when this call started (``resumed_from``: 0 for a new store; for
    a store already complete, all of them)."""

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


def _camera_settings(camera) -> dict:
    """What :meth:`~.opt8241.OPT8241.configure` set beyond the frame format, read back from an
    OPT8241 (nothing from a camera without these registers): PLL 2's frequency, the unambiguous
    range ``c/(2f)``, TI's phase calibration (off: ``disable_offset_corr``,
    ``disable_temp_corr``, ``filt_en``, ``phase_lin_corr_en``), ``hdr_scale``, and
    ``sscg_en`` (left as TI's profile set it)."""
    read = getattr(camera, "read_field", None)
    if read is None or not hasattr(camera, "pll2_freq_hz"):
        return {}
    off = {"disable_offset_corr": 1, "disable_temp_corr": 1, "filt_en": 0,
           "phase_lin_corr_en": 0, "phase_corr_1": 0, "phase_corr_2": 0}
    return {"mod_freq_hz_requested": getattr(camera, "mod_freq_hz", None),
            "pll2_freq_hz": camera.pll2_freq_hz,
            "unambiguous_range_m": camera.unambiguous_range_m,
            "phase_calibration": "off" if all(read(k) == v for k, v in off.items()) else "on",
            "hdr_scale": read("hdr_scale"), "sscg_en": read("sscg_en")}


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
        taps = tap_buckets(frame.taps[None, None])  # per-tap buckets
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


def _check_complete(path, attrs, ok: np.ndarray) -> int:
    """The frames of a store marked complete: ``2·m_acquired``, which ``frames_ok`` must mark
    recorded, and nothing after them (a run stopped early records no more). A deleted
    ``frames_ok`` chunk (read back as 0) or a changed ``m_acquired`` breaks the agreement:
    :class:`StoreDamagedError`, so the store is never read as NaN data nor taken as done."""
    try:
        f = 2 * int(attrs["m_acquired"])
    except (KeyError, TypeError, ValueError):
        raise StoreDamagedError(path, "it is marked complete but records no m_acquired") from None
    if not 0 < f <= ok.shape[0] or not (ok[:f] == 1).all() or (ok[f:] == 1).any():
        first = int(np.flatnonzero(ok[:f] != 1)[0]) if f <= ok.shape[0] and (ok[:f] != 1).any() \
            else None
        what = (f"frames_ok marks frame {first} unrecorded" if first is not None else
                f"frames_ok marks {int((ok == 1).sum())} frames recorded")
        raise StoreDamagedError(path, f"it is marked complete with {f} frames "
                                f"(m_acquired {f // 2}) but {what} (a chunk was deleted or the "
                                "attributes changed?)")
    return f


def _recorded(ok: np.ndarray) -> int:
    """Frames recorded without a gap from the start (``frames_ok == 1``)."""
    bad = np.flatnonzero(ok != 1)
    return int(bad[0]) if bad.size else int(ok.shape[0])


def require_zarr3():
    """The ``zarr`` module, version 3.1.6 or later (the recorder uses the v3 API, and 3.1.6's
    local store writes every chunk atomically: a temporary file renamed over the old one, so
    a killed run never leaves a half-written chunk).

    Raises:
        ImportError: zarr is missing or older than 3.1.6, naming the requirement (zarr 3 needs
            Python ≥ 3.11).
    """
    import sys

    hint = ("torchtof acquire/reconstruct record runs with zarr>=3.1.6, which needs "
            f"Python>=3.11 (this is Python {sys.version_info.major}.{sys.version_info.minor}): "
            "pip install 'torchtof[hardware]' (or pip install 'zarr>=3.1.6')")
    try:
        import zarr
    except ImportError as exc:
        raise ImportError(f"zarr is not installed; {hint}") from exc
    version = str(getattr(zarr, "__version__", "0"))
    parts = []
    for p in version.split(".")[:3]:
        digits = "".join(ch for ch in p if ch.isdigit()) or "0"
        parts.append(int(digits))
    if tuple(parts + [0] * (3 - len(parts))) < (3, 1, 6):
        raise ImportError(f"zarr {version} is installed; {hint}")
    return zarr


class StoreDamagedError(ValueError):
    """A recorded store that fails its integrity check (a chunk whose CRC-32C does not
    match, a chunk missing under a frame marked recorded, unreadable metadata); names the
    store and what is wrong. Re-acquire into a new store (or delete the damaged one)."""

    def __init__(self, path, detail: str) -> None:
        self.path = str(path)
        super().__init__(f"damaged store {path}: {detail}. Re-acquire into a new store (or "
                         "delete this one and run again)")


#: store attributes that do not change the recorded data (everything else must match on
#: resume, including the simulation's configuration and seed from ``metadata``)
_VOLATILE = {"status", "m_acquired", "stopped_early", "retries", "duplicates", "versions",
             "created", "timing_checks"}
#: The attributes acquire() writes itself (``metadata`` may not replace them: a store whose
#: ``order`` or ``n`` disagrees with its patterns would be reconstructed with the wrong
#: operator).
_CORE_ATTRS = {"format", "n", "m", "sr", "order", "frames", "frame_order", "block",
               "sequence", "gate_m", "roi", "frame_ids", "dmd", "camera"} | _VOLATILE


def _first_difference(old, new, where: str = "") -> str | None:
    """The dotted name of the first field in which two JSON-like values differ."""
    if isinstance(old, dict) and isinstance(new, dict):
        for key in [*new, *(k for k in old if k not in new)]:  # this run's order
            if not where and key in _VOLATILE:
                continue
            d = _first_difference(old.get(key), new.get(key), f"{where}.{key}" if where else key)
            if d is not None:
                return d
        return None
    if isinstance(old, (list, tuple)) and isinstance(new, (list, tuple)):
        old, new = list(old), list(new)
    if old != old and new != new:  # NaN == NaN for this purpose
        return None
    return None if old == new else where


def _codecs():
    from zarr.codecs import Crc32cCodec, ZstdCodec

    # every chunk carries a CRC-32C of its compressed bytes, checked on every read
    return [ZstdCodec(level=3), Crc32cCodec()]


def _verify(path, group, n_frames: int) -> np.ndarray:
    """Read every array of the store (each chunk's CRC-32C checked) and check that every
    frame marked recorded has its data; returns ``frames_ok``.

    Raises:
        StoreDamagedError: naming the array and what is wrong.
    """
    arrays = {}
    for name in _ARRAYS:
        try:
            arrays[name] = group[name][:]
        except KeyError:
            raise StoreDamagedError(path, f"array {name!r} is missing") from None
        except Exception as exc:  # noqa: BLE001 - checksum, zstd, JSON: all mean damaged
            raise StoreDamagedError(path, f"array {name!r} does not decode ({exc})") from exc
    ok = arrays["frames_ok"]
    if ok.shape != (n_frames,) or not np.isin(ok, (0, 1)).all():
        raise StoreDamagedError(path, "frames_ok holds values other than 0 and 1")
    rec = ok == 1
    checks = {"frames_id": arrays["frames_id"][rec] >= 0,
              "frames_timestamp": np.isfinite(arrays["frames_timestamp"][rec])}
    for k in ("depth", "gated", "intensity"):
        checks[f"buckets_{k}"] = np.isfinite(arrays[f"buckets_{k}"][0, 0, rec])
    for k in ("frames_depth", "frames_amplitude", "frames_phase"):
        checks[k] = ~np.isnan(arrays[k][rec]).all(axis=(1, 2))
    for name, good in checks.items():
        if not good.all():
            bad = int(np.flatnonzero(rec)[np.flatnonzero(~good)[0]])
            raise StoreDamagedError(path, f"{name} has no data for frame {bad}, which "
                                    "frames_ok marks recorded (a chunk was deleted?)")
    return ok


_ARRAYS = ("patterns", "frames_ok", "frames_id", "frames_timestamp", "frames_depth",
           "frames_amplitude", "frames_phase", "frames_taps", "buckets_depth", "buckets_gated",
           "buckets_intensity", "buckets_taps")


def store_attributes(path: str | Path) -> dict:
    """The attributes of the store at ``path`` (status, plan, settings), read without its
    arrays; :class:`StoreDamagedError` if its metadata does not load."""
    return dict(_open_group(path, "r").attrs)


def _open_group(path, mode: str):
    zarr = require_zarr3()
    try:
        return zarr.open_group(str(path), mode=mode)
    except FileNotFoundError:
        raise
    except Exception as exc:  # noqa: BLE001 - a garbage zarr.json
        raise StoreDamagedError(path, f"its metadata does not load ({exc})") from exc


def _open_store(path, patterns: np.ndarray, attrs: dict, shape_hw: tuple[int, int], chunk: int,
                resume: bool):
    path = Path(path)
    f = patterns.shape[0]
    h, w = shape_hw
    if (path / "zarr.json").exists():
        group = _open_group(path, "a")
        if group.attrs.get("format") != _FORMAT:
            raise FileExistsError(f"acquire: {path} exists and is not a torchtof acquisition")
        if not resume:
            raise FileExistsError(f"acquire: {path} exists; pass resume=True (--resume) to "
                                  "continue it or choose a new path")
        old = dict(group.attrs)
        for key in ("n", "m", "order", "frames", "roi"):  # the commonest first, by name
            if old.get(key) != attrs[key]:
                raise ValueError(f"acquire: cannot resume {path}: it was recorded with "
                                 f"{key}={old.get(key)!r}, this run has {key}={attrs[key]!r}")
        key = _first_difference(old, _json_safe(attrs))
        if key is not None:
            o, n = _lookup(old, key), _lookup(_json_safe(attrs), key)
            raise ValueError(f"acquire: cannot resume {path}: it was recorded with {key}={o!r}, "
                             f"this run has {key}={n!r} (the data would mix two set-ups)")
        ok = _verify(path, group, f)
        if not np.array_equal(group["patterns"][:], patterns):
            raise ValueError(f"acquire: cannot resume {path}: its patterns differ")
        if tuple(group["frames_depth"].shape[1:]) != (h, w):
            old_hw = tuple(group["frames_depth"].shape[1:])
            raise ValueError(f"acquire: cannot resume {path}: frames of {old_hw} px, this "
                             f"ROI has {(h, w)}")
        return group, ok
    if path.exists() and not (path.is_dir() and not any(path.iterdir())):
        # zarr's mode "w" would delete what the folder holds
        raise FileExistsError(f"acquire: {path} exists and is not a torchtof acquisition (a "
                              "file, or a folder holding other files); choose a new path")
    zarr = require_zarr3()
    group = zarr.open_group(str(path), mode="w")
    codecs = _codecs()
    group.create_array("patterns", data=patterns, chunks=(min(f, 256), *patterns.shape[1:]),
                       compressors=codecs)

    def arr(name, shape, dtype, chunks, fill):
        group.create_array(name, shape=shape, dtype=dtype, chunks=chunks, fill_value=fill,
                           compressors=codecs)

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
    group.attrs.update({**_json_safe(attrs), "status": "running", "m_acquired": 0})
    return group, np.zeros(f, dtype=np.uint8)


def _lookup(d, dotted: str):
    for part in dotted.split("."):
        d = d.get(part) if isinstance(d, dict) else None
    return d


def _json_safe(value):
    """``value`` as it reads back from a zarr attribute (tuples become lists)."""
    import json

    return json.loads(json.dumps(value))


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
    trigger: str = "vsync",
    video_hz: float = 60.0,
    check_timing: bool = True,
) -> AcquisitionResult:
    """Acquire the DMD-split Hadamard buckets of a scene into a zarr store (module docstring).

    Args:
        store: path of the zarr v3 store (a directory).
        lightcrafter: a :class:`~torchtof.hardware.dlpc350.LightCrafter4500` (with a video port).
        camera: an :class:`~torchtof.hardware.opt8241.OPT8241` (any object with its methods).
        n: DMD pattern size ``n × n`` (a power of two).
        sr, m: sampling rate ``m / n²`` or the number of ±1 patterns ``m`` (``m`` wins).
        order: Hadamard order (:mod:`torchtof.operators.patterns`).
        exposure_us, period_us: DMD exposure and period per pattern (µs); the camera's frame
            time is programmed to fit the period (``camera.configure(period_us=...)``, which
            also programs the camera's modulation frequency and switches TI's phase
            calibration off: :meth:`~.opt8241.OPT8241.configure`).
        block: ±1 patterns (pairs) per block; ``stop`` is asked after each block but the last.
        stop: optional ``stop(y) -> bool`` called after each block with the signed buckets
            measured so far, ``{"depth", "gated", "intensity"}`` each ``y⁺ − y⁻`` of shape
            ``(1, 1, m_so_far)`` in pattern order (not divided by ``n``), and
            ``"<kind>_sum"`` the pair sums ``y⁺ + y⁻`` (noise level); ``True`` ends the
            acquisition, the store records ``m_acquired`` and ``stopped_early``.
        resume: continue an interrupted store (same patterns and settings; its chunks'
            checksums are verified first).
        retries: re-acquisitions allowed per pattern sequence for transient faults.
        gate_m: depth gate of the gated buckets (paper §3.1: 3 m).
        frame_timeout_s: timeout for the first frame of a sequence.
        progress: show a tqdm progress bar.
        metadata: extra JSON-able store attributes (e.g. the simulated set-up); part of the
            configuration that ``resume`` compares.
        on_frame: called with the frame index after each frame is accepted (before the
            sequence is recorded).
        frame_ids: ``"device"`` (OPT9221 frame numbers checked to be consecutive) or
            ``"count"`` (host numbering; count and timing checks only).
        roi: ``(row, col, height, width)`` of the frame that forms the buckets and is
            recorded; default the whole frame below row 0 (pixel (0, 0) carries the device
            frame number and is refused in ``"device"`` mode).
        trigger: ``"vsync"`` (each pattern starts at a VSYNC of the video input, exposures
            within one video frame: TI's video-mode examples) or ``"internal"``.
        video_hz: frame rate of the video input (``"vsync"``).
        check_timing: check each frame's host timestamp against the pattern schedule (a
            spurious or lost frame shifts the spacing): needed to see a spurious *and* a lost
            frame in one sequence with ``frame_ids="count"``.

    Returns:
        :class:`AcquisitionResult`.

    Raises:
        FileExistsError: the store exists and ``resume`` is false, or ``path`` is a file or
            a folder with other files (never overwritten).
        ValueError: bad arguments or a store that does not match this run (names the field).
        StoreDamagedError: ``resume`` of a store that fails its integrity check.
        FrameTimeoutError, FrameError, FrameSequenceError, ProtocolError: a transient fault
            that persisted after ``retries`` attempts (names the pattern index / command).
        DeviceLostError: a device disappeared (resume later with ``resume=True``).
        HardwareError: the LightCrafter's video input is not the parallel port, not locked,
            not 912 × 1140 or not at ``video_hz`` (``check_video_input``, before the store
            is created).
    """
    if isinstance(block, bool) or not isinstance(block, int) or block < 1:
        raise ValueError(f"acquire: expected block a positive int, got {block!r}")
    if isinstance(retries, bool) or not isinstance(retries, int) or retries < 0:
        raise ValueError(f"acquire: expected retries a non-negative int, got {retries!r}")
    if stop is not None and not callable(stop):
        raise TypeError(f"acquire: expected stop to be callable or None, got {type(stop).__name__}")
    if frame_ids not in _FRAME_IDS:
        raise ValueError(f"acquire: expected frame_ids in {_FRAME_IDS}, got {frame_ids!r}")
    if trigger not in ("vsync", "internal"):
        raise ValueError(f"acquire: expected trigger 'vsync' or 'internal', got {trigger!r}")
    if isinstance(frame_timeout_s, bool) or not isinstance(frame_timeout_s, (int, float)) \
            or not 0 < frame_timeout_s < math.inf:
        raise ValueError(f"acquire: expected a positive finite frame_timeout_s, got "
                         f"{frame_timeout_s!r}")
    if isinstance(gate_m, bool) or not isinstance(gate_m, (int, float)) \
            or not 0 < gate_m < math.inf:
        raise ValueError(f"acquire: expected gate_m a positive finite number of metres, got "
                         f"{gate_m!r}")
    if on_frame is not None and not callable(on_frame):
        raise TypeError(f"acquire: expected on_frame to be callable or None, got "
                        f"{type(on_frame).__name__}")
    for name, flag in (("progress", progress), ("check_timing", check_timing)):
        if not isinstance(flag, bool):
            raise TypeError(f"acquire: expected {name} a bool, got {type(flag).__name__}")
    if metadata is not None:
        if not isinstance(metadata, dict) or not all(isinstance(k, str) for k in metadata):
            raise TypeError("acquire: expected metadata a dict with str keys")
        clash = sorted(set(metadata) & _CORE_ATTRS)
        if clash:
            raise ValueError(f"acquire: metadata may not replace the store's own attributes "
                             f"{clash} (they describe the patterns recorded)")
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
    check_initialised = getattr(camera, "check_initialised", None)
    if check_initialised is not None:  # before any register write or store (OPT8241 docstring)
        check_initialised()
    if hasattr(camera, "frame_ids"):
        camera.frame_ids = device  # written to debug_frame_number_en by camera.configure()
    period_us = exposure_us if period_us is None else period_us
    from .dlpc350 import pattern_times_us

    times_us = pattern_times_us(seq, exposure_us, period_us, trigger, video_hz)  # validates
    if hasattr(camera, "configure"):  # the frame must fit one pattern (camera docstring)
        spacing = min(b - a for a, b in zip(times_us, times_us[1:])) if seq > 1 else period_us
        camera.configure(period_us=min(period_us, spacing), spacing_us=spacing)
        camera._configured = True
    check_video = getattr(lightcrafter, "check_video_input", None)
    if check_video is not None:  # the bit planes come from the video input: before any store
        check_video(video_hz)
    attrs = {
        "format": _FORMAT, "n": n, "m": m_total, "sr": m_total / (n * n), "order": order,
        "frames": n_frames, "frame_order": "interleaved phi+, phi- (DMDSplit)", "block": block,
        "sequence": seq, "gate_m": gate_m, "roi": list(roi), "frame_ids": frame_ids,
        "dmd": {"exposure_us": exposure_us, "period_us": period_us, "trigger": trigger,
                "video_hz": video_hz, "source": "video", "bitplanes_per_frame": MAX_SEQUENCE},
        "camera": {"freq_hz": camera.freq_hz, "integration_time_us": camera.integration_time_us,
                   "frame_time_us": getattr(camera, "frame_time_us", None),
                   "width": camera.width, "height": camera.height,
                   "rules": vars(camera.rules).copy(), "quads": getattr(camera, "quads", None),
                   "roi": list(camera.roi) if getattr(camera, "roi", None) else None,
                   "mode": getattr(camera, "mode", None), **_camera_settings(camera)},
        "timing_checks": bool(check_timing),
        "versions": _versions(), "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        **(metadata or {}),
    }
    group, ok = _open_store(store, pats, attrs, (h, w), seq, resume)
    done = _recorded(ok)
    done -= done % 2  # restart at a pair boundary: y⁺ and y⁻ taken back to back
    buf = {k: torch.from_numpy(group[f"buckets_{k}"][:]) for k in _KINDS}
    if group.attrs.get("status") == "complete":
        _check_complete(store, group.attrs, ok)
        m_done = int(group.attrs["m_acquired"])
        return AcquisitionResult(str(store), m_done, m_total,
                                 bool(group.attrs.get("stopped_early", False)), 0, 0, m_done)
    stats = {"retries": int(group.attrs.get("retries", 0)),
             "duplicates": int(group.attrs.get("duplicates", 0))}
    bar = None
    if progress:
        from .._optional import progress_bar as tqdm

        bar = tqdm(total=n_frames, initial=done, desc="acquiring ToF frames", unit="frame")

    arrays = {name: group[name] for name in _ARRAYS if name != "patterns"}

    def commit(s0: int, frames: list) -> None:
        """Record a checked sequence with one write per array (chunk-aligned when the
        sequence is), ``frames_ok`` last."""
        cut = [_crop(fr, roi) for fr in frames]
        b = {k: torch.cat([v[..., 0] for v in vs], 0) for k, vs in zip(
            _KINDS, zip(*[[fb[k] for k in _KINDS] for fb in map(
                lambda f: _frame_buckets(f, gate_m), cut)]))}
        s1 = s0 + len(cut)
        arrays["frames_depth"][s0:s1] = torch.stack([f.depth for f in cut]).numpy()
        arrays["frames_amplitude"][s0:s1] = torch.stack([f.amplitude for f in cut]).numpy()
        arrays["frames_phase"][s0:s1] = torch.stack([f.phase for f in cut]).numpy()
        if all(f.taps is not None for f in cut):
            arrays["frames_taps"][s0:s1] = torch.stack([f.taps for f in cut]).numpy()
        arrays["frames_id"][s0:s1] = np.array([f.frame_id for f in cut], dtype=np.int64)
        arrays["frames_timestamp"][s0:s1] = np.array([f.timestamp for f in cut])
        for kind in _KINDS:
            vals = b[kind].reshape(len(cut), -1).T  # (C, K)
            arrays[f"buckets_{kind}"][0, :, s0:s1] = vals.numpy()
            buf[kind][0, :, s0:s1] = vals
        arrays["frames_ok"][s0:s1] = 1  # last: the frames count only once all is written
        if bar is not None:
            bar.update(len(cut))

    stopped = False
    resumed_pairs = done // 2  # what the store held when this call began
    start_block = done // (2 * block)
    run = _Sequences(lightcrafter, camera, pats, exposure_us, period_us, trigger, video_hz,
                     retries, frame_timeout_s, device, check_timing, stats, on_frame)
    try:
        if stop is not None and done > 0:
            # a resumed run asks the rule at every block end already recorded, as the
            # uninterrupted run did: a stateful rule is rebuilt, and a run stopped while the
            # rule was deciding gets the answer it would have had
            for b1 in range(2 * block, min(done, n_frames - 1) + 1, 2 * block):
                if stop(_signed(buf, b1)):
                    stopped = True
                    if b1 < done:  # frames past the stop (a rule that changed its mind)
                        arrays["frames_ok"][b1:done] = 0
                    done = b1
                    break
        if not stopped:
            camera.start()
            for b0 in range(start_block * 2 * block, n_frames, 2 * block):
                b1 = min(b0 + 2 * block, n_frames)
                s0 = max(b0, done)
                while s0 < b1:
                    s1 = min(s0 + seq, b1)
                    commit(s0, run.sequence(s0, s1))
                    s0 = s1
                done = b1
                if stop is not None and b1 < n_frames and stop(_signed(buf, b1)):
                    stopped = True
                    break
            camera.stop()
    except BaseException:  # any stop (a device, Ctrl-C, the disk, a failing stop rule): the
        # recorded sequences stay valid for --resume
        for halt in (getattr(lightcrafter, "stop", None), getattr(camera, "stop", None)):
            try:  # leave the devices idle (best effort: one of them may be gone)
                if halt is not None:
                    halt()
            except Exception:  # noqa: BLE001 - never mask the error that stopped the run
                pass
        try:
            group.attrs.update({"status": "interrupted", **stats})
        except OSError:  # a full disk: the status cannot be written; frames_ok still holds
            pass
        raise
    finally:
        if bar is not None:
            bar.close()
    group.attrs.update({"status": "complete", "m_acquired": done // 2, "stopped_early": stopped,
                        **stats})
    return AcquisitionResult(str(store), done // 2, m_total, stopped, stats["retries"],
                             stats["duplicates"], resumed_pairs)


class _Sequences:
    """One pattern sequence at a time: load and start it, take its frames, check them,
    return them for recording; any failed check discards the whole sequence and shows it
    again (module docstring)."""

    def __init__(self, lcr, camera, pats, exposure_us, period_us, trigger, video_hz, retries,
                 timeout_s, device, check_timing, stats, on_frame) -> None:
        self.lcr, self.camera, self.pats = lcr, camera, pats
        self.exposure_us, self.period_us, self.trigger = exposure_us, period_us, trigger
        self.video_hz, self.retries, self.timeout_s = video_hz, retries, timeout_s
        self.device, self.check_timing, self.stats = device, check_timing, stats
        self.on_frame = on_frame

    def sequence(self, s0: int, s1: int) -> list:
        from .dlpc350 import pattern_times_us

        k_total = s1 - s0
        t_us = pattern_times_us(k_total, self.exposure_us, self.period_us, self.trigger,
                                self.video_hz)
        gaps = np.diff(t_us) * 1e-6 if k_total > 1 else np.array([self.period_us * 1e-6])
        tol = 0.4 * float(gaps.min())
        # later frames: a few pattern periods (at most the first frame's timeout)
        next_timeout = min(self.timeout_s, float(gaps.max()) * 4 + 0.5)
        tail = max(0.05, 1.5 * float(gaps.max()))  # no frame may follow within this
        overflow = getattr(self.camera, "check_output_overflow", None)
        attempt = 0
        while True:
            frames: list = []
            try:
                self.camera.pattern_index = s0
                self.lcr.show_sequence(self.pats[s0:s1], self.exposure_us, self.period_us,
                                       trigger=self.trigger, video_hz=self.video_hz)
                while len(frames) < k_total:
                    k = s0 + len(frames)
                    self.camera.pattern_index = k
                    fr = self.camera.grab(self.timeout_s if not frames else next_timeout)
                    if frames and _same_bytes(fr, frames[-1]):  # a duplicated transfer
                        self.stats["duplicates"] += 1
                        continue
                    if self.device and frames:
                        want = (frames[-1].frame_id + 1) % 256
                        if fr.frame_id == frames[-1].frame_id:
                            raise FrameIdError(k, want, fr.frame_id,
                                               "repeated id on a different frame")
                        if fr.frame_id != want:
                            raise FrameIdError(k, want, fr.frame_id)
                    if self.check_timing and frames:
                        dt = fr.timestamp - frames[0].timestamp
                        expect = (t_us[len(frames)] - t_us[0]) * 1e-6
                        if abs(dt - expect) > tol:
                            raise FrameTimingError(k, expect, dt)
                    frames.append(fr)
                    if self.on_frame is not None:
                        self.on_frame(k)
                self.camera.pattern_index = None
                while True:  # the count check: no frame may follow the last pattern
                    try:
                        fr = self.camera.grab(tail)
                    except FrameTimeoutError:
                        break
                    if _same_bytes(fr, frames[-1]):
                        self.stats["duplicates"] += 1
                        continue
                    raise FrameSequenceError(k_total, k_total + 1, s0)
                if overflow is not None:  # the camera's output kept up (OPT9221 op_overflow)
                    self.camera.pattern_index = s0
                    overflow()
                    self.camera.pattern_index = None
                return frames
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
                clear = getattr(self.camera, "clear_output_overflow", None)
                if clear is not None:  # an overflow of the failed attempt: not the next one's
                    try:
                        clear()
                    except TransientError:  # left set, it costs the next attempt one retry
                        pass


def _same_bytes(a, b) -> bool:
    ra, rb = getattr(a, "raw", None), getattr(b, "raw", None)
    return ra is not None and ra == rb


def load_buckets(path: str | Path) -> tuple[dict[str, torch.Tensor], dict]:
    """Recorded interleaved buckets ``{"depth", "depth_gated", "intensity", "taps"}`` (each
    ``(1, C, 2·m_acquired)``) and the store attributes.

    Every chunk's CRC-32C and every recorded frame's data are checked first (as ``resume``
    does).

    Raises:
        ValueError: not a torchtof acquisition, or no complete pattern pair recorded.
        StoreDamagedError: the store fails its integrity check.
    """
    group = _open_group(path, "r")
    attrs = dict(group.attrs)
    if attrs.get("format") != _FORMAT:
        raise ValueError(f"load_buckets: {path} is not a torchtof acquisition store")
    ok = _verify(path, group, int(attrs.get("frames", 0)))
    f = _recorded(ok)
    if attrs.get("status") == "complete":
        f = _check_complete(path, attrs, ok)
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
