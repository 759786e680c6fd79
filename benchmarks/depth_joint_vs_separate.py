"""Joint (vectorial-TV) vs separate I/Q reconstruction: depth RMSE over scenes, SRs, seeds.

The paper's experiment with its default noise (``PaperExperiment``), multipath on (default,
a 35 % copy at +1.6 m) and off; ``R`` noise realisations per scene. Depth RMSE (m) over the
object at DMD resolution for the I/Q pseudo-inverse, the package's TVAL3 per image, the
vectorial-TV solver with TV per image (``JointTV(joint=False)``) and jointly
(``JointTV(joint=True)``); "wins" counts the realisations where joint < separate (paired).

    python benchmarks/depth_joint_vs_separate.py [--realisations 5] [--out DIR]

``--out DIR`` writes ``DIR/depth_joint.json`` (the rows, the per-multipath summary and the
machine's load at start and end), which ``docs/build.py`` renders into the README.
"""

import argparse
import json
from pathlib import Path

import torch

from torchtof.apps.bench.timing import machine_load
from torchtof.experiment import PaperExperiment
from torchtof.metrics import depth_rmse
from torchtof.recon import TVAL3, DepthResolved, JointTV, PseudoInverse

SCENES = ("motorcycle", "steps", "slanted", "sky")
SRS = (0.0625, 0.125, 0.25)


def main(argv=None) -> list[dict]:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--realisations", type=int, default=5)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", default=None, help="write the rows alone to this file")
    p.add_argument("--out", default=None, help="write DIR/depth_joint.json")
    args = p.parse_args(argv)
    torch.set_num_threads(1)
    start = machine_load()
    rows = []
    print("scene       multipath  SR      pinv    TVAL3   vTV-sep joint   joint wins")
    for scene in SCENES:
        for mp in ("on", "off"):
            over = {} if mp == "on" else {"multipath_strength": 0.0}
            data = PaperExperiment(sr=max(SRS), scene=scene, srs=SRS, **over).run(
                seed=args.seed, realisations=args.realisations)
            truth = data.depth_m.expand(args.realisations, -1, -1, -1)
            obj = (data.x > 0).expand_as(truth)
            for sr in SRS:
                A, y = data.measurements(sr, kind="taps")
                e = {}
                for name, rec in (("pinv", PseudoInverse(A)), ("TVAL3", TVAL3(A)),
                                  ("vTV-sep", JointTV(A, joint=False)),
                                  ("joint", JointTV(A, joint=True))):
                    e[name] = depth_rmse(DepthResolved(rec).solve(y).depth, truth, obj)
                wins = int((e["joint"] < e["vTV-sep"]).sum())
                row = {"scene": scene, "multipath": mp, "sr": sr, "wins": wins,
                       "realisations": args.realisations,
                       **{k: float(v.mean()) for k, v in e.items()}}
                rows.append(row)
                print(f"{scene:11s} {mp:9s}  {sr:6.2%}  " + "  ".join(
                    f"{row[k]:.4f}" for k in ("pinv", "TVAL3", "vTV-sep", "joint"))
                    + f"  {wins}/{args.realisations}", flush=True)
    summary = {}
    for mp in ("on", "off"):
        low = [r for r in rows if r["multipath"] == mp and r["sr"] <= 0.125]
        rel = sum(r["joint"] / r["vTV-sep"] for r in low) / len(low)
        w = sum(r["wins"] for r in low)
        n = sum(r["realisations"] for r in low)
        summary[mp] = {"ratio": rel, "wins": w, "paired": n, "cells": len(low)}
        print(f"multipath {mp}, SR <= 12.5 %: joint/separate RMSE ratio {rel:.3f} "
              f"(mean over {len(low)} scene-SR cells), joint wins {w}/{n} paired realisations")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=2)
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        res = {"command": "python benchmarks/depth_joint_vs_separate.py --realisations "
               f"{args.realisations} --seed {args.seed}", "scenes": list(SCENES),
               "srs": list(SRS), "realisations": args.realisations, "rows": rows,
               "summary": summary, "machine": {"start": start, "end": machine_load()}}
        (out / "depth_joint.json").write_text(json.dumps(res, indent=1) + "\n", encoding="utf-8")
    return rows


if __name__ == "__main__":
    main()
