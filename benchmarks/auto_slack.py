"""``auto``'s ``slack`` (tolerance towards the less regularised candidate) on the peers' cells.

For every stored cell of ``docs/peers.json`` with the given (order, n, noise, SRs), ``auto``
runs once (``return_result=True``); for each slack its choice is recomputed from the same
scores (``auto``'s ``_pick``) and refitted as ``auto`` refits (``auto_eval.refit``), and
scored against the best oracle-tuned peer of the cell
(``benchmarks/peers.py``'s PSNR on [0, 1]). No box (the plain ``auto(y, A)`` call).

    OMP_NUM_THREADS=1 python benchmarks/auto_slack.py cake_cutting 32 0.01 0.0625 0.125 0.25 0.375
    OMP_NUM_THREADS=1 python benchmarks/auto_slack.py sequency 32 0.01 0.0625 0.125 0.25 0.375
    OMP_NUM_THREADS=1 python benchmarks/auto_slack.py cake_cutting 32 0.05 0.125 0.375

Prints, per cell, the gap to the best tuned peer for each slack, then the mean and the number
of cells at or above the peer.
"""

from __future__ import annotations

import importlib
import json
import statistics
import sys
from pathlib import Path

import peers_scenes as ps  # benchmarks/ is the script's directory
import torch
from auto_eval import refit

SLACKS = (0.0, 0.02, 0.05, 0.1)
ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str]) -> dict:
    if len(argv) < 4:
        raise SystemExit(__doc__)
    order, n, level = argv[0], int(argv[1]), float(argv[2])
    srs = [float(v) for v in argv[3:]]
    au = importlib.import_module("torchtof.recon.auto")
    torch.set_num_threads(1)
    stored = {(c["scene"], c["n"], c["sr"], c["order"], c["level"]): c
              for c in json.loads((ROOT / "docs" / "peers.json").read_text())["cells"]}
    out = {s: [] for s in SLACKS}
    for sr in srs:
        for sc in ps.SCENES:
            k = (sc, n, sr, order, level)
            if k not in stored:
                continue
            best_peer = stored[k]["headline"]["best_peer_psnr"]
            x, A, y, _ = ps.make_problem(sc, n, sr, order, level)
            r = au.auto(y, A, return_result=True)
            rank = au._rank(r.candidates, y)
            row = []
            for sl in SLACKS:
                c = r.candidates[int(au._pick(r.score[0], rank, sl)[0])]
                xx = refit(c, y, A)
                g = ps.score(xx, x) - best_peer
                out[sl].append(g)
                row.append(f"{g:+.2f}")
            print(sc, sr, " ".join(row), flush=True)
    for sl in SLACKS:
        print(f"slack {sl}: mean {statistics.mean(out[sl]):+.3f} dB, >= 0 in "
              f"{sum(v >= 0 for v in out[sl])}/{len(out[sl])}")
    return out


if __name__ == "__main__":
    main(sys.argv[1:])
