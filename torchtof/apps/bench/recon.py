"""Run time against error for every reconstructor: ``torchtof bench recon`` and
``torchtof bench tradeoff``.

Each reconstructor is swept over its work knob (iterations, unrolled K, DIP steps); every
point records wall time per image, PSNR (8-bit protocol of :func:`torchtof.metrics.compare`),
SSIM and RMSE in the scene's units (metres for depth scenes). Scenes of one size are solved
as one batch (the solvers are batched; the DIP loops over samples) and the time is divided
by the batch size. Measurements: ``y = A x + e`` with Gaussian ``e`` of σ = ``noise`` × the
spread of ``A x`` (1 % by default), seeded.

The Pareto front is marked per (n, SR) on the scene-averaged points: a point is on the front
when no other point is both faster and more accurate.
"""

from __future__ import annotations

import time
from pathlib import Path

import torch

from ...metrics import compare, depth_rmse
from ...operators import Hadamard
from ...report import print_table
from ...scenes import get_scene

__all__ = ["KNOBS", "QUICK_KNOBS", "make_reconstructor", "sweep", "pareto", "bench_recon",
           "print_recon", "plot_sweep"]

#: method -> budgets of its work knob (None = the solver's own stopping rule / shipped K).
KNOBS: dict[str, list] = {
    "PINV": [None],
    "BP": [20, 80, 320, None],
    "TVAL3": [10, 40, 160, None],
    "Unrolled": [None],
    "DIP": [100, 300],
}
QUICK_KNOBS: dict[str, list] = {
    "PINV": [None],
    "BP": [40, None],
    "TVAL3": [20, None],
    "Unrolled": [None],
    "DIP": [150],
}
DEPTH_SCENES = ("steps", "motorcycle")
SCENES = ("sky", "steps", "motorcycle", "binary:horse", "skimage:camera")


def make_reconstructor(method: str, A: Hadamard, budget):
    """The reconstructor ``method`` on ``A`` at work ``budget`` (``None``: its default)."""
    from ... import recon

    spec = recon.get(method)  # ValueError for an unknown method
    return spec.build(A, **spec.budget_options(budget)), spec.per_sample


def _images(scenes, n: int) -> tuple[torch.Tensor, list[bool]]:
    xs, is_depth = [], []
    for name in scenes:
        s = get_scene(name, n)
        depth = name in DEPTH_SCENES
        xs.append(s.depth_m if depth else s.reflectance)
        is_depth.append(depth)
    return torch.cat(xs), is_depth


def sweep(ns=(32, 64, 128), srs=(0.0625, 0.125, 0.25, 0.375), scenes=SCENES, knobs=None,
          noise: float = 0.01, seed: int = 0, progress: bool = True) -> list[dict]:
    """Every (n, SR, method, budget) point, per scene; returns a list of row dicts."""
    from ..._optional import progress_bar as tqdm

    knobs = knobs or KNOBS
    rows = []
    total = len(ns) * len(srs) * sum(len(v) for v in knobs.values())
    bar = tqdm(total=total, desc="sweep", leave=False, disable=not progress)
    for n in ns:
        x, is_depth = _images(scenes, n)
        for sr in srs:
            A = Hadamard(n, sr=sr)
            g = torch.Generator().manual_seed(seed)
            clean = A(x)
            spread = clean.amax(-1, keepdim=True) - clean.amin(-1, keepdim=True)
            y = clean + noise * spread * torch.randn(clean.shape, generator=g)
            for method, budgets in knobs.items():
                for budget in budgets:
                    bar.set_postfix_str(f"n={n} SR={sr:.2%} {method}@{budget}")
                    try:
                        rec, per_sample = make_reconstructor(method, A, budget)
                    except (FileNotFoundError, ValueError) as err:  # e.g. no shipped weights
                        rows.append({"n": n, "sr": sr, "method": method, "budget": budget,
                                     "error": str(err)})
                        bar.update(1)
                        continue
                    if not per_sample:  # warm-up on one sample (lazy init, caches)
                        with torch.no_grad():
                            rec(y[:1])
                    t0 = time.perf_counter()
                    if per_sample:
                        x_hat = torch.cat([rec(y[i : i + 1]).detach() for i in range(len(y))])
                    else:
                        with torch.no_grad():
                            res = rec.solve(y) if hasattr(rec, "solve") else None
                            x_hat = rec(y) if res is None else res.x
                    dt = (time.perf_counter() - t0) / len(y)
                    s = compare(x_hat, x, "positive")
                    rmse = depth_rmse(x_hat, x)
                    iters = None
                    if not per_sample and res is not None and hasattr(res, "n_iter"):
                        iters = float(torch.as_tensor(res.n_iter).float().mean())
                    for i, name in enumerate(scenes):
                        rows.append({
                            "n": n, "sr": sr, "method": method, "budget": budget,
                            "label": f"{method}" + ("" if budget is None else f"@{budget}"),
                            "scene": name, "time_s": dt, "psnr": float(s["psnr"][i]),
                            "ssim": float(s["ssim"][i]), "rmse": float(rmse[i]),
                            "rmse_unit": "m" if is_depth[i] else "a.u.", "iters": iters,
                        })
                    bar.update(1)
    bar.close()
    return rows


