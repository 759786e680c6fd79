"""Bucket formation: sum a region of interest (ROI) of each ToF frame into one number.

The ToF camera plays the single-pixel bucket detector of computational ghost
imaging (paper §2.2). A sequence of ``M`` frames, one per DMD pattern, is stacked
on a frame axis: depth and amplitude frames are ``(B, M, H, W)``, tap frames are
``(B, M, 4, H, W)``. The buckets come out as measurements ``(B, C, M)`` —
``C = 1`` for depth/intensity, ``C = 4`` for taps — ready for the reconstructors.

- :func:`depth_bucket` — ``D_i = Σ_{p∈ROI} d_i(p)`` (paper Eq. 10), optionally after
  the depth gate. Without the gate, pixels that see no light read 5 m (camera
  rule, §2.2), so ``D_i`` *falls* as more light arrives and the reconstructed
  images are negative (§3.1).
- :func:`depth_gate` — the paper's "low-pass filter" (§3.1): depths beyond
  ``gate_m`` (3 m in the paper, :data:`PAPER_GATE_M`) are set to 0 before summing,
  so ``D_i`` grows with the lit area and far multipath returns are removed.
- :func:`intensity_bucket` — ``S_i = Σ_{p∈ROI} a_i(p)`` (the ``S_i`` of Eq. 9).
- :func:`tap_buckets` — ``C_{k,i} = Σ_{p∈ROI} c_{k,i}(p)`` per correlation tap,
  linear in the light, so CGI on each tap gives four tap images (:mod:`torchtof.recon.depth`).

ROI (:func:`roi_mask`): ``None`` (whole frame), a box ``(top, left, height, width)``
in pixels that must lie inside the frame, or a bool mask ``(H, W)``.

Half precision: torch accumulates float16/bfloat16 sums in float32 and rounds once, so a
bucket is exact up to that rounding; one beyond float16's range (65504: a 256×256-pixel ROI
at 5 m sums to 327680) comes out ``inf``, the IEEE outcome for a value float16 cannot hold.
Use float32 or bfloat16 frames for large ROIs.

Example:
    >>> depth = torch.full((1, 3, 4, 4), 5.0)
    >>> depth_bucket(depth, roi=(0, 0, 2, 2)).tolist()
    [[[20.0, 20.0, 20.0]]]
"""

from __future__ import annotations

import numbers
from collections.abc import Sequence

import torch
from torch import nn

from torchtof._checks import check_finite, check_positive, check_rank, is_tracing

__all__ = [
    "PAPER_GATE_M",
    "roi_mask",
    "depth_gate",
    "DepthGate",
    "depth_bucket",
    "DepthBucket",
    "intensity_bucket",
    "IntensityBucket",
    "tap_buckets",
    "TapBuckets",
]

#: Depth gate of the paper's "low-pass filter" (§3.1), metres.
PAPER_GATE_M: float = 3.0


def _check_frames(x: object, rank: int, name: str, func: str, layout: str) -> None:
    """A real floating tensor of ``rank`` (depth, amplitude and taps are real)."""
    check_rank(x, rank, name, func, layout)
    if x.is_complex():
        raise TypeError(f"{func}: expected {name} to be a real tensor, got dtype {x.dtype}")


def _check_box(roi: Sequence[int], func: str) -> tuple[int, int, int, int]:
    """Validate a ``(top, left, height, width)`` box without knowing the frame."""
    if len(roi) != 4 or not all(isinstance(v, numbers.Integral) and not isinstance(v, bool)
                                for v in roi):
        raise TypeError(f"{func}: expected roi as (top, left, height, width) ints, got {roi!r}")
    top, left, height, width = (int(v) for v in roi)
    if height <= 0 or width <= 0:
        raise ValueError(
            f"{func}: expected roi of positive height and width (empty ROI), got {roi!r}"
        )
    if top < 0 or left < 0:
        raise ValueError(f"{func}: expected roi with top >= 0 and left >= 0, got {roi!r}")
    return top, left, height, width


