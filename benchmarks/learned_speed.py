"""Time per image of several learned weights files and TVAL3's defaults, interleaved.

On the three held-out depth scenes of ``eval_learned.py`` at SR 12.5 % and 1 % noise (one
batched call of 3 scenes, divided by 3), one thread: a warm-up call each, then ``rounds``
rounds that call every method once in turn; the minimum per method (the least disturbed
by other processes). Only the ratios within one run compare. ``--auto``: instead, the time
of :func:`torchtof.recon.auto.auto` (which stacks the network) with each file in place of the
shipped one, on the same buckets, interleaved the same way.

usage: OMP_NUM_THREADS=1 python benchmarks/learned_speed.py W1 [W2 ...] [--sizes 32 128 256]
           [--rounds 5] [--auto] [--out speed.json]
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
import eval_learned as ev  # noqa: E402

from torchtof.operators import Hadamard  # noqa: E402
from torchtof.recon.auto import auto  # noqa: E402
from torchtof.recon.learned import Learned  # noqa: E402
from torchtof.recon.tval3 import tval3  # noqa: E402

lm = importlib.import_module("torchtof.recon.learned")  # the module (the package exports a function of that name)


def _with_weights(w: str, A: Hadamard):
    def fn(v):
        lm.WEIGHTS_FILE = Path(w).resolve()  # what auto stacks
        return auto(v, A)
    return fn


def run(weights: list[str], sizes: list[int], rounds: int, with_auto: bool = False) -> list[dict]:
    torch.set_num_threads(1)
    shipped = lm.WEIGHTS_FILE
    rows = []
    for n in sizes:
        A = Hadamard(n, sr=0.125)
        x = ev.scenes("depth", n)
        y = ev.buckets(A, x, 0.01, salt=n)
        if with_auto:
            fns = {w: _with_weights(w, A) for w in weights}
        else:
            fns = {w: Learned(A, pretrained=w) for w in weights}
        fns["tval3"] = lambda v, A=A: tval3(v, A)
        t = ev.interleaved_min(fns, y, rounds)
        lm.WEIGHTS_FILE = shipped
        row = {"n": n, "auto": with_auto, "ms": {k: 1e3 * v for k, v in t.items()},
               "load_avg": os.getloadavg()[0]}
        rows.append(row)
        print(json.dumps(row), flush=True)
    return rows


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("weights", nargs="+")
    p.add_argument("--sizes", type=int, nargs="+", default=[32, 128, 256])
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--auto", action="store_true", help="time auto stacking each file")
    p.add_argument("--out", default=None)
    a = p.parse_args()
    rows = run(a.weights, a.sizes, a.rounds, a.auto)
    if a.out:
        Path(a.out).write_text(json.dumps({"rows": rows}, indent=1))


if __name__ == "__main__":
    main()
