"""``torchtof`` command line: ``demo``, ``bench``, ``reproduce``, ``export``, ``acquire``,
``reconstruct``."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import torch

__all__ = ["main"]


def _print_rows(rows: list[dict]) -> None:
    from .bench._timing import print_table

    table = []
    for r in rows:
        table.append({
            "method": r["method"],
            "gate": "3 m" if r.get("gate") else "none",
            "PSNR dB": f"{r['psnr']:.2f}"
            + (f" ± {r['psnr_std']:.2f}" if r.get("psnr_std") else ""),
            "SSIM": f"{r['ssim']:.3f}",
            "time s": f"{r['time_s']:.3f}" if r.get("time_s") is not None else "-",
        })
    print_table(table, ["method", "gate", "PSNR dB", "SSIM", "time s"])


def save_grid(path: Path, columns: list[tuple[str, torch.Tensor]], rows: list[str] | None = None,
              title: str = "") -> Path:
    """Save images as a labelled grid PNG (matplotlib; plain montage without it).

    ``columns``: (label, tensor (R, 1, H, W)); each tensor's first ``len(rows)`` images fill
    the rows (row ``r`` uses image ``r`` or the last one).
    """
    from .metrics import normalize_image

    rows = rows or [""]
    imgs = [[normalize_image(t[min(r, t.shape[0] - 1) : min(r, t.shape[0] - 1) + 1].float())[0, 0]
             for r in range(len(rows))] for _, t in columns]
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:  # pragma: no cover - plot extra not installed
        import numpy as np
        from skimage.io import imsave

        grid = np.concatenate(
            [np.concatenate([c[r].numpy() for c in imgs], axis=1) for r in range(len(rows))]
        )
        imsave(str(path), (grid * 255).astype("uint8"), check_contrast=False)
        return path
    fig, axes = plt.subplots(len(rows), len(columns),
                             figsize=(1.6 * len(columns), 1.75 * len(rows)), squeeze=False)
    for c, (label, _) in enumerate(columns):
        for r in range(len(rows)):
            ax = axes[r][c]
            ax.imshow(imgs[c][r].numpy(), cmap="gray", vmin=0, vmax=1)
            ax.set_xticks([])
            ax.set_yticks([])
            if r == 0:
                ax.set_title(label, fontsize=8)
            if c == 0 and rows[r]:
                ax.set_ylabel(rows[r], fontsize=8)
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)
    return path


def cmd_demo(args: argparse.Namespace) -> int:
    if args.depth:  # depth-resolved ghost imaging (torchtof/depth_demo.py)
        from .depth_demo import run_depth_demo
        return run_depth_demo(args)
    if args.auto:  # scene-adaptive acquisition and reconstruction (torchtof.adaptive)
        from .adaptive.demo import demo_auto

        return demo_auto(args)
    from tqdm.auto import tqdm

    from .experiment import PaperExperiment
    from .methods import DEFAULT_METHODS, evaluate, raw_tof_scores

    torch.manual_seed(args.seed)
    t_all = time.perf_counter()
    exp = PaperExperiment(sr=args.sr, scattering=args.scattering, scene=args.scene, n=args.n,
                          roi_px=2 * args.n, srs=(args.sr,))
    print(f"torchtof demo: {exp}")
    data = exp.run(seed=args.seed, realisations=args.realisations, progress=True)
    print(f"simulated {data.buckets['depth'].shape[-1]} ToF frames of {exp.config.roi_px}x"
          f"{exp.config.roi_px} px x {args.realisations} realisation(s) in "
          f"{data.timings['simulate_s']:.1f} s")
    methods = args.methods.split(",") if args.methods else list(DEFAULT_METHODS)
    raw = raw_tof_scores(data)
    rows = [{"method": "raw ToF", "gate": False, "time_s": None, **raw}]
    images = {}
    steps = [(gate, m) for gate in (False, True) for m in methods]
    with tqdm(total=len(steps), desc="reconstructing", leave=False) as bar:
        for gate in (False, True):
            def tick(name, gate=gate):
                bar.set_postfix_str(f"{name} ({'gate' if gate else 'no gate'})")
                bar.update(1)

            r, im = evaluate(data, args.sr, gate, methods, progress=tick)
            rows += r
            images[gate] = im
    print(f"\nSR {args.sr:.2%}, scene {args.scene!r}, n={args.n}, "
          f"{'through the scattering sheet' if args.scattering else 'in air'}; PSNR on the 8-bit "
          f"scale after min-max normalisation and physics polarity (README 'Scoring')")
    _print_rows(rows)
    out = Path(args.out)
    cols = [("object", data.x), ("raw ToF", data.raw_tof_image)]
    # one row per gate setting; the raw ToF image has no gate
    grid_cols = []
    for label, t in cols:
        grid_cols.append((label, torch.cat([t[:1], t[:1]])))
    for m in methods:
        grid_cols.append((m, torch.cat([images[False][m][:1], images[True][m][:1]])))
    png = save_grid(out / "demo.png", grid_cols, rows=["no gate", "gate 3 m"],
                    title=f"ToF-CGI at SR {args.sr:.2%} (cf. paper Fig. 5)")
    (out / "demo.json").write_text(json.dumps(rows, indent=2))
    print(f"\nwrote {png} and {out / 'demo.json'}; total {time.perf_counter() - t_all:.1f} s")
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    name = args.which
    if name == "operators":
        from .bench.operators import bench_operators, print_operators

        res = bench_operators(ns=tuple(args.n or (32, 64, 128, 256)), batch=args.batch, sr=args.sr)
        print_operators(res)
    elif name == "recon":
        from .bench.recon import bench_recon, print_recon

        res = bench_recon(quick=args.quick, plot=args.plot, out=args.out)
        print_recon(res)
    elif name == "onnx":
        from .bench.onnx import bench_onnx, print_onnx

        res = bench_onnx()
        print_onnx(res)
    elif name == "tradeoff":
        from .bench.tradeoff import bench_tradeoff, print_tradeoff

        res = bench_tradeoff(quick=args.quick, out=args.out)
        print_tradeoff(res)
    elif name == "adaptive":
        from .bench.adaptive import (
            bench_adaptive,
            bench_adaptive_seeds,
            parse_seeds,
            print_adaptive,
            print_adaptive_seeds,
        )

        kw = dict(realisations=args.realisations or (3 if args.quick else 6), progress=False)
        if args.signal_e is not None:
            kw["signal_e"] = args.signal_e
        if args.noise is not None:
            kw["pipeline"] = {"noise": args.noise}
        if args.seeds is not None:
            res = bench_adaptive_seeds(parse_seeds(args.seeds), **kw)
            print_adaptive_seeds(res)
        else:
            res = bench_adaptive(seed=args.seed, **kw)
            print_adaptive(res)
    elif name == "stability":
        from .bench.stability import bench_stability, print_stability

        res = bench_stability()
        print_stability(res)
    else:  # pragma: no cover - argparse restricts choices
        raise ValueError(name)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(res, indent=2, default=str))
        print(f"wrote {args.json}")
    return 0


def cmd_reproduce(args: argparse.Namespace) -> int:
    from .reproduce import reproduce

    reproduce(out=Path(args.out), quick=args.quick, realisations=args.realisations)
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    from .onnx import MODELS, export_model

    if args.model not in MODELS:
        print(f"unknown model {args.model!r}; choose from {sorted(MODELS)}", file=sys.stderr)
        return 2
    path = export_model(args.model, n=args.n, sr=args.sr, path=args.output, opset=args.opset)
    print(f"wrote {path}")
    return 0


def cmd_train(args: argparse.Namespace) -> int:
    from .recon.learned_train import main as train_main  # options: learned_train.add_arguments

    return train_main(args)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="torchtof", description=__doc__)
    p.add_argument("--threads", type=int, default=1,
                   help="torch intra-op threads (default 1: fastest for these problem sizes)")
    sub = p.add_subparsers(dest="cmd", required=True)

    d = sub.add_parser("demo", help="reconstruct the paper's experiment (SR 12.5 %%) and plot it")
    d.add_argument("--sr", type=float, default=0.125)
    d.add_argument("--scene", default="sky")
    d.add_argument("--n", type=int, default=32)
    d.add_argument("--scattering", action="store_true")
    d.add_argument("--realisations", type=int, default=1)
    d.add_argument("--methods", default=None, help="comma-separated subset, e.g. CGI,TVAL3")
    d.add_argument("--seed", type=int, default=0)
    d.add_argument("--out", default="demo_out")
    d.add_argument("--depth", nargs="?", const="motorcycle", default=None, metavar="SCENE",
                   help="depth-resolved GI from per-tap buckets on SCENE (default motorcycle)")
    d.add_argument("--auto", action="store_true",
                   help="adaptive pipeline vs the fixed one (skip what the scene doesn't need)")
    d.set_defaults(func=cmd_demo)

    b = sub.add_parser("bench", help="benchmarks: operators, recon, onnx, tradeoff, stability, "
                       "adaptive")
    b.add_argument("which", choices=["operators", "recon", "onnx", "tradeoff", "stability",
                                     "adaptive"])
    b.add_argument("--n", type=int, nargs="*", default=None)
    b.add_argument("--batch", type=int, default=16)
    b.add_argument("--sr", type=float, default=0.25)
    b.add_argument("--quick", action="store_true")
    b.add_argument("--plot", action="store_true")
    b.add_argument("--out", default="bench_out")
    b.add_argument("--json", default=None, help="write the result as JSON to this path")
    b.add_argument("--seed", type=int, default=0, help="adaptive: noise seed (default 0)")
    b.add_argument("--seeds", default=None,
                   help="adaptive: several seeds, e.g. 0-5 or 0,3,7 (one table per seed)")
    b.add_argument("--signal-e", type=float, default=None,
                   help="adaptive: signal electrons (the paper's set-up: 400; 4000 = 10x light)")
    b.add_argument("--noise", choices=["repeat", "pairs"], default=None,
                   help="adaptive: noise estimate of the adaptive pipeline (default: "
                        "run_adaptive's)")
    b.add_argument("--realisations", type=int, default=None,
                   help="adaptive: noise realisations per scene (default 6, --quick 3; the "
                        "empty field 4x)")
    b.set_defaults(func=cmd_bench)

    r = sub.add_parser("reproduce", help="regenerate the paper's figures and PSNR table")
    r.add_argument("--out", default="reproduce_out")
    r.add_argument("--quick", action="store_true")
    r.add_argument("--realisations", type=int, default=None)
    r.set_defaults(func=cmd_reproduce)

    e = sub.add_parser("export", help="export a model to ONNX")
    e.add_argument("model")
    e.add_argument("--n", type=int, default=32)
    e.add_argument("--sr", type=float, default=0.25)
    e.add_argument("--opset", type=int, default=None)
    e.add_argument("-o", "--output", required=True)
    e.set_defaults(func=cmd_export)

    t = sub.add_parser("train", help="train the learned reconstructor (weights + recipe.json)")
    t.add_argument("--model", choices=["learned"], default="learned")
    from .recon.learned_train import add_arguments as add_train_arguments

    add_train_arguments(t)
    t.set_defaults(func=cmd_train)

    from .hardware.cli import add_parsers as add_hardware_parsers  # acquire, reconstruct

    add_hardware_parsers(sub)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    # Our problems are small (32–128 px images, ≤ 1k patterns): one intra-op thread is as fast
    # and does not collapse when other processes share the cores (OpenMP spin-waiting made a
    # 32×32 transform 500× slower with 2 threads on a loaded 2-core machine).
    torch.set_num_threads(args.threads)
    return args.func(args)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
