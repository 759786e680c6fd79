"""Adapting the learned network to a user's own scenes (``torchtof train --images``): one real
depth map split in two, the network fine-tuned on one part and scored on the other.

The domain: the Middlebury "motorcycle" disparity that scikit-image bundles (Scharstein et al.
2014; no download), turned into depth ``z ∝ 1/δ`` with invalid pixels filled from the nearest
valid one (as :func:`torchtof.scenes.motorcycle_depth`). Its left half (columns
``[0, W/2)``) is the user's training data, written by ``--make-data DIR`` as
``DIR/motorcycle_left.npy``; its right half gives the evaluation scenes, three fixed square
crops (top, bottom, and a zoom on the rear wheel), none of whose pixels training sees.

Each cell (n, SR, noise level) scores TVAL3's defaults and every weights file given (the
shipped network unless ``--weights`` says otherwise) on the same buckets: cake-cutting
Hadamard rows, Gaussian noise of ``level × (max y − min y)``, one seeded draw per scene,
PSNR of the output clipped to [0, 1] (``benchmarks/eval_learned.py``'s conventions).

    python benchmarks/learned_user_domain.py --make-data ud            # [--split top-bottom]
    torchtof --threads 1 train --init shipped --images ud/motorcycle_left.npy \\
        --steps 1500 --lr 5e-4 --seed 1 --out ft_moto
    OMP_NUM_THREADS=1 python benchmarks/learned_user_domain.py \\
        --weights shipped ft_moto/learned.pt --out user_domain.json

``--auto`` also scores ``auto(y, A, learned=W)`` for each file (its stacking with that
network; about 5–10 s per cell at n = 32–64). ``--eval-images PATH ...`` scores your own
held-out scenes instead of the motorcycle's right half (anything
:func:`torchtof.data.load_images` reads; each centre-cropped to a square, resized to n and
min–max normalised), e.g. after ``torchtof train --images`` on the rest of your recordings:

    python benchmarks/learned_user_domain.py --eval-images held_out/ --weights shipped mine/learned.pt
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

sys.path.insert(0, str(Path(__file__).resolve().parent))
from eval_learned import buckets, score  # noqa: E402  (the held-out evaluation's conventions)

from torchtof.apps.args import OneLineParser  # noqa: E402
from torchtof.operators import Hadamard  # noqa: E402
from torchtof.recon.auto import auto  # noqa: E402
from torchtof.recon.learned import WEIGHTS_FILE, Learned  # noqa: E402
from torchtof.recon.tval3 import tval3  # noqa: E402

#: The evaluation crops ``(row, column, side)`` of each split's held-out part: the right half
#: (500 × 370) of ``left-right``, the bottom half (250 × 741) of ``top-bottom``.
CROPS = {"left-right": ((0, 0, 370), (130, 0, 370), (150, 120, 200)),
         "top-bottom": ((0, 0, 250), (0, 245, 250), (0, 491, 250))}
#: The training part's file name of each split (``--make-data``).
TRAIN_FILE = {"left-right": "motorcycle_left.npy", "top-bottom": "motorcycle_top.npy"}


def depth_map() -> np.ndarray:
    """The full-resolution depth (arbitrary units, ``1/δ``) of the motorcycle scene."""
    import skimage.data
    from scipy.ndimage import distance_transform_edt

    disp = np.asarray(skimage.data.stereo_motorcycle()[2], dtype=np.float64)
    invalid = ~np.isfinite(disp) | (disp <= 0)
    idx = distance_transform_edt(invalid, return_distances=False, return_indices=True)
    return 1.0 / disp[tuple(idx)]


def halves(split: str = "left-right") -> tuple[np.ndarray, np.ndarray]:
    """``(training part, held-out part)`` of the depth map: left and right halves, or top and
    bottom halves."""
    z = depth_map()
    if split == "top-bottom":
        h = z.shape[0] // 2
        return z[:h], z[h:]
    w = z.shape[1] // 2
    return z[:, :w], z[:, w:]


def _square(img: torch.Tensor, n: int) -> torch.Tensor:
    """``img (H, W)``: its centred square resized to ``n × n`` (anti-aliased), min–max
    normalised, ``(1, 1, n, n)`` float64."""
    h, w = img.shape
    s = min(h, w)
    crop = img[(h - s) // 2 : (h - s) // 2 + s, (w - s) // 2 : (w - s) // 2 + s][None, None]
    x = F.interpolate(crop.double(), size=(n, n), mode="bilinear", antialias=True)
    if not x.amax() > x.amin():
        raise ValueError(f"learned_user_domain: a constant scene at n = {n} (nothing to score)")
    return (x - x.amin()) / (x.amax() - x.amin())


def eval_scenes(n: int, images: tuple[torch.Tensor, ...] | None = None,
                split: str = "left-right") -> torch.Tensor:
    """The evaluation scenes at side ``n``, each min–max normalised to [0, 1]: the held-out
    part's crops (:data:`CROPS` of ``split``), or ``images`` (the caller's, ``(H, W)`` each)
    centre-cropped to a square; ``(K, 1, n, n)`` float32."""
    if images is not None:
        return torch.cat([_square(img, n) for img in images]).float()
    held = torch.from_numpy(halves(split)[1])
    return torch.cat([_square(held[r : r + s, c : c + s], n)
                      for r, c, s in CROPS[split]]).float()


def run(sizes, srs, levels, weights: list[str], with_auto: bool = False,
        images: tuple[torch.Tensor, ...] | None = None, split: str = "left-right") -> list[dict]:
    rows = []
    for n in sizes:
        x = eval_scenes(n, images, split)
        for sr in srs:
            A = Hadamard(n, sr=sr, order="cake_cutting")
            nets = {w: Learned(A, pretrained=WEIGHTS_FILE if w == "shipped" else w).eval()
                    for w in weights}
            for level in levels:
                y = buckets(A, x, level, salt=7 * n + int(sr * 1e4) + int(level * 1e4))
                row = {"n": n, "sr": sr, "level": level}
                with torch.no_grad():
                    row["tval3"] = score(tval3(y, A), x)[0]
                    for w, net in nets.items():
                        row[w] = score(net(y), x)[0]
                    for w in weights if with_auto else ():
                        row[f"auto+{w}"] = score(auto(y, A, learned=WEIGHTS_FILE if w == "shipped"
                                                      else w), x)[0]
                rows.append(row)
                print(f"n={n} SR {sr * 100:g} % noise {level * 100:g} %: TVAL3 "
                      f"{row['tval3']:.2f} dB; " + "; ".join(
                          f"{w} {row[w] - row['tval3']:+.2f}" for w in row
                          if w not in ("n", "sr", "level", "tval3")), flush=True)
    return rows


def table(rows: list[dict], weights: list[str]) -> str:
    """Markdown: mean Δ against TVAL3 per (noise, n) for each weights file, and overall."""
    out = ["| weights | " + " | ".join(
        f"{lv * 100:g} %, n = {n}" for lv in sorted({r['level'] for r in rows})
        for n in sorted({r['n'] for r in rows})) + " | all cells | worst cell |",
        "|---" * (3 + len({r['level'] for r in rows}) * len({r['n'] for r in rows})) + "|"]
    for w in weights:
        cells = []
        for lv in sorted({r["level"] for r in rows}):
            for n in sorted({r["n"] for r in rows}):
                d = [r[w] - r["tval3"] for r in rows if r["n"] == n and r["level"] == lv]
                cells.append(f"{np.mean(d):+.2f}")
        d = [r[w] - r["tval3"] for r in rows]
        out.append(f"| {w} | " + " | ".join(cells) + f" | {np.mean(d):+.2f} | {min(d):+.2f} |")
    return "\n".join(out)


def main(argv=None) -> int:
    p = OneLineParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--make-data", type=Path, default=None, metavar="DIR",
                   help="write the split's training half (DIR/motorcycle_left.npy or "
                        "DIR/motorcycle_top.npy) and exit")
    p.add_argument("--split", choices=list(CROPS), default="left-right",
                   help="train on the left (top) half, score crops of the right (bottom) half")
    p.add_argument("--weights", nargs="+", default=["shipped"],
                   help="weights files to score ('shipped': the package's)")
    p.add_argument("--sizes", type=int, nargs="+", default=[32, 64, 128])
    p.add_argument("--srs", type=float, nargs="+", default=[0.0625, 0.125, 0.25])
    p.add_argument("--levels", type=float, nargs="+", default=[0.0, 0.01, 0.05])
    p.add_argument("--eval-images", nargs="+", default=None, metavar="PATH",
                   help="score these held-out scenes instead of the motorcycle's right half")
    p.add_argument("--auto", action="store_true",
                   help="also score auto(y, A, learned=W) for each weights file (slow)")
    p.add_argument("--out", type=Path, default=None)
    p.add_argument("--table", type=Path, default=None, help="print a stored --out file's table")
    a = p.parse_args(argv)
    if a.make_data is not None:
        a.make_data.mkdir(parents=True, exist_ok=True)
        part = halves(a.split)[0]
        np.save(a.make_data / TRAIN_FILE[a.split], part)
        print(f"wrote {a.make_data / TRAIN_FILE[a.split]} ({part.shape[0]} × {part.shape[1]})")
        return 0
    if a.table is not None:
        d = json.loads(a.table.read_text())
        print(table(d["rows"], [k for k in d["rows"][0] if k not in ("n", "sr", "level",
                                                                          "tval3")]))
        return 0
    for w in a.weights:
        if w != "shipped" and not Path(w).is_file():
            p.error(f"argument --weights: no such file: {w!r}")
    images = None
    if a.eval_images is not None:
        from torchtof.data import load_images

        try:
            images = load_images(a.eval_images)
        except (OSError, ValueError, TypeError) as exc:
            p.error(f"argument --eval-images: {exc}")
    torch.set_num_threads(1)
    rows = run(a.sizes, a.srs, a.levels, a.weights, a.auto, images, a.split)
    print(table(rows, [k for k in rows[0] if k not in ("n", "sr", "level", "tval3")]))
    if a.out is not None:
        a.out.write_text(json.dumps({"weights": a.weights, "rows": rows,
                                     "scenes": a.eval_images or {a.split: CROPS[a.split]}},
                                    indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
