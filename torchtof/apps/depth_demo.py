"""``torchtof demo --depth`` and the depth part of ``torchtof reproduce``.

One simulated run of the paper's experiment (:class:`~torchtof.experiment.PaperExperiment`,
default noise: shot, read and ADC noise, ambient light, stray returns, multipath; the
scattering sheet on request) on a scene with depth structure, scored by the depth RMSE in
metres over the object (pixels with reflectance > 0; every pixel for the motorcycle,
steps and slanted scenes) at DMD resolution:

- **raw ToF**: the camera's own depth image with every mirror on, averaged onto the DMD
  grid (``ExperimentData.raw_tof_image``).
- **depth-sum (paper)**: TVAL3 on the paper's depth buckets ``D_i = Σ_p d_i(p)`` (Eq. 10),
  without and with the 3 m gate (§3.1). That image is a silhouette, not a depth map: its
  values mix depth, the lit area and the camera rules. It is scored after the
  least-squares affine map ``a·x + b`` onto the true depth over the object — an oracle
  calibration that favours it (no real system knows ``a, b``).
- **I/Q pinv**, **I/Q TVAL3** (separate, the package's TVAL3 on each of I and Q),
  **I/Q vTV-separate** (the :func:`~torchtof.recon.joint_tv` solver with TV per image) and
  **I/Q joint** (the same solver with the vectorial TV of I and Q): depth from Eq. 7 and 1
  per DMD pixel (:class:`~torchtof.recon.DepthResolved`), no calibration.
"""

from __future__ import annotations

import csv
import json
import time
from pathlib import Path

import torch

from ..experiment import PAPER_SRS, ExperimentData, PaperExperiment
from ..metrics import depth_rmse
from ..recon.depth import DepthResolved, JointTV
from ..recon.pinv import PseudoInverse
from ..recon.tval3 import TVAL3

__all__ = ["DEPTH_METHODS", "affine_fit", "evaluate_depth", "run_depth_demo", "depth_curves",
           "plot_depth_maps"]

#: Methods of the depth comparison, in table order (module docstring).
DEPTH_METHODS = ("raw ToF", "depth-sum", "depth-sum gate", "I/Q pinv", "I/Q TVAL3",
                 "I/Q vTV-separate", "I/Q joint")


