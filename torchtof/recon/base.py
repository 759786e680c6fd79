"""The typed result every reconstructor's ``solve(y)`` returns, and helpers to fill it.

``ReconResult(x, n_iter, residual, converged, stop_reason)``, per sample ``(B, C)``:

- ``n_iter``: iterations run (0 for a direct method), int64;
- ``residual``: ``‖A x − y‖ / ‖y‖`` (0 where ``y = 0``) in the dtype of ``y``;
- ``converged``: bool, the method's own stopping rule was met (always for direct methods);
- ``stop_reason``: one name for the whole batch (``"direct"``, ``"fixed"``) or a tuple of
  tuples ``[b][c]`` of names.
"""

from __future__ import annotations

import warnings
from typing import NamedTuple

import torch

from ..operators.base import LinearOperator

__all__ = ["ReconResult", "relative_residual", "direct_result", "renamed_option"]


class ReconResult(NamedTuple):
    """Result of ``solve(y)`` of a reconstructor (module docstring)."""

    x: torch.Tensor
    n_iter: torch.Tensor
    residual: torch.Tensor
    converged: torch.Tensor
    stop_reason: str | tuple[tuple[str, ...], ...]


def relative_residual(x: torch.Tensor, y: torch.Tensor, A: LinearOperator) -> torch.Tensor:
    """``‖A x − y‖ / ‖y‖`` per sample ``(B, C)``; 0 where ``y`` is all zero (no sync)."""
    r = (A(x.to(y.dtype)) - y).norm(dim=-1)
    ny = y.norm(dim=-1)
    return torch.where(ny > 0, r / torch.where(ny > 0, ny, torch.ones_like(ny)), r)


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
