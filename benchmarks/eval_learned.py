"""Held-out evaluation of the learned reconstructor against TVAL3's defaults, the automatic
TV reconstructor (:func:`torchtof.recon.auto.auto`, its defaults) and the unrolled TVAL3 where
it ships weights.

Scenes that training never saw: three classes, each from generators seeded at
``torchtof.data.EVAL_SEED_BASE`` and up (checked disjoint from every scene seed of the shipped
run) or from held-out scikit-image images:

- ``depth``: piecewise-planar and piecewise-smooth depth maps (eval seeds);
- ``silhouette``: the horse (held-out image, Otsu mask), the paper's character 天
  (:func:`torchtof.scenes.sky_character`) and a random silhouette (eval seed);
- ``natural``: camera, astronaut, Shepp–Logan (held-out images).

Buckets: ``Hadamard(n, sr, order)`` with Gaussian noise of ``level × (max y − min y)``
(the package's convention), one seeded draw per scene. Score: PSNR (paper Eqs. 13–14 with
MAX = 1, no quantisation) and SSIM of the reconstruction clipped to [0, 1] against the scene.
Time: wall time of one batched call over the class's scenes divided by their number, one
thread, after a warm-up call, TVAL3 and the learned model interleaved (same machine load);
``auto`` is scored, and timed without a warm-up (it costs about 5–9× a default TVAL3 solve, docs/auto.md).

usage: python benchmarks/eval_learned.py [--sizes 32 64 128] [--srs 0.0625 0.125 0.25 0.375]
       [--levels 0 0.01 0.05] [--out main.json] [--generalisation] [--methods ...]
       python benchmarks/eval_learned.py --table main.json auto.json
       python benchmarks/eval_learned.py --compare with_tval3.json other_weights.json
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from torchtof.data import EVAL_SEED_BASE, NoiseRecipe, draw_scene, grey_image, noisy_buckets
from torchtof.metrics import psnr, ssim
from torchtof.operators import Hadamard
from torchtof.recon.auto import auto
from torchtof.recon.learned import WEIGHTS_FILE, Learned
from torchtof.recon.synthetic import scene_seed
from torchtof.recon.tval3 import tval3
from torchtof.recon.unrolled import UnrolledTVAL3, weight_path
from torchtof.scenes import binary_scene, sky_character

CLASSES = ("depth", "silhouette", "natural")


def _resize(img: torch.Tensor, n: int) -> torch.Tensor:
    h, w = img.shape
    s = min(h, w)
    img = img[(h - s) // 2 : (h - s) // 2 + s, (w - s) // 2 : (w - s) // 2 + s]
    x = F.interpolate(img[None, None], size=(n, n), mode="bilinear", antialias=True)
    return x.clamp(0, 1)


def scenes(cls: str, n: int) -> torch.Tensor:
    """The held-out scenes of a class, ``(3, 1, n, n)`` in [0, 1]."""
    if cls == "depth":
        xs = [draw_scene(n, EVAL_SEED_BASE + 0, "planar"), draw_scene(n, EVAL_SEED_BASE + 1, "smooth"),
              draw_scene(n, EVAL_SEED_BASE + 2, "planar")]
    elif cls == "silhouette":
        xs = [binary_scene("horse", n), sky_character(n), draw_scene(n, EVAL_SEED_BASE + 3, "silhouette")]
    else:
        xs = [_resize(grey_image(k), n) for k in ("camera", "astronaut", "shepp_logan_phantom")]
    return torch.cat(xs).float()


def recipe_of(weights: Path) -> Path:
    """The ``recipe.json`` of a weights file: ``NAME.recipe.json`` beside it (the candidates
    kept in ``docs/learned/candidates``) or ``recipe.json`` in its folder (a training run's)."""
    own = weights.with_suffix(".recipe.json")
    return own if own.is_file() else weights.parent / "recipe.json"


def check_seeds_unseen(recipe: dict) -> None:
    """Every scene seed of the shipped run differs from the evaluation seeds."""
    steps, batch, seed = recipe["steps_run"], recipe["batch_size"], recipe["seed"]
    eval_seeds = {EVAL_SEED_BASE + i for i in range(4)}
    for step in range(steps):
        for i in range(batch):
            if scene_seed(seed, step, i) in eval_seeds:
                raise SystemExit(f"evaluation seed {scene_seed(seed, step, i)} was seen in training")


def buckets(A: Hadamard, x: torch.Tensor, level: float, salt: int) -> torch.Tensor:
    gens = [torch.Generator().manual_seed(10_000 * salt + i) for i in range(x.shape[0])]
    return noisy_buckets(A, x, [NoiseRecipe(level=level)] * x.shape[0], gens)


def timed(fn, y: torch.Tensor) -> tuple[torch.Tensor, float]:
    with torch.no_grad():
        fn(y[:1])  # warm-up
        t = time.perf_counter()
        x = fn(y)
        return x, (time.perf_counter() - t) / y.shape[0]


def score(x_hat: torch.Tensor, x: torch.Tensor) -> tuple[float, float]:
    xh = x_hat.clamp(0, 1).double()
    return (float(psnr(xh, x.double(), bits=None).mean()), float(ssim(xh, x.double()).mean()))


METHODS = ("learned", "tval3", "auto", "unrolled")


def run_cell(n, sr, order, level, cls, methods=METHODS, weights=True, oracle_sigma=False,
             flips=1):
    """One (n, SR, order, noise, class) cell: PSNR/SSIM and time per image of each method
    (``oracle_sigma``: the learned model is given the true bucket noise std instead of
    estimating it; ``flips``: the learned model's self-ensemble, ``Learned(flips=...)``)."""
    A = Hadamard(n, sr=sr, order=order)
    x = scenes(cls, n)
    y = buckets(A, x, level, salt=n + int(sr * 1e4) + int(level * 1e4))
    row = {"n": n, "sr": sr, "order": order, "level": level, "class": cls}
    if "learned" in methods:
        net = Learned(A, pretrained=weights, flips=flips)
        fn = net
        if oracle_sigma:
            y0 = A(x)
            sigma = level * (y0.amax(-1) - y0.amin(-1))  # (B, C): the std buckets() drew

            def fn(v, net=net, sigma=sigma):
                net.noise_sigma = sigma[: v.shape[0]]  # the warm-up call takes one scene
                return net(v)
        xl, row["t_learned"] = timed(fn, y)
        row["learned"] = score(xl, x)
    if "tval3" in methods:
        xt, row["t_tval3"] = timed(lambda v: tval3(v, A), y)
        row["tval3"] = score(xt, x)
    if "auto" in methods:
        with torch.no_grad():
            t = time.perf_counter()
            xa = auto(y, A)
            row["t_auto"] = (time.perf_counter() - t) / y.shape[0]
        row["auto"] = score(xa, x)
    if ("unrolled" in methods and order == "cake_cutting"
            and weight_path(n, A.m, 12).is_file()):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            un = UnrolledTVAL3(A)
        xu, tu = timed(un, y)
        row["unrolled"], row["t_unrolled"] = score(xu, x), tu
    return row


def merge(files: list[str]) -> list[dict]:
    """The rows of several ``--out`` files, the fields of one cell joined (later files add
    the methods that earlier ones lack)."""
    cells: dict = {}
    for f in files:
        for r in json.load(open(f))["rows"]:
            key = (r["n"], r["sr"], r["order"], r["level"], r["class"], bool(r.get("generalisation")))
            cells.setdefault(key, {}).update({k: v for k, v in r.items()
                                              if k not in cells.get(key, {})})
    return list(cells.values())


def table(rows: list[dict]) -> str:
    """Markdown: one line per (n, SR, noise), the PSNR difference learned − TVAL3 per class,
    the mean PSNRs and SSIMs, and the time ratio."""
    out = ["| n | SR % | noise % | " + " | ".join(f"Δ {c} dB" for c in CLASSES)
           + " | learned dB / SSIM | TVAL3 dB / SSIM | auto dB / SSIM | unrolled dB "
           "| learned ms | TVAL3 ms | auto ms |",
           "|---" * (10 + len(CLASSES)) + "|"]
    rows = [r for r in rows if "learned" in r and "tval3" in r]
    keys = sorted({(r["n"], r["sr"], r["level"]) for r in rows if not r.get("generalisation")})
    for n, sr, level in keys:
        cell = [r for r in rows if (r["n"], r["sr"], r["level"]) == (n, sr, level)
                and not r.get("generalisation")]
        by = {r["class"]: r for r in cell}
        d = [f"{by[c]['learned'][0] - by[c]['tval3'][0]:+.2f}" if c in by else "-" for c in CLASSES]
        ml = np.mean([r["learned"][0] for r in cell])
        mt = np.mean([r["tval3"][0] for r in cell])
        sl = np.mean([r["learned"][1] for r in cell])
        st = np.mean([r["tval3"][1] for r in cell])
        un = [r["unrolled"][0] for r in cell if "unrolled" in r]
        tl = np.mean([r["t_learned"] for r in cell]) * 1e3
        tt = np.mean([r["t_tval3"] for r in cell]) * 1e3
        au = [r for r in cell if "auto" in r]
        a_s = (f"{np.mean([r['auto'][0] for r in au]):.2f} / "
               f"{np.mean([r['auto'][1] for r in au]):.3f}" if au else "-")
        a_t = f"{np.mean([r['t_auto'] for r in au]) * 1e3:.0f}" if au else "-"
        out.append(f"| {n} | {sr * 100:g} | {level * 100:g} | " + " | ".join(d)
                   + f" | {ml:.2f} / {sl:.3f} | {mt:.2f} / {st:.3f} | {a_s} | "
                   + (f"{np.mean(un):.2f}" if un else "-") + f" | {tl:.1f} | {tt:.1f} | {a_t} |")
    return "\n".join(out)


def acceptance(rows: list[dict]) -> str:
    """The acceptance numbers: mean Δ (learned − TVAL3, and learned − auto) over the (class, n,
    SR) cells at SR <= 12.5 % and 1 % noise, the cells more than 0.5 dB below TVAL3 (and
    below auto), and the median time ratio TVAL3 / learned per n."""
    rows = [r for r in rows if not r.get("generalisation") and "learned" in r and "tval3" in r]
    low = [r for r in rows if r["sr"] <= 0.125 + 1e-9 and abs(r["level"] - 0.01) < 1e-9]
    out = []
    for ref in ("tval3", "auto"):
        have = [r for r in rows if ref in r]  # auto may cover part of the cells
        d = [r["learned"][0] - r[ref][0] for r in low if ref in r]
        if not d:
            continue
        worse = sorted(((r["learned"][0] - r[ref][0], i) for i, r in enumerate(have)
                        if r["learned"][0] - r[ref][0] < -0.5))
        worse = [(dd, have[i]) for dd, i in worse]
        out.append(f"vs {ref}: mean Δ at SR <= 12.5 %, 1 % noise {np.mean(d):+.2f} dB "
                   f"(min {min(d):+.2f}, {len(d)} cells); {len(worse)} of {len(have)} cells "
                   "worse by > 0.5 dB" + (":" if worse else ""))
        out += [f"  n={r['n']} SR {r['sr'] * 100:g} % noise {r['level'] * 100:g} % "
                f"{r['class']} {dd:+.2f}" for dd, r in worse]
    for n in sorted({r["n"] for r in rows}):
        ratio = [r["t_tval3"] / r["t_learned"] for r in rows if r["n"] == n]
        extra = ""
        if all("t_auto" in r for r in rows if r["n"] == n):
            extra = (", auto / learned "
                     f"{np.median([r['t_auto'] / r['t_learned'] for r in rows if r['n'] == n]):.0f}×")
        out.append(f"n={n}: median time TVAL3 / learned {np.median(ratio):.1f}× "
                   f"(min {min(ratio):.1f}×){extra}")
    return "\n".join(out)


def summary_table(rows: list[dict]) -> str:
    """Markdown: mean Δ (learned − TVAL3) over SR and class per (noise, n), with the worst
    (class, SR) cell, and the median time per image per n (the README's table)."""
    rows = [r for r in rows if not r.get("generalisation") and "learned" in r and "tval3" in r]
    sizes = sorted({r["n"] for r in rows})
    out = ["| noise | " + " | ".join(f"n = {n}" for n in sizes) + " |",
           "|---" * (1 + len(sizes)) + "|"]
    for level in sorted({r["level"] for r in rows}):
        cells = []
        for n in sizes:
            d = [r["learned"][0] - r["tval3"][0] for r in rows if r["n"] == n and r["level"] == level]
            cells.append(f"{np.mean(d):+.2f} (min {min(d):+.2f})" if d else "-")
        out.append(f"| {level * 100:g} % | " + " | ".join(cells) + " |")
    tl = [np.median([r["t_learned"] for r in rows if r["n"] == n]) * 1e3 for n in sizes]
    tt = [np.median([r["t_tval3"] for r in rows if r["n"] == n]) * 1e3 for n in sizes]
    out.append("| time learned / TVAL3 (median per image) | "
               + " | ".join(f"{a:.0f} / {b:.0f} ms" for a, b in zip(tl, tt, strict=True)) + " |")
    return "\n".join(out)


def compare(files: list[str]) -> str:
    """The acceptance criteria of several weights on the same cells: the learned rows of each
    file against the TVAL3 rows of the first (n <= 128, cake-cutting): mean Δ at SR <= 12.5 %,
    1 % noise, the cells more than 0.5 dB worse, the worst cell, and mean Δ per (noise, n)."""
    def key(r):
        return (r["n"], r["sr"], r["level"], r["class"])

    def rows(f):
        return [r for r in json.load(open(f))["rows"] if not r.get("generalisation")]

    ref = {key(r): r for r in rows(files[0]) if "tval3" in r and r["n"] <= 128}
    out = []
    for f in files:
        got = {key(r): r for r in rows(f) if "learned" in r}
        ks = sorted(set(got) & set(ref))
        d = {k: got[k]["learned"][0] - ref[k]["tval3"][0] for k in ks}
        low = [d[k] for k in ks if k[1] <= 0.125 + 1e-9 and abs(k[2] - 0.01) < 1e-9]
        worst = min(d, key=d.get)
        out.append(f"{f}: {len(ks)} cells; mean Δ at SR <= 12.5 %, 1 % noise {np.mean(low):+.2f} dB "
                   f"({len(low)} cells); {sum(v < -0.5 for v in d.values())} cells worse by "
                   f"> 0.5 dB; worst {d[worst]:+.2f} dB (n={worst[0]} SR {worst[1] * 100:g} % "
                   f"noise {worst[2] * 100:g} % {worst[3]})")
        for lev in sorted({k[2] for k in ks}):
            out.append(f"  noise {lev * 100:g} %: " + ", ".join(
                f"n={n} {np.mean([d[k] for k in ks if k[:1] == (n,) and k[2] == lev]):+.2f} "
                f"(min {min(d[k] for k in ks if k[:1] == (n,) and k[2] == lev):+.2f})"
                for n in sorted({k[0] for k in ks if k[2] == lev})))
    return "\n".join(out)


def gen_table(rows: list[dict]) -> str:
    """Markdown: mean PSNR difference learned − TVAL3 over the classes per (order, SR), n = 64,
    noise 1 %."""
    rows = [r for r in rows if r.get("generalisation")]
    orders = sorted({r["order"] for r in rows})
    srs = sorted({r["sr"] for r in rows})
    out = ["| order | " + " | ".join(f"SR {s * 100:g} %" for s in srs) + " |",
           "|---" * (1 + len(srs)) + "|"]
    for o in orders:
        cells = []
        for s in srs:
            c = [r["learned"][0] - r["tval3"][0] for r in rows if r["order"] == o and r["sr"] == s]
            cells.append(f"{np.mean(c):+.2f}")
        out.append(f"| {o} | " + " | ".join(cells) + " |")
    return "\n".join(out)


def onnx_times(sizes=(32, 128), batch: int = 8, repeats: int = 5, weights=True) -> list[dict]:
    """Export at batch 2 (dynamic batch) to a temporary file, then the median time per image
    of onnxruntime (1 thread) and of eager PyTorch on a batch of ``batch`` at SR 12.5 %, and
    the max abs difference on [0, 1] scenes."""
    import tempfile

    import onnxruntime as ort

    out = []
    for n in sizes:
        A = Hadamard(n, sr=0.125)
        net = Learned(A, pretrained=weights).eval()
        x = torch.cat([draw_scene(n, EVAL_SEED_BASE + 10 + i) for i in range(batch)])
        y = A(x)
        with tempfile.TemporaryDirectory() as d, warnings.catch_warnings():
            warnings.simplefilter("ignore")
            path = f"{d}/learned.onnx"
            torch.onnx.export(net, (y[:2],), path, dynamo=False, opset_version=17,
                              input_names=["y"], output_names=["x"],
                              dynamic_axes={"y": {0: "batch"}, "x": {0: "batch"}})
            so = ort.SessionOptions()
            so.intra_op_num_threads = 1
            sess = ort.InferenceSession(path, so, providers=["CPUExecutionProvider"])
            feed = {"y": y.numpy()}
            sess.run(None, feed)
            t_ort = []
            for _ in range(repeats):
                t = time.perf_counter()
                got = sess.run(None, feed)[0]
                t_ort.append((time.perf_counter() - t) / batch)
        t_pt = []
        with torch.no_grad():
            ref = net(y)
            for _ in range(repeats):
                t = time.perf_counter()
                net(y)
                t_pt.append((time.perf_counter() - t) / batch)
        out.append({"n": n, "batch": batch, "ort_ms": 1e3 * float(np.median(t_ort)),
                    "torch_ms": 1e3 * float(np.median(t_pt)),
                    "max_abs_err": float(np.abs(got - ref.numpy()).max())})
        print(out[-1], flush=True)
    return out


def interleaved_min(fns: dict, y: torch.Tensor, rounds: int) -> dict:
    """Seconds per image of each ``fns[k](y)``: a warm-up call on one sample each, then
    ``rounds`` rounds calling every method once in turn; the minimum per method."""
    t = {k: [] for k in fns}
    with torch.no_grad():
        for fn in fns.values():
            fn(y[:1])
        for _ in range(rounds):
            for k, fn in fns.items():
                t0 = time.perf_counter()
                fn(y)
                t[k].append((time.perf_counter() - t0) / y.shape[0])
    return {k: min(v) for k, v in t.items()}


def speed(sizes=(32, 64, 128, 256), repeats: int = 3, weights=True,
          flips_options=(1,)) -> list[dict]:
    """Time per image, learned vs TVAL3's defaults, on the three depth scenes at SR 12.5 % and
    1 % noise (one batched call / 3), 1 thread: after a warm-up, ``repeats`` rounds that
    alternate the two methods; the minimum of each (the least disturbed by other processes).
    ``flips_options``: the learned model with each of these self-ensembles, interleaved too
    (``learned_f{k}_ms`` and ``ratio_f{k}``; ``flips = 1`` keeps the keys ``learned_ms``,
    ``ratio``)."""
    out = []
    for n in sizes:
        A = Hadamard(n, sr=0.125)
        x = scenes("depth", n)
        y = buckets(A, x, 0.01, salt=n)
        fns = {"learned" if k == 1 else f"learned_f{k}": Learned(A, pretrained=weights, flips=k)
               for k in flips_options}
        fns["tval3"] = lambda v, A=A: tval3(v, A)
        t = interleaved_min(fns, y, repeats)
        row = {"n": n, **{f"{k}_ms": 1e3 * v for k, v in t.items()},
               "load_avg": os.getloadavg()[0]}
        for k in flips_options:
            name = "learned" if k == 1 else f"learned_f{k}"
            row["ratio" if k == 1 else f"ratio_f{k}"] = row["tval3_ms"] / row[f"{name}_ms"]
        out.append(row)
        print(row, flush=True)
    return out


def paper(realisations: int = 3, weights=True) -> list[dict]:
    """The paper's experiment (:class:`torchtof.experiment.PaperExperiment`, 天 at n = 32, in
    air, default stray light), depth buckets without and with the 3 m gate, the paper's SRs:
    :func:`torchtof.metrics.compare` (8-bit PSNR after min-max normalisation, physics
    polarity), mean over ``realisations`` noise draws, learned vs TVAL3's defaults."""
    from torchtof.experiment import PaperExperiment
    from torchtof.metrics import compare

    data = PaperExperiment(sr=0.375).run(seed=0, realisations=realisations)
    out = []
    for gate in (False, True):
        for sr in (0.0625, 0.125, 0.1875, 0.25, 0.3125, 0.375):
            A, y = data.measurements(sr, gate=gate)
            x = data.x.to(y.dtype).expand(y.shape[0], -1, -1, -1)
            pol = data.polarity(gate)
            row = {"sr": sr, "gate": gate}
            for name, fn in (("learned", lambda v, A=A: Learned(A, pretrained=weights)(v)),
                             ("tval3", lambda v, A=A: tval3(v, A))):
                with torch.no_grad():
                    s = compare(fn(y), x, pol)
                row[name] = (float(s["psnr"].mean()), float(s["ssim"].mean()))
            out.append(row)
            print(row, flush=True)
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[32, 64, 128])
    p.add_argument("--srs", type=float, nargs="+", default=[0.0625, 0.125, 0.25, 0.375])
    p.add_argument("--levels", type=float, nargs="+", default=[0.0, 0.01, 0.05])
    p.add_argument("--classes", nargs="+", default=list(CLASSES))
    p.add_argument("--generalisation", action="store_true",
                   help="also orders other than cake-cutting and SRs beyond training (n=64, 1 %%)")
    p.add_argument("--methods", nargs="+", default=list(METHODS), choices=list(METHODS),
                   help="methods to run (default: all; auto is slow: it can run separately "
                        "and be joined by --table)")
    p.add_argument("--onnx", action="store_true", help="only the onnxruntime timing/parity")
    p.add_argument("--paper", action="store_true", help="only the paper's experiment")
    p.add_argument("--speed", action="store_true",
                   help="only the time per image learned vs TVAL3 (n = 32 … 256, min of 3)")
    p.add_argument("--out", default=None, help="JSON file of every row")
    p.add_argument("--oracle-sigma", action="store_true",
                   help="give the learned model the true noise std (diagnostic)")
    p.add_argument("--weights", default=None,
                   help="a weights file to evaluate (recipe.json beside it; default: shipped)")
    p.add_argument("--flips", type=int, default=1, choices=(1, 2, 4),
                   help="the learned model's self-ensemble over image flips (Learned(flips=))")
    p.add_argument("--compare", nargs="+", default=None,
                   help="the acceptance criteria of each file's learned rows against the TVAL3 "
                        "rows of the first file (same cells), and exit")
    p.add_argument("--table", nargs="+", default=None,
                   help="print the markdown tables of JSON files (joined cell by cell) and exit")
    args = p.parse_args()
    if args.compare:
        print(compare(args.compare))
        return 0
    if args.table:
        rows = merge(args.table)
        print(table(rows))
        print()
        print(summary_table(rows))
        print()
        print(acceptance(rows))
        if any(r.get("generalisation") for r in rows):
            print()
            print(gen_table(rows))
        return 0
    torch.set_num_threads(1)
    if args.onnx or args.paper or args.speed:
        if args.speed:
            rows = speed(weights=args.weights or True,
                         flips_options=(1,) if args.flips == 1 else (1, args.flips))
        else:
            w = args.weights or True
            rows = onnx_times(weights=w) if args.onnx else paper(weights=w)
        if args.out:
            with open(args.out, "w") as f:
                json.dump(rows, f, indent=0)
        return 0
    recipe = None
    weights = Path(args.weights) if args.weights else WEIGHTS_FILE
    if "learned" in args.methods:
        if not weights.is_file():
            raise SystemExit(f"no weights at {weights}")
        recipe = json.loads(recipe_of(weights).read_text())
        check_seeds_unseen(recipe)
    rows = []
    t0 = time.perf_counter()
    for n in args.sizes:
        for sr in args.srs:
            for level in args.levels:
                for cls in args.classes:
                    r = run_cell(n, sr, "cake_cutting", level, cls, args.methods, weights,
                                 args.oracle_sigma, args.flips)
                    if args.flips > 1:
                        r["flips"] = args.flips
                    rows.append(r)
                    if args.out:  # after every cell: an interrupted run keeps what it measured
                        with open(args.out, "w") as f:
                            json.dump({"recipe": recipe, "rows": rows}, f, indent=0)
                    print(f"n={n:3d} sr={sr:.4f} noise={level:.2f} {cls:10s} " + "  ".join(
                        f"{k} {r[k][0]:6.2f} dB {r['t_' + k] * 1e3:7.1f} ms"
                        for k in METHODS if k in r), flush=True)
    if args.generalisation:
        for order in ("cake_cutting", "sequency", "russian_doll", "natural"):
            for sr in (0.125, 0.25, 0.5, 0.75):
                for cls in args.classes:
                    r = run_cell(64, sr, order, 0.01, cls, ("learned", "tval3"), weights)
                    r["generalisation"] = True
                    rows.append(r)
                    print(f"gen order={order:12s} sr={sr:.3f} {cls:10s} learned "
                          f"{r['learned'][0]:6.2f} tval3 {r['tval3'][0]:6.2f} "
                          f"d={r['learned'][0] - r['tval3'][0]:+5.2f}", flush=True)
    print(f"total {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    if args.out:
        with open(args.out, "w") as f:
            json.dump({"recipe": recipe, "rows": rows}, f, indent=0)
    return 0


if __name__ == "__main__":
    sys.exit(main())
