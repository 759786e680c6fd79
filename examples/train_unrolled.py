"""Train the unrolled TVAL3 on synthetic scenes (CPU, minutes), one process or data-parallel.

One configuration::

    python examples/train_unrolled.py --n 32 --sr 0.25 --steps 300 --out /tmp/w.pt

Regenerate every shipped weight file (n = 32, 64 at the paper's six SRs) into
``torchtof/weights/``::

    python examples/train_unrolled.py --all

Data-parallel over N processes (DDP, gloo backend on CPU; the union of the shards is the
single-process global batch, so the result is the same model)::

    torchrun --nproc_per_node 2 -- examples/train_unrolled.py --n 32 --sr 0.25 --out /tmp/w.pt

(``--`` ends torchrun's own options: without it torchrun's parser rejects ``--n`` as an
ambiguous abbreviation of its ``--nnodes``/``--nproc-per-node``; ``--size`` is an alias of
``--n`` that needs no ``--``.) The global ``--batch`` must be divisible by the number of
processes. Run from an environment where ``torchtof`` is importable (``pip install -e .``
or ``PYTHONPATH=.``).
"""

from __future__ import annotations

import argparse
import os
import time

import torch

from torchtof.apps.args import (
    OneLineParser,
    nonneg_int,
    positive_float,
    positive_int,
    power_of_two,
    sampling_rate,
)
from torchtof.recon.train import PAPER_SRS, train_unrolled
from torchtof.recon.unrolled import DEFAULT_N_ITER, WEIGHTS_DIR, sr_code

#: Steps of the shipped weights per image side (≤ ~2 min each on 2 cores).
ALL_STEPS = {32: 400, 64: 600}


def main(argv: list[str] | None = None) -> None:
    p = OneLineParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter,
                                allow_abbrev=False)
    p.add_argument("--n", "--size", dest="n", type=power_of_two, default=32,
                   help="image side (a power of two in [4, 256])")
    p.add_argument("--sr", type=sampling_rate, default=0.25, help="sampling rate M/n² in (0, 1]")
    p.add_argument("--n-iter", type=positive_int, default=DEFAULT_N_ITER,
                   help="unrolled iterations K")
    p.add_argument("--order", default="cake_cutting", help="Hadamard order")
    p.add_argument("--steps", type=positive_int, default=300, help="optimiser steps")
    p.add_argument("--batch", type=positive_int, default=16, help="global batch (scenes per step)")
    p.add_argument("--lr", type=positive_float, default=0.05, help="peak Adam learning rate")
    p.add_argument(
        "--noise",
        type=float,
        nargs=2,
        default=(0.0, 0.02),
        metavar=("LO", "HI"),
        help="range of the per-scene noise level (fraction of the bucket spread)",
    )
    p.add_argument("--seed", type=int, default=0, help="base seed of the scene stream")
    p.add_argument("--threads", type=positive_int, default=1, help="torch threads per process")
    p.add_argument("--out", default=None, help="weight file to write (rank 0)")
    p.add_argument(
        "--all",
        action="store_true",
        help="regenerate every shipped file in torchtof/weights/ (ignores --n/--sr/--out)",
    )
    p.add_argument("--log-every", type=nonneg_int, default=50,
                   help="print the loss every N steps, 0: never (default: %(default)s)")
    a = p.parse_args(argv)
    torch.set_num_threads(a.threads)

    if a.all:
        jobs = [
            (n, sr, ALL_STEPS[n], WEIGHTS_DIR / f"unrolled_n{n}_sr{sr_code(sr)}_K{a.n_iter}.pt")
            for n in ALL_STEPS
            for sr in PAPER_SRS
        ]
    else:
        jobs = [(a.n, a.sr, a.steps, a.out)]
    for n, sr, steps, out in jobs:
        t0 = time.perf_counter()
        res = train_unrolled(
            n=n,
            sr=sr,
            n_layers=a.n_iter,
            order=a.order,
            steps=steps,
            batch_size=a.batch,
            lr=a.lr,
            noise_level=tuple(a.noise),
            seed=a.seed,
            out=out,
            log_every=a.log_every,
        )
        dt = time.perf_counter() - t0
        if int(os.environ.get("RANK", "0")) != 0:
            continue
        print(
            f"n={n} sr={sr} K={a.n_iter}: loss {res.losses[0]:.5f} -> {res.losses[-1]:.5f} "
            f"in {dt:.1f} s" + (f", wrote {out}" if out else ""),
            flush=True,
        )


if __name__ == "__main__":
    main()
