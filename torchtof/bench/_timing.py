"""Small, robust timer: warm-up, then the median of repeated calls (noisy shared machines)."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable


def time_call(fn: Callable[[], object], repeat: int = 7, min_time_s: float = 0.05, warmup: int = 1):
    """Median wall time (s) of ``fn()``; each sample loops until it lasts ``min_time_s``."""
    for _ in range(warmup):
        fn()
    t0 = time.perf_counter()
    fn()
    one = max(time.perf_counter() - t0, 1e-7)
    inner = max(1, int(min_time_s / one))
    samples = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(inner):
            fn()
        samples.append((time.perf_counter() - t0) / inner)
    return statistics.median(samples)


def print_table(rows: list[dict], cols: list[str], floatfmt: str = "{:.3g}") -> None:
    """Print ``rows`` as an aligned text table with the given column order."""
    cells = [[c for c in cols]] + [
        [floatfmt.format(r[c]) if isinstance(r.get(c), float) else str(r.get(c, "")) for c in cols]
        for r in rows
    ]
    widths = [max(len(row[i]) for row in cells) for i in range(len(cols))]
    for k, row in enumerate(cells):
        print("  ".join(v.rjust(w) for v, w in zip(row, widths)))
        if k == 0:
            print("  ".join("-" * w for w in widths))
