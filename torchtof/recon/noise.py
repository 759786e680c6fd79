"""Noise level of the buckets, estimated from the data: one module for every estimator.

The estimates feed the noise-aware solvers (TVAL3's ``mu="auto"``, BP's ``eps="auto"``, the
DIP's ``zeta="auto"``) and the stopping rules (the discrepancy principle
``‖A x − y‖² ≤ τ M σ²``, Morozov 1966; :data:`torchtof.constants.DISCREPANCY_TAU`).

- :func:`tail_noise_sigma`: one run in a low-to-high order (cake-cutting, sequency,
  Russian-doll): the signal falls with the order while white noise stays flat, so a quantile
  of ``|y|`` over the last measurements estimates the noise (``q = 0.5``: the MAD rule of
  Donoho & Johnstone 1994). Signal left there biases it upwards.
- :func:`noise_from_blocks`: the same idea over the complete blocks of the high-order half
  of the record (MAD).
- :func:`noise_from_repeats`: ``R ≥ 2`` realisations of the same buckets (repeated ToF frames
  of the same patterns). ``y_r = s + e_r`` with i.i.d. noise, so the unbiased sample variance
  over ``r``, averaged over the ``M`` patterns, estimates ``σ²`` whatever the signal ``s``.
- :func:`noise_from_pairs` / :func:`noise_from_pair_sums`: free, from the complementary DMD
  pairs of one run. Every ±1 row is shown as ``φ⁺ = (1 + h)/2`` and ``φ⁻ = (1 − h)/2``, so
  ``φ⁺ + φ⁻`` is the all-on pattern for every row: for linear (intensity) buckets
  ``s_i = y⁺_i + y⁻_i`` is the same for every pair up to noise, and nearly so for the depth
  buckets (each pixel is lit by exactly one of the two patterns). The noise of ``s_i/n``
  equals that of the signed coefficient ``(y⁺_i − y⁻_i)/n`` (same two frames), so the spread
  of the pair sums over the pairs measured so far estimates ``σ`` without repeated patterns,
  with degrees of freedom growing with ``m``. Successive differences remove a slow drift of
  the light; the first (all-on, dark) pair is skipped.
"""

from __future__ import annotations

import math
from statistics import NormalDist

import torch

from .._checks import (
    check_bool,
    check_finite,
    check_in_range,
    check_rank,
    check_real,
    check_tensor,
)
from .base import pow2_scale

__all__ = ["tail_noise_sigma", "abs_quantile_sigma", "noise_from_repeats", "noise_from_blocks",
           "noise_from_pairs", "noise_from_pair_sums", "pair_sums", "pair_differences",
           "pair_noise_dof", "variance_lower_factor"]

_MAD = NormalDist().inv_cdf(0.75)  # median |z| of a standard normal z
_INTERPOLATION = ("linear", "lower")


def abs_quantile_sigma(t: torch.Tensor, quantile: float = 0.5,
                       interpolation: str = "linear") -> torch.Tensor:
    r"""Noise std from the ``q``-quantile of ``|t|`` over the last axis (white Gaussian noise).

    .. math:: \hat\sigma = Q_q(|t|) / \Phi^{-1}\big(\tfrac{1 + q}{2}\big)

    (``|z|`` of ``z ~ N(0, σ²)`` is half-normal; ``q = 0.5`` is the MAD rule of Donoho &
    Johnstone 1994). ``interpolation``: ``"linear"`` between order statistics (as
    ``torch.quantile``) or ``"lower"`` (the lower one; at ``q = 0.5`` the value of
    ``torch.median``). All indices are static (Python ints), so tracing records none.

    Example:
        >>> round(float(abs_quantile_sigma(torch.tensor([-1.0, 2.0, -3.0]))), 4)
        2.9652
    """
    fn = "abs_quantile_sigma"
    if interpolation not in _INTERPOLATION:
        raise ValueError(f"{fn}: expected interpolation in {_INTERPOLATION}, "
                         f"got {interpolation!r}")
    check_real(t, "t", fn)  # shape and range only: its callers have checked the values
    check_in_range(quantile, 0.0, 1.0, "quantile", fn, True, True)
    if t.ndim < 1 or t.shape[-1] < 1:
        raise ValueError(f"{fn}: expected t with at least one value on its last axis, got "
                         f"shape {tuple(t.shape)}")
    k = int(t.shape[-1])
    s = torch.sort(t.abs(), dim=-1).values
    pos = quantile * (k - 1)
    lo, frac = int(math.floor(pos)), pos - math.floor(pos)
    if interpolation == "lower" or frac == 0.0:
        q = s[..., lo]
    else:
        q = s[..., lo] * (1 - frac) + s[..., min(lo + 1, k - 1)] * frac
    return q / NormalDist().inv_cdf((1.0 + quantile) / 2)


