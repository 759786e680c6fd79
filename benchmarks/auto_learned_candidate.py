"""Would the shipped learned network help as one more candidate of ``auto``? (Offline study.)

For each peers cell (``benchmarks/peers_scenes.py``: same image, Hadamard rows, noise draw and
PSNR as ``benchmarks/peers.py``; tail split only, so every training set is a prefix of the
rows and the network sees a plain ``Hadamard(n, m=k)``), ``auto(y, A)`` runs once; the
learned network (``torchtof.recon.learned``) is then fitted on the same folds (the first
``k`` rows of each fold), its held-out and training errors are scored exactly as ``auto``
scores its candidates (each fold's error over that fold's best, summed; the discrepancy
bound), and the cell's result is the learned network's full-row output where it would have
won, else ``auto``'s. Prints per cell and the mean gap to the best oracle-tuned peer of
``docs/peers.json``: ``auto``, ``auto`` with the learned candidate, and the oracle
``max(auto, learned)``.

    OMP_NUM_THREADS=1 python benchmarks/auto_learned_candidate.py --n 32 \\
        --orders cake_cutting sequency
    OMP_NUM_THREADS=1 python benchmarks/auto_learned_candidate.py --n 64 --sr 0.25 0.375
"""

from __future__ import annotations

import importlib
import json
import statistics
from pathlib import Path

import peers_scenes as ps  # benchmarks/ is the script's directory
import torch

from torchtof.operators import Hadamard
from torchtof.recon import auto
from torchtof.recon.learned import learned
from torchtof.recon.tval3 import holdout_split

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> dict:
    p = ps.cell_parser(__doc__.splitlines()[0])
    p.add_argument("--peers", default=str(ROOT / "docs" / "peers.json"))
    a = p.parse_args(argv)
    am = importlib.import_module("torchtof.recon.auto")
    torch.set_num_threads(1)
    stored = {(c["scene"], c["n"], c["sr"], c["order"], c["level"]): c
              for c in json.loads(Path(a.peers).read_text())["cells"]}
    rows = []
    for order in a.orders:
        for sr in a.sr:
            for scene in a.scenes:
                key = (scene, a.n, sr, order, a.noise)
                if key not in stored:
                    continue
                x, A, y, _ = ps.make_problem(scene, a.n, sr, order, a.noise)
                r = auto(y, A, return_result=True)
                held, train = holdout_split(A, am.TAIL_FOLDS, y, 0, "tail")
                held, train = held[:am.TAIL_USE], train[:am.TAIL_USE]
                cv_l, fit_l = [], 0.0
                with torch.no_grad():
                    for f in range(held.shape[0]):
                        k = int(train[f].sum())
                        assert bool(train[f, :k].all()), "a tail fold trains on a prefix"
                        xf = learned(y[..., :k], Hadamard(a.n, m=k, order=order))
                        r2 = (A(xf) - y).square()[0, 0]
                        cv_l.append(float((r2 * held[f]).sum()))
                        fit_l += float((r2 * train[f]).sum())
                    x_l = learned(y, A)
                cv = torch.cat([r.cv_fold[0, 0], torch.tensor(cv_l, dtype=y.dtype)[:, None]], 1)
                fit = torch.cat([r.fit_error[0, 0], torch.tensor([fit_l], dtype=y.dtype)])
                score = am._score(cv[None], fit[None], r.fit_bound[0, 0].reshape(1, 1))[0]
                pick = int(score.argmin()) == len(score) - 1
                res = stored[key]["results"]
                peer = max(v["psnr"] for v in res.values()
                           if v.get("peer") != "torchtof" and v["psnr"] is not None)
                p_auto, p_l = ps.score(r.x, x), ps.score(x_l, x)
                row = dict(scene=scene, n=a.n, sr=sr, order=order, auto=p_auto, learned=p_l,
                           picks_learned=pick, peer=peer)
                rows.append(row)
                print(f"{order} SR={sr} {scene}: auto {p_auto:.2f}, learned {p_l:.2f}, "
                      f"picks learned {pick} (score {float(score[-1]):.3f} vs "
                      f"{float(score[:-1].min()):.3f})", flush=True)
    gap = {k: statistics.mean(f(r) - r["peer"] for r in rows) for k, f in (
        ("auto", lambda r: r["auto"]),
        ("with_learned", lambda r: r["learned"] if r["picks_learned"] else r["auto"]),
        ("oracle", lambda r: max(r["auto"], r["learned"])))}
    print(f"{len(rows)} cells, mean gap to the best tuned peer: auto {gap['auto']:+.2f} dB, "
          f"with the learned candidate {gap['with_learned']:+.2f} dB, oracle "
          f"max(auto, learned) {gap['oracle']:+.2f} dB; learned picked in "
          f"{sum(r['picks_learned'] for r in rows)}")
    return dict(rows=rows, gap=gap)


if __name__ == "__main__":
    main()
