"""Noise level of Hadamard buckets: from repeated frames or from high-order coefficients.

Both estimates feed the stopping rules of :mod:`torchtof.adaptive` (the progressive stop and
the discrepancy principle, ``‖A x − y‖² ≤ τ M σ²``; Morozov 1966).

- :func:`noise_from_repeats`: ``R ≥ 2`` realisations of the same buckets (repeated ToF frames
  of the same patterns). ``y_r = s + e_r`` with i.i.d. noise, so the unbiased sample variance
  over ``r``, averaged over the ``M`` patterns, estimates ``σ²`` whatever the signal ``s``.
- :func:`noise_from_blocks`: one run only. For low-to-high orders (cake-cutting, sequency,
  Russian-doll) the signal falls with the order while the noise stays flat, so the robust
  spread of the high-order half of the record, ``median|y| / Φ⁻¹(3/4)`` (the MAD rule,
  Donoho & Johnstone 1994), estimates the noise. Signal left there biases it upwards, which
  makes the rules that use it stop earlier; prefer repeated frames when they can be had.
"""

from __future__ import annotations

from statistics import NormalDist

import torch

from .._checks import check_finite, check_rank, check_tensor

__all__ = ["noise_from_repeats", "noise_from_blocks", "variance_lower_factor"]

_MAD = NormalDist().inv_cdf(0.75)  # median |z| of a standard normal z


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
    return y.var(dim=0, unbiased=True).mean(dim=-1).sqrt()


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
    return tail.abs().median(dim=-1).values / _MAD


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
