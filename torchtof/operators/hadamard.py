"""Hadamard measurement operator with orthonormal rows, by a fast transform.

``A = P H_N / √N``: ``H_N = H_n ⊗ H_n`` the 2-D Sylvester basis,
``P`` selects the first ``M`` rows of an order (:mod:`.patterns`). Then
``A Aᵀ = I`` and ``A⁺ = Aᵀ``. Three exact implementations of ``H_N`` on an
``n × n`` image, never an ``N × N`` matrix:

- ``"matmul"``: separable ``H_n X H_n`` (two ``n × n`` matmuls, O(n³) = O(N^1.5), BLAS);
- ``"kron"``: mixed-radix Kronecker factorisation ``H_N = H_16 ⊗ … ⊗ H_16`` (small batched
  GEMMs on contiguous views, ``N Σ r_i`` multiply-adds, :func:`.fwht.fwht_kron`);
- ``"fwht"``: butterfly Walsh–Hadamard transform, O(N log N).

``method="auto"`` takes the one that ``torchtof bench operators`` measured fastest on
CPU at that size: ``"matmul"`` below :data:`AUTO_KRON_MIN_N`, ``"kron"`` from there on
(the butterflies lose to both at every size: one allocation per stage).
"""

from __future__ import annotations

import torch

from .._checks import cache_build
from .._memory import check_memory, check_rows, itemsize
from .base import LinearOperator
from .fwht import fwht2_matmul, fwht2_unchecked, fwht_kron, kron_factors, sylvester
from .patterns import check_n_order, check_sign_dtype, hadamard_order, num_patterns

__all__ = ["Hadamard", "hadamard_forward", "hadamard_adjoint", "AUTO_KRON_MIN_N"]

#: From ``torchtof bench operators`` (one thread): the separable matmul is as fast as the
#: Kronecker stages up to n = 32; from n = 64 on the radix-16 stages win (1.7× at 64,
#: 3× at 128, 5× at 256 over the separable matmul).
AUTO_KRON_MIN_N = 64
METHODS = ("auto", "matmul", "kron", "fwht")

#: What the functional forms take as ``h``: ``H_n`` (matmul), the Kronecker factors
#: (kron) or ``None`` (butterflies).
Transform = torch.Tensor | tuple[torch.Tensor, ...] | None


def _transform(x: torch.Tensor, h: Transform) -> torch.Tensor:
    """Unnormalised ``H_n X H_n`` on the last two axes (``h``: see :data:`Transform`)."""
    if h is None:
        return fwht2_unchecked(x)
    if isinstance(h, tuple):
        n1, n2 = x.shape[-2], x.shape[-1]
        return fwht_kron(x.reshape(*x.shape[:-2], n1 * n2), h).reshape(x.shape)
    return fwht2_matmul(x, h)


def _to_float(h: Transform) -> Transform:
    if h is None:
        return None
    if isinstance(h, tuple):
        return tuple(f.float() for f in h)
    return h.float()


def hadamard_forward(x: torch.Tensor, index: torch.Tensor, h: Transform = None) -> torch.Tensor:
    """``y = P H_N x / √N`` for images ``x``.

    Args:
        x: images ``(B, C, n, n)``.
        index: natural indices ``(M,)`` of the selected rows (:func:`hadamard_order`): int64,
            distinct, in ``[0, n²)``. Not checked here (these are the solvers' inner-loop
            forms; :class:`Hadamard` checks its own): :func:`hadamard_adjoint` scatters one
            value per index, so a repeated row is not the adjoint of this function.
        h: Sylvester ``H_n`` (``(n, n)``, dtype of ``x``) for the matmul path, a tuple of
            Kronecker factors ``H_{r_i}`` (``∏ r_i = n²``) for the kron path, or ``None``
            for the butterfly path.

    Returns:
        ``(B, C, M)`` coefficients ``⟨h_{ij}, x⟩ / n``.
    """
    n = x.shape[-1]
    if x.dtype in (torch.float16, torch.bfloat16):  # H X H reaches n²·max|x| before the /n
        return hadamard_forward(x.float(), index, _to_float(h)).to(x.dtype)
    # scale before summing: H (x/n) H stays within n·max|x|, the bound of the result itself,
    # where H x H reached n²·max|x| (inf at 1e36 in float32 for n = 32); n is a power of two,
    # so x/n is exact (away from subnormals)
    coef = _transform(x / n, h).reshape(*x.shape[:-2], n * n)
    return coef.index_select(-1, index)