def _roi_mask(
    shape_hw: Sequence[int], roi: object, device: torch.device | str | None, func: str,
    frames: str | None = None,
) -> torch.Tensor | None:
    """Bool ``(H, W)`` mask of ``roi`` for a frame of ``shape_hw``; ``None`` = whole frame.
    ``frames``: the caller's frame argument, named instead of ``shape_hw`` in the errors."""
    if (not isinstance(shape_hw, (Sequence, torch.Size)) or len(shape_hw) != 2
            or not all(isinstance(v, numbers.Integral) and not isinstance(v, bool)
                       for v in shape_hw)):
        raise TypeError(f"{func}: expected shape_hw as (H, W) ints, got {shape_hw!r}")
    h, w = (int(v) for v in shape_hw)
    if h <= 0 or w <= 0:
        if frames is not None:
            raise ValueError(f"{func}: expected {frames} frames of positive height and width, "
                             f"got (H, W) = ({h}, {w})")
        raise ValueError(f"{func}: expected shape_hw of a frame of positive size, got {shape_hw}")
    if roi is None:
        return None
    if isinstance(roi, torch.Tensor):
        if roi.dtype != torch.bool:
            raise TypeError(f"{func}: expected roi mask of dtype torch.bool, got {roi.dtype}")
        if tuple(roi.shape) != (h, w):
            raise ValueError(
                f"{func}: expected roi mask of shape (H, W) = ({h}, {w}), got {tuple(roi.shape)}"
            )
        if not is_tracing() and not bool(roi.any()):
            raise ValueError(f"{func}: roi mask selects no pixel (empty ROI)")
        return roi.to(device=device)
    if not isinstance(roi, Sequence) or isinstance(roi, str):
        raise TypeError(
            f"{func}: expected roi to be None, (top, left, height, width) or a bool tensor, "
            f"got {type(roi).__name__}"
        )
    top, left, height, width = _check_box(roi, func)
    if top + height > h or left + width > w:
        raise ValueError(
            f"{func}: expected roi (top, left, height, width) inside the {h}x{w} frame, got {roi!r}"
        )
    rows = torch.arange(h, device=device)
    cols = torch.arange(w, device=device)
    in_rows = (rows >= top) & (rows < top + height)
    in_cols = (cols >= left) & (cols < left + width)
    return in_rows[:, None] & in_cols[None, :]


def roi_mask(
    shape_hw: Sequence[int], roi: object = None, device: torch.device | str | None = None
) -> torch.Tensor:
    """The region of interest of the ToF sensor as a bool mask.

    Args:
        shape_hw: frame size ``(H, W)``.
        roi: ``None`` (whole frame), a box ``(top, left, height, width)`` inside the
            frame, or a bool tensor ``(H, W)`` with at least one ``True``.
        device: device of the returned mask (a bool ``roi`` is moved there).

    Returns:
        ``True`` on the ROI pixels.

    Raises:
        TypeError: if ``roi`` has the wrong type (e.g. a non-bool tensor, non-int box).
        ValueError: if the ROI is empty (zero area, out of frame, all-False mask) or the
            mask shape differs from ``shape_hw``.

    Shape:
        - Output: :math:`(H, W)`.

    Example:
        >>> roi_mask((3, 4), (1, 1, 2, 2)).int().tolist()
        [[0, 0, 0, 0], [0, 1, 1, 0], [0, 1, 1, 0]]
    """
    mask = _roi_mask(shape_hw, roi, device, "roi_mask")
    if mask is None:
        h, w = shape_hw
        return torch.ones(h, w, dtype=torch.bool, device=device)
    return mask


def _roi_sum(x: torch.Tensor, roi: object, func: str, name: str) -> torch.Tensor:
    """Sum of the last two axes of ``x`` (the argument ``name``) over the ROI."""
    mask = _roi_mask(x.shape[-2:], roi, x.device, func, name)
    if mask is not None:
        x = torch.where(mask, x, torch.zeros_like(x))
    return x.sum(dim=(-2, -1))


def depth_gate(depth: torch.Tensor, gate_m: float = PAPER_GATE_M) -> torch.Tensor:
    r"""The paper's "low-pass filter" on depth (§3.1): null every depth beyond the gate.

    .. math::
        \tilde d(p) = \begin{cases} d(p) & d(p) \le g \\ 0 & d(p) > g \end{cases}

    Far returns (no-photon pixels at 5 m, multipath) drop out, so a depth bucket
    grows with the lit area instead of falling. Differentiable everywhere except at
    ``d = g`` (gradient 1 on kept pixels, 0 on gated ones).

    Args:
        depth: depth frames in metres.
        gate_m: gate distance ``g`` in metres, ``> 0`` (paper: 3 m).

    Returns:
        Gated depth, same shape and dtype.

    Raises:
        TypeError: if ``depth`` is not a floating tensor.
        ValueError: if ``depth`` is not rank 4, holds NaN/Inf, or ``gate_m <= 0``.

    Shape:
        - depth: :math:`(B, M, H, W)`.
        - Output: :math:`(B, M, H, W)`.

    Example:
        >>> depth_gate(torch.tensor([[[[2.0, 5.0]]]])).tolist()
        [[[[2.0, 0.0]]]]
    """
    func = "depth_gate"
    _check_frames(depth, 4, "depth", func, "(B, M, H, W)")
    check_finite(depth, "depth", func)
    gate = check_positive(gate_m, "gate_m", func)
    return torch.where(depth > gate, torch.zeros_like(depth), depth)


