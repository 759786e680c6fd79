"""DMD patterns: 2-D Hadamard rows in several orders, random binary and Gaussian speckle.

The 2-D Hadamard basis of an ``n × n`` DMD has ``N = n²`` patterns
``h_{ij} = h_i h_jᵀ`` (outer products of rows of the Sylvester matrix ``H_n``);
the natural index ``k = i·n + j`` matches row ``k`` of ``H_N = H_n ⊗ H_n``
(``scipy.linalg.hadamard(N)``). An *order* is a permutation of ``0 … N−1``; the
first ``M`` entries choose the patterns at sampling rate ``SR = M/N``.

Orders:

- ``natural``: Sylvester/Kronecker index.
- ``sequency``: ascending total number of sign changes ``s_i + s_j`` (Walsh order in
  2-D; ties by ``max(s_i, s_j)`` then natural index).
- ``russian_doll`` (Sun et al., Sci. Rep. 7:3464, 2017): nested square blocks —
  all patterns with ``max(s_i, s_j) < 2^k`` come before any other, so the first
  ``4^k`` patterns are exactly the ``2^k × 2^k`` block-average basis.
- ``cake_cutting`` (Yu, Sensors 19:4122, 2019), the default: ascending number of
  connected ±1 regions ("cake pieces"), ties by natural index. For an outer product
  the regions form a ``(s_i+1) × (s_j+1)`` checkerboard of rectangles in which
  neighbours always differ in sign, so the count is ``(s_i + 1)(s_j + 1)`` exactly
  (the tests check it against ``scipy.ndimage.label``).
"""

from __future__ import annotations

import functools
import numbers

import torch

from .._checks import built_for_cache, check_in_range, check_int, check_power_of_two
from .._memory import check_memory
from .fwht import sylvester

__all__ = [
    "ORDERS",
    "hadamard_order",
    "hadamard_patterns",
    "row_sequency",
    "random_binary_patterns",
    "gaussian_speckle_patterns",
    "num_patterns",
]

ORDERS = ("natural", "sequency", "russian_doll", "cake_cutting")
N_MIN, N_MAX = 4, 256


def row_sequency(n: int) -> torch.Tensor:
    """Number of sign changes of each row of the Sylvester matrix ``H_n``, shape ``(n,)``."""
    h = sylvester(n, torch.float64)
    return (h[:, 1:] != h[:, :-1]).sum(dim=1)


@functools.lru_cache(maxsize=64)
@built_for_cache
def _order_cpu(n: int, order: str) -> torch.Tensor:
    s = row_sequency(n).to(torch.int64)
    si = s.repeat_interleave(n)  # s_i of natural index k = i*n + j
    sj = s.repeat(n)
    k = torch.arange(n * n, dtype=torch.int64)
    big = n * n  # > any key component, so lexicographic keys pack into one int64
    if order == "natural":
        return k
    if order == "sequency":
        key = ((si + sj) * big + torch.maximum(si, sj)) * big + k
    elif order == "russian_doll":
        # doll level = bit_length(max(s_i, s_j)): 0 -> 0, 1 -> 1, 2..3 -> 2, 4..7 -> 3 ...
        mx = torch.maximum(si, sj)
        level = sum(((mx >> b) > 0).long() for b in range(n.bit_length()))
        key = ((level * 2 * big + (si + sj)) * big) + k
    elif order == "cake_cutting":
        key = ((si + 1) * (sj + 1)) * big + k
    else:  # pragma: no cover - validated by the caller
        raise ValueError(order)
    return torch.argsort(key, stable=True)


def check_n_order(n: int, order: str, func: str) -> int:
    """``n`` as a Python int (a NumPy integer too); errors name ``n`` or ``order``."""
    n = check_power_of_two(n, "n", func, lo=N_MIN, hi=N_MAX)
    if order not in ORDERS:
        raise ValueError(f"{func}: expected order in {ORDERS}, got {order!r}")
    return n


def hadamard_order(n: int, order: str = "cake_cutting") -> torch.Tensor:
    """Permutation of the natural 2-D Hadamard indices for ``order``.

    Args:
        n: DMD side, a power of two in [4, 256].
        order: one of :data:`ORDERS`.

    Returns:
        ``int64`` tensor ``(n²,)``; entry ``r`` is the natural index ``i·n + j`` of the
        ``r``-th pattern.

    Raises:
        ValueError: ``n`` not a power of two in range, or unknown ``order``.

    Example:
        >>> hadamard_order(4, "natural")[:3]
        tensor([0, 1, 2])
    """
    n = check_n_order(n, order, "hadamard_order")
    return _order_cpu(n, order).clone()


def num_patterns(n: int, sr: float | None = None, m: int | None = None, func: str = "") -> int:
    """Resolve the number of patterns from a sampling rate ``sr = m / n²`` or ``m``."""
    func = func or "num_patterns"
    big = n * n
    if (sr is None) == (m is None):
        raise ValueError(f"{func}: give exactly one of sr and m, got sr={sr}, m={m}")
    if sr is not None:
        check_in_range(sr, 0.0, 1.0, "sr", func, lo_open=True)
        return max(1, min(big, int(round(sr * big))))
    if isinstance(m, bool) or not isinstance(m, numbers.Integral):
        raise TypeError(f"{func}: expected m to be an int, got {type(m).__name__}")
    m = int(m)
    if not 1 <= m <= big:
        raise ValueError(f"{func}: expected m in [1, {big}], got {m}")
    return m


