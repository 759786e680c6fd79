"""Skip what a scene doesn't need: scene-adaptive acquisition and reconstruction."""

from .budget import DEFAULT_TABLE, MethodChoice, choose_method, load_table, save_table
from .detect import (
    DarkReference,
    FarEstimate,
    VeilEstimate,
    dark_reference,
    detect_far_background,
    detect_veil,
)
from .noise import (
    noise_from_blocks,
    noise_from_pair_sums,
    noise_from_pairs,
    noise_from_repeats,
    pair_differences,
    pair_noise_dof,
    pair_sums,
    variance_lower_factor,
)
from .pipeline import AdaptiveResult, run_adaptive, run_fixed, signed_buckets
from .progressive import (
    BUCKET_KINDS,
    PROGRESSIVE_RULES,
    ProgressiveResult,
    ProgressiveStop,
    block_statistics,
    run_progressive,
)
from .solvers import SOLVERS, SolveResult, solve_at_noise

__all__ = [
    "AdaptiveResult",
    "run_adaptive",
    "run_fixed",
    "signed_buckets",
    "SOLVERS",
    "SolveResult",
    "solve_at_noise",
    "DEFAULT_TABLE",
    "MethodChoice",
    "choose_method",
    "load_table",
    "save_table",
    "DarkReference",
    "FarEstimate",
    "VeilEstimate",
    "dark_reference",
    "detect_far_background",
    "detect_veil",
    "noise_from_repeats",
    "noise_from_blocks",
    "noise_from_pairs",
    "noise_from_pair_sums",
    "pair_sums",
    "pair_differences",
    "pair_noise_dof",
    "variance_lower_factor",
    "BUCKET_KINDS",
    "PROGRESSIVE_RULES",
    "ProgressiveStop",
    "ProgressiveResult",
    "block_statistics",
    "run_progressive",
]