def hadamard_adjoint(
    y: torch.Tensor, index: torch.Tensor, n: int, h: Transform = None
) -> torch.Tensor:
    """``x = Aᵀ y = H_Nᵀ Pᵀ y / √N``: scatter into the coefficient grid, transform back.

    ``index`` as in :func:`hadamard_forward` (distinct rows: the scatter keeps one value per
    coefficient, which ONNX exports as a ScatterND with any batch size)."""
    if y.dtype in (torch.float16, torch.bfloat16):  # see hadamard_forward
        return hadamard_adjoint(y.float(), index, n, _to_float(h)).to(y.dtype)
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
        method: ``"auto"``, ``"matmul"``, ``"kron"`` or ``"fwht"`` (see module docstring).

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
        n = check_n_order(n, order, "Hadamard")
        if sr is None and m is None:
            m = n * n
        m = num_patterns(n, sr, m, func="Hadamard")
        if method not in METHODS:
            raise ValueError(f"Hadamard: expected method in {METHODS}, got {method!r}")
        super().__init__(n, m)
        self.order = order
        self.method = ("kron" if n >= AUTO_KRON_MIN_N else "matmul") if method == "auto" else method
        self.register_buffer("index", hadamard_order(n, order)[:m], persistent=False)
        self.register_buffer("h", sylvester(n, torch.float32), persistent=False)
        self.kron_radices = kron_factors(n * n)
        self._kron_cache: dict = {}

    @property
    def sr(self) -> float:
        return self.m / (self.n * self.n)

    def transform_spec(self, like: torch.Tensor) -> Transform:
        """The ``h`` argument of :func:`hadamard_forward`/:func:`hadamard_adjoint` for this
        operator's method, in the dtype and on the device of ``like`` (±1: exact in any
        dtype)."""
        if self.method == "fwht":
            return None
        if self.method == "kron":
            key = (like.dtype, like.device)
            hs = self._kron_cache.get(key)
            if hs is None:
                with cache_build():
                    hs = tuple(sylvester(r, like.dtype, like.device) for r in self.kron_radices)
                self._kron_cache[key] = hs
            return hs
        return self.h.to(dtype=like.dtype, device=like.device)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        self._check_x(x, "Hadamard.forward")
        return hadamard_forward(x, self.index.to(x.device), self.transform_spec(x))

    def adjoint(self, y: torch.Tensor) -> torch.Tensor:
        self._check_y(y, "Hadamard.adjoint")
        return hadamard_adjoint(y, self.index.to(y.device), self.n, self.transform_spec(y))

    def loop_pair(self, like: torch.Tensor):
        """``(A, Aᵀ)`` for a solver's loop (:meth:`LinearOperator.loop_pair`): the transforms
        without the per-call input checks, with ``H_n`` and the row index cast once. A
        subclass that overrides ``forward`` or ``adjoint`` gets its own methods instead."""
        cls = type(self)
        if cls.forward is not Hadamard.forward or cls.adjoint is not Hadamard.adjoint:
            return super().loop_pair(like)
        h = self.transform_spec(like)
        index, n = self.index.to(like.device), self.n
        return (
            lambda x: hadamard_forward(x, index, h),
            lambda y: hadamard_adjoint(y, index, n, h),
        )

    def patterns(
        self, dtype: torch.dtype = torch.float32, start: int = 0, stop: int | None = None
    ) -> torch.Tensor:
        """The selected ±1 patterns ``(M, n, n)`` (unnormalised: row ``r`` of ``A`` is
        ``patterns[r] / n``), or only rows ``start:stop`` (``(stop − start, n, n)``: stream a
        large set in chunks instead of materialising all ``M·n²`` entries).

        Raises:
            ValueError: for a range outside ``[0, M]`` or a stack larger than the memory
                limit (:func:`torchtof.set_memory_limit`).
        """
        check_sign_dtype(dtype, "Hadamard.patterns")
        start, stop = check_rows(start, stop, self.m, "Hadamard.patterns")
        check_memory((stop - start) * self.n**2 * itemsize(dtype, "Hadamard.patterns"),
                     f"{stop - start} patterns of {self.n}x{self.n}", "Hadamard.patterns",
                     "ask for rows start:stop in chunks")
        h = self.h.to(dtype)
        idx = self.index[start:stop]
        i, j = idx // self.n, idx % self.n
        return h[i][:, :, None] * h[j][:, None, :]

    def extra_repr(self) -> str:
        return (f"n={self.n}, m={self.m}, sr={self.sr:.4g}, order={self.order!r}, "
                f"method={self.method!r}")

