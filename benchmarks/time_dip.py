"""Wall time of exactly ITERS DIP iterations (early_stop=None) at 32x32, per sampling rate.

Usage: python benchmarks/time_dip.py [--iters 300] [--repeats 5] [--threads 2] [--out DIR]
(minutes of silent work with the defaults; --help lists the options). ``--out DIR`` writes
``DIR/time_dip.json`` (every wall time and the machine's load at start and end), which
``docs/build.py`` renders into the README."""

import argparse
import json
import statistics
import time
from pathlib import Path

from torchtof.apps.args import OneLineParser, positive_int, sampling_rate


def main(argv: list[str] | None = None) -> None:
    p = OneLineParser(
        description="Time DIP (torchtof.recon.dip.fit_dip) on the 32x32 sky character: "
        "ITERS iterations without early stopping, REPEATS seeds per sampling rate; prints "
        "the min/median/max wall time. Takes minutes with the defaults.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter, allow_abbrev=False)
    p.add_argument("--iters", type=positive_int, default=300, help="DIP iterations per run")
    p.add_argument("--repeats", type=positive_int, default=5, help="runs (seeds) per sampling rate")
    p.add_argument("--threads", type=positive_int, default=2, help="torch intra-op threads")
    p.add_argument("--srs", type=sampling_rate, nargs="+", default=[0.0625, 0.125],
                   help="sampling rates M/n²")
    p.add_argument("--out", default=None, help="write DIR/time_dip.json")
    a = p.parse_args(argv)

    import torch

    from torchtof.apps.bench.timing import machine_load
    from torchtof.operators import Hadamard
    from torchtof.recon.dip import fit_dip
    from torchtof.scenes import sky_character

    torch.set_num_threads(a.threads)
    start, rows = machine_load(), []
    for sr in a.srs:
        A = Hadamard(32, sr=sr)
        y = A(sky_character(32))
        fit_dip(y, A, max_iter=10)  # warm-up
        walls = []
        for s in range(a.repeats):
            t = time.perf_counter()
            r = fit_dip(y, A, max_iter=a.iters, early_stop=None, seed=s)
            walls.append(time.perf_counter() - t)
        print(f"sr {sr} threads {torch.get_num_threads()} iterations {r.n_iter} "
              f"wall min {min(walls):.2f} s median {statistics.median(walls):.2f} s "
              f"max {max(walls):.2f} s")
        rows.append({"sr": sr, "iterations": r.n_iter, "walls_s": walls,
                     "median_s": statistics.median(walls)})
    if a.out:
        out = Path(a.out)
        out.mkdir(parents=True, exist_ok=True)
        res = {"command": f"python benchmarks/time_dip.py --iters {a.iters} --repeats "
               f"{a.repeats} --threads {a.threads}", "n": 32, "iters": a.iters,
               "repeats": a.repeats, "rows": rows,
               "machine": {"start": start, "end": machine_load()}}
        (out / "time_dip.json").write_text(json.dumps(res, indent=1) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
