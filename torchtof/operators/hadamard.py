"""Hadamard measurement operator with orthonormal rows, by a fast transform.

``A = P H_N / √N`` (DESIGN.md §2): ``H_N = H_n ⊗ H_n`` the 2-D Sylvester basis,
``P`` selects the first ``M`` rows of an order (:mod:`.patterns`). Then
``A Aᵀ = I`` and ``A⁺ = Aᵀ``. Two exact implementations of ``H_N`` on an
``n × n`` image, never an ``N × N`` matrix:

- ``"matmul"``: separable ``H_n X H_n`` (two ``n × n`` matmuls, O(n³) = O(N^1.5), BLAS);
- ``"fwht"``: butterfly Walsh–Hadamard transform, O(N log N).

``method="auto"`` takes the one that ``torchtof bench operators`` measured faster on
CPU at that size (:data:`AUTO_FWHT_MIN_N`).
"""

from __future__ import annotations

import torch

from .base import LinearOperator
from .fwht import fwht2, sylvester
from .patterns import _check_n_order, hadamard_order, num_patterns

__all__ = ["Hadamard", "hadamard_forward", "hadamard_adjoint", "AUTO_FWHT_MIN_N"]

#: From ``torchtof bench operators`` on 2 CPU cores: matmul wins up to this size (exclusive).
AUTO_FWHT_MIN_N = 256
METHODS = ("auto", "matmul", "fwht")


def _transform(x: torch.Tensor, h: torch.Tensor | None) -> torch.Tensor:
    """Unnormalised ``H_n X H_n`` on the last two axes (``h=None`` → butterflies)."""
    if h is None:
        return fwht2(x)
    return h @ x @ h


def hadamard_forward(
    x: torch.Tensor, index: torch.Tensor, h: torch.Tensor | None = None
) -> torch.Tensor:
    """``y = P H_N x / √N`` for images ``x``.

    Args:
        x: images ``(B, C, n, n)``.
        index: natural indices ``(M,)`` of the selected rows (:func:`hadamard_order`).
        h: Sylvester ``H_n`` (``(n, n)``, dtype of ``x``) for the matmul path, or ``None``
            for the butterfly path.

    Returns:
        ``(B, C, M)`` coefficients ``⟨h_{ij}, x⟩ / n``.
    """
    n = x.shape[-1]
    if x.dtype in (torch.float16, torch.bfloat16):  # H X H reaches n²·max|x| before the /n
        h32 = None if h is None else h.float()
        return hadamard_forward(x.float(), index, h32).to(x.dtype)
    coef = _transform(x, h).reshape(*x.shape[:-2], n * n)
    return coef.index_select(-1, index) / n


def hadamard_adjoint(
    y: torch.Tensor, index: torch.Tensor, n: int, h: torch.Tensor | None = None
) -> torch.Tensor:
    """``x = Aᵀ y = H_Nᵀ Pᵀ y / √N``: scatter into the coefficient grid, transform back."""
    if y.dtype in (torch.float16, torch.bfloat16):  # see hadamard_forward
        h32 = None if h is None else h.float()
        return hadamard_adjoint(y.float(), index, n, h32).to(y.dtype)
    coef = y.new_zeros(*y.shape[:-1], n * n)
    coef = coef.index_copy(-1, index, y / n)  # out of place: autograd + ONNX (ScatterND)
    return _transform(coef.reshape(*y.shape[:-1], n, n), h)


class Hadamard(LinearOperator):
    """2-D Hadamard sampling with orthonormal rows (``A Aᵀ = I``).

    Args:
        n: DMD side, power of two in [4, 256].
        sr: sampling rate ``M / n²`` in (0, 1] (give ``sr`` or ``m``).
        m: number of patterns in [1, n²].
        order: ``"cake_cutting"`` (default), ``"natural"``, ``"sequency"``, ``"russian_doll"``.
        method: ``"auto"``, ``"matmul"`` or ``"fwht"`` (see module docstring).

    Shape:
        ``(B, C, n, n) -> (B, C, M)``; ``adjoint``/``pinv``: ``(B, C, M) -> (B, C, n, n)``.

    Example:
        >>> A = Hadamard(n=32, sr=0.25)
        >>> A(torch.rand(2, 1, 32, 32)).shape
        torch.Size([2, 1, 256])
    """

    orthonormal_rows = True

    def __init__(
        self,
        n: int,
        sr: float | None = None,
        m: int | None = None,
        order: str = "cake_cutting",
        method: str = "auto",
    ) -> None:
        _check_n_order(n, order, "Hadamard")
        if sr is None and m is None:
            m = n * n
        m = num_patterns(n, sr, m, func="Hadamard")
        if method not in METHODS:
            raise ValueError(f"Hadamard: expected method in {METHODS}, got {method!r}")
        super().__init__(n, m)
        self.order = order
        self.method = ("fwht" if n >= AUTO_FWHT_MIN_N else "matmul") if method == "auto" else method
        self.register_buffer("index", hadamard_order(n, order)[:m], persistent=False)
        self.register_buffer("h", sylvester(n, torch.float32), persistent=False)

    @property
    def sr(self) -> float:
        return self.m / (self.n * self.n)

    def _h(self, like: torch.Tensor) -> torch.Tensor | None:
        if self.method == "fwht":
            return None
        return self.h.to(dtype=like.dtype, device=like.device)  # ±1: exact in any dtype

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        self._check_x(x, "Hadamard.forward")
        return hadamard_forward(x, self.index, self._h(x))

    def adjoint(self, y: torch.Tensor) -> torch.Tensor:
        self._check_y(y, "Hadamard.adjoint")
        return hadamard_adjoint(y, self.index, self.n, self._h(y))

    def pinv(self, y: torch.Tensor) -> torch.Tensor:
        """``A⁺ y = Aᵀ y`` (orthonormal rows)."""
        return self.adjoint(y)

    def patterns(self, dtype: torch.dtype = torch.float32) -> torch.Tensor:
        """The selected ±1 patterns ``(M, n, n)`` (unnormalised: row ``r`` of ``A`` is
        ``patterns[r] / n``)."""
        h = self.h.to(dtype)
        i, j = self.index // self.n, self.index % self.n
        return h[i][:, :, None] * h[j][:, None, :]

    def extra_repr(self) -> str:
        return f"n={self.n}, m={self.m}, sr={self.sr:.4g}, order={self.order!r}, method={self.method!r}"

