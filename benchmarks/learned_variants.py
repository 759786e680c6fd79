"""Design measurements of the learned reconstructor's prior: cost per step and short trainings
compared on one fixed validation set.

- ``--time``: time of one prior pass (:class:`torchtof.recon.learned.LearnedPrior`) per image,
  batch 3, one thread, median of 5 after a warm-up, for ``(width, shuffle)`` variants at
  n = 32, 128, 256.
- ``--train WIDTH SHUFFLE STEPS``: :func:`torchtof.recon.learned_train.train_learned` with the
  shipped recipe otherwise (final data-consistency step off, no calibration), then the mean
  PSNR on the validation set: 6 procedural scenes per size (seed 7, steps 2·10⁶ + n, training
  generators but steps no run of < 2·10⁶ steps draws) × n ∈ {32, 64, 128} × SR ∈ {6.25, 12.5,
  25} % × Gaussian noise {0, 1, 5} % of the measurement spread, cake-cutting order.
  ``--resume`` continues ``--out`` to more steps (the cosine schedule then spans the new
  total).

- ``--sigma``: the conditioning ``σ_n = σ·n/‖y‖`` of the held-out depth scenes
  (``benchmarks/eval_learned.py``) with the true ``σ`` (noise std of the buckets) and with the
  ``"auto"`` estimate, against ``σ·n/‖A x‖`` (the scale without noise), at n = 32 … 256.

usage: python benchmarks/learned_variants.py --time
       python benchmarks/learned_variants.py --train 16 1 200 --out /tmp/v16
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np
import torch

from torchtof.data import TRAIN_IMAGES, NoiseRecipe, draw_scenes, noisy_buckets
from torchtof.operators import Hadamard
from torchtof.recon.learned import LearnedPrior
from torchtof.recon.learned_train import psnr_loss, train_learned

VARIANTS = ((16, 1), (16, 2), (24, 2), (32, 2), (32, 4))


def prior_times(sizes=(32, 128, 256)) -> list[dict]:
    out = []
    for n in sizes:
        z, c = torch.randn(3, 1, n, n), torch.randn(3, 3)
        for width, shuffle in VARIANTS:
            net = LearnedPrior(width, shuffle=shuffle)
            with torch.no_grad():
                net(z, c)
                ts = []
                for _ in range(5):
                    t = time.perf_counter()
                    net(z, c)
                    ts.append((time.perf_counter() - t) / 3)
            row = {"n": n, "width": width, "shuffle": shuffle, "ms": 1e3 * float(np.median(ts)),
                   "params": sum(p.numel() for p in net.parameters())}
            out.append(row)
            print(row, flush=True)
    return out


def sigma_table() -> list[dict]:
    from eval_learned import buckets, scenes

    from torchtof.recon.tval3 import bucket_noise_sigma

    out = []
    for n in (32, 64, 128, 256):
        for sr in (0.0625, 0.125):
            for level in (0.01, 0.05):
                A = Hadamard(n, sr=sr, order="cake_cutting")
                x = scenes("depth", n)
                y0 = A(x)
                y = buckets(A, x, level, salt=n + int(sr * 1e4) + int(level * 1e4))
                sigma = level * (y0.amax(-1) - y0.amin(-1))
                row = {"n": n, "sr": sr, "level": level,
                       "sigma_n_true": float((sigma * n / y.norm(dim=-1)).mean()),
                       "sigma_n_auto": float((bucket_noise_sigma(y) * n / y.norm(dim=-1)).mean()),
                       "sigma_n_clean_scale": float((sigma * n / y0.norm(dim=-1)).mean()),
                       "bound_1_over_sqrt_sr": sr ** -0.5}
                out.append(row)
                print({k: round(v, 2) if isinstance(v, float) else v for k, v in row.items()},
                      flush=True)
    return out


def validation_set() -> list:
    out = []
    for n in (32, 64, 128):
        x = draw_scenes(n, 7, 2_000_000 + n, range(6), images=TRAIN_IMAGES).float()
        for sr in (0.0625, 0.125, 0.25):
            for level in (0.0, 0.01, 0.05):
                A = Hadamard(n, sr=sr, order="cake_cutting")
                g = [torch.Generator().manual_seed(100 * n + i) for i in range(6)]
                out.append(((n, sr, level), A, x, noisy_buckets(A, x, [NoiseRecipe(level)] * 6, g)))
    return out


def validate(model) -> dict:
    """Mean PSNR (dB) per (n, noise) and overall, final step off as in training."""
    model.final_dc = False
    res = {}
    with torch.no_grad():
        for key, A, x, y in validation_set():
            model.A = A
            res[key] = -float(psnr_loss(model(y), x))
    by: dict = {}
    for (n, _, level), v in res.items():
        by.setdefault(f"n{n}/{level * 100:g}%", []).append(v)
    return {"mean": float(np.mean(list(res.values()))),
            **{k: float(np.mean(v)) for k, v in sorted(by.items())}}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--time", action="store_true")
    p.add_argument("--sigma", action="store_true")
    p.add_argument("--train", nargs=3, type=int, metavar=("WIDTH", "SHUFFLE", "STEPS"))
    p.add_argument("--out", default=None)
    p.add_argument("--resume", action="store_true")
    args = p.parse_args()
    torch.set_num_threads(1)
    if args.time:
        prior_times()
    if args.sigma:
        sigma_table()
    if args.train:
        width, shuffle, steps = args.train
        t = time.perf_counter()
        r = train_learned(steps=steps, width=width, shuffle=shuffle, progress=False,
                          calibrate=False, out=args.out, resume=args.resume)
        row = {"width": width, "shuffle": shuffle, "steps": steps,
               "train_s": round(time.perf_counter() - t), **validate(r.model)}
        print(json.dumps(row), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
