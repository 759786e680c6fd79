"""The typed result every reconstructor's ``solve(y)`` returns, and helpers to fill it.

``ReconResult(x, n_iter, residual, converged, stop_reason)``, per sample ``(B, C)``:

- ``n_iter``: iterations run (0 for a direct method), int64;
- ``residual``: ``‖A x − y‖ / ‖y‖`` (``‖A x‖`` where ``y = 0``: 0 for the fit ``x = 0``) in
  the dtype of ``y``, with no over- or underflow at extreme scales (:func:`relative_residual`);
- ``converged``: bool, the method's own stopping rule was met (always for direct methods);
- ``stop_reason``: one name for the whole batch (``"direct"``, ``"fixed"``) or a tuple of
  tuples ``[b][c]`` of names.
"""

from __future__ import annotations

import warnings
from typing import NamedTuple

import torch

from .._checks import is_tracing
from ..operators.base import LinearOperator

__all__ = ["ReconResult", "relative_residual", "pow2_scale", "direct_result", "renamed_option"]


class ReconResult(NamedTuple):
    """Result of ``solve(y)`` of a reconstructor (module docstring)."""

    x: torch.Tensor
    n_iter: torch.Tensor
    residual: torch.Tensor
    converged: torch.Tensor
    stop_reason: str | tuple[tuple[str, ...], ...]


#: IEEE layout of the dtypes :func:`pow2_scale` builds powers of two in: (bits as an int dtype,
#: mantissa bits, exponent bias).
_IEEE = {torch.float32: (torch.int32, 23, 127), torch.float64: (torch.int64, 52, 1023)}


def pow2_scale(v: torch.Tensor, dim: int = -1, band: int | None = None) -> torch.Tensor:
    """A power of two ``2^-k`` per slice of ``v`` along ``dim`` (kept as a size-1 dim) that
    brings the slice's ``max |v|`` to about 1, or exactly ``1`` where ``max |v|`` already lies
    within ``2^±band`` (default: a quarter of the exponent range, ``2^±32`` in float32,
    ``2^±256`` in float64; 1 for an all-zero slice).

    Multiplying by a power of two is exact, so a sum of squares of ``v · 2^-k`` neither
    overflows nor underflows, ratios of such sums equal the unscaled ones bit for bit wherever
    those do neither, and at ordinary scales (the factor is 1) nothing changes at all. The
    factor is built from its IEEE bits (no ``exp2`` rounding on any device); float32 and
    float64 (other dtypes: 1).

    Example:
        >>> pow2_scale(torch.tensor([[2.0**40, -3.0], [2.0, 0.5]])).flatten().tolist() == [
        ...     2.0**-41, 1.0]
        True
    """
    peak = v.abs().amax(dim=dim, keepdim=True)
    if v.dtype not in _IEEE:  # other dtypes: no rescaling
        return torch.ones_like(peak)
    ibits, nmant, bias = _IEEE[v.dtype]
    band = (bias + 1) // 4 if band is None else band
    e = torch.frexp(peak).exponent.to(ibits)  # peak ∈ [2^(e−1), 2^e)
    k = torch.where(e.abs() > band, e, torch.zeros_like(e)).clamp(1 - bias, bias - 1)
    return ((bias - k) << nmant).view(v.dtype)  # 2^-k, a normal number


def relative_residual(x: torch.Tensor, y: torch.Tensor, A: LinearOperator) -> torch.Tensor:
    """``‖A x − y‖ / ‖y‖`` per sample ``(B, C)`` in the dtype of ``y``; where ``y`` is all zero
    (``max |y| = 0``) the plain ``‖A x‖`` (0 for the exact fit ``x = 0``). No host sync.

    Both ``A x − y`` and ``y`` are first multiplied by the power of two of
    :func:`pow2_scale` (``max |y|`` brought to about 1), so neither sum of squares over- or
    underflows (float32 buckets of ``1e±30``), as in the scaled 2-norm of LAPACK's ``xNRM2``
    (Anderson et al., *LAPACK Users' Guide*, 3rd ed., SIAM 1999); the scale is exact and is 1
    at ordinary scales, so there the ratio is bit for bit the unscaled one. While tracing
    (ONNX export; the graph outputs ``x`` only) the scale is 1: the tracer has no bit cast."""
    u = torch.ones_like(y[..., :1]) if is_tracing() else pow2_scale(y)  # (B, C, 1)
    r = ((A(x.to(y.dtype)) - y) * u).norm(dim=-1)
    ny = (y * u).norm(dim=-1)
    zero = y.abs().amax(dim=-1) == 0
    return torch.where(zero, r, r / torch.where(zero, torch.ones_like(ny), ny))


def direct_result(x: torch.Tensor, y: torch.Tensor, A: LinearOperator, n_iter: int = 0,
                  reason: str = "direct") -> ReconResult:
    """The result of a method with a fixed amount of work: ``n_iter`` for every sample, all
    converged, one ``reason``."""
    shape = y.shape[:-1]
    with torch.no_grad():
        res = relative_residual(x.detach(), y.detach(), A)
    return ReconResult(
        x,
        torch.full(shape, n_iter, dtype=torch.int64, device=y.device),
        res,
        torch.ones(shape, dtype=torch.bool, device=y.device),
        reason,
    )


def renamed_option(func: str, old: str, new: str, old_value, new_value, default):
    """``new_value``, or ``old_value`` (with a ``DeprecationWarning``) when only the old name
    was given; ``TypeError`` when both were."""
    if old_value is None:
        return new_value
    if new_value != default:
        raise TypeError(f"{func}: got both {new}= and its old name {old}=; pass {new}= only")
    warnings.warn(f"{func}: {old}= is renamed {new}=; {old}= will be removed in the next release",
                  DeprecationWarning, stacklevel=3)
    return old_value
