"""Orthonormal 2-D sparsity bases: DCT-II and the multilevel Haar wavelet.

Both act on the last two axes of ``(…, n, n)`` tensors and are orthonormal, so the
inverse is the transpose (adjoint) and ``‖dct2(x)‖ = ‖x‖``. They are the ``Ψ`` of basis
pursuit, ``min ‖Ψᵀx‖₁ s.t. Ax = y`` (Candès & Romberg 2005):

- DCT-II with orthonormal scaling (Ahmed, Natarajan & Rao 1974; the ``norm="ortho"``
  convention of ``scipy.fft.dctn``): ``C = D X Dᵀ`` with the ``n × n`` matrix

  .. math:: D_{ki} = \\alpha_k \\cos\\frac{\\pi (2i + 1) k}{2n},\\quad
            \\alpha_0 = \\sqrt{1/n},\\ \\alpha_{k>0} = \\sqrt{2/n},

  applied as two matmuls with a cached matrix (exact inverse ``X = Dᵀ C D``);
- Haar (Mallat 1989, the 2-D "non-standard" pyramid of ``pywt.wavedec2``): each level
  maps the top-left ``s × s`` block to averages and differences
  ``(a ± b)/√2`` of neighbouring rows, then of neighbouring columns, leaving the
  approximation in the top-left ``s/2 × s/2`` block; ``n`` must be a power of two.
"""

from __future__ import annotations

import math
from functools import lru_cache

import torch
from torch import nn

from .._checks import built_for_cache, check_power_of_two, check_tensor, is_tracing

__all__ = ["dct_matrix", "dct2", "idct2", "haar2", "ihaar2", "DCT2", "Haar2"]


