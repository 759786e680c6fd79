"""What each candidate group of ``auto`` is worth, on the peers' stored cells of one size.

``auto`` runs once per cell (``return_result=True``); its choice is then recomputed from the
same per-fold held-out errors with some candidates removed (the score renormalised over the
candidates kept, as ``auto``'s ``_score`` does), refitted as ``auto`` refits, and scored
against the best oracle-tuned peer of the cell (``docs/peers.json``). Variants: ``full``;
``no_tgv_nonneg`` (TGV² without the ``x ≥ 0`` bound); ``tv_only`` (``priors=("tv",)``);
``no_nonneg`` (no ``x ≥ 0`` bound for either prior). An approximation for the reduced sets:
second-stage weights exist only around the full set's first-stage choice.

    OMP_NUM_THREADS=1 python benchmarks/auto_ablation.py 32     # or 64, 128
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

ROOT = Path(__file__).resolve().parents[1]
VARIANTS = {
    "full": lambda c: True,
    "no_tgv_nonneg": lambda c: not (c["prior"] == "tgv" and c["bounds"] is not None),
    "tv_only": lambda c: c["prior"] == "tv",
    "no_nonneg": lambda c: c["bounds"] is None,
}


def main(argv: list[str]) -> dict:
    if len(argv) != 1 or argv[0] not in ("32", "64", "128"):  # --help included: the usage
        raise SystemExit(__doc__)
    n = int(argv[0])
    au = importlib.import_module("torchtof.recon.auto")
    torch.set_num_threads(1)
    cells = [c for c in json.loads((ROOT / "docs" / "peers.json").read_text())["cells"]
             if c["n"] == n]
    out = {k: [] for k in VARIANTS}
    for cell in cells:
        best_peer = cell["headline"]["best_peer_psnr"]
        x, A, y, _ = ps.make_problem(cell["scene"], n, cell["sr"], cell["order"], cell["level"])
        r = au.auto(y, A, return_result=True)
        rank = au._rank(r.candidates, y)
        row = []
        for name, keep in VARIANTS.items():
            m = torch.tensor([keep(c) for c in r.candidates])
            cvf = r.cv_fold[0].clone()
            cvf[:, :, ~m] = float("nan")
            fe = r.fit_error[0].clone()
            fe[:, ~m] = float("nan")
            score = au._score(cvf, fe, r.fit_bound[0].reshape(-1, 1))
            c = r.candidates[int(au._pick(score, rank, 0.0)[0])]
            xx = refit(c, y, A)
            g = ps.score(xx, x) - best_peer
            out[name].append(g)
            row.append(f"{g:+.2f}")
        print(cell["scene"], cell["sr"], cell["order"], cell["level"], " ".join(row), flush=True)
    for k, v in out.items():
        print(f"{k}: mean {statistics.mean(v):+.3f} dB against the best tuned peer, >= 0 in "
              f"{sum(g >= 0 for g in v)}/{len(v)}")
    return out


if __name__ == "__main__":
    main(sys.argv[1:])
