"""Rules for ``auto``'s inferred box on binary scenes, tried after the held-out peers run.

``auto(y, A)`` without ``bounds`` looks for two levels in its refit (``_two_level``: the
medians of the pixels below and above the midpoint of the range) and, when the refit is
two-level, refines the chosen prior and norm with that box (``torchtof.recon.auto`` module
doc, "The inferred box"). On the held-out binary scenes of ``benchmarks/peers_scenes.py``
(``glyph``, ``blobs``) this lost up to 7 dB against spyrit's projected gradient, which the
benchmark gives the true box ``[0, 1]``. The variants compared on the same buckets
(``peers_scenes.make_problem``, noise seed 0 for the benchmark's own scenes, 1 for the held-out
ones, as in the stored runs):

- ``V0``: ``auto(y, A)``, the shipped rule;
- ``V1``: the same rule with the levels taken as the refit's minimum and maximum (an outward
  box: a loose box was expected to cost less than an inward-biased one);
- ``V2``: the median levels passed as ``bounds`` (the open choice: every prior and norm with
  the box, and the box-only test, as for a box the caller gives);
- ``V3``: the min/max levels passed as ``bounds``;
- ``box01``: ``auto(y, A, bounds=(0, 1))``, the true box (what the projected-gradient peer is
  given).

Validation scenes beyond the benchmark's: ``val_<family>_<k>`` draws
``torchtof.data.draw_scene(n, EVAL_SEED_BASE + 9100 + k, family)``.

    OMP_NUM_THREADS=1 python benchmarks/auto_box_rules.py --scenes glyph blobs sky horse \
        --orders cake_cutting sequency --out docs/auto/box_rules.json
    OMP_NUM_THREADS=1 python benchmarks/auto_box_rules.py --scenes val_strokes_0 \
        val_strokes_1 val_silhouette_0 val_silhouette_1 --out docs/auto/box_rules_val.json
"""

from __future__ import annotations

import argparse
import importlib
import json
import statistics
import time
from pathlib import Path

import peers_scenes as ps  # benchmarks/ is the script's directory
import torch

import torchtof as tt
from torchtof.data import EVAL_SEED_BASE, draw_scene

VARIANTS = ("V0", "V1", "V2", "V3", "box01")


def _range_levels(orig):
    """``_two_level`` with the levels replaced by the minimum and maximum (same test)."""
    def two_level(x):
        _, _, frac = orig(x)
        v = x.flatten(1)
        return v.amin(1), v.amax(1), frac
    return two_level


def problem(name: str, n: int, sr: float, order: str, level: float):
    if name.startswith("val_"):
        family, k = name[4:].rsplit("_", 1)
        x = draw_scene(n, EVAL_SEED_BASE + 9100 + int(k), family, dtype=torch.float32)
        A = tt.operators.Hadamard(n, sr=sr, order=order)
        return x, A, ps.noisy_buckets(x, A, level, seed=1)[0]
    x, A, y, _ = ps.make_problem(name, n, sr, order, level,
                                 seed=0 if name in ps.SCENES else 1)
    return x, A, y


def run_cell(au, x, A, y) -> dict:
    orig = au._two_level
    row = {}
    try:
        row["V0"] = ps.score(tt.recon.auto(y, A), x)
        au._two_level = _range_levels(orig)
        row["V1"] = ps.score(tt.recon.auto(y, A), x)
    finally:
        au._two_level = orig
    pre = tt.recon.Auto(A, infer_box=False, learned=False, gauss=False)(y)
    for key, rule in (("V2", orig), ("V3", _range_levels(orig))):
        lo, hi, frac = rule(pre.reshape(1, 1, A.n, A.n))
        if float(frac[0]) >= au.TWO_LEVEL and float(hi[0]) > float(lo[0]):
            box = (float(lo[0]), float(hi[0]))
            row[key], row[key + "_box"] = ps.score(tt.recon.auto(y, A, bounds=box), x), box
        else:
            row[key] = row["V0"]
    row["box01"] = ps.score(tt.recon.auto(y, A, bounds=(0.0, 1.0)), x)
    return row


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenes", nargs="+", required=True)
    p.add_argument("--orders", nargs="+", default=["cake_cutting"], choices=ps.ORDERS)
    p.add_argument("--n", type=int, default=32)
    p.add_argument("--sr", type=float, nargs="+", default=[0.0625, 0.125, 0.25, 0.375])
    p.add_argument("--noise", type=float, default=0.01)
    p.add_argument("--out", type=Path, default=None)
    a = p.parse_args(argv)
    torch.set_num_threads(1)
    au = importlib.import_module("torchtof.recon.auto")
    rows = []
    for scene in a.scenes:
        for order in a.orders:
            for sr in a.sr:
                t0 = time.perf_counter()
                x, A, y = problem(scene, a.n, sr, order, a.noise)
                row = {"scene": scene, "n": a.n, "sr": sr, "order": order, "level": a.noise,
                       **run_cell(au, x, A, y), "time_s": time.perf_counter() - t0}
                rows.append(row)
                print(f"{scene} {order} SR {sr:g}: "
                      + ", ".join(f"{k} {row[k]:.2f}" for k in VARIANTS), flush=True)
    means = {k: statistics.mean(r[k] for r in rows) for k in VARIANTS}
    print("mean PSNR: " + ", ".join(f"{k} {v:.2f}" for k, v in means.items()))
    print("mean change against V0: " + ", ".join(
        f"{k} {statistics.mean(r[k] - r['V0'] for r in rows):+.2f} dB "
        f"(worst {min(r[k] - r['V0'] for r in rows):+.2f})" for k in VARIANTS[1:]))
    out = {"args": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(a).items()},
           "rows": rows, "mean_psnr": means}
    if a.out is not None:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text(json.dumps(out, indent=1))
    return out


if __name__ == "__main__":
    main()