def pareto(rows: list[dict]) -> list[dict]:
    """Scene-averaged points per (n, SR, label) with ``pareto`` marking the front."""
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        if "error" in r:
            continue
        groups.setdefault((r["n"], r["sr"], r["label"]), []).append(r)
    pts = []
    for (n, sr, label), rs in groups.items():
        k = len(rs)
        pts.append({"n": n, "sr": sr, "label": label, "method": rs[0]["method"],
                    "budget": rs[0]["budget"], "time_s": sum(r["time_s"] for r in rs) / k,
                    "psnr": sum(r["psnr"] for r in rs) / k, "ssim": sum(r["ssim"] for r in rs) / k,
                    "depth_rmse_m": (sum(r["rmse"] for r in rs if r["rmse_unit"] == "m")
                                     / max(1, sum(r["rmse_unit"] == "m" for r in rs)))})
    for p in pts:
        same = [q for q in pts if q["n"] == p["n"] and q["sr"] == p["sr"] and q is not p]
        p["pareto"] = not any(q["time_s"] <= p["time_s"] and q["psnr"] >= p["psnr"]
                              and (q["time_s"] < p["time_s"] or q["psnr"] > p["psnr"])
                              for q in same)
    return sorted(pts, key=lambda p: (p["n"], p["sr"], p["time_s"]))


def plot_sweep(points: list[dict], path: Path, title: str = "") -> Path | None:
    """The time-vs-PSNR curves of :func:`sweep` per (n, SR) with the Pareto front; ``None``
    (and a note on stderr) without matplotlib."""
    from ...report import no_plot, pyplot

    plt = pyplot()
    if plt is None:
        no_plot(Path(path).name)
        return None

    ns = sorted({p["n"] for p in points})
    srs = sorted({p["sr"] for p in points})
    fig, axes = plt.subplots(len(ns), len(srs), figsize=(3.2 * len(srs), 2.8 * len(ns)),
                             squeeze=False, sharey="row")
    colors = {m: f"C{i}" for i, m in enumerate(KNOBS)}
    for i, n in enumerate(ns):
        for j, sr in enumerate(srs):
            ax = axes[i][j]
            sel = [p for p in points if p["n"] == n and p["sr"] == sr]
            for m in KNOBS:
                ms = sorted((p for p in sel if p["method"] == m), key=lambda p: p["time_s"])
                if ms:
                    ax.plot([p["time_s"] for p in ms], [p["psnr"] for p in ms], "-o", ms=3,
                            color=colors[m], label=m)
            front = sorted((p for p in sel if p["pareto"]), key=lambda p: p["time_s"])
            ax.plot([p["time_s"] for p in front], [p["psnr"] for p in front], "k--", lw=0.8,
                    label="Pareto front")
            ax.set_xscale("log")
            ax.set_title(f"n={n}, SR {sr:.2%}", fontsize=8)
            if i == len(ns) - 1:
                ax.set_xlabel("seconds per image (log)")
            if j == 0:
                ax.set_ylabel("PSNR (dB)")
    axes[0][0].legend(fontsize=6)
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def bench_recon(quick: bool = False, plot: bool = False, out: str | Path = "bench_out",
                ns=None, srs=None) -> dict:
    """``torchtof bench recon``: the full grid (n ∈ {32, 64, 128}, SR ∈ {6.25, 12.5, 25,
    37.5} %)."""
    ns = ns or ((32, 64) if quick else (32, 64, 128))
    srs = srs or ((0.125, 0.25) if quick else (0.0625, 0.125, 0.25, 0.375))
    scenes = ("sky", "steps", "binary:horse") if quick else SCENES
    t0 = time.perf_counter()
    rows = sweep(ns, srs, scenes, QUICK_KNOBS if quick else KNOBS)
    pts = pareto(rows)
    res = {"benchmark": "recon", "quick": quick, "noise": 0.01, "scenes": list(scenes),
           "threads": torch.get_num_threads(), "torch": torch.__version__, "points": pts,
           "rows": rows, "total_s": time.perf_counter() - t0}
    if plot:
        png = plot_sweep(pts, Path(out) / "recon.png", "torchtof bench recon")
        res["plot"] = None if png is None else str(png)
    return res


def print_recon(res: dict) -> None:
    print(f"{res['benchmark']}: scenes {res['scenes']}, noise {res['noise']:.0%} of the "
          f"measurement spread, {res['threads']} thread{'s' * (res['threads'] != 1)}; "
          "scene-averaged; * = Pareto front")
    table = [{**p, "front": "*" if p["pareto"] else "", "sr": f"{p['sr']:.2%}"}
             for p in res["points"]]
    print_table(table, ["n", "sr", "label", "time_s", "psnr", "ssim", "depth_rmse_m", "front"])
    errs = [r for r in res["rows"] if "error" in r]
    for e in errs:
        print(f"not run: n={e['n']} SR {e['sr']:.2%} {e['method']}@{e['budget']}: {e['error']}")
    if res.get("plot"):
        print(f"plot: {res['plot']}")
    print(f"total {res['total_s']:.0f} s")
