"""DMD → ToF sensor imaging: area-overlap resampling of phasors (mixed/flying pixels).

The DMD plane (``H × W`` mirrors, the paper's 32×32) is imaged onto a ``P₁ × P₂`` region of
the ToF sensor (pixel ``p``: ``a_p e^{jθ_p} = Σ_u K_{pu} O(u) φ_i(u) ρ e^{j4πf z(u)/c}``).
Each sensor pixel integrates the light of the DMD area it sees, so ``K`` is the area
overlap of the two pixel grids, normalised per sensor pixel (rows sum to 1: each sensor
pixel reports the area-weighted average). The map is separable,

.. math::

    S = K_r\\, X\\, K_c^{\\mathsf T}, \\qquad
    (K_r)_{pu} = \\frac{|[p\\,H/P_1, (p+1)\\,H/P_1) ∩ [u, u+1)|}{H/P_1},

and ``K_c`` likewise for the columns. When ``P/n`` is an integer every DMD mirror images
onto an exact block of sensor pixels (block replication). Otherwise sensor pixels on
block borders straddle two mirrors and mix their phasors — at a depth edge that is a
flying (mixed) pixel, whose phase is ``arg`` of the area-weighted phasor sum
(neither depth, in general). Applied to phasors (complex) the map is linear in the light; it also
accepts real images (intensities). Because rows sum to 1 a uniform field keeps its value
per pixel; the total over the region scales by ``P₁P₂/(HW)`` (multiply by ``HW/(P₁P₂)``
where photo-electron counts must be conserved).

:func:`blur_phasor` is the other spatial mixing the simulator uses: a Gaussian blur of the
real and imaginary parts (spread multipath, forward scatter).
"""

from __future__ import annotations

import functools
import math

import torch
from torch import nn
from torch.nn import functional as F

from .._checks import (
    built_for_cache,
    check_finite,
    check_float_dtype,
    check_positive,
    check_rank,
    check_tensor,
)
from .._memory import check_memory

__all__ = ["area_overlap_matrix", "dmd_to_sensor", "DMDToSensor", "blur_phasor"]


