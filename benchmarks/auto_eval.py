"""How well :func:`torchtof.recon.auto` chooses: PSNR against TVAL3's default, against the best
and the median of its own candidates (each refitted on all buckets with the same budget).

Scenes: binary silhouettes (the paper's character, scikit-image ``horse`` thresholded),
grey natural images (scikit-image ``camera``, ``coins``, ``moon``) and a procedurally drawn
piecewise-planar depth map (normalised to [0, 1]). Hadamard cake-cutting rows, Gaussian noise
of 1 % of the bucket spread, one noise draw per cell (seed 0). PSNR on [0, 1] after clamping
(8-bit peak, ``torchtof.metrics.psnr``).

    OMP_NUM_THREADS=1 python benchmarks/auto_eval.py --n 32 64 --out auto_eval.json

Prints a Markdown table (docs/auto.md holds the committed one). ``--peers-cells
docs/peers.json`` runs the same table on the cells of the peers benchmark instead (its
problems and PSNR, ``benchmarks/peers_scenes.py``; the sizes ``--n``), ``--shard I/K`` every
K-th cell (two processes on two cores)::

    OMP_NUM_THREADS=1 python benchmarks/auto_eval.py --peers-cells docs/peers.json --n 32 64 \\
        --shard 0/2 --out regret_0.json     # and --shard 1/2

How the fold layout and score were chosen (docs/auto.md, "The fold score"): ``--fold-study``
fits every first-stage TV candidate on the first 4/8 … 7/8 of the rows and stores its error
on every later eighth and its full-data refit's PSNR; ``--fold-rules`` scores fold rules on
those files (the peers' cells against ``docs/peers.json``)::

    python benchmarks/auto_eval.py --fold-study fs_a32.json --n 32      # and --n 64
    python benchmarks/auto_eval.py --fold-study fs_p.json --peers-cells docs/peers.json
    python benchmarks/auto_eval.py --fold-rules fs_p.json --peers-cells docs/peers.json
"""

from __future__ import annotations

import argparse
import importlib
import json
import math
import statistics
import time

import torch

import torchtof as tt
from torchtof.data import planar_depth
from torchtof.recon import auto, tgv, tval3
from torchtof.recon.auto import AUTO_WEIGHTS

_auto = importlib.import_module("torchtof.recon.auto")  # the module (recon.auto is the function)

SRS = (0.0625, 0.125, 0.25, 0.375)


def _weight(w) -> str:
    return "–" if w is None else f"{w:.2f}"


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


def noisy(name: str, A, noise: float) -> tuple[torch.Tensor, torch.Tensor]:
    """``(x, y)``: the scene at ``A.n`` and its buckets with Gaussian noise of ``noise`` × the
    bucket spread (one draw, seed 0)."""
    x = scene(name, A.n)
    y0 = A(x)
    g = torch.Generator().manual_seed(0)
    return x, y0 + noise * (y0.max() - y0.min()) * torch.randn(y0.shape, dtype=y0.dtype,
                                                               generator=g)


def refit(cand: dict, y: torch.Tensor, A, cv_iter: int = 100, max_iter: int = 1025):
    """``auto``'s refit of one of its candidates on every row (its own ``_fit``: the
    constrained model with the ``cv_iter`` budget it was validated with, TV-L2 up to
    ``max_iter``) -> ``x``."""
    constrained = cand["mu"] is None
    return _auto._fit(_auto._group_of(cand), y, A, 2.0**8 if constrained else cand["mu"],
                      not constrained, cv_iter if constrained else max_iter)[0]


def psnr(a: torch.Tensor, x: torch.Tensor) -> list[float]:
    return tt.metrics.psnr(a.clamp(0, 1), x, bits=8).reshape(-1).tolist()


