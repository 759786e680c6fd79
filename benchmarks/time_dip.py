"""Wall time of exactly ITERS DIP iterations (early_stop=None) at 32x32, per sampling rate.

Usage: python benchmarks/time_dip.py [--iters 300] [--repeats 5] [--threads 2]
(minutes of silent work with the defaults; --help lists the options)."""

import argparse
import statistics
import time

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
    a = p.parse_args(argv)

    import torch

    from torchtof.operators import Hadamard
    from torchtof.recon.dip import fit_dip
    from torchtof.scenes import sky_character

    torch.set_num_threads(a.threads)
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


if __name__ == "__main__":
    main()
