"""A candidate learned weights file on the stored peers cells: the network alone and ``auto``
(which stacks the network) with it, against the shipped file's rows of ``docs/peers.json``.

Same image, rows, noise draw and PSNR as ``benchmarks/peers.py`` (``peers_scenes``); the
candidate replaces :data:`torchtof.recon.learned.WEIGHTS_FILE` in this process only.

usage: OMP_NUM_THREADS=1 python benchmarks/learned_candidate_peers.py WEIGHTS \\
           [--min-n 64] [--max-n 256] [--level 0.01 [0.05]] [--shard I/K] [--out rows.json]
       python benchmarks/learned_candidate_peers.py --summary rows_0.json rows_1.json
"""

from __future__ import annotations

import argparse
import importlib
import json
import statistics
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
import peers_scenes as ps  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def run(weights: str, min_n: int, max_n: int, levels: list[float], shard: tuple[int, int],
        out: str | None) -> list:
    lm = importlib.import_module("torchtof.recon.learned")
    am = importlib.import_module("torchtof.recon.auto")
    lm.WEIGHTS_FILE = Path(weights).resolve()
    torch.set_num_threads(1)
    cells = [c for c in json.loads((ROOT / "docs" / "peers.json").read_text())["cells"]
             if min_n <= c["n"] <= max_n and c["level"] in levels]
    rows = []
    for i, c in enumerate(cells):
        if i % shard[1] != shard[0]:
            continue
        x, A, y, _ = ps.make_problem(c["scene"], c["n"], c["sr"], c["order"], c["level"])
        res = c["results"]
        best = max(v["psnr"] for v in res.values() if v.get("peer") != "torchtof")
        rows.append({"scene": c["scene"], "n": c["n"], "sr": c["sr"], "order": c["order"],
                     "level": c["level"],
                     "auto": ps.score(am.auto(y, A), x), "learned": ps.score(lm.learned(y, A), x),
                     "auto_shipped": res["torchtof auto"]["psnr"],
                     "learned_shipped": res["torchtof learned"]["psnr"], "best_peer": best})
        print(rows[-1], flush=True)
        if out:
            Path(out).write_text(json.dumps({"weights": weights, "rows": rows}, indent=1))
    return rows


def summary(files: list[str]) -> None:
    rows = [r for f in files for r in json.loads(Path(f).read_text())["rows"]]
    groups = {"all": rows}
    for order in sorted({r["order"] for r in rows}):
        groups[order] = [r for r in rows if r["order"] == order]
    for key, name in (("n", "n = {}"), ("level", "noise {:g}")):
        vals = sorted({r.get(key, 0.01) for r in rows})
        if len(vals) > 1:
            for v in vals:
                groups[name.format(v)] = [r for r in rows if r.get(key, 0.01) == v]
    print("| cells | auto − best peer, candidate (≥ 0, worst) | shipped | learned − best peer, "
          "candidate | shipped |")
    print("|---|---|---|---|---|")
    for name, sub in groups.items():
        def gap(k, sub=sub):
            return [r[k] - r["best_peer"] for r in sub]
        a, s = gap("auto"), gap("auto_shipped")
        print(f"| {name} ({len(sub)}) | {statistics.mean(a):+.2f} ({sum(g >= 0 for g in a)}, "
              f"{min(a):+.2f}) | {statistics.mean(s):+.2f} ({sum(g >= 0 for g in s)}, "
              f"{min(s):+.2f}) | {statistics.mean(gap('learned')):+.2f} | "
              f"{statistics.mean(gap('learned_shipped')):+.2f} |")


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("weights", nargs="?")
    p.add_argument("--min-n", type=int, default=64)
    p.add_argument("--max-n", type=int, default=256)
    p.add_argument("--level", type=float, nargs="+", default=[0.01])
    p.add_argument("--shard", default="0/1", type=ps.shard, metavar="I/K")
    p.add_argument("--out", default=None)
    p.add_argument("--summary", nargs="+", default=None)
    a = p.parse_args()
    if a.summary:
        summary(a.summary)
        return 0
    if not a.weights:
        p.error("WEIGHTS is required unless --summary is given")
    run(a.weights, a.min_n, a.max_n, a.level, a.shard, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
