"""TVAL3 benchmark: horse 64x64, Hadamard SR 25 %, Gaussian noise at 1 % of the
measurement spread; TVAL3 on its defaults against a plain ADMM-TV baseline (benchmarks/baseline.py,
same periodic isotropic TV) run to convergence with its weight tuned per noise draw on an oracle
grid (lam = 2^(k/8) sigma, true sigma; the grid is wide enough that its best point is interior).

Timing (median of 9 after a warm-up) on the first seed; PSNR on every seed, because one draw
hides how much the estimated noise std (and with it the automatic weight) varies.

usage: python benchmarks/bench_tval3.py [--threads 2] [--seeds 0-5] [--no-baseline] [--out DIR]

With ``--out DIR`` the timings, rows and the machine's load go to ``DIR/tval3.json`` (the
README's TVAL3 numbers are generated from it by ``docs/build.py``).
"""

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch
from skimage import data, transform

from torchtof.metrics import psnr as _psnr
from torchtof.operators import Hadamard
from torchtof.recon.tval3 import bucket_noise_sigma, tval3

sys.path.insert(0, str(Path(__file__).parent))
from baseline import admm_tv  # noqa: E402

N = 64
GRID = range(-14, 3)  # lam / sigma = 2^(k/8): 2^-1.75 .. 2^0.25


def parse_seeds(text: str) -> list[int]:
    lo, _, hi = text.partition("-")
    return list(range(int(lo), int(hi or lo) + 1))


def psnr(a, b):  # paper Eqs. 13-14 on [0, 1] (MAX = 1), in float64
    return float(_psnr(a.double(), b.double(), bits=None))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--seeds", default="0", help="noise seeds, e.g. 0-5 (default 0)")
    p.add_argument("--no-baseline", action="store_true")
    p.add_argument("--out", type=Path, default=None, help="write DIR/tval3.json")
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    from torchtof.apps.bench.timing import machine_load

    t_run, start, timing = time.perf_counter(), machine_load(), {}
    img = transform.resize(data.horse().astype(np.float64), (N, N), anti_aliasing=True) < 0.5
    x = torch.tensor(img, dtype=torch.float32)[None, None]
    A = Hadamard(N, sr=0.25)
    y0 = A(x)
    sigma = 0.01 * float(y0.max() - y0.min())
    seeds = parse_seeds(args.seeds)
    rows = []
    for i, seed in enumerate(seeds):
        g = torch.Generator().manual_seed(seed)
        y = y0 + sigma * torch.randn(y0.shape, generator=g)
        if i == 0:
            for u_step in ("bb", "exact"):
                tval3(y, A, u_step=u_step)  # warm-up (and the exact step's factor cache)
                ts, cs = [], []
                for _ in range(9):
                    t, c = time.perf_counter(), time.process_time()
                    r = tval3(y, A, u_step=u_step, return_result=True)
                    ts.append(time.perf_counter() - t)
                    cs.append(time.process_time() - c)  # CPU time: much less load-dependent
                timing[u_step] = {"median_s": statistics.median(ts), "min_s": min(ts),
                                  "cpu_median_s": statistics.median(cs),
                                  "n_iter": int(r.n_iter), "converged": bool(r.converged),
                                  "psnr": psnr(r.x, x)}
                print(
                    f"seed {seed}, TVAL3 defaults u_step={u_step}: median "
                    f"{statistics.median(ts):.3f} s, min {min(ts):.3f} s ({args.threads} threads), "
                    f"n_iter={int(r.n_iter)}, converged={bool(r.converged)}, "
                    f"PSNR={psnr(r.x, x):.3f} dB, residual={float(r.residual):.4f}",
                    flush=True,
                )
        row = {
            "seed": seed,
            "sighat": float(bucket_noise_sigma(y)) / sigma,
            "default": psnr(tval3(y, A), x),
            "outer40": psnr(tval3(y, A, max_outer=40), x),
            "true_sigma": psnr(tval3(y, A, noise_sigma=sigma), x),
        }
        if not args.no_baseline:
            ps = {k: psnr(admm_tv(y.double(), A, 2.0 ** (k / 8) * sigma)[0], x) for k in GRID}
            kb = max(ps, key=ps.get)
            if kb in (GRID[0], GRID[-1]):
                print(f"  warning: seed {seed}: the oracle weight is at the grid's edge")
            row["oracle"], row["oracle_log2"] = ps[kb], kb / 8
        rows.append(row)
        print(
            f"seed {seed}: sigma_hat/sigma {row['sighat']:.2f}, TVAL3 defaults "
            f"{row['default']:.3f} dB, max_outer=40 {row['outer40']:.3f}, true sigma "
            f"{row['true_sigma']:.3f}"
            + (
                f"; ADMM-TV oracle {row['oracle']:.3f} at lam=2^{row['oracle_log2']:+.3f} sigma"
                f" (defaults {row['default'] - row['oracle']:+.3f} dB)"
                if "oracle" in row
                else ""
            ),
            flush=True,
        )
    if len(rows) > 1 and not args.no_baseline:
        gaps = [r["default"] - r["oracle"] for r in rows]
        print(
            f"defaults - oracle over {len(rows)} seeds: mean {statistics.mean(gaps):+.3f} dB, "
            f"range {min(gaps):+.3f} .. {max(gaps):+.3f}; seeds with defaults >= oracle: "
            f"{sum(gap >= 0 for gap in gaps)}"
        )
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        res = {"benchmark": "tval3", "n": N, "sr": 0.25, "noise": 0.01, "scene": "horse",
               "threads": args.threads, "torch": torch.__version__, "timing": timing,
               "rows": rows, "total_s": time.perf_counter() - t_run,
               "machine": {"start": start, "end": machine_load()}}
        (args.out / "tval3.json").write_text(json.dumps(res, indent=1))
        print(f"wrote {args.out / 'tval3.json'} ({res['total_s']:.0f} s)")


if __name__ == "__main__":
    main()