def hadamard_patterns(
    n: int,
    m: int | None = None,
    order: str = "cake_cutting",
    dtype: torch.dtype = torch.float32,
    device=None,
) -> torch.Tensor:
    """The first ``m`` ±1 Hadamard patterns in ``order``, shape ``(m, n, n)``.

    Pattern ``r`` is ``h_i h_jᵀ`` with ``(i, j) = divmod(order[r], n)``; only the
    requested patterns are materialised (never the full ``N × N`` basis).
    """
    n = check_n_order(n, order, "hadamard_patterns")
    check_sign_dtype(dtype, "hadamard_patterns")
    m = n * n if m is None else num_patterns(n, m=m, func="hadamard_patterns")
    check_memory(m * n * n * torch.empty((), dtype=dtype).element_size(),
                 f"{m} patterns of {n}x{n}", "hadamard_patterns")
    idx = _order_cpu(n, order)[:m]
    h = sylvester(n, dtype, device)
    i, j = idx // n, idx % n
    return h[i.to(h.device)][:, :, None] * h[j.to(h.device)][:, None, :]


def check_sign_dtype(dtype: object, func: str) -> None:
    """``TypeError`` naming ``dtype`` unless it holds ±1: floating or signed integer (uint8
    wraps −1 to 255, bool makes it True)."""
    if not isinstance(dtype, torch.dtype) or not (dtype.is_floating_point or dtype in (
            torch.int8, torch.int16, torch.int32, torch.int64)):
        raise TypeError(f"{func}: expected dtype a floating or signed integer torch.dtype "
                        f"(the patterns are ±1), got {dtype!r}")


def _check_sizes(m: object, n: object, dtype: object, func: str) -> tuple[int, int]:
    """``(m, n)`` as Python ints >= 1 (NumPy integers too) and an ``(m, n, n)`` float64 draw
    within the memory limit."""
    m, n = check_int(m, "m", func, lo=1), check_int(n, "n", func, lo=1)
    if not isinstance(dtype, torch.dtype) or not dtype.is_floating_point:
        raise TypeError(f"{func}: expected dtype to be a floating torch.dtype, got {dtype!r}")
    check_memory(2 * m * n * n * 8, f"{m} random patterns of {n}x{n}", func)
    return m, n


def random_binary_patterns(
    m: int, n: int, p: float = 0.5, generator: torch.Generator | None = None,
    dtype: torch.dtype = torch.float32,
) -> torch.Tensor:
    """I.i.d. Bernoulli(``p``) 0/1 DMD patterns, shape ``(m, n, n)``, from ``generator``."""
    check_in_range(p, 0.0, 1.0, "p", "random_binary_patterns", lo_open=True, hi_open=True)
    m, n = _check_sizes(m, n, dtype, "random_binary_patterns")
    u = torch.rand(m, n, n, generator=generator, dtype=torch.float64)
    return (u < p).to(dtype)


def gaussian_speckle_patterns(
    m: int, n: int, grain: float = 0.0, generator: torch.Generator | None = None,
    dtype: torch.dtype = torch.float32,
) -> torch.Tensor:
    """Gaussian speckle patterns ``(m, n, n)``: i.i.d. N(0, 1), optionally correlated.

    ``grain > 0`` blurs each pattern with a Gaussian of that σ (pixels; ``2·⌊3σ⌋ + 1`` taps,
    circular boundary, kornia) and re-standardises it, giving speckle grains of about
    ``grain`` pixels (pseudo-thermal light, Shapiro 2008 computational GI). ``grain`` may
    reach ``n``: a window wider than the pattern wraps around it (the taps are summed per
    pixel of the period, the same circular convolution).

    Raises:
        TypeError: if ``m``/``n`` are not ints or ``dtype`` is not a floating dtype.
        ValueError: if ``m``/``n`` < 1, ``grain`` is outside ``[0, n]``, or ``grain > 0``
            with ``n = 1`` (a single pixel has no spatial correlation to give and no
            spread to re-standardise).
    """
    func = "gaussian_speckle_patterns"
    m, n = _check_sizes(m, n, dtype, func)
    check_in_range(grain, 0.0, float(n), "grain", func)
    if grain > 0 and n == 1:
        raise ValueError(f"{func}: expected grain = 0 for n = 1 (one pixel cannot be blurred "
                         f"and re-standardised), got grain={grain}")
    z = torch.randn(m, 1, n, n, generator=generator, dtype=torch.float64)
    if grain > 0:
        import kornia

        k = 2 * int(3 * grain) + 1
        if k // 2 <= n:  # kornia's circular padding wraps at most once
            z = kornia.filters.gaussian_blur2d(z, (k, k), (grain, grain), border_type="circular")
        else:
            z = _circular_blur(z, kornia.filters.get_gaussian_kernel1d(
                k, float(grain), dtype=torch.float64)[0])
        z = (z - z.mean(dim=(-2, -1), keepdim=True)) / z.std(dim=(-2, -1), keepdim=True)
    return z[:, 0].to(dtype)


def _circular_blur(z: torch.Tensor, kernel: torch.Tensor) -> torch.Tensor:
    """Separable circular convolution of ``z (..., n, n)`` with a symmetric 1-D ``kernel``
    of any length: its taps are folded onto the period (tap ``t`` of offset ``t − k//2``
    adds to offset ``(t − k//2) mod n``), then applied as an ``n × n`` circulant matrix."""
    n, k = z.shape[-1], kernel.shape[0]
    offsets = (torch.arange(k) - k // 2) % n
    w = torch.zeros(n, dtype=kernel.dtype).index_add_(0, offsets, kernel)
    idx = torch.arange(n)
    c = w[(idx[None, :] - idx[:, None]) % n]  # c[i, l] = w[(l − i) mod n]
    return c @ z @ c.T