def candidate_psnrs(y, A, x, cands, cv_iter, max_iter=1025, score=psnr):
    """PSNR of every first-stage candidate of ``auto`` refitted on all buckets as ``auto``
    refits its choice (constrained: ``cv_iter`` iterations; TV-L2: up to ``max_iter``), in the
    order of ``cands`` (second-stage weights and the box-only candidate are skipped).
    ``score(x_hat (K, 1, n, n), x (K, 1, n, n)) -> K`` PSNRs."""
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
        xc = solve(y, A, mu=2.0**8, max_iter=cv_iter, tv=tv, boundary=bd, bounds=box)
        out[(*g, None)] = score(xc, x)[0]
        mus = torch.tensor(finite, dtype=y.dtype)[None]
        xl = solve(y.expand(1, len(finite), -1), A, mu=mus, tvl2=True, max_iter=max_iter, tv=tv,
                   boundary=bd, bounds=box)
        for j, p in enumerate(score(xl.transpose(0, 1), x.expand(len(finite), 1, -1, -1))):
            out[(*g, finite[j])] = p
    key = [(c["prior"], c["tv"], c["boundary"], c["bounds"], c["mu"]) for c in cands]
    return [out[k] for k in key if k in out]


STUDY_GROUPS = (("isotropic", None), ("isotropic", (0.0, None)), ("anisotropic", None),
                ("anisotropic", (0.0, None)))  # TV, Neumann (the study predates TGV in auto)


def fold_study_cell(x, A, y, score) -> dict:
    """Per TV group and weight of ``AUTO_WEIGHTS``: the squared error on each eighth of the
    rows of the fit (100 iterations) on the first ``k/8`` rows, ``k = 4…7`` (``blocks[k-4][w]``,
    all 8 eighths), the training misfit, and the full-data refit's PSNR (as ``auto`` refits)."""
    from torchtof.recon.tval3 import MaskedRows, bucket_noise_sigma

    m, w_n = A.m, len(AUTO_WEIGHTS)
    edges = [round(i * m / 8) for i in range(9)]
    inf = float("inf")
    mus = torch.tensor([2.0**8 if w == inf else w for w in AUTO_WEIGHTS], dtype=y.dtype)
    tvl2 = torch.tensor([w != inf for w in AUTO_WEIGHTS])
    masks = torch.zeros(4, m, dtype=torch.bool)
    for i, k in enumerate(range(4, 8)):
        masks[i, : edges[k]] = True
    mask1 = masks.repeat_interleave(w_n, 0)
    yv = y.reshape(-1)
    out = dict(m=m, edges=edges, sigma=float(bucket_noise_sigma(y)), groups={},
               energy=[float(yv[edges[b]:edges[b + 1]].square().sum()) for b in range(8)])
    finite = [w for w in AUTO_WEIGHTS if w != inf]
    for tv, box in STUDY_GROUPS:
        r = tval3(y * mask1.to(y.dtype), MaskedRows(A, mask1), mu=mus.repeat(4)[None],
                  tvl2=tvl2.repeat(4)[None], max_iter=100, tv=tv, boundary="neumann", bounds=box)
        r2 = (A(r) - y).square()[0].reshape(4, w_n, m)
        blocks = torch.stack([r2[..., edges[b]:edges[b + 1]].sum(-1) for b in range(8)], -1)
        fit = (r2 * masks[:, None].to(y.dtype)).sum(-1)
        rc = tval3(y, A, mu=2.0**8, max_iter=100, tv=tv, boundary="neumann", bounds=box)
        rl = tval3(y.expand(1, len(finite), -1), A, mu=torch.tensor(finite, dtype=y.dtype)[None],
                   tvl2=True, max_iter=1025, tv=tv, boundary="neumann", bounds=box)
        ps = [score(rc, x)] + [score(rl[:, j : j + 1], x) for j in range(len(finite))]
        out["groups"][f"{tv[:3]}{'+' if box else ''}"] = dict(
            blocks=blocks.tolist(), fit=fit.tolist(), psnr=ps)
    return out


#: Fold rules compared by ``--fold-rules``: (training eighths k, held-out eighths) per fold,
#: and the score ("raw": summed errors; "best": each fold over its best; "log": log of that;
#: "energy": each fold over its held-out energy).
FOLD_RULES = {
    "quarters, summed (the previous rule)": ([(4, [4, 5]), (6, [6, 7])], "raw"),
    "quarters + a fold on 7/8, summed": ([(4, [4, 5]), (6, [6, 7]), (7, [7])], "raw"),
    "4 eighth-folds (1/2 … 7/8), summed": ([(4, [4]), (5, [5]), (6, [6]), (7, [7])], "raw"),
    "3 eighth-folds (5/8 … 7/8), summed": ([(5, [5]), (6, [6]), (7, [7])], "raw"),
    "4 eighth-folds, each over its held-out energy":
        ([(4, [4]), (5, [5]), (6, [6]), (7, [7])], "energy"),
    "quarters, each over its best": ([(4, [4, 5]), (6, [6, 7])], "best"),
    "4 eighth-folds, log of each over its best": ([(4, [4]), (5, [5]), (6, [6]), (7, [7])], "log"),
    "4 eighth-folds, each over its best": ([(4, [4]), (5, [5]), (6, [6]), (7, [7])], "best"),
    "2 eighth-folds (3/4, 7/8), each over its best": ([(6, [6]), (7, [7])], "best"),
    "3 eighth-folds (5/8, 3/4, 7/8), each over its best (the default)":
        ([(5, [5]), (6, [6]), (7, [7])], "best"),
    "one fold: the last eighth from 7/8": ([(7, [7])], "raw"),
}