class DepthGate(nn.Module):
    """Module wrapper of :func:`depth_gate` (paper §3.1 "low-pass filter")."""

    def __init__(self, gate_m: float = PAPER_GATE_M) -> None:
        super().__init__()
        self.gate_m = check_positive(gate_m, "gate_m", "DepthGate")

    def forward(self, depth: torch.Tensor) -> torch.Tensor:
        return depth_gate(depth, self.gate_m)


def depth_bucket(
    depth: torch.Tensor, roi: object = None, gate_m: float | None = None
) -> torch.Tensor:
    r"""Depth bucket ``D_i = Σ_{p∈ROI} d_i(p)`` of each frame (paper Eq. 10).

    .. math::
        D_i = \sum_{p \in \mathrm{ROI}} \tilde d_i(p), \quad
        \tilde d = d \text{ (no gate) or } \operatorname{depth\_gate}(d, g)

    Without a gate the images reconstructed from ``D_i`` are negative (§3.1:
    no-photon pixels read 5 m, more light → smaller ``D_i``); with ``gate_m`` (3 m in
    the paper, :data:`PAPER_GATE_M`) they come out positive.

    Args:
        depth: ToF depth frames in metres, one per pattern.
        roi: ``None``, ``(top, left, height, width)`` or a bool ``(H, W)`` mask
            (see :func:`roi_mask`).
        gate_m: depth gate in metres, or ``None`` for the raw sum.

    Returns:
        Buckets as measurements with one channel.

    Raises:
        TypeError: if ``depth`` is not a floating tensor or ``roi`` has the wrong type.
        ValueError: if ``depth`` is not rank 4, holds NaN/Inf, ``gate_m <= 0``, or the
            ROI is empty.

    Shape:
        - depth: :math:`(B, M, H, W)`.
        - Output: :math:`(B, 1, M)`.

    Example:
        >>> d = torch.tensor([[[[2.0, 5.0]], [[5.0, 5.0]]]])  # B=1, M=2, 1x2 frames
        >>> depth_bucket(d).tolist(), depth_bucket(d, gate_m=3.0).tolist()
        ([[[7.0, 10.0]]], [[[2.0, 0.0]]])
    """
    func = "depth_bucket"
    _check_frames(depth, 4, "depth", func, "(B, M, H, W)")
    check_finite(depth, "depth", func)
    if gate_m is not None:
        check_positive(gate_m, "gate_m", func)  # named here, not as depth_gate's
        depth = depth_gate(depth, gate_m)
    return _roi_sum(depth, roi, func, "depth").unsqueeze(1)


class _RoiModule(nn.Module):
    """Holds a ROI: a bool mask as a non-persistent buffer, or a box as a tuple."""

    def __init__(self, roi: object, name: str) -> None:
        super().__init__()
        mask, box = None, None
        if isinstance(roi, torch.Tensor):
            if roi.dtype != torch.bool:
                raise TypeError(f"{name}: expected roi mask of dtype torch.bool, got {roi.dtype}")
            if roi.ndim != 2:
                raise ValueError(
                    f"{name}: expected roi mask of shape (H, W), got {tuple(roi.shape)}"
                )
            if not bool(roi.any()):
                raise ValueError(f"{name}: roi mask selects no pixel (empty ROI)")
            mask = roi.clone()
        elif roi is not None:
            if not isinstance(roi, Sequence) or isinstance(roi, str):
                raise TypeError(
                    f"{name}: expected roi to be None, (top, left, height, width) or a bool "
                    f"tensor, got {type(roi).__name__}"
                )
            box = _check_box(roi, name)
        self.register_buffer("roi_mask", mask, persistent=False)
        self.roi_box = box

    @property
    def roi(self) -> torch.Tensor | tuple[int, int, int, int] | None:
        """The ROI as passed to the functions (mask buffer, box tuple or ``None``)."""
        return self.roi_mask if self.roi_mask is not None else self.roi_box


class DepthBucket(_RoiModule):
    """Module wrapper of :func:`depth_bucket` (paper Eq. 10).

    Args:
        roi: ``None``, ``(top, left, height, width)`` or a bool ``(H, W)`` mask.
        gate_m: depth gate in metres or ``None``; the paper's filtered runs use
            :data:`PAPER_GATE_M` = 3 m. Without the gate, images come out negative.
    """

    def __init__(self, roi: object = None, gate_m: float | None = None) -> None:
        super().__init__(roi, "DepthBucket")
        self.gate_m = None if gate_m is None else check_positive(gate_m, "gate_m", "DepthBucket")

    def forward(self, depth: torch.Tensor) -> torch.Tensor:
        return depth_bucket(depth, self.roi, self.gate_m)


