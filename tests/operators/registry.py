"""One registry of operators that the property tests iterate over."""

import torch

from torchtof.operators import (
    DMDSplit,
    Hadamard,
    PatternOperator,
    gaussian_speckle_patterns,
    random_binary_patterns,
)


def _binary():
    g = torch.Generator().manual_seed(1)
    return PatternOperator(random_binary_patterns(20, 8, generator=g))


def _speckle():
    g = torch.Generator().manual_seed(2)
    return PatternOperator(gaussian_speckle_patterns(24, 8, grain=1.0, generator=g))


OPERATORS = {
    "hadamard_cc_matmul": lambda: Hadamard(8, sr=0.25, method="matmul"),
    "hadamard_cc_fwht": lambda: Hadamard(8, sr=0.25, method="fwht"),
    "hadamard_cc_kron": lambda: Hadamard(8, sr=0.25, method="kron"),
    "hadamard_kron_64": lambda: Hadamard(64, sr=0.05, method="kron"),
    "hadamard_natural": lambda: Hadamard(4, m=5, order="natural"),
    "hadamard_sequency": lambda: Hadamard(16, sr=0.1, order="sequency"),
    "hadamard_russian_doll": lambda: Hadamard(8, sr=0.5, order="russian_doll"),
    "hadamard_full": lambda: Hadamard(8),
    "hadamard_one_pattern": lambda: Hadamard(4, m=1),
    "dmd_split": lambda: DMDSplit(Hadamard(8, sr=0.25)),
    "pattern_binary": _binary,
    "pattern_speckle": _speckle,
}
