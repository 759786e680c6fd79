"""ToF frames as the hardware layer delivers them, and the :class:`FrameSource` protocol."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import torch

__all__ = ["Frame", "FrameSource"]


@dataclass(frozen=True)
class Frame:
    """One ToF frame.

    Attributes:
        phase: ``(H, W)`` phase in radians, ``[0, 2π)`` (paper Eq. 7).
        amplitude: ``(H, W)`` amplitude in ADC numbers (Eq. 8).
        depth: ``(H, W)`` depth in metres after the camera rules (Eq. 1, paper §2.2).
        timestamp: seconds (OPT8241: host clock when the transfer completed, as the SDK).
        frame_id: the frame's number (OPT8241: the OPT9221's 8-bit frame number from byte 0
            with ``frame_ids=True``, else counted on the host).
        taps: optional raw correlation taps ``(4, H, W)`` in the Fig. 1 order (ADC numbers).
        ambient: optional 4-bit ambient code per pixel ``(H, W)``.
        flags: optional 4-bit flags per pixel ``(H, W)`` (meaning not documented by TI).
        raw: the bytes the frame was decoded from (duplicate detection), if any.
    """

    phase: torch.Tensor
    amplitude: torch.Tensor
    depth: torch.Tensor
    timestamp: float
    frame_id: int
    taps: torch.Tensor | None = None
    ambient: torch.Tensor | None = None
    flags: torch.Tensor | None = None
    raw: bytes | None = field(default=None, repr=False, compare=False)


@runtime_checkable
class FrameSource(Protocol):
    """Anything that delivers ToF frames: ``start()``, ``grab(timeout_s)``, ``flush()``,
    ``stop()``. ``grab`` returns the next :class:`Frame` in arrival order or raises
    :class:`~torchtof.hardware.errors.FrameTimeoutError` /
    :class:`~torchtof.hardware.errors.FrameError`."""

    def start(self) -> None: ...

    def grab(self, timeout_s: float | None = None) -> Frame: ...

    def flush(self) -> int: ...

    def stop(self) -> None: ...
