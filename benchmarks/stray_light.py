"""How much of the 天 character each bucket kind recovers as the stray light grows.

The paper (§3.1) attributes the raw ToF map's failure to light that reaches the camera
without passing the DMD's on-mirrors, and CGI's success to that light cancelling in the
differential buckets ``y⁺ − y⁻``. That holds for quantities that are *linear* in the
returned light: the four correlation taps (paper Eq. 5–6) and therefore the tap buckets.
It does not hold for the depth buckets (paper Eq. 10): a pixel's depth is the phase of the
phasor sum ``P_object + P_stray`` (Eq. 7), a non-linear function of it. Where the stray
phasor dominates a pixel, switching the object's light on or off barely moves that pixel's
phase, so that part of the object hardly changes the depth bucket and is lost whatever the
reconstructor does. The amplitude (Eq. 8) is non-linear too, though less so.

This script measures it on the simulated experiment: for a grid of stray-light amplitudes it
simulates the paper's frames at SR = 100 % (so that the exact pseudo-inverse isolates the
bucket physics from the reconstructor), reconstructs every bucket kind, and scores

* PSNR (the package's scoring protocol, :func:`torchtof.metrics.compare`, with the physics
  polarity), and
* *recovered*: the fraction of the character's pixels that an Otsu threshold of the
  reconstruction marks as object (recall), and the IoU of that mask with the character.

Bucket kinds: ``depth`` (Eq. 10, ungated: a negative image), ``depth_gated`` (the 3 m gate),
``intensity`` (Eq. 8 amplitude sums) and ``taps`` (the four tap sums, reconstructed
channel-wise and combined per pixel with Eq. 8 — the amplitude of the object's own phasor,
since the stray and ambient terms cancel exactly in ``y⁺ − y⁻`` for linear quantities).

Run::

    python benchmarks/stray_light.py --out docs/stray_light

It writes ``stray_light.json``, ``stray_light.md`` (the table), ``stray_light.png`` (curves)
and ``stray_light_images.png`` (the reconstructions without and with the default stray light).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch
from skimage.filters import threshold_otsu

from torchtof.experiment import PaperExperiment
from torchtof.metrics import compare
from torchtof.sensor.functional import tap_amplitude

KINDS = ("depth", "depth_gated", "intensity", "taps")
LABELS = {
    "depth": "depth sum (paper Eq. 10)",
    "depth_gated": "gated depth (3 m)",
    "intensity": "intensity (Eq. 8 sums)",
    "taps": "taps I/Q (torchtof)",
}


def reconstruct(data, kind: str) -> tuple[torch.Tensor, str]:
    """Exact reconstruction at SR = 100 % and its physics polarity."""
    gate = kind == "depth_gated"
    base = "depth" if gate else kind
    A, y = data.measurements(1.0, kind=base, gate=gate)
    x = A.pinv(y)  # (R, C, n, n)
    if kind == "taps":
        # Linear taps: y⁺ − y⁻ removes every pattern-independent term; Eq. 8 per pixel.
        return tap_amplitude(x), "positive"
    return x, data.polarity(gate, base)


def recovered(x_hat: torch.Tensor, truth: torch.Tensor, polarity: str) -> tuple[float, float]:
    """(recall, IoU) of the Otsu mask of the polarity-resolved reconstruction."""
    img = x_hat[0, 0].double().numpy()
    if polarity == "negative":
        img = -img
    if np.ptp(img) == 0:
        return 0.0, 0.0
    mask = img > threshold_otsu(img)
    obj = truth[0, 0].numpy() > 0.5
    inter = np.logical_and(mask, obj).sum()
    return float(inter / obj.sum()), float(inter / np.logical_or(mask, obj).sum())


def run(strays, noise: str, seed: int, n: int) -> list[dict]:
    rows = []
    quiet = dict(shot=None, read_noise_e=0.0, adc_bits=None) if noise == "none" else {}
    for stray_e in strays:
        exp = PaperExperiment(sr=1.0, n=n, srs=(1.0,), stray_e=float(stray_e), **quiet)
        t0 = time.perf_counter()
        data = exp.run(seed=seed, dtype=torch.float64)
        sim_s = time.perf_counter() - t0
        for kind in KINDS:
            x_hat, pol = reconstruct(data, kind)
            score = compare(x_hat, data.x.to(x_hat.dtype), polarity=pol)
            rec, iou = recovered(x_hat, data.x, pol)
            rows.append({
                "noise": noise, "stray_e": float(stray_e), "kind": kind, "polarity": pol,
                "psnr_db": float(score["psnr"][0]), "ssim": float(score["ssim"][0]),
                "recall": rec, "iou": iou, "simulate_s": sim_s,
            })
            print(f"noise={noise:7s} stray_e={stray_e:6.0f} {kind:12s} "
                  f"PSNR {rows[-1]['psnr_db']:6.2f} dB  recall {rec:5.2f}  IoU {iou:5.2f}",
                  flush=True)
    return rows


def table(rows: list[dict]) -> str:
    strays = sorted({r["stray_e"] for r in rows})
    out = []
    for noise in sorted({r["noise"] for r in rows}, reverse=True):
        out.append(f"\nNoise: {noise}. Cells: PSNR dB / fraction of the character recovered "
                   "(Otsu recall) / IoU.\n")
        out.append("| bucket kind | " + " | ".join(f"stray {s:g} e⁻" for s in strays) + " |")
        out.append("|---|" + "---|" * len(strays))
        for kind in KINDS:
            cells = []
            for s in strays:
                r = next(r for r in rows if r["noise"] == noise and r["kind"] == kind
                         and r["stray_e"] == s)
                cells.append(f"{r['psnr_db']:.1f} / {r['recall']:.2f} / {r['iou']:.2f}")
            out.append(f"| {LABELS[kind]} | " + " | ".join(cells) + " |")
    return "\n".join(out) + "\n"


def figure(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    noises = sorted({r["noise"] for r in rows}, reverse=True)
    fig, axes = plt.subplots(1, 2 * len(noises), figsize=(5.0 * 2 * len(noises), 3.8))
    for j, noise in enumerate(noises):
        for k, (key, ylabel) in enumerate((("recall", "fraction of 天 recovered (Otsu recall)"),
                                          ("psnr_db", "PSNR (dB)"))):
            ax = axes[2 * j + k]
            for kind in KINDS:
                sel = [r for r in rows if r["noise"] == noise and r["kind"] == kind]
                ax.plot([r["stray_e"] for r in sel], [r[key] for r in sel], "o-",
                        label=LABELS[kind])
            ax.axvline(1000.0, color="grey", ls=":", lw=1)
            ax.set_xlabel("stray-light peak amplitude (e⁻); dotted: package default")
            ax.set_ylabel(ylabel)
            ax.set_title(f"noise: {noise}")
            ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle("'sky' character at SR 100 % (exact inverse): stray light cancels in linear "
                 "tap buckets, not in depth buckets")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def image_grid(strays, noise: str, seed: int, n: int, path: Path) -> None:
    """Reconstructions per bucket kind (columns) at each stray level (rows), polarity
    resolved by the physics rule, with PSNR and recall in each title."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    quiet = dict(shot=None, read_noise_e=0.0, adc_bits=None) if noise == "none" else {}
    fig, axes = plt.subplots(len(strays), len(KINDS), figsize=(2.6 * len(KINDS),
                                                              2.7 * len(strays)),
                             squeeze=False)
    for i, stray_e in enumerate(strays):
        exp = PaperExperiment(sr=1.0, n=n, srs=(1.0,), stray_e=float(stray_e), **quiet)
        data = exp.run(seed=seed, dtype=torch.float64)
        for j, kind in enumerate(KINDS):
            x_hat, pol = reconstruct(data, kind)
            score = compare(x_hat, data.x.to(x_hat.dtype), polarity=pol)
            rec, _ = recovered(x_hat, data.x, pol)
            img = x_hat[0, 0].numpy()
            img = (img - img.min()) / max(np.ptp(img), 1e-30)
            if pol == "negative":
                img = 1.0 - img
            ax = axes[i, j]
            ax.imshow(img, cmap="gray", vmin=0, vmax=1)
            ax.set_title(f"{LABELS[kind]}\nstray {stray_e:g} e⁻: "
                         f"{float(score['psnr'][0]):.1f} dB, {rec:.0%}", fontsize=8)
            ax.axis("off")
    fig.suptitle(f"noise: {noise}; negative images flipped (physics polarity); "
                 "% = share of the character recovered", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--out", type=Path, default=Path("stray_light_out"), help="output folder")
    p.add_argument("--stray", type=float, nargs="+",
                   default=[0, 250, 500, 1000, 2000, 4000], help="stray_e values (e⁻)")
    p.add_argument("--noise", choices=("none", "default", "both"), default="both",
                   help="noise-free frames, the experiment's default noise, or both")
    p.add_argument("--n", type=int, default=32, help="image side (power of two)")
    p.add_argument("--seed", type=int, default=0, help="noise seed")
    args = p.parse_args(argv)
    if any(s < 0 for s in args.stray):
        p.error("--stray: values must be >= 0")
    torch.set_num_threads(1)
    noises = ("none", "default") if args.noise == "both" else (args.noise,)
    rows = [r for noise in noises for r in run(args.stray, noise, args.seed, args.n)]
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "stray_light.json").write_text(json.dumps(rows, indent=1))
    (args.out / "stray_light.md").write_text(table(rows))
    figure(rows, args.out / "stray_light.png")
    image_grid(sorted({0.0, 1000.0} & set(args.stray)) or args.stray[:2], noises[-1],
               args.seed, args.n, args.out / "stray_light_images.png")
    print(f"wrote {args.out}/stray_light.{{json,md,png}}")


if __name__ == "__main__":
    main()