def fold_pick(d: dict, folds, norm: str) -> tuple[int, list]:
    """The candidate (index into the groups × weights) a fold rule picks, under the discrepancy
    bound as in ``auto``; and the candidates' PSNRs."""
    g = [d["groups"][k] for k in ("iso", "iso+", "ani", "ani+")]
    w_n = len(AUTO_WEIGHTS)
    ps = [gg["psnr"][w] for gg in g for w in range(w_n)]
    cv, fit, bound = [0.0] * len(ps), [0.0] * len(ps), 0.0
    for k, held in folds:
        e = [sum(gg["blocks"][k - 4][w][b] for b in held) for gg in g for w in range(w_n)]
        if norm in ("best", "log"):
            lo = min(e)
            e = [v / lo if norm == "best" else math.log(v / lo) for v in e]
        elif norm == "energy":
            e = [v / sum(d["energy"][b] for b in held) for v in e]
        cv = [a + b for a, b in zip(cv, e)]
        fit = [a + gg["fit"][k - 4][w] for a, (gg, w) in
               zip(fit, [(gg, w) for gg in g for w in range(w_n)])]
        bound += d["edges"][k] * d["sigma"] ** 2
    ok = [f <= bound for f in fit]
    ok = ok if any(ok) else [True] * len(ps)
    return min((cv[c], c) for c in range(len(ps)) if ok[c])[1], ps


def peer_best(path: str) -> dict:
    """``(scene, n, sr, order, level) -> best tuned peer PSNR`` of the cells with an auto row."""
    with open(path) as f:
        cells = json.load(f)["cells"]
    return {(c["scene"], c["n"], c["sr"], c["order"], c["level"]):
            max(v["psnr"] for v in c["results"].values() if v["peer"] != "torchtof")
            for c in cells if "torchtof auto" in c["results"]}


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
                    d = psnr(tval3(y, A), x)[0] - psnr(tval3(y, A, mu=2.0**8), x)[0]
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
                pb = psnr(basis_pursuit(y, A, eps="auto"), x)[0]
                pt = psnr(tval3(y, A), x)[0]
                rows.append(dict(n=n, sr=sr, scene=name, bp=pb, tval3=pt))
                cells.append(f"{pb:.2f} / {pt:.2f}")
            print(f"| {n} | {100 * sr:g} | " + " | ".join(cells) + " |", flush=True)
    return rows


def problems(args) -> list[tuple]:
    """``(key, x, A, y, score)`` per cell, ``key = (scene, n, sr, order, level)``: the cells of
    the peers JSON ``args.peers_cells`` (``peers_scenes.make_problem``, its PSNR) at the sizes
    ``args.n``, SRs ``args.sr`` and orders ``args.orders`` (``None``: all), or this script's
    grid. ``score(x_hat, x)``: a list of PSNRs over the batch."""
    if args.peers_cells:
        import sys
        from pathlib import Path

        sys.path.insert(0, str(Path(__file__).resolve().parent))
        import peers_scenes as ps

        def many(a, b):
            return [ps.score(a[i : i + 1], b[i : i + 1]) for i in range(a.shape[0])]

        return [(k, *ps.make_problem(*k, args.seed)[:3], many)
                for k in peer_best(args.peers_cells) if k[1] in args.n and k[2] in args.sr
                and (args.orders is None or k[3] in args.orders)
                and (args.scenes is None or k[0] in args.scenes)
                and (args.noise is None or k[4] == args.noise)]
    probs = []
    for n in args.n:
        for sr in args.sr:
            A = tt.operators.Hadamard(n, sr=sr).double()
            for name in args.scenes:
                x, y = noisy(name, A, args.noise)
                probs.append(((name, n, sr, "cake_cutting", args.noise), x, A, y, psnr))
    return probs


