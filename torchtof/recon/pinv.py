"""Pseudo-inverse reconstruction ``x = A⁺ y`` (Gong, Photonics Res. 3, 234, 2015).

For orthonormal Hadamard rows ``A⁺ = Aᵀ``, so traditional GI with ±1 patterns equals the
pseudo-inverse up to scale; for general patterns ``A⁺ = Aᵀ(AAᵀ)⁻¹`` with the Gram inverse
cached by the operator.
"""

from __future__ import annotations

import torch

from .._checks import check_real, unchecked
from ..operators.base import LinearOperator
from .base import ReconResult, direct_result

__all__ = ["pseudo_inverse", "PseudoInverse"]


def pseudo_inverse(y: torch.Tensor, A: LinearOperator) -> torch.Tensor:
    """Minimum-norm least-squares image ``A⁺ y``.

    Args:
        y: measurements ``(B, C, M)``, a real floating-point tensor.
        A: the operator.

    Returns:
        ``(B, C, n, n)``. With the full Hadamard set and no noise it is exact.

    Raises:
        TypeError: if ``A`` is not a :class:`~torchtof.operators.LinearOperator` or ``y`` not
            a real floating-point tensor (complex buckets: reconstruct the real and imaginary
            parts separately).
        ValueError: if ``y`` is not ``(B, C, A.m)`` or holds NaN/Inf (eager mode).
    """
    func = "pseudo_inverse"
    if not isinstance(A, LinearOperator):
        raise TypeError(f"{func}: expected A to be a LinearOperator, got {type(A).__name__}")
    check_real(y, "y", func)
    A._check_y(y, func)  # shape and NaN/Inf, named here
    with unchecked():  # checked above: the operator does not read y back again
        return A.pinv(y)


class PseudoInverse(torch.nn.Module):
    """Module of :func:`pseudo_inverse`: ``forward(y (B,C,M)) -> (B,C,n,n)``."""

    def __init__(self, A: LinearOperator) -> None:
        super().__init__()
        if not isinstance(A, LinearOperator):
            raise TypeError(
                f"PseudoInverse: expected A to be a LinearOperator, got {type(A).__name__}"
            )
        self.A = A

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        return pseudo_inverse(y, self.A)

    def solve(self, y: torch.Tensor) -> ReconResult:
        """``forward`` with its :class:`~torchtof.recon.base.ReconResult` (direct: no
        iterations, ``"direct"``, ``residual = ‖A x − y‖ / ‖y‖``)."""
        return direct_result(self(y), y, self.A)
