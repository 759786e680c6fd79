"""``LinearOperator``: the measurement model ``y = A x`` as an ``nn.Module``.

An operator maps images ``x`` of shape ``(B, C, n, n)`` to measurements ``y`` of
shape ``(B, C, m)``; each row of ``A`` is one DMD pattern flattened row-major
(paper Eq. 11, ``y = H O``). Subclasses implement :meth:`forward` and
:meth:`adjoint`; the base class derives ``pinv``, ``normal``, ``matrix`` and
the adjointness test from them (deepinv's ``LinearPhysics`` is the model).
"""

from __future__ import annotations

import torch
from torch import nn

from .._checks import cache_build, check_finite, check_rank, check_shape, unchecked
from .._memory import check_memory

__all__ = ["LinearOperator"]


class LinearOperator(nn.Module):
    """Base class of the linear measurement operators.

    Args:
        n: side of the square image on the DMD (pixels).
        m: number of measurements (patterns).

    Attributes:
        n, m: sizes; ``shape_in == (n, n)``.
        orthonormal_rows: ``True`` when ``A Aᵀ = I`` (then ``pinv == adjoint``).
        state_version: bumped when ``load_state_dict`` changes the operator.

    Shape:
        - forward: ``(B, C, n, n) -> (B, C, m)``
        - adjoint: ``(B, C, m) -> (B, C, n, n)``
    """

    orthonormal_rows: bool = False
    #: Bumped when loaded values change the operator (``load_state_dict``): caches derived
    #: from an operator (the exact u-step's factors, ``s₂``) key on it.
    state_version: int = 0

    def __init__(self, n: int, m: int) -> None:
        super().__init__()
        self.n = int(n)
        self.m = int(m)

    @property
    def shape_in(self) -> tuple[int, int]:
        return (self.n, self.n)

    # -- checks shared by subclasses -------------------------------------------------
    def _check_x(self, x: torch.Tensor, func: str) -> None:
        check_shape(x, (None, None, self.n, self.n), "x", func, "(B, C, n, n)")
        check_finite(x, "x", func)

    def _check_y(self, y: torch.Tensor, func: str) -> None:
        check_shape(y, (None, None, self.m), "y", func, "(B, C, M)")
        check_finite(y, "y", func)

    # -- interface ---------------------------------------------------------------------
    def forward(self, x: torch.Tensor) -> torch.Tensor:  # pragma: no cover - abstract
        raise NotImplementedError

    def adjoint(self, y: torch.Tensor) -> torch.Tensor:  # pragma: no cover - abstract
        raise NotImplementedError

    def loop_pair(self, like: torch.Tensor):
        """``(A, Aᵀ)`` as two callables for an iterative solver's loop, whose inputs have the
        dtype and device of ``like`` and were validated once at the solver's entry.

        The same arithmetic as :meth:`forward` and :meth:`adjoint` (bit for bit); operators
        may skip their per-call checks and casts there (at small ``n`` a solver step is a few
        hundred small tensor operations, and those checks add tens of them per step). The
        default is ``(self.forward, self.adjoint)``: bound methods, so module hooks
        registered on the operator do not run inside a solver's loop.
        """
        return self.forward, self.adjoint

    def normal(self, x: torch.Tensor) -> torch.Tensor:
        """``AᵀA x``, shape ``(B, C, n, n) -> (B, C, n, n)``."""
        return self.adjoint(self.forward(x))

    def gram(self, dtype: torch.dtype = torch.float64) -> torch.Tensor:
        """Dense ``A Aᵀ`` of shape ``(m, m)`` (small problems and checks only)."""
        a = self.matrix(dtype=dtype)
        return a @ a.T

    def pinv(self, y: torch.Tensor) -> torch.Tensor:
        """Minimum-norm least-squares solution ``A⁺ y = Aᵀ (A Aᵀ)⁻¹ y``.

        Orthonormal rows (``A Aᵀ = I``) reduce it to ``Aᵀ y`` (Gong 2015, pseudo-inverse GI).
        Otherwise the dense ``A⁺`` is computed once from a float64 SVD and cached per dtype
        (a rank-deficient pattern set still gets the minimum-norm answer); float16/bfloat16
        are solved in float32 and rounded once.
        """
        self._check_y(y, f"{type(self).__name__}.pinv")
        if self.orthonormal_rows:
            with unchecked():  # y checked above, under this call's name
                return self.adjoint(y)
        if y.dtype in (torch.float16, torch.bfloat16):  # A⁺ entries grow like κ(A)
            return self.pinv(y.float()).to(y.dtype)
        p = self._cached_pinv(y.dtype, y.device)  # (n², m)
        return (y @ p.T).reshape(*y.shape[:-1], self.n, self.n)

    def _cached_pinv(self, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
        """Dense ``A⁺`` ``(n², m)`` from a float64 SVD (``torch.linalg.pinv``), cached per
        dtype/device: error ``κ(A)·ε`` where the Gram route ``Aᵀ(AAᵀ)⁺`` loses ``κ(A)²·ε``."""
        key = (dtype, device)
        cache = self.__dict__.setdefault("_pinv_cache", {})
        if key not in cache:
            big = self.n * self.n
            check_memory(8 * (3 * self.m * big + min(self.m, big) ** 2),
                         f"the dense {self.m}x{big} pseudo-inverse (float64 SVD)",
                         f"{type(self).__name__}.pinv", "use an operator with orthonormal rows")
            with cache_build():
                a = self.matrix(dtype=torch.float64)
                cache[key] = torch.linalg.pinv(a).to(dtype=dtype, device=device)
        return cache[key]

    def matrix(self, dtype: torch.dtype = torch.float64, device=None) -> torch.Tensor:
        """The dense matrix ``A`` of shape ``(m, n*n)``, built by applying ``Aᵀ`` to the unit
        measurement vectors (small problems and tests only: O(m·n²) memory)."""
        item = torch.empty((), dtype=dtype).element_size()
        check_memory(item * self.m * (self.m + 2 * self.n * self.n),
                     f"the dense {self.m}x{self.n * self.n} matrix",
                     f"{type(self).__name__}.matrix")
        eye = torch.eye(self.m, dtype=dtype, device=device).reshape(self.m, 1, self.m)
        cols = self.adjoint(eye)  # (m, 1, n, n): row i of A
        return cols.reshape(self.m, self.n * self.n)

    def adjointness_test(
        self, dtype: torch.dtype = torch.float64, batch: int = 2, channels: int = 1, seed: int = 0
    ) -> float:
        """Relative adjointness error ``|<Ax, y> − <x, Aᵀy>| / (‖Ax‖ ‖y‖)`` on random data."""
        g = torch.Generator().manual_seed(seed)
        x = torch.randn(batch, channels, self.n, self.n, generator=g, dtype=dtype)
        y = torch.randn(batch, channels, self.m, generator=g, dtype=dtype)
        ax = self.forward(x)
        aty = self.adjoint(y)
        lhs = (ax * y).sum()
        rhs = (x * aty).sum()
        denom = ax.norm() * y.norm()
        return float((lhs - rhs).abs() / denom.clamp_min(torch.finfo(dtype).tiny))

    def extra_repr(self) -> str:
        return f"n={self.n}, m={self.m}"


def _rank4(x: torch.Tensor, name: str, func: str) -> None:
    check_rank(x, 4, name, func, "(B, C, H, W)")
