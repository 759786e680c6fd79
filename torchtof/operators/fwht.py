"""Fast Walsh–Hadamard transform (natural / Sylvester order) in PyTorch.

``fwht(x)`` computes ``H_N x`` along the last axis with ``log2 N`` butterfly stages
(O(N log N), no N×N matrix); ``fwht2(x)`` the separable 2-D transform
``H_n X H_nᵀ`` on the last two axes, which equals the 1-D transform of the
row-major flattened image because ``H_{n²} = H_n ⊗ H_n`` (Sylvester construction).
``sylvester(n)`` builds the ``n × n`` ±1 matrix for the matmul variant.
``fwht_kron(x, hs)`` is the mixed-radix form of the same transform: Sylvester matrices
factor as ``H_N = H_{r_1} ⊗ … ⊗ H_{r_k}`` for any powers of two with ``∏ r_i = N``, so
``H_N x`` is ``k`` passes of a small ``r_i × r_i`` matrix along one axis of ``x`` viewed
as an ``r_1 × … × r_k`` tensor (Van Loan, *Computational Frameworks for the FFT*, 1992,
§1.4 and §3.3 on Kronecker factorisations). Each pass is one batched GEMM on a
contiguous view (no permutes), ``N Σ r_i`` multiply-adds in all (radix 16 at
``n = 64``: 3·16·4096 ≈ 0.2 M against 2·64³ ≈ 0.5 M for the separable matmul): more
arithmetic than the ``N log₂ N`` butterflies but ``⌈log₁₆ N⌉`` memory passes instead of
``log₂ N``, at BLAS speed (``torchtof bench operators`` keeps the fastest per size).
All are unnormalised: ``fwht(fwht(x)) = N x``.
"""

from __future__ import annotations

import functools

import torch

from .._checks import built_for_cache, check_finite, check_power_of_two, check_tensor

__all__ = ["fwht", "fwht2", "fwht2_matmul", "fwht_kron", "kron_factors", "sylvester"]


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
    if x.ndim < 1:
        raise ValueError(f"fwht: expected x with at least one axis, got shape {tuple(x.shape)}")
    check_power_of_two(x.shape[-1], "x.shape[-1]", "fwht")
    check_finite(x, "x", "fwht")
    return _fwht(x)


def _fwht(x: torch.Tensor) -> torch.Tensor:
    """:func:`fwht` without the checks (callers validated ``x``)."""
    n = x.shape[-1]
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
    """Separable 2-D transform ``H_{n1} X H_{n2}ᵀ`` of the last two axes by butterflies.

    Args:
        x: floating tensor ``(..., n1, n2)``, ``n1`` and ``n2`` powers of two.

    Returns:
        The transform, same shape (unnormalised: ``fwht2(fwht2(x)) = n1·n2·x``).

    Raises:
        TypeError: if ``x`` is not a floating tensor.
        ValueError: if ``x`` has fewer than two axes, a side that is not a power of two, or
            NaN/Inf values.

    Example:
        >>> fwht2(torch.ones(2, 2))
        tensor([[4., 0.],
                [0., 0.]])
    """
    check_tensor(x, "x", "fwht2")
    if x.ndim < 2:
        raise ValueError(f"fwht2: expected x with at least two axes, got shape {tuple(x.shape)}")
    check_power_of_two(x.shape[-2], "x.shape[-2]", "fwht2")
    check_power_of_two(x.shape[-1], "x.shape[-1]", "fwht2")
    check_finite(x, "x", "fwht2")
    return fwht2_unchecked(x)


def fwht2_unchecked(x: torch.Tensor) -> torch.Tensor:
    """:func:`fwht2` without the checks, for callers that validated ``x`` (the Hadamard
    operator, whose solver loops run it on every step)."""
    # H_{n1 n2} = H_{n1} ⊗ H_{n2}: one 1-D transform of the row-major flattened image.
    n1, n2 = x.shape[-2], x.shape[-1]
    return _fwht(x.reshape(*x.shape[:-2], n1 * n2)).reshape(x.shape)


@functools.lru_cache(maxsize=32)
@built_for_cache
def _sylvester_cpu(n: int, dtype: torch.dtype) -> torch.Tensor:
    h = torch.ones(1, 1, dtype=dtype)
    while h.shape[0] < n:
        h = torch.cat((torch.cat((h, h), 1), torch.cat((h, -h), 1)), 0)
    return h


def sylvester(n: int, dtype: torch.dtype = torch.float32, device=None) -> torch.Tensor:
    """Sylvester–Hadamard matrix ``H_n`` (±1, natural order), shape ``(n, n)``.

    Always a fresh tensor owned by the caller: the cached copy behind it (and behind every
    :class:`~torchtof.operators.Hadamard` buffer) is never handed out, so writing into the
    result cannot change any operator.
    """
    check_power_of_two(n, "n", "sylvester")
    return _sylvester_cpu(n, dtype).to(device=device, copy=True)


def fwht2_matmul(x: torch.Tensor, h: torch.Tensor) -> torch.Tensor:
    """``H X Hᵀ`` on the last two axes with two ``n × n`` matmuls (``H`` symmetric)."""
    return h @ x @ h


def kron_factors(big: int, radix: int = 16) -> tuple[int, ...]:
    """Radices ``(r_1, …, r_k)`` with ``∏ r_i = big``: as many ``radix`` as fit, the
    remainder (a smaller power of two) first. ``kron_factors(4096) == (16, 16, 16)``."""
    big = check_power_of_two(big, "big", "kron_factors")
    radix = check_power_of_two(radix, "radix", "kron_factors")
    p, q = big.bit_length() - 1, radix.bit_length() - 1
    rest = p % q
    return ((1 << rest,) if rest else ()) + (radix,) * (p // q)


def fwht_kron(x: torch.Tensor, hs: tuple[torch.Tensor, ...]) -> torch.Tensor:
    """``H_N x`` along the last axis from the Kronecker factors ``hs = (H_{r_1}, …, H_{r_k})``
    (Sylvester, ``∏ r_i = N``; :func:`kron_factors`, :func:`sylvester`).

    Pass ``i`` applies ``H_{r_i}`` to axis ``i`` of ``x`` viewed as ``(…, r_1, …, r_k)``:
    a batched ``(r_i × r_i) @ (r_i × stride)`` product on a contiguous view, the last
    axis (``stride = 1``) as one ``(… × r_k) @ (r_k × r_k)`` GEMM (``H`` is symmetric).
    Plain matmuls and reshapes: differentiable and exportable to ONNX.
    """
    shape = x.shape
    big = shape[-1]
    total = 1
    for h in hs:
        total *= h.shape[-1]
    if total != big:
        raise ValueError(f"fwht_kron: factors multiply to {total}, expected x.shape[-1]={big}")
    y = x
    stride = 1
    for h in reversed(hs):
        r = h.shape[-1]
        y = y.reshape(-1, r) @ h if stride == 1 else h @ y.reshape(-1, r, stride)
        stride *= r
    return y.reshape(shape)