def tail_noise_sigma(y: torch.Tensor, tail: float = 0.25, quantile: float = 0.2,
                     min_count: int = 8, interpolation: str = "linear") -> torch.Tensor:
    r"""Noise std of buckets in a low-to-high order from a quantile of their high-order tail.

    With ``t = |y|`` over the last ``k = min(M, max(min_count, ⌈tail·M⌉))`` measurements,
    ``σ̂ = Q_q(t) / Φ⁻¹((1 + q)/2)`` (:func:`abs_quantile_sigma`). A low quantile
    (``q = 0.2``, TVAL3's and the DIP's default) lets the many small signal coefficients of
    piecewise-constant scenes pull the estimate towards 0, so noise-free buckets of such
    scenes read as noise-free; scenes with rich texture still leave signal in the tail and
    read as slightly noisy. ``q = 0.5``, ``min_count=1``, ``interpolation="lower"`` is the
    plain MAD rule over the last quarter (BP's ``eps="auto"``). For operators without a
    low-to-high order pass the noise level instead.

    Args:
        y: buckets ``(B, C, M)``, ``M >= 1``.
        tail: fraction of the measurements used, from the end, in ``(0, 1]``.
        quantile: ``q`` in ``(0, 1)``.
        min_count: at least this many measurements (``>= 1``; all of them if ``M`` is less).
        interpolation: ``"linear"`` or ``"lower"`` (:func:`abs_quantile_sigma`).

    Returns:
        ``(B, C)`` noise std in the units of ``y``.

    Example:
        >>> y = 0.5 * torch.randn(1, 1, 65536, generator=torch.Generator().manual_seed(0))
        >>> round(float(tail_noise_sigma(y)), 1)
        0.5
    """
    fn = "tail_noise_sigma"
    check_real(y, "y", fn)
    if y.ndim < 1:
        raise ValueError(f"{fn}: expected y with a measurement axis, got a 0-d tensor")
    check_finite(y, "y", fn)
    check_in_range(tail, 0.0, 1.0, "tail", fn, lo_open=True)
    check_in_range(quantile, 0.0, 1.0, "quantile", fn, True, True)
    if isinstance(min_count, bool) or not isinstance(min_count, int) or min_count < 1:
        raise ValueError(f"{fn}: expected min_count to be an int >= 1, got {min_count!r}")
    m = int(y.shape[-1])
    if m < 1:
        raise ValueError(f"{fn}: expected y with at least one measurement, got {tuple(y.shape)}")
    k = min(m, max(min_count, int(math.ceil(tail * m))))
    return abs_quantile_sigma(y[..., m - k :], quantile, interpolation)


def noise_from_repeats(y: torch.Tensor) -> torch.Tensor:
    """Noise std of buckets from ``R`` repeated realisations on the batch axis.

    .. math:: \\hat\\sigma^2 = \\frac{1}{M}\\sum_i \\frac{1}{R-1}\\sum_r (y_{r,i} - \\bar y_i)^2

    Args:
        y: buckets ``(R, C, M)``, ``R ≥ 2`` realisations of the same patterns.

    Returns:
        ``(C,)`` noise std in the units of ``y``.

    Raises:
        ValueError: fewer than 2 realisations, wrong rank, NaN/Inf.

    Example:
        >>> g = torch.Generator().manual_seed(0)
        >>> s = torch.randn(1, 1, 4096, generator=g)
        >>> y = s + 0.5 * torch.randn(4, 1, 4096, generator=g)
        >>> round(float(noise_from_repeats(y)), 1)
        0.5
    """
    fn = "noise_from_repeats"
    check_tensor(y, "y", fn)
    check_rank(y, 3, "y", fn, "(R, C, M)")
    if y.shape[0] < 2 or y.shape[-1] < 1:
        raise ValueError(f"{fn}: expected y of shape (R >= 2, C, M >= 1), got {tuple(y.shape)}")
    check_finite(y, "y", fn)
    k = pow2_scale(y.transpose(0, 1).reshape(y.shape[1], -1))  # (C, 1), exact
    # scaled by a power of two per channel: the squares neither overflow nor underflow
    return (y * k).var(dim=0, unbiased=True).mean(dim=-1).sqrt() / k[:, 0]