def affine_fit(x: torch.Tensor, depth: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Least-squares ``a·x + b`` onto ``depth`` over ``mask``, per image (oracle calibration).

    :func:`torchtof.metrics.affine_fit` with a mask: the same ``(a, b)`` as the library's fit
    of the masked pixels alone, applied to every pixel (the background is shown in the depth
    maps but not fitted). Without a mask argument the library's function cannot give this;
    with an all-true mask the two agree (``tests/test_depth_demo.py``).

    Args:
        x: images ``(B, 1, H, W)``; depth: true depth broadcastable to ``x``; mask: bool,
        broadcastable, the pixels that count.

    Returns:
        ``a·x + b`` ``(B, 1, H, W)`` with ``(a, b)`` minimising the squared error over ``mask``.
    """
    m = torch.broadcast_to(mask, x.shape).flatten(1).to(x.dtype)
    xf, zf = x.flatten(1), torch.broadcast_to(depth, x.shape).flatten(1)
    cnt = m.sum(1).clamp_min(1)
    mx, mz = (m * xf).sum(1) / cnt, (m * zf).sum(1) / cnt
    cov = (m * (xf - mx[:, None]) * (zf - mz[:, None])).sum(1)
    var = (m * (xf - mx[:, None]) ** 2).sum(1)
    a = torch.where(var > 0, cov / var.clamp_min(torch.finfo(x.dtype).tiny), torch.zeros_like(var))
    return a.reshape(-1, 1, 1, 1) * (x - mx.reshape(-1, 1, 1, 1)) + mz.reshape(-1, 1, 1, 1)


def evaluate_depth(data: ExperimentData, sr: float, methods=DEPTH_METHODS):
    """Depth RMSE of each method at ``sr``: ``(rows, depth maps)`` (module docstring).

    Returns:
        ``rows``: ``{"method", "sr", "rmse_m", "rmse_std_m", "mask", "time_s"}`` per method
        (mean and std over the realisations; ``mask``: fraction of object pixels in the
        amplitude mask, I/Q methods only); ``maps``: method → depth maps ``(R, 1, n, n)``.
    """
    truth = data.depth_m.expand(data.raw_tof_image.shape[0], -1, -1, -1)
    obj = (data.x > 0).expand_as(truth)
    freq = data.config.freq_hz
    A, y = data.measurements(sr, kind="taps")
    builders = {
        "I/Q pinv": lambda: PseudoInverse(A),
        "I/Q TVAL3": lambda: TVAL3(A),
        "I/Q vTV-separate": lambda: JointTV(A, joint=False),
        "I/Q joint": lambda: JointTV(A, joint=True),
    }
    rows, maps = [], {}
    for m in methods:
        t0 = time.perf_counter()
        cover = None
        if m == "raw ToF":
            d = data.raw_tof_image
        elif m.startswith("depth-sum"):
            Ad, yd = data.measurements(sr, kind="depth", gate=m.endswith("gate"))
            d = affine_fit(TVAL3(Ad)(yd), truth, obj)
        elif m in builders:
            res = DepthResolved(builders[m](), freq).solve(y)
            d = res.depth
            cover = float((res.mask & obj).sum() / obj.sum())
        else:
            raise ValueError(f"evaluate_depth: unknown method {m!r}; expected one of "
                             f"{DEPTH_METHODS}")
        dt = time.perf_counter() - t0
        e = depth_rmse(d, truth, obj)
        rows.append({"method": m, "sr": sr, "rmse_m": float(e.mean()),
                     "rmse_std_m": float(e.std()) if e.numel() > 1 else 0.0, "mask": cover,
                     "time_s": None if m == "raw ToF" else dt})
        maps[m] = d
    return rows, maps


def plot_depth_maps(path: Path, truth: torch.Tensor, maps: dict, rows: list[dict],
                    title: str) -> Path:
    """Save the true depth map and each method's map (metres, colour bar) as a PNG (without
    matplotlib: a plain montage on the true map's range)."""
    from ..report import pyplot, save_montage

    lo, hi = float(truth.min()), float(truth.max())
    cols = [("true depth", truth, None)] + [(m, maps[m], r["rmse_m"]) for m, r in
                                             zip(maps, rows, strict=True)]
    plt = pyplot()
    if plt is None:  # the plot extra is not installed
        return save_montage(path, [[((img[0, 0] - lo) / max(hi - lo, 1e-12))
                                    for _, img, _ in cols]])
    fig, axes = plt.subplots(1, len(cols), figsize=(1.75 * len(cols), 2.3), squeeze=False)
    for ax, (label, img, err) in zip(axes[0], cols, strict=True):
        im = ax.imshow(img[0, 0].detach().cpu().numpy(), cmap="viridis", vmin=lo, vmax=hi)
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_title(label + ("" if err is None else f"\n{err:.3f} m"), fontsize=7)
    fig.colorbar(im, ax=axes[0].tolist(), shrink=0.7, label="depth (m)")
    fig.suptitle(title, fontsize=8)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=130, bbox_inches="tight")
    plt.close(fig)
    return path


def _print(rows: list[dict]) -> None:
    from ..report import print_table

    print_table([{
        "method": r["method"],
        "depth RMSE m": f"{r['rmse_m']:.3f}" + (f" ± {r['rmse_std_m']:.3f}" if r["rmse_std_m"]
                                                 else ""),
        "mask": "-" if r["mask"] is None else f"{r['mask']:.0%}",
        "time s": "-" if r["time_s"] is None else f"{r['time_s']:.2f}",
    } for r in rows], ["method", "depth RMSE m", "mask", "time s"])


def run_depth_demo(args) -> int:
    """``torchtof demo --depth [SCENE]``: simulate, reconstruct, print the table, plot."""
    scene = args.depth
    t0 = time.perf_counter()
    exp = PaperExperiment(sr=args.sr, scattering=args.scattering, scene=scene, n=args.n,
                          roi_px=2 * args.n, srs=(args.sr,))
    print(f"torchtof demo --depth: {exp}")
    data = exp.run(seed=args.seed, realisations=args.realisations, progress=True)
    rows, maps = evaluate_depth(data, args.sr)
    print(f"\nscene {scene!r}, SR {args.sr:.2%}, n={args.n}, "
          f"{'through the scattering sheet' if args.scattering else 'in air'}, default noise "
          f"and multipath; depth RMSE over the object at DMD resolution (mean ± std over "
          f"{args.realisations} realisation(s)); depth-sum rows after an oracle affine fit")
    _print(rows)
    out = Path(args.out)
    png = plot_depth_maps(out / "depth.png", data.depth_m, maps, rows,
                          f"depth-resolved ghost imaging: {scene}, SR {args.sr:.2%}")
    (out / "depth.json").write_text(json.dumps(rows, indent=2))
    # the depth-sum rows are fitted to the true depth (an oracle; exact on a scene at one
    # depth), so the best is named among the methods that see only the buckets
    best = min((r for r in rows if r["method"] != "raw ToF"
                and not r["method"].startswith("depth-sum")), key=lambda r: r["rmse_m"])
    print(f"\ntorchtof demo --depth: best without the oracle fit {best['method']} "
          f"{best['rmse_m']:.3f} m RMSE; wrote "
          f"{png} and {out / 'depth.json'} in {time.perf_counter() - t0:.1f} s")
    return 0


