"""Fast Walsh–Hadamard transform (natural / Sylvester order) in PyTorch.

``fwht(x)`` computes ``H_N x`` along the last axis with ``log2 N`` butterfly stages
(O(N log N), no N×N matrix); ``fwht2(x)`` the separable 2-D transform
``H_n X H_nᵀ`` on the last two axes, which equals the 1-D transform of the
row-major flattened image because ``H_{n²} = H_n ⊗ H_n`` (Sylvester construction).
``sylvester(n)`` builds the ``n × n`` ±1 matrix for the matmul variant.
Both are unnormalised: ``fwht(fwht(x)) = N x``.
"""

from __future__ import annotations

import functools

import torch

from .._checks import check_power_of_two, check_tensor

__all__ = ["fwht", "fwht2", "fwht2_matmul", "sylvester"]


def fwht(x: torch.Tensor) -> torch.Tensor:
    """Unnormalised Walsh–Hadamard transform along the last axis (natural order).

    Args:
        x: tensor ``(..., N)``, N a power of two.

    Returns:
        ``H_N x`` of the same shape; ``H_N`` is the Sylvester matrix
        (``scipy.linalg.hadamard(N)``).

    Example:
        >>> fwht(torch.tensor([1.0, 0.0, 0.0, 0.0]))
        tensor([1., 1., 1., 1.])
    """
    check_tensor(x, "x", "fwht")
    n = x.shape[-1]
    check_power_of_two(n, "x.shape[-1]", "fwht")
    lead = x.shape[:-1]
    h = 1
    y = x
    # Stage h combines pairs (a, b) at distance h: (a + b, a − b).  Written with
    # reshape/cat so it traces to static ONNX ops.
    while h < n:
        y = y.reshape(*lead, n // (2 * h), 2, h)
        a, b = y[..., 0, :], y[..., 1, :]
        y = torch.stack((a + b, a - b), dim=-2)
        h *= 2
    return y.reshape(*lead, n)


def fwht2(x: torch.Tensor) -> torch.Tensor:
    """Separable 2-D transform ``H_n X H_nᵀ`` of the last two axes by butterflies."""
    # H_{n1 n2} = H_{n1} ⊗ H_{n2}: one 1-D transform of the row-major flattened image.
    n1, n2 = x.shape[-2], x.shape[-1]
    return fwht(x.reshape(*x.shape[:-2], n1 * n2)).reshape(x.shape)


@functools.lru_cache(maxsize=32)
def _sylvester_cpu(n: int, dtype: torch.dtype) -> torch.Tensor:
    h = torch.ones(1, 1, dtype=dtype)
    while h.shape[0] < n:
        h = torch.cat((torch.cat((h, h), 1), torch.cat((h, -h), 1)), 0)
    return h


def sylvester(n: int, dtype: torch.dtype = torch.float32, device=None) -> torch.Tensor:
    """Sylvester–Hadamard matrix ``H_n`` (±1, natural order), shape ``(n, n)``."""
    check_power_of_two(n, "n", "sylvester")
    return _sylvester_cpu(n, dtype).to(device)


def fwht2_matmul(x: torch.Tensor, h: torch.Tensor) -> torch.Tensor:
    """``H X Hᵀ`` on the last two axes with two ``n × n`` matmuls (``H`` symmetric)."""
    return h @ x @ h
