"""DIP's quality against TVAL3's defaults and ``auto`` on the 32×32 proxy problems.

Scenes: the paper's character 天 (``sky``) and two held-out silhouettes (scikit-image
``horse``, ``camera`` thresholded: :func:`torchtof.scenes.binary_scene`), 32×32, the first
``M = SR·n²`` rows of the cake-cutting Hadamard operator, Gaussian noise of ``level`` × the
bucket spread (:func:`torchtof.data.noise.noisy_buckets`, one seeded draw per repeat).
Methods at their defaults: ``dip`` (:func:`torchtof.recon.dip.dip`, calibrated output,
early stopping ES-WMV), ``tval3`` (``mu="auto"``) and ``auto``. Score: PSNR of the output
clamped to [0, 1] (8-bit peak, as ``benchmarks/auto_eval.py``); wall time per image.

    OMP_NUM_THREADS=1 python benchmarks/dip_vs_tval3.py --out docs/bench

``--out DIR`` writes ``DIR/dip_vs_tval3.json`` (every PSNR and time, the machine's load),
which ``docs/build.py`` renders into the README."""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

from torchtof.apps.args import OneLineParser, positive_int, sampling_rate

SCENES = ("sky", "horse", "camera")


def main(argv: list[str] | None = None) -> dict:
    p = OneLineParser(
        description="DIP vs TVAL3's defaults and auto at 32x32 (sky, horse, camera; cake-cutting "
        "Hadamard; Gaussian noise): PSNR and wall time per image. Takes minutes.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter, allow_abbrev=False)
    p.add_argument("--srs", type=sampling_rate, nargs="+", default=[0.0625, 0.125],
                   help="sampling rates M/n²")
    p.add_argument("--levels", type=float, nargs="+", default=[0.01, 0.05],
                   help="Gaussian noise std as a fraction of the bucket spread")
    p.add_argument("--repeats", type=positive_int, default=3, help="noise draws per cell")
    p.add_argument("--scenes", nargs="+", default=list(SCENES), choices=SCENES)
    p.add_argument("--threads", type=positive_int, default=1, help="torch intra-op threads")
    p.add_argument("--out", default=None, help="write DIR/dip_vs_tval3.json")
    a = p.parse_args(argv)

    import torch

    from torchtof.apps.bench.timing import machine_load
    from torchtof.data.noise import NoiseRecipe, noisy_buckets
    from torchtof.metrics import psnr
    from torchtof.operators import Hadamard
    from torchtof.recon import auto, tval3
    from torchtof.recon.dip import dip
    from torchtof.scenes import binary_scene, sky_character

    torch.set_num_threads(a.threads)
    methods = {
        "dip": lambda y, A: dip(y, A),
        "tval3": lambda y, A: tval3(y, A),
        "auto": lambda y, A: auto(y, A),
    }
    start, rows = machine_load(), []
    for name in a.scenes:
        x = sky_character(32) if name == "sky" else binary_scene(name, 32)
        x = x.to(torch.float32)
        for sr in a.srs:
            A = Hadamard(32, sr=sr, order="cake_cutting")
            for level in a.levels:
                for r in range(a.repeats):
                    g = torch.Generator().manual_seed(1000 * r + 7)
                    y = noisy_buckets(A, x, [NoiseRecipe(level=level)], [g])
                    row = {"scene": name, "sr": sr, "level": level, "repeat": r}
                    for m, f in methods.items():
                        t = time.perf_counter()
                        xh = f(y, A)
                        row[f"t_{m}"] = time.perf_counter() - t
                        row[m] = psnr(xh.clamp(0, 1), x, bits=8).item()
                    rows.append(row)
                    print(json.dumps(row), flush=True)
    summary = []
    for name in a.scenes:
        for sr in a.srs:
            for level in a.levels:
                cell = [r for r in rows if (r["scene"], r["sr"], r["level"]) == (name, sr, level)]
                summary.append({"scene": name, "sr": sr, "level": level, **{
                    m: statistics.mean(r[m] for r in cell) for m in methods}, **{
                    f"t_{m}": statistics.median(r[f"t_{m}"] for r in cell) for m in methods}})
    res = {"command": "python benchmarks/dip_vs_tval3.py " + " ".join(sys.argv[1:] if argv is None else argv),
           "n": 32, "order": "cake_cutting", "repeats": a.repeats, "threads": a.threads,
           "rows": rows, "cells": summary, "machine": {"start": start, "end": machine_load()}}
    if a.out:
        out = Path(a.out)
        out.mkdir(parents=True, exist_ok=True)
        (out / "dip_vs_tval3.json").write_text(json.dumps(res, indent=1) + "\n")
    for s in summary:
        print(f"{s['scene']:7s} SR {s['sr']:.4f} noise {s['level']:.2f}: DIP {s['dip']:.2f} dB, "
              f"TVAL3 {s['tval3']:.2f} dB, auto {s['auto']:.2f} dB; median time DIP "
              f"{s['t_dip']:.2f} s, TVAL3 {s['t_tval3']:.3f} s, auto {s['t_auto']:.2f} s")
    return res


if __name__ == "__main__":
    main()