def _check_size(value: object, name: str, func: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise TypeError(f"{func}: expected {name} to be an int, got {type(value).__name__}")
    if value < 1:
        raise ValueError(f"{func}: expected {name} >= 1, got {value}")
    return value


def size_pair(value: object, name: str, func: str) -> tuple[int, int]:
    if isinstance(value, (tuple, list)):
        if len(value) != 2:
            raise ValueError(f"{func}: expected {name} to be (rows, cols), got {value!r}")
        return _check_size(value[0], name, func), _check_size(value[1], name, func)
    size = _check_size(value, name, func)
    return size, size


@functools.lru_cache(maxsize=64)
@built_for_cache
def _overlap_cpu(n_in: int, n_out: int) -> torch.Tensor:
    """Row-normalised area overlap ``(n_out, n_in)`` in float64, exact integer arithmetic."""
    # in units of 1/(n_in·n_out): output pixel p spans [p·n_in, (p+1)·n_in),
    # input pixel u spans [u·n_out, (u+1)·n_out); each output pixel has length n_in.
    p = torch.arange(n_out, dtype=torch.int64).view(-1, 1)
    u = torch.arange(n_in, dtype=torch.int64).view(1, -1)
    hi = torch.minimum((p + 1) * n_in, (u + 1) * n_out)
    lo = torch.maximum(p * n_in, u * n_out)
    return (hi - lo).clamp_min(0).to(torch.float64) / n_in


def area_overlap_matrix(
    n_in: int,
    n_out: int,
    dtype: torch.dtype | None = None,
    device: torch.device | str | None = None,
) -> torch.Tensor:
    """One-dimensional area-overlap resampling matrix ``K`` (rows sum to 1).

    ``K[p, u]`` is the fraction of output pixel ``p`` covered by input pixel ``u`` when both
    grids span the same length (box integration; see the module docstring).

    Args:
        n_in: number of input pixels (DMD mirrors along one axis), ``≥ 1``.
        n_out: number of output pixels (sensor pixels along that axis), ``≥ 1``.
        dtype: floating dtype of the result (default: ``torch.get_default_dtype()``; the
            weights are fractions, an integer dtype would truncate them).
        device: device of the result.

    Returns:
        ``(n_out, n_in)`` non-negative matrix with unit row sums.

    Raises:
        TypeError: if a size is not an int or ``dtype`` not a floating dtype.
        ValueError: if a size is below 1.

    Example:
        >>> area_overlap_matrix(2, 3)
        tensor([[1.0000, 0.0000],
                [0.5000, 0.5000],
                [0.0000, 1.0000]])
    """
    func = "area_overlap_matrix"
    _check_size(n_in, "n_in", func)
    _check_size(n_out, "n_out", func)
    dtype = torch.get_default_dtype() if dtype is None else check_float_dtype(dtype, "dtype", func)
    check_memory(3 * n_in * n_out * 8, f"an {n_out}x{n_in} overlap matrix", func)
    return _overlap_cpu(n_in, n_out).to(dtype=dtype, device=device, copy=True)


def _apply(x: torch.Tensor, k_rows: torch.Tensor, k_cols: torch.Tensor) -> torch.Tensor:
    if x.is_complex():  # real matrices: map Re and Im (complex32 has no matmul kernel)
        return torch.complex(_apply(x.real, k_rows, k_cols), _apply(x.imag, k_rows, k_cols))
    k_rows = k_rows.to(dtype=x.dtype, device=x.device)
    k_cols = k_cols.to(dtype=x.dtype, device=x.device)
    return k_rows @ x @ k_cols.transpose(0, 1)


def _check_input(x: object, func: str) -> torch.Tensor:
    check_tensor(x, "x", func)
    check_rank(x, 4, "x", func, "(B, C, H, W)")
    check_finite(x, "x", func)
    return x


def dmd_to_sensor(x: torch.Tensor, out_hw: int | tuple[int, int]) -> torch.Tensor:
    """Image a DMD-plane field onto the ToF sensor by area overlap, ``S = K_r X K_cᵀ``.

    Args:
        x: ``(B, C, H, W)`` DMD-plane phasors (complex) or intensities (real).
        out_hw: sensor region ``(P₁, P₂)`` (or one int for a square region).

    Returns:
        ``(B, C, P₁, P₂)`` sensor-plane field, same dtype as ``x``. Integer ``P/H`` gives
        exact block replication; otherwise border pixels mix neighbouring mirrors.

    Raises:
        TypeError: if ``x`` is not a floating/complex tensor or a size is not an int.
        ValueError: on a wrong rank, non-finite input or a size below 1.

    Shape:
        - x: :math:`(B, C, H, W)`
        - output: :math:`(B, C, P_1, P_2)`

    Example:
        >>> x = torch.arange(4.0).view(1, 1, 2, 2)
        >>> dmd_to_sensor(x, (4, 4))[0, 0]
        tensor([[0., 0., 1., 1.],
                [0., 0., 1., 1.],
                [2., 2., 3., 3.],
                [2., 2., 3., 3.]])
    """
    func = "dmd_to_sensor"
    _check_input(x, func)
    p1, p2 = size_pair(out_hw, "out_hw", func)
    return _apply(x, _overlap_cpu(x.shape[-2], p1), _overlap_cpu(x.shape[-1], p2))


class DMDToSensor(nn.Module):
    """Module wrapper of :func:`dmd_to_sensor` with the two matrices as buffers.

    The matrices are built once at construction (float64, non-persistent buffers) and cast
    to the input's dtype/device in ``forward``.

    Args:
        in_hw: DMD size ``(H, W)`` or one int ``n``.
        out_hw: sensor region ``(P₁, P₂)`` or one int.

    Example:
        >>> m = DMDToSensor(32, 64)
        >>> m(torch.zeros(2, 1, 32, 32, dtype=torch.complex64)).shape
        torch.Size([2, 1, 64, 64])
    """

    k_rows: torch.Tensor
    k_cols: torch.Tensor

    def __init__(self, in_hw: int | tuple[int, int], out_hw: int | tuple[int, int]) -> None:
        super().__init__()
        func = "DMDToSensor"
        self.in_hw = size_pair(in_hw, "in_hw", func)
        self.out_hw = size_pair(out_hw, "out_hw", func)
        rows = area_overlap_matrix(self.in_hw[0], self.out_hw[0], torch.float64)
        cols = area_overlap_matrix(self.in_hw[1], self.out_hw[1], torch.float64)
        self.register_buffer("k_rows", rows, persistent=False)
        self.register_buffer("k_cols", cols, persistent=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        func = "DMDToSensor"
        _check_input(x, func)
        if tuple(x.shape[-2:]) != self.in_hw:
            raise ValueError(
                f"{func}: expected x of shape (B, C, {self.in_hw[0]}, {self.in_hw[1]}), "
                f"got {tuple(x.shape)}"
            )
        return _apply(x, self.k_rows, self.k_cols)

    def extra_repr(self) -> str:
        return f"in_hw={self.in_hw}, out_hw={self.out_hw}"


def blur_phasor(x: torch.Tensor, sigma_px: float) -> torch.Tensor:
    """Gaussian blur of a phasor (or real) image, applied to real and imaginary parts.

    The blur is linear, so blurring ``Re P`` and ``Im P`` separately blurs the phasor:
    neighbouring returns add as phasors (forward scatter of a sheet, spread multipath
    returns). The kernel of ``kornia.filters.gaussian_blur2d`` with reflect borders: sampled
    at integer offsets up to a radius ``⌈3σ⌉`` (clipped per axis to the image, ``H − 1`` for
    the column and ``W − 1`` for the row kernel, so the reflection is defined) and normalised
    to sum 1, applied as a row and a column convolution.

    Args:
        x: ``(B, C, H, W)`` complex phasors or real image.
        sigma_px: standard deviation in pixels, ``> 0``.

    Returns:
        Blurred ``(B, C, H, W)``, same dtype.

    Raises:
        TypeError: if ``x`` is not a floating/complex tensor.
        ValueError: on a wrong rank, non-finite input or a non-positive ``sigma_px``.

    Example:
        >>> p = torch.full((1, 1, 8, 8), 1.0 + 1.0j)
        >>> torch.allclose(blur_phasor(p, 1.5), p)  # a constant field is unchanged
        True
    """
    func = "blur_phasor"
    _check_input(x, func)
    sigma = check_positive(sigma_px, "sigma_px", func)
    full = math.ceil(3.0 * sigma)
    radius = (min(full, x.shape[-2] - 1), min(full, x.shape[-1] - 1))  # (rows, cols)
    if not x.is_complex():
        return _blur_real(x, radius, sigma)
    c = x.shape[1]
    parts = _blur_real(torch.cat([x.real, x.imag], dim=1), radius, sigma)
    return torch.complex(parts[:, :c], parts[:, c:])


@functools.lru_cache(maxsize=64)
def _gauss_taps(radius: int, sigma: float) -> tuple[float, ...]:
    """Taps ``exp(−k²/2σ²)`` for ``k = −radius … radius``, normalised to sum 1 (float64)."""
    w = [math.exp(-0.5 * (k / sigma) ** 2) for k in range(-radius, radius + 1)]
    total = math.fsum(w)
    return tuple(v / total for v in w)


def _blur_real(x: torch.Tensor, radius: tuple[int, int], sigma: float) -> torch.Tensor:
    """Separable Gaussian blur of a real ``(B, C, H, W)`` image with reflected borders: the
    kernel of ``kornia.filters.gaussian_blur2d`` (sampled, normalised), built once per
    ``(radius, σ)`` and applied as a row then a column convolution of every channel;
    ``radius = (r_H, r_W)``, the column and the row kernel's (0: no blur along that axis)."""
    r_h, r_w = radius
    if r_h == 0 and r_w == 0:
        return x
    b, c, h, w = x.shape
    z = F.pad(x.reshape(b * c, 1, h, w), (r_w, r_w, r_h, r_h), mode="reflect")
    if r_w:
        k = torch.tensor(_gauss_taps(r_w, sigma), dtype=x.dtype, device=x.device)
        z = F.conv2d(z, k.view(1, 1, 1, -1))
    if r_h:
        k = torch.tensor(_gauss_taps(r_h, sigma), dtype=x.dtype, device=x.device)
        z = F.conv2d(z, k.view(1, 1, -1, 1))
    return z.reshape(b, c, h, w)
