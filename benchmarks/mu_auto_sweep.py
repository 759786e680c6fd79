"""TVAL3's ``mu="auto"`` against the published ``μ = 2⁸`` and the best of a small ``μ`` grid.

Cells: scenes (the paper's character ``sky``, scikit-image ``horse`` thresholded, ``camera``,
``coins``, ``moon``, a procedurally drawn piecewise-planar depth map) × n {32, 64, 128} × SR
{6.25, 12.5, 25, 37.5} % × Gaussian noise {0, 1, 5} % of the bucket spread (one draw, seed 0)
× Hadamard order {cake-cutting, sequency}. PSNR on [0, 1] after clamping (8-bit peak), as
``benchmarks/auto_eval.py``. Per cell it records:

- ``auto``: PSNR of ``tval3(y, A)`` (``mu="auto"``, the default) and its time;
- ``est_pct``: the noise estimate ``bucket_noise_sigma(y)`` in % of the bucket spread (the
  bias table: the true level is ``noise``);
- with ``--what ref`` instead: ``mu256``, the published constrained model ``μ = 2⁸``, and
  ``grid``, the TV-L2 model at ``μ ∈ 2^{4, 6, 8, 10, 12}`` (one batched call, ``4β``);
  these do not depend on the ``mu="auto"`` code, so they are computed once.

    OMP_NUM_THREADS=1 python benchmarks/mu_auto_sweep.py --what ref --out ref.json
    OMP_NUM_THREADS=1 python benchmarks/mu_auto_sweep.py --what auto --out auto.json
    python benchmarks/mu_auto_sweep.py --report ref.json auto.json [--baseline auto_old.json]

``--report`` prints the Markdown tables of ``docs/noise.md``: the loss of ``mu="auto"``
against ``μ = 2⁸`` on noise-free buckets (target: at most 0.5 dB in every cell), its gap to
the best of the grid, the change against a baseline run of older code on the noisy cells,
and the noise estimate's bias.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import torch
from auto_eval import psnr  # benchmarks/ is the script's directory
from auto_eval import scene as _scene

import torchtof as tt
from torchtof.recon import tval3
from torchtof.recon.tval3 import bucket_noise_sigma

SCENES = ("sky", "binary:horse", "camera", "coins", "moon", "planar")
NS = (32, 64, 128)
SRS = (0.0625, 0.125, 0.25, 0.375)
NOISES = (0.0, 0.01, 0.05)
ORDERS = ("cake_cutting", "sequency")
GRID = tuple(2.0**k for k in (4, 6, 8, 10, 12))


def cells(ns, srs, scenes, noises, orders):
    for order in orders:
        for n in ns:
            for sr in srs:
                A = tt.operators.Hadamard(n, sr=sr, order=order).double()
                for name in scenes:
                    x = _scene(name, n)
                    y0 = A(x)
                    spread = float(y0.max() - y0.min())
                    for lev in noises:
                        g = torch.Generator().manual_seed(0)
                        y = y0 + lev * spread * torch.randn(y0.shape, dtype=y0.dtype, generator=g)
                        yield dict(scene=name, n=n, sr=sr, noise=lev, order=order), A, x, y, spread


def run(what, ns, srs, scenes, noises, orders) -> list[dict]:
    rows = []
    for key, A, x, y, spread in cells(ns, srs, scenes, noises, orders):
        row = dict(key)
        if what == "auto":
            row["est_pct"] = 100 * float(bucket_noise_sigma(y)) / spread
            t0 = time.perf_counter()
            xa = tval3(y, A)
            row["t_auto"] = time.perf_counter() - t0
            row["auto"] = psnr(xa, x)[0]
        else:
            row["mu256"] = psnr(tval3(y, A, mu=2.0**8), x)[0]
            mus = torch.tensor(GRID, dtype=y.dtype)[None]
            xg = tval3(y.expand(1, len(GRID), -1), A, mu=mus, tvl2=True)
            row["grid"] = dict(zip((f"{m:g}" for m in GRID),
                                   psnr(xg.transpose(0, 1), x.expand(len(GRID), 1, -1, -1)),
                                   strict=True))
        rows.append(row)
        print(json.dumps(row), flush=True)
    return rows


def _key(r):
    return (r["scene"], r["n"], r["sr"], r["noise"], r["order"])


def report(ref_path, auto_path, base_path=None) -> None:
    with open(ref_path) as f:
        ref = {_key(r): r for r in json.load(f)}
    with open(auto_path) as f:
        auto = {_key(r): r for r in json.load(f)}
    base = None
    if base_path:
        with open(base_path) as f:
            base = {_key(r): r for r in json.load(f)}
    keys = [k for k in auto if k in ref]
    for k in keys:
        a, r = auto[k], ref[k]
        a["best"] = max(r["mu256"], *r["grid"].values())
        a["d256"] = a["auto"] - r["mu256"]
        a["gap"] = a["best"] - a["auto"]
        if base is not None and k in base:
            a["dbase"] = a["auto"] - base[k]["auto"]
    scenes = list(dict.fromkeys(k[0] for k in keys))
    orders = list(dict.fromkeys(k[4] for k in keys))
    ns = sorted({k[1] for k in keys})
    srs = sorted({k[2] for k in keys})
    noises = sorted({k[3] for k in keys})

    def summary(sel, field, worst=min, name="worst"):
        v = [auto[k][field] for k in sel if field in auto[k]]
        if not v:
            return "-"
        return f"mean {statistics.fmean(v):+.2f}, {name} {worst(v):+.2f} dB ({len(v)} cells)"

    print("### Summary\n")
    for lev in noises:
        sel = [k for k in keys if k[3] == lev]
        print(f"- noise {100 * lev:g} %: auto − μ=2⁸ {summary(sel, 'd256')}; "
              f"best of grid − auto: {summary(sel, 'gap', max, 'max')}"
              + (f"; auto − baseline {summary(sel, 'dbase')}, changed in "
                 f"{sum(1 for k in sel if abs(auto[k].get('dbase', 0.0)) > 0.005)}"
                 if base else ""))
    miss = [k for k in keys if k[3] == 0 and auto[k]["d256"] < -0.5]
    print(f"- noise-free cells losing more than 0.5 dB against μ = 2⁸: {len(miss)} of "
          f"{sum(1 for k in keys if k[3] == 0)}"
          + (": " + ", ".join(f"{k[0]} n={k[1]} SR {100 * k[2]:g} % {k[4]} "
                              f"({auto[k]['d256']:+.2f})" for k in miss) if miss else ""))
    for order in orders:
        print(f"\n### PSNR of mu=\"auto\" − μ = 2⁸ (dB), {order} rows; "
              "[best of the grid − auto]" + ("; {auto − baseline}" if base else "") + "\n")
        print("| n | SR % | noise % | " + " | ".join(s.replace("binary:", "") for s in scenes)
              + " |")
        print("|---|---|---|" + "---|" * len(scenes))
        for n in ns:
            for sr in srs:
                for lev in noises:
                    cs = []
                    for s in scenes:
                        a = auto.get((s, n, sr, lev, order))
                        if a is None or "d256" not in a:
                            cs.append("-")
                            continue
                        c = f"{a['d256']:+.1f} [{a['gap']:.1f}]"
                        if "dbase" in a:
                            c += f" {{{a['dbase']:+.1f}}}"
                        cs.append(c)
                    print(f"| {n} | {100 * sr:g} | {100 * lev:g} | " + " | ".join(cs) + " |")
    for order in orders:
        print(f"\n### Noise estimate in % of the bucket spread (true level: noise %), {order} rows\n")
        print("| n | SR % | noise % | " + " | ".join(s.replace("binary:", "") for s in scenes)
              + " |")
        print("|---|---|---|" + "---|" * len(scenes))
        for n in ns:
            for sr in srs:
                for lev in noises:
                    cs = [f"{auto[(s, n, sr, lev, order)]['est_pct']:.2f}"
                          if (s, n, sr, lev, order) in auto else "-" for s in scenes]
                    print(f"| {n} | {100 * sr:g} | {100 * lev:g} | " + " | ".join(cs) + " |")


def main(argv=None) -> list[dict] | None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--what", choices=("auto", "ref"), default="auto")
    ap.add_argument("--n", type=int, nargs="+", default=list(NS))
    ap.add_argument("--sr", type=float, nargs="+", default=list(SRS))
    ap.add_argument("--scenes", nargs="+", default=list(SCENES))
    ap.add_argument("--noise", type=float, nargs="+", default=list(NOISES))
    ap.add_argument("--order", nargs="+", default=list(ORDERS))
    ap.add_argument("--out", default=None)
    ap.add_argument("--report", nargs=2, metavar=("REF", "AUTO"), default=None)
    ap.add_argument("--baseline", default=None, help="an --what auto JSON of older code")
    args = ap.parse_args(argv)
    if args.report:
        report(*args.report, args.baseline)
        return None
    torch.set_num_threads(1)
    rows = run(args.what, args.n, args.sr, args.scenes, args.noise, args.order)
    if args.out:
        with open(args.out, "w") as f:
            json.dump(rows, f, indent=1)
    return rows


if __name__ == "__main__":
    main()
