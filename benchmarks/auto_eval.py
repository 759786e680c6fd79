"""How well :func:`torchtof.recon.auto` chooses: PSNR against TVAL3's default, against the best
and the median of its own candidates (each refitted on all buckets with the same budget).

Scenes: binary silhouettes (the paper's character, scikit-image ``horse`` thresholded),
grey natural images (scikit-image ``camera``, ``coins``, ``moon``) and a procedurally drawn
piecewise-planar depth map (normalised to [0, 1]). Hadamard cake-cutting rows, Gaussian noise
of 1 % of the bucket spread, one noise draw per cell (seed 0). PSNR on [0, 1] after clamping
(8-bit peak, ``torchtof.metrics.psnr``).

    OMP_NUM_THREADS=1 python benchmarks/auto_eval.py --n 32 64 --out auto_eval.json

Prints a Markdown table (docs/auto.md holds the committed one).
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import time

import torch

import torchtof as tt
from torchtof.data import planar_depth
from torchtof.recon import auto, tgv, tval3
from torchtof.recon.auto import AUTO_WEIGHTS

SRS = (0.0625, 0.125, 0.25, 0.375)


def scene(name: str, n: int) -> torch.Tensor:
    if name == "sky":
        x = tt.scenes.sky_character(32).double()
        return x if n == 32 else torch.nn.functional.interpolate(x, size=n, mode="nearest")
    if name == "planar":
        return planar_depth(n)
    if name.startswith("binary:"):
        return tt.scenes.binary_scene(name[7:], n, dtype=torch.float64)
    return tt.scenes.skimage_scene(name, n, dtype=torch.float64)


SCENES = ("sky", "binary:horse", "camera", "coins", "moon", "planar")


def psnr(a: torch.Tensor, x: torch.Tensor) -> list[float]:
    return tt.metrics.psnr(a.clamp(0, 1), x, bits=8).reshape(-1).tolist()


def candidate_psnrs(y, A, x, cands, cv_iter, max_iter=1025):
    """PSNR of every first-stage candidate of ``auto`` refitted on all buckets as ``auto``
    refits its choice (constrained: ``cv_iter`` iterations; TV-L2: up to ``max_iter``), in the
    order of ``cands`` (second-stage weights and the box-only candidate are skipped)."""
    out = {}
    groups = []
    for c in cands:
        g = (c["prior"], c["tv"], c["boundary"], c["bounds"])
        if c["stage"] == 1 and c["prior"] != "box" and g not in groups:
            groups.append(g)
    finite = [w for w in AUTO_WEIGHTS if w != float("inf")]
    for g in groups:
        prior, tv, bd, box = g
        solve = tgv if prior == "tgv" else tval3
        r = solve(y, A, mu=2.0**8, max_iter=cv_iter, tv=tv, boundary=bd, bounds=box)
        out[(*g, None)] = psnr(r.x, x)[0]
        mus = torch.tensor(finite, dtype=y.dtype)[None]
        r = solve(y.expand(1, len(finite), -1), A, mu=mus, tvl2=True, max_iter=max_iter, tv=tv,
                  boundary=bd, bounds=box)
        for j, p in enumerate(psnr(r.x.transpose(0, 1), x.expand(len(finite), 1, -1, -1))):
            out[(*g, finite[j])] = p
    key = [(c["prior"], c["tv"], c["boundary"], c["bounds"], c["mu"]) for c in cands]
    return [out[k] for k in key if k in out]


def noise_table(ns, srs, scenes, levels=(0.0, 0.01, 0.03)) -> list[dict]:
    """Bias of TVAL3's tail noise estimate (% of the bucket spread; true level in the header)
    and the PSNR of ``mu="auto"`` minus that of the published ``μ = 2⁸``."""
    from torchtof.recon.tval3 import bucket_noise_sigma

    rows = []
    print("| n | SR % | noise % | " + " | ".join(scenes) + " |")
    print("|---|---|---|" + "---|" * len(scenes))
    for n in ns:
        for sr in srs:
            A = tt.operators.Hadamard(n, sr=sr).double()
            for lev in levels:
                cells = []
                for name in scenes:
                    x = scene(name, n)
                    y0 = A(x)
                    spread = float(y0.max() - y0.min())
                    g = torch.Generator().manual_seed(0)
                    y = y0 + lev * spread * torch.randn(y0.shape, dtype=y0.dtype, generator=g)
                    est = 100 * float(bucket_noise_sigma(y)) / spread
                    d = psnr(tval3(y, A).x, x)[0] - psnr(tval3(y, A, mu=2.0**8).x, x)[0]
                    rows.append(dict(n=n, sr=sr, noise=lev, scene=name, est_pct=est, dpsnr=d))
                    cells.append(f"{est:.2f} ({d:+.1f})")
                print(f"| {n} | {100 * sr:g} | {100 * lev:g} | " + " | ".join(cells) + " |",
                      flush=True)
    return rows


def bp_table(ns, srs, scenes, noise=0.01) -> list[dict]:
    """Basis pursuit's registry default (``eps="auto"``, DCT) against TVAL3's default."""
    from torchtof.recon import basis_pursuit

    rows = []
    print("| n | SR % | " + " | ".join(scenes) + " |")
    print("|---|---|" + "---|" * len(scenes))
    for n in ns:
        for sr in srs:
            A = tt.operators.Hadamard(n, sr=sr).double()
            cells = []
            for name in scenes:
                x = scene(name, n)
                y0 = A(x)
                g = torch.Generator().manual_seed(0)
                y = y0 + noise * (y0.max() - y0.min()) * torch.randn(y0.shape, dtype=y0.dtype,
                                                                      generator=g)
                pb = psnr(basis_pursuit(y, A, eps="auto").x, x)[0]
                pt = psnr(tval3(y, A).x, x)[0]
                rows.append(dict(n=n, sr=sr, scene=name, bp=pb, tval3=pt))
                cells.append(f"{pb:.2f} / {pt:.2f}")
            print(f"| {n} | {100 * sr:g} | " + " | ".join(cells) + " |", flush=True)
    return rows


def main(argv=None) -> list[dict]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[32, 64])
    ap.add_argument("--sr", type=float, nargs="+", default=list(SRS))
    ap.add_argument("--scenes", nargs="+", default=list(SCENES))
    ap.add_argument("--noise", type=float, default=0.01)
    ap.add_argument("--cv-iter", type=int, default=100)
    ap.add_argument("--out", default=None)
    ap.add_argument("--noise-table", action="store_true",
                    help="the noise estimate's bias table instead (estimate %% (dB vs mu=2^8))")
    ap.add_argument("--bp", action="store_true",
                    help="basis pursuit's default against TVAL3's default instead (PSNR dB)")
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    if args.bp:
        return bp_table(args.n, args.sr, args.scenes)
    if args.noise_table:
        rows = noise_table(args.n, args.sr, args.scenes)
        if args.out:
            with open(args.out, "w") as f:
                json.dump(rows, f, indent=1)
        return rows
    rows = []
    print("| scene | n | SR % | TVAL3 default | auto | best cand. | median cand. | regret | "
          "vs median | chosen | t default s | t auto s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for n in args.n:
        for sr in args.sr:
            A = tt.operators.Hadamard(n, sr=sr).double()
            for name in args.scenes:
                x = scene(name, n)
                y0 = A(x)
                g = torch.Generator().manual_seed(0)
                y = y0 + args.noise * (y0.max() - y0.min()) * torch.randn(
                    y0.shape, dtype=y0.dtype, generator=g)
                t0 = time.perf_counter()
                d = tval3(y, A)
                t_def = time.perf_counter() - t0
                t0 = time.perf_counter()
                r = auto(y, A, cv_iter=args.cv_iter, return_result=True)
                t_auto = time.perf_counter() - t0
                cp = candidate_psnrs(y, A, x, r.candidates, args.cv_iter)
                ch = r.choice[0][0]
                row = dict(scene=name, n=n, sr=sr, default=psnr(d.x, x)[0],
                           auto=psnr(r.x, x)[0], best=max(cp), median=statistics.median(cp),
                           chosen=dict(prior=ch["prior"], tv=ch["tv"], bounds=ch["bounds"],
                                       mu=ch["mu"]),
                           t_default=t_def, t_auto=t_auto)
                rows.append(row)
                mu = "c" if ch["mu"] is None else f"2^{round(math.log2(ch['mu']))}"
                bd = {None: "-", (0.0, None): "≥0"}.get(ch["bounds"], str(ch["bounds"]))
                print(f"| {name} | {n} | {100 * sr:g} | {row['default']:.2f} | "
                      f"{row['auto']:.2f} | {row['best']:.2f} | {row['median']:.2f} | "
                      f"{row['best'] - row['auto']:.2f} | {row['auto'] - row['median']:+.2f} | "
                      f"{ch['prior']} {(ch['tv'] or '')[:3]} {bd} {mu} | {t_def:.2f} | "
                      f"{t_auto:.1f} |", flush=True)
    if args.out:
        with open(args.out, "w") as f:
            json.dump(rows, f, indent=1)
    return rows


if __name__ == "__main__":
    main()