def _dct_matrix(n: int, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    # Under torch.export/onnx tracing the tensor would be a fake one: never cache it then.
    if is_tracing():
        return _dct_matrix_uncached(n, dtype, device)
    return _dct_matrix_cached(n, dtype, device)


@lru_cache(maxsize=32)
@built_for_cache
def _dct_matrix_cached(n: int, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    return _dct_matrix_uncached(n, dtype, device)


def _dct_matrix_uncached(n: int, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    k = torch.arange(n, dtype=torch.float64)[:, None]
    i = torch.arange(n, dtype=torch.float64)[None, :]
    d = torch.cos(math.pi * (2 * i + 1) * k / (2 * n)) * math.sqrt(2.0 / n)
    d[0] = d[0] / math.sqrt(2.0)
    return d.to(dtype=dtype, device=device)


def dct_matrix(n: int, dtype: torch.dtype = torch.float64, device=None) -> torch.Tensor:
    """Orthonormal DCT-II matrix ``D`` of shape ``(n, n)`` (``D Dᵀ = I``; Ahmed et al. 1974).

    Built in float64 and cast; cached per ``(n, dtype, device)``.

    Args:
        n: transform length, ``n >= 1``.
        dtype: floating-point dtype of the result.
        device: device of the result.

    Returns:
        ``D`` with ``D[k, i] = α_k cos(π (2i + 1) k / (2n))``.

    Raises:
        TypeError, ValueError: ``n`` not a positive int.

    Example:
        >>> D = dct_matrix(4)
        >>> torch.allclose(D @ D.T, torch.eye(4, dtype=torch.float64))
        True
    """
    if isinstance(n, bool) or not isinstance(n, int):
        raise TypeError(f"dct_matrix: expected n to be an int, got {type(n).__name__}")
    if n < 1:
        raise ValueError(f"dct_matrix: expected n >= 1, got {n}")
    return _dct_matrix(n, dtype, torch.device("cpu" if device is None else device))


def _square(x: torch.Tensor, func: str) -> int:
    check_tensor(x, "x", func)
    if x.ndim < 2 or x.shape[-1] != x.shape[-2]:
        raise ValueError(f"{func}: expected x of shape (..., n, n), got {tuple(x.shape)}")
    return int(x.shape[-1])


def _matrix_for(x: torch.Tensor, matrix: torch.Tensor | None, func: str) -> torch.Tensor:
    n = _square(x, func)
    if matrix is None:
        return dct_matrix(n, x.dtype, x.device)
    if matrix.shape != (n, n):
        raise ValueError(f"{func}: expected matrix of shape ({n}, {n}), got {tuple(matrix.shape)}")
    return matrix.to(dtype=x.dtype, device=x.device)


def dct2(x: torch.Tensor, matrix: torch.Tensor | None = None) -> torch.Tensor:
    """Orthonormal 2-D DCT-II on the last two axes: ``C = D X Dᵀ`` (Ahmed et al. 1974).

    Equal to ``scipy.fft.dctn(x, type=2, norm="ortho", axes=(-2, -1))``.

    Args:
        x: ``(…, n, n)`` real tensor.
        matrix: optional precomputed :func:`dct_matrix` ``(n, n)`` (avoids the cache look-up
            inside iterative solvers).

    Returns:
        Coefficients ``(…, n, n)``; ``C[..., 0, 0]`` is ``n`` times the mean.

    Raises:
        TypeError: ``x`` not a floating-point tensor.
        ValueError: ``x`` not square in its last two axes, or ``matrix`` of the wrong shape.

    Shape:
        ``(…, n, n) -> (…, n, n)``.

    Example:
        >>> dct2(torch.ones(1, 1, 4, 4))[0, 0, 0, 0]
        tensor(4.)
    """
    d = _matrix_for(x, matrix, "dct2")
    return d @ x @ d.transpose(-1, -2)


def idct2(c: torch.Tensor, matrix: torch.Tensor | None = None) -> torch.Tensor:
    """Inverse of :func:`dct2` (its transpose, the orthonormal DCT-III): ``X = Dᵀ C D``.

    Args:
        c: coefficients ``(…, n, n)``.
        matrix: optional precomputed :func:`dct_matrix` ``(n, n)``.

    Returns:
        Image ``(…, n, n)``.

    Raises:
        TypeError, ValueError: as :func:`dct2`.

    Shape:
        ``(…, n, n) -> (…, n, n)``.

    Example:
        >>> x = torch.rand(2, 1, 8, 8, dtype=torch.float64)
        >>> torch.allclose(idct2(dct2(x)), x)
        True
    """
    d = _matrix_for(c, matrix, "idct2")
    return d.transpose(-1, -2) @ c @ d


def _haar_levels(n: int, levels: int | None, func: str) -> int:
    check_power_of_two(n, "n (the image side)", func)
    full = n.bit_length() - 1
    if levels is None:
        return full
    if isinstance(levels, bool) or not isinstance(levels, int):
        raise TypeError(f"{func}: expected levels to be an int, got {type(levels).__name__}")
    if not 0 <= levels <= full:
        raise ValueError(f"{func}: expected levels in [0, {full}] for n={n}, got {levels}")
    return levels


def _paste(c: torch.Tensor, blk: torch.Tensor) -> torch.Tensor:
    """Replace the top-left block of ``c`` by ``blk`` (out of place, ONNX-friendly)."""
    s = blk.shape[-1]
    top = torch.cat((blk, c[..., :s, s:]), dim=-1)
    return torch.cat((top, c[..., s:, :]), dim=-2)


def haar2(x: torch.Tensor, levels: int | None = None) -> torch.Tensor:
    """Orthonormal multilevel 2-D Haar wavelet transform (Mallat 1989, non-standard pyramid).

    One level on an ``s × s`` block: rows ``(x_{2i} ± x_{2i+1})/√2`` (averages on top,
    differences below), then the same on columns; the next level works on the top-left
    ``s/2 × s/2`` approximation.

    Args:
        x: ``(…, n, n)`` with ``n`` a power of two.
        levels: number of levels in ``[0, log2 n]`` (default ``log2 n``: full pyramid,
            ``[..., 0, 0]`` is ``n`` times the mean).

    Returns:
        Coefficients ``(…, n, n)`` in the ``pywt.coeffs_to_array`` layout.

    Raises:
        TypeError: ``x`` not a floating-point tensor, ``levels`` not an int.
        ValueError: ``x`` not square, ``n`` not a power of two, ``levels`` out of range.

    Shape:
        ``(…, n, n) -> (…, n, n)``.

    Example:
        >>> c = haar2(torch.ones(1, 1, 4, 4, dtype=torch.float64))
        >>> round(float(c[0, 0, 0, 0]), 12), float(c.abs().sum() - c[0, 0, 0, 0].abs())
        (4.0, 0.0)
    """
    n = _square(x, "haar2")
    r = 1.0 / math.sqrt(2.0)
    c = x
    for level in range(_haar_levels(n, levels, "haar2")):
        blk = c[..., : n >> level, : n >> level]
        e, o = blk[..., 0::2, :], blk[..., 1::2, :]
        blk = torch.cat((e + o, e - o), dim=-2) * r
        e, o = blk[..., 0::2], blk[..., 1::2]
        blk = torch.cat((e + o, e - o), dim=-1) * r
        c = _paste(c, blk)
    return c


def ihaar2(c: torch.Tensor, levels: int | None = None) -> torch.Tensor:
    """Inverse (= transpose) of :func:`haar2` with the same ``levels``.

    Args:
        c: coefficients ``(…, n, n)``, ``n`` a power of two.
        levels: as in :func:`haar2`.

    Returns:
        Image ``(…, n, n)``.

    Raises:
        TypeError, ValueError: as :func:`haar2`.

    Shape:
        ``(…, n, n) -> (…, n, n)``.

    Example:
        >>> x = torch.rand(1, 1, 8, 8, dtype=torch.float64)
        >>> torch.allclose(ihaar2(haar2(x)), x)
        True
    """
    n = _square(c, "ihaar2")
    r = 1.0 / math.sqrt(2.0)
    x = c
    for level in reversed(range(_haar_levels(n, levels, "ihaar2"))):
        s = n >> level
        blk = x[..., :s, :s]
        a, d = blk[..., : s // 2], blk[..., s // 2 :]
        blk = torch.stack(((a + d) * r, (a - d) * r), dim=-1).flatten(-2)
        a, d = blk[..., : s // 2, :], blk[..., s // 2 :, :]
        blk = torch.stack(((a + d) * r, (a - d) * r), dim=-2).flatten(-3, -2)
        x = _paste(x, blk)
    return x


class DCT2(nn.Module):
    """Module of :func:`dct2` with the DCT matrix as a non-persistent buffer.

    Args:
        n: image side.

    Shape:
        ``forward``: ``(…, n, n) -> (…, n, n)``; :meth:`inverse` likewise.

    Example:
        >>> DCT2(4)(torch.ones(1, 1, 4, 4))[0, 0, 0, 0]
        tensor(4.)
    """

    def __init__(self, n: int) -> None:
        super().__init__()
        self.register_buffer("matrix", dct_matrix(n, torch.float64).clone(), persistent=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return dct2(x, self.matrix)

    def inverse(self, c: torch.Tensor) -> torch.Tensor:
        """:func:`idct2`."""
        return idct2(c, self.matrix)


class Haar2(nn.Module):
    """Module of :func:`haar2`.

    Args:
        n: image side, a power of two.
        levels: number of levels (default ``log2 n``).

    Shape:
        ``forward``: ``(…, n, n) -> (…, n, n)``; :meth:`inverse` likewise.
    """

    def __init__(self, n: int, levels: int | None = None) -> None:
        super().__init__()
        self.n = n
        self.levels = _haar_levels(n, levels, "Haar2")

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return haar2(x, self.levels)

    def inverse(self, c: torch.Tensor) -> torch.Tensor:
        """:func:`ihaar2`."""
        return ihaar2(c, self.levels)
