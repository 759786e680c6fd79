"""Small, robust timer: warm-up, then the median of repeated calls (noisy shared machines).

Every sample synchronises the device of a CUDA call (``torch.cuda.synchronize``) so that an
asynchronous kernel launch is not timed as its run."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable

import torch

__all__ = ["time_call", "machine_load"]


def time_call(fn: Callable[[], object], repeat: int = 7, min_time_s: float = 0.05, warmup: int = 1):
    """Median wall time (s) of ``fn()``; each sample loops until it lasts ``min_time_s``."""
    sync = torch.cuda.synchronize if torch.cuda.is_available() else (lambda: None)
    for _ in range(warmup):
        fn()
    sync()
    t0 = time.perf_counter()
    fn()
    sync()
    one = max(time.perf_counter() - t0, 1e-7)
    inner = max(1, int(min_time_s / one))
    samples = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(inner):
            fn()
        sync()
        samples.append((time.perf_counter() - t0) / inner)
    return statistics.median(samples)


def machine_load() -> dict:
    """What the machine was doing: the 1-minute load average (``os.getloadavg``, ``None``
    where the OS has none), the CPU count and torch's intra-op threads. Benchmarks record it
    at their start and end, because their seconds only mean something with the load."""
    import os

    try:
        load = round(os.getloadavg()[0], 2)
    except (AttributeError, OSError):  # Windows
        load = None
    return {"load_1min": load, "cpus": os.cpu_count(), "threads": torch.get_num_threads()}
