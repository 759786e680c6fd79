"""Wall time of exactly 300 DIP iterations (early_stop=None) at 32x32, 2 threads.

Usage: python benchmarks/time_dip.py"""

import statistics
import time

import torch

torch.set_num_threads(2)
from torchtof.operators import Hadamard
from torchtof.recon.dip import fit_dip
from torchtof.scenes import sky_character

for sr in (0.0625, 0.125):
    A = Hadamard(32, sr=sr)
    y = A(sky_character(32))
    fit_dip(y, A, max_iter=10)
    walls = []
    for s in range(5):
        t = time.perf_counter()
        r = fit_dip(y, A, max_iter=300, early_stop=None, seed=s)
        walls.append(time.perf_counter() - t)
    print(
        "sr",
        sr,
        "threads",
        torch.get_num_threads(),
        "iterations",
        r.n_iter,
        f"wall min {min(walls):.2f} s median {statistics.median(walls):.2f} s max {max(walls):.2f} s",
    )
