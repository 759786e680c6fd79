"""Noise level of Hadamard buckets: re-exported from :mod:`torchtof.recon.noise`, the one
module of noise estimators (repeated frames, the high-order tail, the DMD pair sums).

They feed the stopping rules of :mod:`torchtof.adaptive` (the progressive stop and the
discrepancy principle, ``‖A x − y‖² ≤ τ M σ²``; Morozov 1966).
"""

from __future__ import annotations

from ..recon.noise import (
    noise_from_blocks,
    noise_from_pair_sums,
    noise_from_pairs,
    noise_from_repeats,
    pair_differences,
    pair_noise_dof,
    pair_sums,
    variance_lower_factor,
)

__all__ = ["noise_from_repeats", "noise_from_blocks", "noise_from_pairs", "noise_from_pair_sums",
           "pair_sums", "pair_differences", "pair_noise_dof", "variance_lower_factor"]