def fold_study(args, out: str) -> list[dict]:
    # one PSNR of one image for fold_study_cell
    probs = [(k, x, A, y, lambda a, b, s=s: s(a, b)[0]) for k, x, A, y, s in problems(args)]
    rows = []
    for key, x, A, y, score in probs:
        t0 = time.perf_counter()
        rows.append(dict(cell=list(key), **fold_study_cell(x, A, y, score)))
        print(key, f"{time.perf_counter() - t0:.1f} s", flush=True)
        with open(out, "w") as f:
            json.dump(rows, f)
    return rows


def fold_rules(paths: list[str], peers: str | None) -> list[dict]:
    data = []
    for p in paths:
        with open(p) as f:
            data += json.load(f)
    best = peer_best(peers) if peers else {}
    out = []
    print("| rule | folds | mean vs best peer dB | ≥ 0 | worst dB | regret median / max dB | "
          "cells < median − 0.5 dB |")
    print("|---|---|---|---|---|---|---|")
    for name, (folds, norm) in FOLD_RULES.items():
        gaps, reg, below = [], [], 0
        for d in data:
            k, ps = fold_pick(d, folds, norm)
            reg.append(max(ps) - ps[k])
            below += ps[k] < statistics.median(ps) - 0.5
            if tuple(d["cell"]) in best:
                gaps.append(ps[k] - best[tuple(d["cell"])])
        row = dict(rule=name, folds=len(folds), regret_median=statistics.median(reg),
                   regret_max=max(reg), below_median=below)
        pg = (f"{statistics.mean(gaps):+.2f} | {sum(g >= 0 for g in gaps)}/{len(gaps)} | "
              f"{min(gaps):.2f}") if gaps else "– | – | –"
        print(f"| {name} | {len(folds)} | {pg} | {row['regret_median']:.2f} / "
              f"{row['regret_max']:.2f} | {below} |")
        out.append(row)
    return out


def _bounds(b) -> str:
    """``-``, ``≥0`` or ``[lo, hi]`` (a box, e.g. the inferred two levels) for the table."""
    if b is None:
        return "-"
    if tuple(b) == (0.0, None):
        return "≥0"
    return "[" + ", ".join("-" if v is None else f"{v:.2f}" for v in b) + "]"