def _plot_curves(path: Path, scene: str, rows: list[dict]) -> None:
    from ..report import no_plot, pyplot

    plt = pyplot()
    if plt is None:
        no_plot(path.name)
        return

    fig, axes = plt.subplots(1, 2, figsize=(8.4, 3.2), sharey=False)
    for ax, mp in zip(axes, ("on", "off"), strict=True):
        for m in DEPTH_METHODS:
            rs = [r for r in rows if r["method"] == m and r["multipath"] == mp]
            if not rs:
                continue
            ax.errorbar([100 * r["sr"] for r in rs], [r["rmse_m"] for r in rs],
                        yerr=[r["rmse_std_m"] for r in rs], marker="o", ms=3, capsize=2,
                        label=m, ls="--" if m == "raw ToF" else "-")
        ax.set_yscale("log")
        ax.set_xlabel("sampling rate (%)")
        ax.set_ylabel("depth RMSE (m)")
        ax.set_title(f"{scene}, multipath {mp}", fontsize=9)
    axes[0].legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def depth_curves(out: Path, quick: bool = False, realisations: int | None = None,
                 seed: int = 0, scenes=("motorcycle", "steps", "slanted")) -> dict:
    """Depth-RMSE-vs-SR curves and depth maps for ``torchtof reproduce``.

    Writes ``depth_rmse.csv``, ``depth_rmse_{scene}.png`` (multipath on/off side by side) and
    ``depth_maps_{scene}.png`` (every method at SR 12.5 % and 25 %). ``quick``: the
    motorcycle scene at SR 6.25, 12.5, 25 %, multipath on, 1 realisation.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    r = realisations or (1 if quick else 3)
    srs = (0.0625, 0.125, 0.25) if quick else PAPER_SRS
    scenes = scenes[:1] if quick else scenes
    t0 = time.perf_counter()
    rows = []
    for scene in scenes:
        scene_rows = []
        for mp in (("on",) if quick else ("on", "off")):
            over = {} if mp == "on" else {"multipath_strength": 0.0}
            data = PaperExperiment(sr=max(srs), scene=scene, srs=srs, **over).run(
                seed=seed, realisations=r)
            for sr in srs:
                rs, maps = evaluate_depth(data, sr)
                for row in rs:
                    row.update(scene=scene, multipath=mp)
                scene_rows += rs
                if mp == "on" and abs(sr - 0.25) < 1e-9:
                    plot_depth_maps(out / f"depth_maps_{scene}.png", data.depth_m, maps, rs,
                               f"{scene}, SR {sr:.2%}, default noise and multipath")
        _plot_curves(out / f"depth_rmse_{scene}.png", scene, scene_rows)
        rows += scene_rows
    with open(out / "depth_rmse.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["scene", "multipath", "method", "sr", "rmse_m", "rmse_std_m", "mask"])
        for row in rows:
            w.writerow([row["scene"], row["multipath"], row["method"], row["sr"],
                        f"{row['rmse_m']:.4f}", f"{row['rmse_std_m']:.4f}",
                        "" if row["mask"] is None else f"{row['mask']:.3f}"])
    md = _markdown(rows, srs, r)
    (out / "depth_table.md").write_text(md)
    print(md)
    return {"rows": rows, "realisations": r, "total_s": time.perf_counter() - t0}


def _markdown(rows: list[dict], srs, r: int) -> str:
    lines = [f"Depth RMSE (m, mean over {r} realisation(s)) over the object, DMD resolution.", ""]
    for scene in dict.fromkeys(x["scene"] for x in rows):
        for mp in dict.fromkeys(x["multipath"] for x in rows if x["scene"] == scene):
            lines += [f"### {scene}, multipath {mp}", "",
                      "| method | " + " | ".join(f"{s:.2%}" for s in srs) + " |",
                      "|---|" + "---|" * len(srs)]
            for m in DEPTH_METHODS:
                cells = [next(f"{x['rmse_m']:.3f}" for x in rows if x["scene"] == scene
                              and x["multipath"] == mp and x["method"] == m and x["sr"] == s)
                         for s in srs]
                lines.append(f"| {m} | " + " | ".join(cells) + " |")
            lines.append("")
    return "\n".join(lines)