def intensity_bucket(amplitude: torch.Tensor, roi: object = None) -> torch.Tensor:
    r"""Intensity bucket ``S_i = Σ_{p∈ROI} a_i(p)`` of each frame (the ``S_i`` of Eq. 9).

    .. math::
        S_i = \sum_{p \in \mathrm{ROI}} a_i(p)

    A sum over the ROI, so linear in the per-pixel values it is given. With the offset
    (intensity) image those are linear in the light; the ToF amplitude (Eq. 8) is not:
    it is ``½|P|`` of the phasor sum of every return on the pixel, so where two returns
    overlap (stray light, multipath, a scattering sheet) ``½|P₁ + P₂| ≤ ½|P₁| + ½|P₂|`` and
    the bucket of the object's light depends on the phases of the others (it can even fall
    as more light arrives).

    Args:
        amplitude: amplitude/intensity frames, one per pattern.
        roi: ``None``, ``(top, left, height, width)`` or a bool ``(H, W)`` mask.

    Returns:
        Buckets as measurements with one channel.

    Raises:
        TypeError: if ``amplitude`` is not a floating tensor or ``roi`` has the wrong type.
        ValueError: if ``amplitude`` is not rank 4, holds NaN/Inf, or the ROI is empty.

    Shape:
        - amplitude: :math:`(B, M, H, W)`.
        - Output: :math:`(B, 1, M)`.

    Example:
        >>> intensity_bucket(torch.ones(2, 5, 3, 3)).shape
        torch.Size([2, 1, 5])
    """
    func = "intensity_bucket"
    _check_frames(amplitude, 4, "amplitude", func, "(B, M, H, W)")
    check_finite(amplitude, "amplitude", func)
    return _roi_sum(amplitude, roi, func, "amplitude").unsqueeze(1)


class IntensityBucket(_RoiModule):
    """Module wrapper of :func:`intensity_bucket` (``S_i`` of Eq. 9)."""

    def __init__(self, roi: object = None) -> None:
        super().__init__(roi, "IntensityBucket")

    def forward(self, amplitude: torch.Tensor) -> torch.Tensor:
        return intensity_bucket(amplitude, self.roi)


def tap_buckets(taps: torch.Tensor, roi: object = None) -> torch.Tensor:
    r"""Per-tap buckets ``C_{k,i} = Σ_{p∈ROI} c_{k,i}(p)`` (Eq. 6 taps, depth-resolved CGI).

    .. math::
        C_{k,i} = \sum_{p \in \mathrm{ROI}} c_{k,i}(p), \quad k = 1, \dots, 4

    Each tap ``c_k = B + (a/2) cos(θ + τ_k)`` (Eq. 6) is linear in the light, so the
    bucket is linear in the scene: ``tap_buckets(a + b) = tap_buckets(a) +
    tap_buckets(b)``, and CGI on each tap gives one tap image. The tap order is kept
    as given (the sensor's order).

    Args:
        taps: correlation-tap frames, one per pattern.
        roi: ``None``, ``(top, left, height, width)`` or a bool ``(H, W)`` mask.

    Returns:
        Buckets as measurements with four channels (one per tap).

    Raises:
        TypeError: if ``taps`` is not a floating tensor or ``roi`` has the wrong type.
        ValueError: if ``taps`` is not ``(B, M, 4, H, W)``, holds NaN/Inf, or the ROI is
            empty.

    Shape:
        - taps: :math:`(B, M, 4, H, W)`.
        - Output: :math:`(B, 4, M)`.

    Example:
        >>> tap_buckets(torch.ones(1, 3, 4, 2, 2)).shape
        torch.Size([1, 4, 3])
    """
    func = "tap_buckets"
    _check_frames(taps, 5, "taps", func, "(B, M, 4, H, W)")
    if taps.shape[2] != 4:
        raise ValueError(f"{func}: expected taps of shape (B, M, 4, H, W), got {tuple(taps.shape)}")
    check_finite(taps, "taps", func)
    return _roi_sum(taps, roi, func, "taps").transpose(1, 2)


class TapBuckets(_RoiModule):
    """Module wrapper of :func:`tap_buckets`."""

    def __init__(self, roi: object = None) -> None:
        super().__init__(roi, "TapBuckets")

    def forward(self, taps: torch.Tensor) -> torch.Tensor:
        return tap_buckets(taps, self.roi)
