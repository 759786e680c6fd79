"""Where the TV/TGV choice and the learned network err, by band of Hadamard rows. (Diagnostic.)

``auto`` stacks the learned network with its TV/TGV choice by a weight read from tail folds:
each fold is fitted on the first ``k`` measured rows and scored on the next ones (``auto``'s
module doc, "Stacking"). That scores how well a model predicts the rows *just after* those it
was fitted on. The image's error, though, lies mostly in the rows far beyond the measured set.
This script measures, on peers cells (``benchmarks/peers_scenes.py``: same image, rows, noise
draw), with the ground truth:

- for the full-row reconstructions (``auto(y, A, learned=False)`` and ``learned(y, A)``), the
  squared error of their Hadamard coefficients on the measured rows ``[0, M)``, on the next
  eighth ``[M, M + M/8)`` and on every row beyond it ``[M + M/8, n²)``;
- for each of ``auto``'s tail folds, the two models' held-out prediction errors against the
  noisy buckets (what ``auto`` sees) and against the noise-free ones, and the stacking weight
  ``auto`` derives from them.

    OMP_NUM_THREADS=1 python benchmarks/auto_bands.py
    OMP_NUM_THREADS=1 python benchmarks/auto_bands.py --cells sky:64:0.25:cake_cutting:0.01

(``--out FILE``: the rows as JSON.)
"""

from __future__ import annotations

import importlib
import json
import warnings
from pathlib import Path

import peers_scenes as ps  # benchmarks/ is the script's directory
import torch
from auto_stack_rules import fold_predictions

from torchtof.apps.args import OneLineParser
from torchtof.operators import Hadamard
from torchtof.recon import auto, learned

#: scene:n:SR:order:noise level — the peers cells where the network's full image beats the
#: stacked ``auto`` most, and one where it does not (``coins``).
CELLS = ("sky:32:0.375:sequency:0.01", "sky:64:0.25:cake_cutting:0.01",
         "planes:32:0.125:cake_cutting:0.05", "coins:32:0.125:sequency:0.01")


def parse_cell(text: str) -> tuple:
    scene, n, sr, order, level = text.split(":")
    return scene, int(n), float(sr), order, float(level)


def sq(e: torch.Tensor) -> float:
    return float(e.square().sum())


def measure(scene: str, n: int, sr: float, order: str, level: float) -> dict:
    am = importlib.import_module("torchtof.recon.auto")  # the package exports auto()
    x, A, y, sigma = ps.make_problem(scene, n, sr, order, level, 0)
    x, y = x.double(), y.double()
    y0 = A(x)
    res = auto(y, A, learned=False, return_result=True)
    xt, xl = res.x, learned(y, A)
    full = Hadamard(n, order=order)
    c0 = full(x)[0, 0]
    et, el = full(xt)[0, 0] - c0, full(xl)[0, 0] - c0
    m, h = A.m, A.m // 8
    bands = {"measured": (0, m), "next eighth": (m, m + h), "beyond": (m + h, n * n)}
    row = {"cell": f"{scene}:{n}:{sr}:{order}:{level}", "psnr_choice": ps.score(xt, x),
           "psnr_learned": ps.score(xl, x),
           "bands": {k: {"rows": [lo, hi], "choice": sq(et[lo:hi]), "learned": sq(el[lo:hi])}
                     for k, (lo, hi) in bands.items()}}
    pa, pl, held = fold_predictions(y, A, res.choice[0][0], am)
    folds = []
    for f in range(held.shape[0]):
        hf = held[f].to(y.dtype)
        folds.append({"train_rows": int(held[f].nonzero()[0]), "held_rows": int(held[f].sum()),
                      "noisy": {"choice": sq((pa[0, f] - y[0, 0]) * hf),
                                "learned": sq((pl[0, f] - y[0, 0]) * hf)},
                      "clean": {"choice": sq((pa[0, f] - y0[0, 0]) * hf),
                                "learned": sq((pl[0, f] - y0[0, 0]) * hf)},
                      "noise_energy": int(held[f].sum()) * sigma ** 2})
    row["folds"] = folds
    row["weight"] = float(am.stack_weight(pa, pl, y, held)[0])
    return row


def show(r: dict) -> str:
    out = [f"{r['cell']}: PSNR choice {r['psnr_choice']:.2f} dB, learned {r['psnr_learned']:.2f}"
           f" dB; auto's weight of the network {r['weight']:.2f}"]
    for k, b in r["bands"].items():
        out.append(f"  truth, rows {k} [{b['rows'][0]}, {b['rows'][1]}): squared error choice "
                   f"{b['choice']:.3g}, learned {b['learned']:.3g}")
    for f in r["folds"]:
        out.append(f"  fold on {f['train_rows']} rows, next {f['held_rows']}: noisy "
                   f"{f['noisy']['choice']:.3g} / {f['noisy']['learned']:.3g}, clean "
                   f"{f['clean']['choice']:.3g} / {f['clean']['learned']:.3g} "
                   f"(choice / learned; noise energy {f['noise_energy']:.3g})")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    p = OneLineParser(description=__doc__.splitlines()[0])
    p.add_argument("--cells", nargs="+", default=[parse_cell(c) for c in CELLS],
                   type=parse_cell, metavar="SCENE:N:SR:ORDER:NOISE")
    p.add_argument("--out", default=None, help="JSON file of the rows")
    a = p.parse_args(argv)
    torch.set_num_threads(1)
    rows = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for cell in a.cells:
            rows.append(measure(*cell))
            print(show(rows[-1]), flush=True)
    if a.out:
        Path(a.out).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
