"""``torchtof bench tradeoff``: run time against error over the paper's sampling rates.

The same engine as ``bench recon`` (:func:`torchtof.apps.bench.recon.sweep`), on the paper's SRs
(6.25 … 37.5 %) and the depth scenes (metres, so the depth RMSE is physical) plus the 天
object; each reconstructor is swept over its work knob. Writes ``tradeoff.json`` and
``tradeoff.png`` (time on a log axis, the Pareto front dashed) and prints which method to use
for which time budget.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import torch

from ...adaptive.budget import save_table
from ...experiment import PAPER_SRS
from .recon import KNOBS, pareto, plot_sweep, print_recon, sweep

__all__ = ["bench_tradeoff", "print_tradeoff", "recommend"]

QUICK = {"PINV": [None], "BP": [20, 160], "TVAL3": [10, 80, None], "Unrolled": [None],
         "DIP": [100]}


def recommend(points: list[dict], budgets_s=(1e-3, 1e-2, 1e-1, 1.0, 10.0)) -> list[dict]:
    """Best scene-averaged PSNR reachable within each time budget, per n (averaged over SR)."""
    out = []
    for n in sorted({p["n"] for p in points}):
        labels = sorted({p["label"] for p in points if p["n"] == n})
        avg = []
        for lab in labels:
            ps = [p for p in points if p["n"] == n and p["label"] == lab]
            avg.append((sum(p["time_s"] for p in ps) / len(ps),
                        sum(p["psnr"] for p in ps) / len(ps), lab))
        for b in budgets_s:
            ok = [a for a in avg if a[0] <= b]
            best = max(ok, key=lambda a: a[1]) if ok else None
            out.append({"n": n, "budget_s": b, "method": best[2] if best else "-",
                        "psnr": best[1] if best else None, "time_s": best[0] if best else None})
    return out


def bench_tradeoff(quick: bool = False, out: str | Path = "bench_out",
                   json_path: str | Path | None = None) -> dict:
    """Sweep every reconstructor's work knob; write the JSON to ``json_path`` (default
    ``OUT/tradeoff.json``) and the plot to ``OUT/tradeoff.png``."""
    t0 = time.perf_counter()
    ns = (32, 64) if quick else (32, 64, 128)
    srs = (0.0625, 0.125, 0.25) if quick else PAPER_SRS
    scenes = ("sky", "steps") if quick else ("sky", "steps", "motorcycle")
    rows = sweep(ns, srs, scenes, QUICK if quick else KNOBS)
    pts = pareto(rows)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    res = {"benchmark": "tradeoff", "quick": quick, "noise": 0.01, "scenes": list(scenes),
           "threads": torch.get_num_threads(), "torch": torch.__version__, "points": pts,
           "rows": rows, "recommend": recommend(pts)}
    png = plot_sweep(pts, out / "tradeoff.png", "run time vs PSNR (bench tradeoff)")
    res["plot"] = None if png is None else str(png)
    res["total_s"] = time.perf_counter() - t0
    path = Path(json_path) if json_path is not None else out / "tradeoff.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(res, indent=2, default=str))
    res["json"] = str(path)
    # the scene-averaged points in the format choose_method reads (the shipped table's)
    res["budget_table"] = str(save_table(path, out / "budget_table.json"))
    return res


def print_tradeoff(res: dict) -> None:
    print_recon(res)
    print("\nwhich method for which budget (best scene- and SR-averaged PSNR within the budget):")
    from ...report import print_table

    print_table([{**r, "psnr": "-" if r["psnr"] is None else f"{r['psnr']:.2f}"}
                 for r in res["recommend"]], ["n", "budget_s", "method", "psnr", "time_s"])
    print(f"wrote {res['json']}, {res['budget_table']}"
          + (f" and {res['plot']}" if res['plot'] else ""))