def noise_from_blocks(y: torch.Tensor, block: int = 32) -> torch.Tensor:
    r"""Noise std of buckets in a low-to-high order from the high-order half of the record.

    .. math:: \hat\sigma = \operatorname{median}_{i > m/2} |y_i| / \Phi^{-1}(3/4)

    over the coefficients of the complete blocks in the second half of the record (at least
    one block), the MAD rule of Donoho & Johnstone (1994). For low-to-high orders the high
    orders carry the least signal; what signal is left there biases the estimate upwards.

    Args:
        y: buckets ``(B, C, M)`` in acquisition order, ``M ≥ 2·block``.
        block: block length ``≥ 4``.

    Returns:
        ``(B, C)`` noise std in the units of ``y``.

    Raises:
        ValueError: ``M < 2·block``, ``block < 4``, wrong rank, NaN/Inf.

    Example:
        >>> y = torch.randn(1, 1, 1024, generator=torch.Generator().manual_seed(0))
        >>> 0.9 < float(noise_from_blocks(y, 64)) < 1.1
        True
    """
    fn = "noise_from_blocks"
    check_tensor(y, "y", fn)
    check_rank(y, 3, "y", fn, "(B, C, M)")
    if isinstance(block, bool) or not isinstance(block, int) or block < 4:
        raise ValueError(f"{fn}: expected block to be an int >= 4, got {block!r}")
    m = y.shape[-1]
    if m < 2 * block:
        raise ValueError(f"{fn}: expected y with at least 2*block = {2 * block} buckets, got {m}")
    check_finite(y, "y", fn)
    k = m // block
    tail = y[..., (k - k // 2) * block : k * block]
    return abs_quantile_sigma(tail, 0.5, "lower")


def pair_sums(y_split: torch.Tensor, n: int) -> torch.Tensor:
    """Interleaved DMD buckets ``(B, C, 2M)`` → pair sums ``(y⁺ + y⁻)/n`` ``(B, C, M)``.

    The companion of :func:`~torchtof.operators.split.combine_split` (``(y⁺ − y⁻)/n``): the
    same two frames, so the same noise per coefficient, but the signal of the all-on pattern
    ``φ⁺ + φ⁻`` for every row (module docstring).

    Raises:
        ValueError: not ``(B, C, 2M)`` with an even, non-zero last axis; ``n < 1``; NaN/Inf.

    Example:
        >>> pair_sums(torch.tensor([[[3.0, 1.0, 2.0, 2.0]]]), 2)
        tensor([[[2., 2.]]])
    """
    fn = "pair_sums"
    check_tensor(y_split, "y_split", fn)
    check_rank(y_split, 3, "y_split", fn, "(B, C, 2M)")
    if y_split.shape[-1] < 2 or y_split.shape[-1] % 2:
        raise ValueError(f"{fn}: expected y_split with an even number >= 2 of buckets, got "
                         f"{y_split.shape[-1]}")
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ValueError(f"{fn}: expected n to be an int >= 1, got {n!r}")
    check_finite(y_split, "y_split", fn)
    y = y_split.reshape(*y_split.shape[:-1], -1, 2)
    return (y[..., 0] + y[..., 1]) / n


def pair_differences(s: torch.Tensor, skip: int = 1) -> torch.Tensor:
    """Successive differences ``d_i = s_{i+1} − s_i`` of pair sums ``(B, C, M)``, the first
    ``skip`` pairs left out: ``(B, C, M − skip − 1)``.

    For a constant sum plus i.i.d. noise, ``d_i`` has variance ``2σ²``, like the difference
    ``y − y′`` of two measurements of one pattern, so it can stand in for repeated
    differences (e.g. in :func:`~torchtof.adaptive.detect.gate_changes_image`); a drift ``δ``
    per pair adds only ``δ`` to it.

    Raises:
        ValueError: fewer than ``skip + 3`` sums, ``skip < 0``, wrong rank, NaN/Inf.
    """
    fn = "pair_differences"
    check_tensor(s, "s", fn)
    check_rank(s, 3, "s", fn, "(B, C, M)")
    if isinstance(skip, bool) or not isinstance(skip, int) or skip < 0:
        raise ValueError(f"{fn}: expected skip to be an int >= 0, got {skip!r}")
    if s.shape[-1] < skip + 3:
        raise ValueError(f"{fn}: expected at least skip + 3 = {skip + 3} pair sums, got "
                         f"{s.shape[-1]}")
    check_finite(s, "s", fn)
    t = s[..., skip:]
    return t[..., 1:] - t[..., :-1]


def noise_from_pair_sums(s: torch.Tensor, skip: int = 1, robust: bool = True) -> torch.Tensor:
    r"""Noise std of the signed coefficients from the pair sums ``s = (y⁺ + y⁻)/n``.

    With ``d`` the successive differences of the sums (:func:`pair_differences`):

    .. math::

        \hat\sigma = \frac{\operatorname{median}|d_i|}{\sqrt2\,\Phi^{-1}(3/4)}
        \quad(\text{robust}), \qquad
        \hat\sigma^2 = \frac{1}{2K}\sum_{i=1}^{K} d_i^2 \quad(\text{else; von Neumann 1941}).

    Robust: an outlying pair (a glitch frame) or a step in the light moves it little. Either
    way the depth buckets' sums are only nearly constant, so ``σ̂`` is biased up (README).

    Args:
        s: pair sums ``(B, C, M)`` in acquisition order (:func:`pair_sums`).
        skip: leading pairs left out (1: the all-on/dark pair).
        robust: MAD of the differences (default) or their root mean square.

    Returns:
        ``(B, C)`` noise std in the units of the signed coefficients.

    Raises:
        ValueError: as :func:`pair_differences`.

    Example:
        >>> g = torch.Generator().manual_seed(0)
        >>> s = 7.0 + 0.5 * torch.randn(1, 1, 4096, generator=g)
        >>> round(float(noise_from_pair_sums(s)), 1)
        0.5
    """
    check_bool(robust, "robust", "noise_from_pair_sums")
    d = pair_differences(s, skip)
    if robust:
        return d.abs().median(dim=-1).values / (_MAD * 2**0.5)
    k = pow2_scale(d)  # (B, C, 1), exact: the squares neither overflow nor underflow
    return ((d * k).pow(2).mean(dim=-1) / 2).sqrt() / k[..., 0]


def noise_from_pairs(y_split: torch.Tensor, n: int, skip: int = 1,
                     robust: bool = True) -> torch.Tensor:
    """Noise std ``(B, C)`` of ``(y⁺ − y⁻)/n`` from interleaved DMD buckets ``(B, C, 2M)`` of
    one run: :func:`noise_from_pair_sums` of :func:`pair_sums` (module docstring)."""
    return noise_from_pair_sums(pair_sums(y_split, n), skip, robust)


#: effective χ² degrees of freedom per successive difference of the pair-sum estimates
#: (``2 E[σ̂²]² / Var σ̂²`` for Gaussian sums, 20 000 simulated records of K = 128 and 512:
#: 0.306 for the MAD of differences, 0.67–0.673 for their mean square, whose asymptotic value
#: is 2/3, von Neumann 1941).
_PAIR_DOF = {True: 0.306, False: 2.0 / 3.0}


def pair_noise_dof(k: int, robust: bool = True) -> int:
    """Effective degrees of freedom of :func:`noise_from_pair_sums` from ``k`` differences.

    ``σ̂²`` is then treated as ``σ² χ²_ν/ν`` with ``ν`` this value (e.g. in
    :func:`variance_lower_factor`): successive differences are correlated (lag-one correlation
    −1/2) and the MAD is less efficient than the mean square, so ``ν < k``.

    Raises:
        ValueError: ``k < 1``.

    Example:
        >>> pair_noise_dof(126), pair_noise_dof(126, robust=False)
        (39, 84)
    """
    if isinstance(k, bool) or not isinstance(k, int) or k < 1:
        raise ValueError(f"pair_noise_dof: expected k to be an int >= 1, got {k!r}")
    check_bool(robust, "robust", "pair_noise_dof")
    return max(1, round(_PAIR_DOF[bool(robust)] * k))


def variance_lower_factor(dof: int, level: float = 0.05) -> float:
    r"""Lower confidence factor of a variance estimated from ``dof`` degrees of freedom.

    ``σ̂² = ‖d‖²/(2B)`` from ``B`` repeated differences has ``Bσ̂²/σ² ~ χ²_B``, so

    .. math::

        q = B / \chi^2_{B}(1 - \text{level}), \qquad
        P(q\,\hat\sigma^2 \le \sigma^2) = 1 - \text{level}

    (the lower confidence limit of ``σ²``; ``χ²_B(p)`` is the ``p`` quantile of ``χ²_B``).

    ``q σ̂²`` is a variance that the noise exceeds with probability ``1 − level``: a
    discrepancy bound ``‖Ax − y‖² ≤ M q σ̂²`` then stops a solver early (on an over-estimated
    ``σ̂``) in at most a fraction ``level`` of runs (Morozov's rule with ``τ = q``).

    Args:
        dof: degrees of freedom ``B ≥ 1`` of the estimate.
        level: one-sided level in ``(0, 1)``.

    Returns:
        ``q`` (``< 1`` for ``level < 0.5``; ``→ 1`` as ``dof → ∞``).

    Raises:
        ValueError: ``dof < 1`` or ``level`` outside ``(0, 1)``.

    Example:
        >>> round(variance_lower_factor(32), 2)
        0.69
    """
    fn = "variance_lower_factor"
    if isinstance(dof, bool) or not isinstance(dof, int) or dof < 1:
        raise ValueError(f"{fn}: expected dof to be an int >= 1, got {dof!r}")
    if not 0.0 < float(level) < 1.0:
        raise ValueError(f"{fn}: expected level in (0, 1), got {level!r}")
    from scipy.stats import chi2

    return dof / float(chi2.ppf(1.0 - float(level), dof))
