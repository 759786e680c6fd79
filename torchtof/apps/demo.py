"""``torchtof demo``: the paper's experiment simulated once and reconstructed by every method."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch

from .._optional import progress_bar
from ..report import print_method_rows

__all__ = ["TAP_METHODS", "demo_figure", "evaluate_taps", "run_demo"]

#: methods also run on torchtof's tap buckets (linear, so the stray light cancels exactly).
TAP_METHODS: tuple[str, ...] = ("PINV", "TVAL3", "Auto")

_ROW_LABELS = {
    "depth": "depth buckets, no gate\n(negative image: shown\nflipped, physics rule)",
    "depth_gated": "depth buckets,\n3 m gate",
    "taps": "tap buckets I/Q\n(torchtof; Eq. 8\nper pixel)",
}


def evaluate_taps(data, sr: float, methods, progress=None) -> tuple[list[dict], dict]:
    """Reconstruct the four tap-bucket channels with each method and combine them per pixel
    with paper Eq. 8 (amplitude of the object's own phasor: the taps are linear in the light,
    so the stray and ambient terms cancel exactly in ``y⁺ − y⁻``); positive polarity."""
    from ..methods import build_method, score_image
    from ..sensor.functional import tap_amplitude

    rows, images = [], {}
    for name in methods:
        if progress is not None:
            progress(name)
        method = build_method(name, data, sr, False, kind="taps")
        with torch.no_grad():
            t0 = time.perf_counter()
            taps = method()
            dt = time.perf_counter() - t0
        img = tap_amplitude(taps)
        images[name] = img
        rows.append({"method": name, "sr": sr, "gate": False, "buckets": "taps", "time_s": dt,
                     **score_image(img, data, "positive")})
    return rows, images


def _merge_identical(methods, images) -> list[list[str]]:
    """Groups of methods whose display images (min-max normalised) agree to 1e-3 (below one
    8-bit grey level) for both depth-bucket kinds — CGI, DGI and the pseudo-inverse with
    complementary pairs (affine functions of Aᵀ(y⁺ − y⁻)); checked numerically, not assumed."""
    from ..metrics import normalize_image

    groups: list[list[str]] = []
    for m in methods:
        for g in groups:
            same = all(
                torch.allclose(normalize_image(im[m][:1].double()),
                               normalize_image(im[g[0]][:1].double()), atol=1e-3)
                for kind, im in images.items() if kind != "taps" and m in im and g[0] in im
            )
            if same:
                g.append(m)
                break
        else:
            groups.append([m])
    return groups


def demo_figure(path: Path, data, images: dict, rows: list[dict], methods, title: str = "") -> Path:
    """The demo's picture: one row per bucket kind, the object, the raw ToF depth map (metres,
    colour bar) and each method (identical ones merged), PSNR/SSIM in every panel; negative
    images are flipped by the physics rule the scoring uses (README 'Scoring')."""
    from ..metrics import normalize_image
    from ..report import pyplot, save_grid

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    kinds = [k for k in ("depth", "depth_gated", "taps") if k in images]
    plt = pyplot()
    if plt is None:  # the plot extra is not installed: a plain montage, a row per bucket kind
        # negative images (ungated depth buckets, raw depth) flipped as the scoring does; a
        # method not run on a row's buckets leaves its panel blank
        neg = data.polarity(False, "depth") == "negative"
        cols = [("object", data.x[:1]),
                ("raw ToF", -data.raw_tof_image[:1] if neg else data.raw_tof_image[:1])]
        for g in _merge_identical(methods, images):
            panels = []
            for k in kinds:
                img = images[k].get(g[0], torch.zeros_like(data.x))[:1].to(data.x.dtype)
                panels.append(-img if k == "depth" and neg else img)
            cols.append((g[0], torch.cat(panels)))
        return save_grid(path, cols, rows=kinds, title=title)

    groups = _merge_identical(methods, images)
    score = {(r["method"], r["buckets"]): r for r in rows}
    ncol = 2 + len(groups)
    fig, axes = plt.subplots(len(kinds), ncol, figsize=(1.9 * ncol + 0.6, 2.1 * len(kinds)),
                             squeeze=False)
    for r, kind in enumerate(kinds):
        ax = axes[r][0]
        if r == 0:
            ax.imshow(data.x[0, 0].float().numpy(), cmap="gray", vmin=0, vmax=1)
            ax.set_title("object (truth)", fontsize=7)
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_ylabel(_ROW_LABELS[kind], fontsize=7)
        if r > 0:
            ax.axis("off")
            ax.text(0.5, 0.5, _ROW_LABELS[kind], ha="center", va="center", fontsize=7,
                    transform=ax.transAxes)
        ax = axes[r][1]
        if r == 0:
            im = ax.imshow(data.raw_tof_image[0, 0].float().numpy(), cmap="viridis")
            cb = fig.colorbar(im, ax=ax, fraction=0.046, pad=0.03)
            cb.set_label("depth (m)", fontsize=6)
            cb.ax.tick_params(labelsize=6)
            s = score[("raw ToF", "raw")]
            ax.set_title(f"raw ToF map\n{s['psnr']:.2f} dB / {s['ssim']:.2f}", fontsize=7)
            ax.set_xticks([])
            ax.set_yticks([])
        else:
            ax.axis("off")
        for c, group in enumerate(groups):
            ax = axes[r][2 + c]
            present = [g for g in group if g in images[kind]]
            if not present:
                ax.axis("off")
                continue
            m = present[0]
            group = present if kind == "taps" else group
            img = normalize_image(images[kind][m][:1].float())[0, 0]
            if data.polarity(kind == "depth_gated", "depth") == "negative" and kind == "depth":
                img = 1.0 - img
            ax.imshow(img.numpy(), cmap="gray", vmin=0, vmax=1)
            s = score[(m, kind)]
            ax.set_title(f"{' = '.join(group)}\n{s['psnr']:.2f} dB / {s['ssim']:.2f}", fontsize=7)
            ax.set_xticks([])
            ax.set_yticks([])
    note = "PSNR (8-bit) / SSIM per panel"
    if any(len(g) > 1 for g in groups):
        note += "; '=' merges methods with identical images (affine in Aᵀ(y⁺ − y⁻))"
    fig.suptitle(f"{title}\n{note}" if title else note, fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)
    return path


def run_demo(args: argparse.Namespace) -> int:
    """Simulate the experiment of ``args`` (``sr``, ``scene``, ``n``, ``scattering``,
    ``realisations``, ``seed``), reconstruct with ``args.methods`` without and with the 3 m
    depth gate, print the PSNR/SSIM table and write ``demo.png`` and ``demo.json`` under
    ``args.out``."""
    from ..experiment import PaperExperiment
    from ..methods import DEFAULT_METHODS, evaluate, raw_tof_scores

    torch.manual_seed(args.seed)
    t_all = time.perf_counter()
    exp = PaperExperiment(sr=args.sr, scattering=args.scattering, scene=args.scene, n=args.n,
                          roi_px=2 * args.n, srs=(args.sr,))
    print(f"torchtof demo: {exp}")
    data = exp.run(seed=args.seed, realisations=args.realisations, progress=True)
    print(f"simulated {data.buckets['depth'].shape[-1]} ToF frames of {exp.config.roi_px}x"
          f"{exp.config.roi_px} px x {args.realisations} realisation(s) in "
          f"{data.timings['simulate_s']:.1f} s")
    methods = list(args.methods) if args.methods else list(DEFAULT_METHODS)
    raw = raw_tof_scores(data)
    rows = [{"method": "raw ToF", "gate": False, "buckets": "raw", "time_s": None, **raw}]
    images: dict[str, dict[str, torch.Tensor]] = {}
    tap_methods = [m for m in methods if m in TAP_METHODS]
    with progress_bar(total=2 * len(methods) + len(tap_methods), desc="reconstructing",
                      leave=False) as bar:
        for gate in (False, True):
            def tick(name, gate=gate):
                bar.set_postfix_str(f"{name} ({'gate' if gate else 'no gate'})")
                bar.update(1)

            r, im = evaluate(data, args.sr, gate, methods, progress=tick)
            rows += [{**x, "buckets": "depth_gated" if gate else "depth"} for x in r]
            images["depth_gated" if gate else "depth"] = im
        if tap_methods:
            r, im = evaluate_taps(data, args.sr, tap_methods,
                                  progress=lambda name: (bar.set_postfix_str(f"{name} (taps)"),
                                                         bar.update(1)))
            rows += r
            images["taps"] = im
    print(f"\nSR {args.sr:.2%}, scene {args.scene!r}, n={args.n}, "
          f"{'through the scattering sheet' if args.scattering else 'in air'}; PSNR on the 8-bit "
          f"scale after min-max normalisation and physics polarity (README 'Scoring'); "
          f"gate 'taps': torchtof's per-tap I/Q buckets, Eq. 8 amplitude per pixel")
    print_method_rows(rows)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "demo.json").write_text(json.dumps(rows, indent=2))  # before the figure
    png = demo_figure(out / "demo.png", data, images, rows, methods,
                      title=f"ToF-CGI, scene {args.scene!r}, SR {args.sr:.2%}, "
                            f"{'scattering sheet' if args.scattering else 'in air'} "
                            f"(cf. paper Fig. 5)")
    best = max(rows[1:], key=lambda r: r["psnr"])
    kinds = {"depth": "depth buckets", "depth_gated": "gated depth buckets", "taps": "tap buckets"}
    print(f"\ntorchtof demo: best {best['method']} ({kinds[best['buckets']]}) "
          f"{best['psnr']:.2f} dB; wrote {png} and {out / 'demo.json'} in "
          f"{time.perf_counter() - t_all:.1f} s")
    return 0
