"""Correlation (ghost-imaging) reconstructors: g2, traditional GI and differential GI.

The patterns are the rows ``φ_i`` of the operator ``A`` (``y_i = ⟨φ_i, x⟩``) and
``⟨·⟩`` is the mean over the ``M`` measurements. With ``R_i = Σ_u φ_i(u)`` the row sums:

- normalised second-order correlation (paper Eq. 9; Eq. 10 with depth buckets ``D_i``):
  ``g2(u) = ⟨y φ(u)⟩ / (⟨y⟩ ⟨φ(u)⟩)``;
- traditional GI: ``G(u) = ⟨y φ(u)⟩ − ⟨y⟩⟨φ(u)⟩``;
- differential GI (Ferri et al., PRL 104, 253603, 2010):
  ``G(u) = ⟨y φ(u)⟩ − (⟨y⟩ / ⟨R⟩) ⟨R φ(u)⟩``.

Every sum over patterns is one adjoint ``Aᵀ`` (fast for Hadamard), never a Python loop.

**Zero denominators.** ``g2`` divides by ``⟨y⟩⟨φ⟩`` and DGI by ``⟨R⟩``; both vanish for
legitimate inputs (all-zero buckets; ±1 Hadamard rows, whose sums are zero except the
first). Both quotients are ``a/b`` where ``|b| > √ε·max|b|`` (ε the dtype's machine
epsilon, the maximum per sample) and 0 where ``b`` is negligible — never NaN or Inf, exact
(no bias for DGI's cancellation to amplify), and free of ``b²``, which would overflow or
underflow for buckets at 1e±30 in float32.

**Precision.** The images are small differences of large bucket sums (depth buckets carry an
offset of ~10³–10⁵), so float32 loses about five digits; below float64 the estimators compute
in float64 and round the result once (output dtype = input dtype).

**Negative images.** With raw depth buckets (no gate) ``D_i`` falls as more light arrives
(paper §3.1), so every correlation image comes out negative; the sign is physical and kept
(resolve it with :func:`torchtof.metrics.resolve_sign`).
"""

from __future__ import annotations

import math
import warnings

import torch

from .._checks import is_tracing
from ..operators.base import LinearOperator
from .base import ReconResult, direct_result

__all__ = ["cgi", "g2", "tgi", "dgi", "CGI", "TGI", "DGI"]


