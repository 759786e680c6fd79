"""Measurement operators: Hadamard (fast), dense patterns, DMD split, pattern generators."""

from .base import LinearOperator
from .dense import PatternOperator, pattern_adjoint, pattern_forward
from .fwht import fwht, fwht2, sylvester
from .hadamard import Hadamard, hadamard_adjoint, hadamard_forward
from .patterns import (
    ORDERS,
    gaussian_speckle_patterns,
    hadamard_order,
    hadamard_patterns,
    random_binary_patterns,
    row_sequency,
)
from .split import DMDSplit, combine_split, split_patterns

__all__ = [
    "LinearOperator",
    "Hadamard",
    "PatternOperator",
    "DMDSplit",
    "ORDERS",
    "hadamard_order",
    "hadamard_patterns",
    "random_binary_patterns",
    "gaussian_speckle_patterns",
    "row_sequency",
    "fwht",
    "fwht2",
    "sylvester",
    "hadamard_forward",
    "hadamard_adjoint",
    "pattern_forward",
    "pattern_adjoint",
    "split_patterns",
    "combine_split",
]