def main(argv=None) -> list[dict]:
    import peers_scenes as ps
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[32, 64])
    ap.add_argument("--sr", type=float, nargs="+", default=list(SRS))
    ap.add_argument("--scenes", nargs="+", default=None,
                    help=f"scenes (default {' '.join(SCENES)}; with --peers-cells: only the "
                    "cells of these peers scenes, default every one)")
    ap.add_argument("--noise", type=float, default=None,
                    help="relative noise level (default 0.01; with --peers-cells: only the "
                    "cells at this level, default every one)")
    ap.add_argument("--cv-iter", type=int, default=100)
    ap.add_argument("--out", default=None)
    ap.add_argument("--noise-table", action="store_true",
                    help="the noise estimate's bias table instead (estimate %% (dB vs mu=2^8))")
    ap.add_argument("--fold-study", default=None, metavar="OUT",
                    help="the fold study's per-candidate errors instead (JSON)")
    ap.add_argument("--fold-rules", nargs="+", default=None, metavar="STUDY",
                    help="score the fold rules on these fold-study files (Markdown table)")
    ap.add_argument("--peers-cells", default=None, metavar="PEERS_JSON",
                    help="the cells of this peers JSON (problems of peers_scenes.py, its PSNR) "
                         "at the sizes --n instead of the grid; with --fold-rules: their best "
                         "peer")
    ap.add_argument("--seed", type=int, default=0,
                    help="with --peers-cells: the cells' noise draw (peers.py --seed; the "
                         "held-out runs of docs/peers_heldout.json used 1)")
    ap.add_argument("--orders", nargs="+", default=None, metavar="ORDER",
                    help="with --peers-cells: only the cells of these Hadamard orders "
                         "(cake_cutting, sequency; default every order)")
    ap.add_argument("--shard", default="0/1", type=ps.shard, metavar="I/K",
                    help="run every K-th cell from the I-th (two processes: 0/2 and 1/2)")
    ap.add_argument("--reuse", default=None, metavar="AUTO_EVAL_JSON",
                    help="take each cell's candidate PSNRs (best, median) from this earlier "
                         "output instead of refitting every candidate; auto and TVAL3's "
                         "default still run (the candidates do not depend on auto's rule)")
    ap.add_argument("--bp", action="store_true",
                    help="basis pursuit's default against TVAL3's default instead (PSNR dB)")
    args = ap.parse_args(argv)
    if not args.peers_cells or args.bp or args.noise_table:  # this script's own grid
        args.scenes = list(SCENES) if args.scenes is None else args.scenes
        args.noise = 0.01 if args.noise is None else args.noise
    if args.orders is not None and not args.peers_cells:
        ap.error("--orders selects cells of --peers-cells (this script's own grid is "
                 "cake-cutting rows only)")
    torch.set_num_threads(1)
    if args.fold_rules:
        return fold_rules(args.fold_rules, args.peers_cells)
    if args.fold_study:
        return fold_study(args, args.fold_study)
    if args.bp:
        return bp_table(args.n, args.sr, args.scenes)
    if args.noise_table:
        rows = noise_table(args.n, args.sr, args.scenes)
        if args.out:
            with open(args.out, "w") as f:
                json.dump(rows, f, indent=1)
        return rows
    rows = []
    reuse = {}
    if args.reuse:
        with open(args.reuse) as f:
            reuse = {(r["scene"], r["n"], r["sr"]): r for r in json.load(f)}
    print("| scene | n | SR % | TVAL3 default | auto | best cand. | median cand. | regret | "
          "vs median | chosen | learned w | t default s | t auto s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for key, x, A, y, score in problems(args)[args.shard[0]::args.shard[1]]:
        name, n, sr = key[:3]
        t0 = time.perf_counter()
        x_def = tval3(y, A)
        t_def = time.perf_counter() - t0
        t0 = time.perf_counter()
        r = auto(y, A, cv_iter=args.cv_iter, return_result=True)
        t_auto = time.perf_counter() - t0
        if (name, n, sr) in reuse and not args.peers_cells:
            old = reuse[(name, n, sr)]
            best, median = old["best"], old["median"]
        else:
            cp = candidate_psnrs(y, A, x, r.candidates, args.cv_iter, score=score)
            best, median = max(cp), statistics.median(cp)
        ch = r.choice[0][0]
        row = dict(scene=name, n=n, sr=sr, order=key[3], level=key[4],
                   default=score(x_def, x)[0], auto=score(r.x, x)[0], best=best, median=median,
                   chosen=dict(prior=ch["prior"], tv=ch["tv"], bounds=ch["bounds"],
                               mu=ch["mu"], learned_weight=ch.get("learned_weight"),
                               ell=ch.get("ell"), gamma=ch.get("gamma")),
                   t_default=t_def, t_auto=t_auto)
        rows.append(row)
        mu = "c" if ch["mu"] is None else f"2^{round(math.log2(ch['mu']))}"
        if ch["prior"] == "gauss":
            mu = f"ℓ={ch['ell']:g} γ=4^{round(math.log(ch['gamma'], 4))}"
        bd = _bounds(ch["bounds"])
        label = name if not args.peers_cells else f"{name} {key[3][:3]} {100 * key[4]:g}%"
        print(f"| {label} | {n} | {100 * sr:g} | {row['default']:.2f} | "
              f"{row['auto']:.2f} | {row['best']:.2f} | {row['median']:.2f} | "
              f"{row['best'] - row['auto']:.2f} | {row['auto'] - row['median']:+.2f} | "
              f"{ch['prior']} {(ch['tv'] or '')[:3]} {bd} {mu} | "
              f"{_weight(ch.get('learned_weight'))} | {t_def:.2f} | "
              f"{t_auto:.1f} |", flush=True)
        if args.out:  # after every cell: a cut-short run keeps what it measured
            with open(args.out, "w") as f:
                json.dump(rows, f, indent=1)
    if args.out:
        with open(args.out, "w") as f:
            json.dump(rows, f, indent=1)
    return rows


if __name__ == "__main__":
    main()