def _safe_div(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """``a / b`` where ``|b| > √eps · max|b|`` (per sample), 0 elsewhere (module docstring)."""
    info = torch.finfo(b.dtype)
    # .max() not .amax(): onnxscript rejects a dim-less aten.amax in the dynamo exporter
    scale = b.abs().flatten(2).amax(dim=-1)[..., None, None] if b.ndim == 4 else b.abs().max()
    keep = b.abs() > scale * info.eps**0.5  # all False when b == 0; no b², a·b: no overflow
    q = a / torch.where(keep, b, torch.ones_like(b))
    return torch.where(keep, q, torch.zeros_like(q))


def _check(y: torch.Tensor, A: LinearOperator, func: str) -> None:
    if not isinstance(A, LinearOperator):
        raise TypeError(f"{func}: expected A to be a LinearOperator, got {type(A).__name__}")
    if isinstance(y, torch.Tensor) and (y.is_complex() or not y.is_floating_point()):
        raise TypeError(f"{func}: expected y to be a real floating tensor (buckets), got {y.dtype}")
    A._check_y(y, func)


def _empty(y: torch.Tensor, A: LinearOperator) -> torch.Tensor:
    """The result for an empty batch ``(0, C, M)``: ``(0, C, n, n)``."""
    return y.new_zeros(y.shape[:-1] + (A.n, A.n))


def _pattern_stats(A: LinearOperator, like: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Row sums ``R = A·1`` ``(M,)`` and mean pattern ``⟨φ⟩ = Aᵀ1 / M`` ``(n, n)``."""
    ones_x = like.new_ones(1, 1, A.n, A.n)
    ones_y = like.new_ones(1, 1, A.m)
    return A(ones_x)[0, 0], A.adjoint(ones_y)[0, 0] / A.m


def tgi(y: torch.Tensor, A: LinearOperator) -> torch.Tensor:
    """Traditional ghost image ``⟨yφ⟩ − ⟨y⟩⟨φ⟩ = Aᵀ(y − ⟨y⟩) / M``.

    Args:
        y: buckets ``(B, C, M)``.
        A: operator whose rows are the patterns.

    Returns:
        ``(B, C, n, n)``.
    """
    _check(y, A, "tgi")
    if y.shape[0] == 0:
        return _empty(y, A)
    if y.dtype in (torch.float16, torch.bfloat16, torch.float32):  # module docstring
        return tgi(y.double(), A).to(y.dtype)
    return A.adjoint(y - y.mean(dim=-1, keepdim=True)) / A.m


def cgi(y: torch.Tensor, A: LinearOperator) -> torch.Tensor:
    """Normalised second-order correlation ``g2 = ⟨yφ⟩ / (⟨y⟩⟨φ⟩)`` (paper Eqs. 9–10).

    Args:
        y: buckets ``(B, C, M)`` (intensity ``S_i`` or depth ``D_i``).
        A: operator whose rows are the patterns ``φ_i`` (e.g. the 0/1 DMD patterns of
            :class:`~torchtof.operators.DMDSplit`).

    Returns:
        ``(B, C, n, n)``; a zero mean bucket gives 0 (see module docstring), never NaN.

    Warns:
        UserWarning: when the mean pattern is ≤ 0 somewhere (signed patterns such as the ±1
        Hadamard rows): g2 is undefined there (on the paper's experiment at SR 12.5 % with
        the gate, CGI on the ±1 operator scores 6.1 dB where the pseudo-inverse of the same
        buckets scores 9.3 dB).

    Example:
        >>> from torchtof.operators import Hadamard, DMDSplit
        >>> S = DMDSplit(Hadamard(8))
        >>> x = torch.zeros(1, 1, 8, 8); x[..., 2:5, 3:6] = 1
        >>> g = cgi(S(x), S)
        >>> bool(g[0, 0, 3, 4] > g[0, 0, 0, 0])
        True
    """
    _check(y, A, "cgi")
    if y.shape[0] == 0:
        return _empty(y, A)
    if y.dtype in (torch.float16, torch.bfloat16, torch.float32):  # module docstring
        return cgi(y.double(), A).to(y.dtype)
    _, mean_phi = _pattern_stats(A, y)
    if not (is_tracing() or mean_phi.is_meta):  # one check per call, outside any loop
        bad = int((mean_phi <= 0).sum())
        if bad:
            warnings.warn(
                f"cgi: g2 = ⟨yφ⟩/(⟨y⟩⟨φ⟩) needs light patterns (φ ≥ 0), but the mean pattern of "
                f"A is ≤ 0 at {bad} of {A.n * A.n} pixels (e.g. a ±1 Hadamard operator), where "
                f"g2 is undefined and set to 0. Use the 0/1 DMD patterns — DMDSplit(A) with the "
                f"raw interleaved buckets — or PseudoInverse(A) on the differential buckets.",
                UserWarning, stacklevel=2)
    num = A.adjoint(y) / A.m
    ybar = y.mean(dim=-1, keepdim=True)
    # a mean bucket within the rounding of its sum (√M·eps·⟨|y|⟩, the spread of M rounding
    # errors; Higham 2002, Accuracy and Stability of Numerical Algorithms, §4.2) is zero: its
    # sign and size are rounding noise, which the quotient would amplify without bound
    floor = math.sqrt(A.m) * torch.finfo(y.dtype).eps * y.abs().mean(dim=-1, keepdim=True)
    ybar = torch.where(ybar.abs() > floor, ybar, torch.zeros_like(ybar))
    den = ybar[..., None] * mean_phi
    return _safe_div(num, den)


g2 = cgi


def dgi(y: torch.Tensor, A: LinearOperator) -> torch.Tensor:
    """Differential ghost image ``⟨yφ⟩ − (⟨y⟩/⟨R⟩)⟨Rφ⟩`` (Ferri et al. 2010).

    Args:
        y: buckets ``(B, C, M)``.
        A: operator whose rows are the patterns; ``R_i`` are its row sums.

    Returns:
        ``(B, C, n, n)``. Patterns with ``⟨R⟩ = 0`` (balanced ±1 rows) reduce it to
        ``⟨yφ⟩`` (the regularised quotient vanishes).
    """
    _check(y, A, "dgi")
    if y.shape[0] == 0:
        return _empty(y, A)
    if y.dtype in (torch.float16, torch.bfloat16, torch.float32):  # module docstring
        return dgi(y.double(), A).to(y.dtype)
    r, _ = _pattern_stats(A, y)
    ratio = _safe_div(y.mean(dim=-1, keepdim=True), r.mean().expand(y.shape[:-1] + (1,)))
    return A.adjoint(y - ratio * r) / A.m


class _Correlation(torch.nn.Module):
    _fn = staticmethod(tgi)

    def __init__(self, A: LinearOperator) -> None:
        super().__init__()
        if not isinstance(A, LinearOperator):
            raise TypeError(
                f"{type(self).__name__}: expected A to be a LinearOperator, got {type(A).__name__}"
            )
        self.A = A

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        return type(self)._fn(y, self.A)

    def solve(self, y: torch.Tensor) -> ReconResult:
        """``forward`` with its :class:`~torchtof.recon.base.ReconResult` (direct: no
        iterations, ``"direct"``). ``residual = ‖A x − y‖ / ‖y‖`` only says how far the
        correlation image is from fitting the buckets: it is not a least-squares solution."""
        return direct_result(self(y), y, self.A)


class CGI(_Correlation):
    """Module of :func:`cgi` (g2, paper Eq. 9/10): ``forward(y (B,C,M)) -> (B,C,n,n)``."""

    _fn = staticmethod(cgi)


class TGI(_Correlation):
    """Module of :func:`tgi` (traditional GI)."""

    _fn = staticmethod(tgi)


class DGI(_Correlation):
    """Module of :func:`dgi` (differential GI, Ferri 2010)."""

    _fn = staticmethod(dgi)
