"""``torchtof bench operators``: forward + adjoint time of the fast Hadamard operator
against a dense matmul baseline and :class:`PatternOperator`, as ratios from one run.

The dense baseline is a plain ``(M, N)`` float32 matrix product ``y = x A^T``,
``x = y A``: what a generic single-pixel-imaging library does. Sizes whose dense matrix
would exceed ``dense_max_bytes`` are not built (reported as skipped, with the size).
"""

from __future__ import annotations

import math

import torch

from ..._optional import progress_bar
from ...operators import Hadamard, PatternOperator
from ...report import print_table
from .timing import time_call


def bench_operators(
    ns=(32, 64, 128, 256), batch: int = 16, sr: float = 0.25, dense_max_bytes: float = 2.5e9,
    repeat: int = 5, progress: bool = False,
) -> dict:
    """Median time of forward + adjoint per operator and DMD side ``n`` (a progress bar on
    stderr with ``progress``)."""
    rows = []
    for n in progress_bar(ns, desc="bench operators", disable=not progress, leave=False):
        big = n * n
        x = torch.randn(batch, 1, n, n)
        row = {"n": n, "N": big, "M": Hadamard(n, sr=sr).m, "batch": batch}  # M >= 1, as used
        for method in ("matmul", "kron", "fwht"):
            A = Hadamard(n, sr=sr, method=method)
            row[f"hadamard_{method}_s"] = time_call(lambda A=A, x=x: A.adjoint(A(x)), repeat=repeat)
        row["hadamard_auto"] = Hadamard(n, sr=sr).method
        m = row["M"]
        nbytes = 4.0 * m * big
        if nbytes <= dense_max_bytes:
            A = Hadamard(n, sr=sr)
            pats = A.patterns() / n
            dense = pats.reshape(m, big).contiguous()
            xf = x.reshape(batch, big)
            row["dense_s"] = time_call(lambda xf=xf, d=dense: (xf @ d.T) @ d, repeat=repeat)
            P = PatternOperator(pats)
            row["pattern_operator_s"] = time_call(lambda P=P, x=x: P.adjoint(P(x)), repeat=repeat)
            del dense, pats, P
        else:
            row["dense_s"] = None
            row["pattern_operator_s"] = None
            row["dense_skipped"] = f"dense matrix would need {nbytes / 1e9:.1f} GB"
        best = min(row[f"hadamard_{k}_s"] for k in ("matmul", "kron", "fwht"))
        row["best_hadamard_s"] = best
        if row["dense_s"]:
            row["speedup_vs_dense"] = row["dense_s"] / best
            row["speedup_vs_pattern_operator"] = row["pattern_operator_s"] / best
        row["fwht_s_per_NlogN_ns"] = row["hadamard_fwht_s"] / (big * math.log2(big)) * 1e9
        rows.append(row)
    # growth: time ratio between consecutive sizes vs the N log N ratio
    for a, b in zip(rows, rows[1:]):
        nlogn = (b["N"] * math.log2(b["N"])) / (a["N"] * math.log2(a["N"]))
        b["kron_growth"] = b["hadamard_kron_s"] / a["hadamard_kron_s"]
        b["fwht_growth"] = b["hadamard_fwht_s"] / a["hadamard_fwht_s"]
        b["NlogN_growth"] = nlogn
    return {
        "benchmark": "operators",
        "batch": batch,
        "sr": sr,
        "repeat": repeat,
        "threads": torch.get_num_threads(),
        "torch": torch.__version__,
        "rows": rows,
    }


def print_operators(result: dict) -> None:
    cols = [
        "n", "M", "hadamard_matmul_s", "hadamard_kron_s", "hadamard_fwht_s", "hadamard_auto",
        "dense_s",
        "pattern_operator_s", "speedup_vs_dense", "speedup_vs_pattern_operator",
        "kron_growth", "fwht_growth", "NlogN_growth",
    ]
    print(f"forward+adjoint, batch {result['batch']}, SR {result['sr']:.0%}, "
          f"{result['threads']} thread{'s' * (result['threads'] != 1)}, torch {result['torch']}")
    print_table(result["rows"], cols)
    for r in result["rows"]:
        if r.get("dense_skipped"):
            print(f"n={r['n']}: dense baseline skipped ({r['dense_skipped']})")
