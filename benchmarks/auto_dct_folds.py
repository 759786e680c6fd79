"""Would an L1-in-DCT candidate help ``auto``? Its fold score against its full-row PSNR. (Study.)

pylops' FISTA-L1 in the DCT, with its weight tuned against the ground truth, is the best peer
on two of ``auto``'s losing peers cells (``coins`` and 天 at n = 32, SR 12.5 %, sequency
rows). torchtof's ``basis_pursuit(y, A, basis="dct", lam=λ)`` is the same model. For each
peers cell (``benchmarks/peers_scenes.py``: same image, rows, noise draw and PSNR) this
script fits it on ``auto``'s own tail folds for ``λ = f · max|y|``, ``f`` in :data:`LAMBDAS`,
and compares its held-out errors with those of ``auto``'s choice
(``auto(y, A, learned=False)``) fitted on the same folds:

- ``ratio``: the fold score, the mean over the folds of the DCT model's held-out squared error
  divided by the choice's (below 1: the folds would prefer the DCT model), at the ``λ`` the
  folds pick;
- ``Δ dB``: the full-row PSNR of the DCT model at that ``λ`` minus the choice's, and the
  oracle (best over the grid, against the truth).

Only the ground-truth columns use the truth.

    OMP_NUM_THREADS=1 python benchmarks/auto_dct_folds.py --n 32 --orders sequency cake_cutting
"""

from __future__ import annotations

import importlib
import json
import warnings
from pathlib import Path

import peers_scenes as ps  # benchmarks/ is the script's directory
import torch

from torchtof.recon import auto, basis_pursuit

#: The weights tried, as fractions of ``max|y|``.
LAMBDAS = (1e-4, 3e-4, 1e-3, 3e-3, 1e-2)


def main(argv: list[str] | None = None) -> list[dict]:
    p = ps.cell_parser(__doc__.splitlines()[0])
    p.add_argument("--iters", type=int, default=300, help="FISTA iterations of each fit")
    p.add_argument("--out", default=None, help="JSON file of the per-cell rows")
    a = p.parse_args(argv)
    am = importlib.import_module("torchtof.recon.auto")
    masked_rows = importlib.import_module("torchtof.recon.tval3").MaskedRows
    torch.set_num_threads(1)
    warnings.simplefilter("ignore", UserWarning)  # BP's "ran out of iterations"
    rows = []
    for order in a.orders:
        for sr in a.sr:
            for scene in a.scenes:
                x, A, y = ps.make_problem(scene, a.n, sr, order, a.noise)[:3]
                r = auto(y, A, learned=False, return_result=True)
                ch = r.choice[0][0]
                if ch["prior"] == "box":
                    continue
                held, train = am.cv_folds(A, y, None, 0, "tail")
                h = held.to(y.dtype)
                e_choice = ((y - am.choice_predictions(y, A, [ch], train, 100)) * h)
                e_choice = e_choice.square().sum(-1)[0]  # (F,)
                top = float(y.abs().max())
                fits = []
                for f in LAMBDAS:
                    xs = torch.cat([basis_pursuit(y * train[k].to(y.dtype),
                                                  masked_rows(A, train[k : k + 1]), basis="dct",
                                                  lam=top * f, n_iter=a.iters)
                                    for k in range(train.shape[0])], dim=1)
                    e = ((y - A(xs)) * h).square().sum(-1)[0]
                    full = ps.score(basis_pursuit(y, A, basis="dct", lam=top * f,
                                                  n_iter=a.iters), x)
                    fits.append((float((e / e_choice).mean()), f, full, (e / e_choice).tolist()))
                ratio, f, full, per_fold = min(fits)
                base = ps.score(r.x, x)
                row = dict(scene=scene, n=a.n, sr=sr, order=order, choice=ch["prior"],
                           choice_psnr=base, ratio=ratio, per_fold=per_fold, lam=f,
                           delta=full - base, oracle_delta=max(v[2] for v in fits) - base)
                rows.append(row)
                print(f"{order} SR={sr} {scene}: choice {ch['prior']} {base:.2f} dB; DCT at the "
                      f"folds' λ = {f:g}·max|y|: fold ratio {ratio:.2f}, {row['delta']:+.2f} dB "
                      f"(oracle λ {row['oracle_delta']:+.2f} dB)", flush=True)
    better = [r for r in rows if r["ratio"] < 1]
    changes = ", ".join(f"{r['delta']:+.2f}" for r in better) or "-"
    wins = [f"{r['scene']} {r['order']} {r['sr']} ({r['oracle_delta']:+.2f}, fold ratio "
            f"{r['ratio']:.1f})" for r in rows if r["oracle_delta"] > 0]
    print(f"{len(rows)} cells; the folds prefer the DCT model in {len(better)}, where it "
          f"changes the PSNR by {changes} dB; with the oracle λ it is better in {len(wins)}: "
          f"{'; '.join(wins) or '-'}")
    if a.out:
        Path(a.out).write_text(json.dumps(rows, indent=0))
    return rows


if __name__ == "__main__":
    main()
