"""Problems for ``benchmarks/peers.py``: scenes, Hadamard rows, one noise draw, the score.

Everything here needs only torchtof (no peer library), so that the problem generation and
the scoring are tested on their own (``tests/test_peers_bench.py``).

- Scenes, all ``(1, 1, n, n)`` in ``[0, 1]``: the paper's character 天 (``sky``), binary
  silhouettes thresholded from scikit-image samples (``horse``), grey natural images bundled
  with scikit-image (``camera``, ``coins``), and a procedurally generated piecewise-planar
  depth map (``planes``: a seeded Voronoi partition, one random plane per cell, depth mapped
  to ``[0.1, 0.9]``).
- Held-out scenes (:data:`HELD_OUT_SCENES`), for a re-run on images that neither chose
  ``auto``'s rules nor trained the learned network: the grey ``astronaut`` and
  ``phantom`` (Shepp–Logan), both kept out of :data:`torchtof.data.TRAIN_IMAGES`, and four
  procedural scenes of :func:`torchtof.data.draw_scene` at seeds no training run and no other
  benchmark draws (``EVAL_SEED_BASE + 9000 + k``): a character-like ``glyph``, a binary
  ``blobs`` silhouette (``k = 9``: the first ``k >= 4`` whose bright part covers 20–80 % of
  the image at ``n = 128``; the draw at ``k = 1`` was 1.7 % foreground, almost empty), and the depth maps ``objects`` (objects at several depths, each on
  its own plane) and ``smooth`` (curved surfaces).
- Rows: the first ``M = round(SR · n²)`` rows of the orthonormal 2-D Hadamard operator
  :class:`torchtof.operators.Hadamard` in the lowest-sequency (``"sequency"``) or
  cake-cutting order.
- Noise: one seeded Gaussian draw with ``‖e‖₂ ≈ level · ‖A x‖₂`` (relative noise; the
  per-bucket standard deviation is ``σ = level · ‖A x‖₂ / √M``).
- Score: :func:`torchtof.metrics.psnr` with ``MAX = 1`` (paper Eqs. 13–14) on the estimate
  clipped to ``[0, 1]``, the range of every ground truth here, for every method alike.
"""

from __future__ import annotations

import numpy as np
import torch

import torchtof as tt

SCENES: tuple[str, ...] = ("sky", "horse", "camera", "coins", "planes")
#: Scenes held out from every choice made on :data:`SCENES` and from the learned network's
#: training (see the module docstring).
HELD_OUT_SCENES: tuple[str, ...] = ("astronaut", "phantom", "glyph", "blobs", "objects", "smooth")
#: ``draw_scene`` family and seed offset (from ``EVAL_SEED_BASE + 9000``) of the procedural
#: held-out scenes.
_DRAWN: dict[str, tuple[str, int]] = {
    "glyph": ("strokes", 0), "blobs": ("silhouette", 9), "objects": ("planar", 2),
    "smooth": ("smooth", 3)}
ORDERS: tuple[str, ...] = ("sequency", "cake_cutting")


def planes_depth(n: int, seed: int = 0, cells: int = 6) -> torch.Tensor:
    """A piecewise-planar depth map ``(1, 1, n, n)`` in ``[0.1, 0.9]``.

    ``cells`` seeds drawn uniformly in the unit square split the image into Voronoi cells;
    cell ``k`` carries the plane ``d = a_k + b_k u + c_k v`` (``a`` uniform in [0, 1], slopes
    uniform in [-1, 1] per unit length), then the whole map is mapped affinely to
    ``[0.1, 0.9]``. Deterministic for a given ``(n, seed, cells)``.
    """
    if not isinstance(n, int) or n < 4:
        raise ValueError(f"planes_depth: expected n an int >= 4, got {n!r}")
    if not isinstance(cells, int) or cells < 2:
        raise ValueError(f"planes_depth: expected cells an int >= 2, got {cells!r}")
    rng = np.random.default_rng(seed)
    pts = rng.uniform(0.0, 1.0, (cells, 2))
    a = rng.uniform(0.0, 1.0, cells)
    slope = rng.uniform(-1.0, 1.0, (cells, 2))
    t = (np.arange(n) + 0.5) / n
    v, u = np.meshgrid(t, t, indexing="ij")
    d2 = (u[..., None] - pts[:, 0]) ** 2 + (v[..., None] - pts[:, 1]) ** 2
    lab = d2.argmin(-1)
    depth = a[lab] + slope[lab, 0] * u + slope[lab, 1] * v
    lo, hi = depth.min(), depth.max()
    depth = 0.1 + 0.8 * (depth - lo) / (hi - lo)
    return torch.from_numpy(depth.astype(np.float32))[None, None]


def make_scene(name: str, n: int) -> torch.Tensor:
    """Ground truth ``(1, 1, n, n)`` float32 in ``[0, 1]`` for a name in :data:`SCENES`."""
    if name == "sky":
        x = tt.scenes.sky_character(n)
    elif name == "horse":
        x = tt.scenes.binary_scene("horse", n)
    elif name in ("camera", "coins", "moon"):
        x = tt.scenes.skimage_scene(name, n)
    elif name == "planes":
        x = planes_depth(n)
    elif name == "astronaut":
        x = tt.scenes.skimage_scene("astronaut", n)
    elif name == "phantom":
        x = tt.scenes.skimage_scene("shepp_logan_phantom", n)
    elif name in _DRAWN:
        from torchtof.data import EVAL_SEED_BASE, draw_scene

        family, k = _DRAWN[name]
        x = draw_scene(n, EVAL_SEED_BASE + 9000 + k, family, dtype=torch.float32)
    else:
        raise ValueError(f"make_scene: expected name in {SCENES + HELD_OUT_SCENES}, "
                         f"got {name!r}")
    return x.to(torch.float32).clamp(0.0, 1.0)


def make_problem(name: str, n: int, sr: float, order: str, level: float, seed: int = 0):
    """``(x, A, y, sigma)``: truth, operator, noisy buckets ``(1, 1, M)``, per-bucket std."""
    if order not in ORDERS:
        raise ValueError(f"make_problem: expected order in {ORDERS}, got {order!r}")
    if not level >= 0.0:
        raise ValueError(f"make_problem: expected level >= 0, got {level!r}")
    x = make_scene(name, n)
    A = tt.operators.Hadamard(n, sr=sr, order=order)
    return (x, A, *noisy_buckets(x, A, level, seed))


def noisy_buckets(x: torch.Tensor, A, level: float, seed: int = 0):
    """``(y, sigma)``: the buckets ``A x`` plus one seeded Gaussian draw of relative level
    ``level`` (``‖e‖₂ ≈ level · ‖A x‖₂``) and its per-bucket standard deviation."""
    y0 = A(x)
    sigma = level * float(y0.norm()) / y0.shape[-1] ** 0.5
    g = torch.Generator().manual_seed(seed)
    return y0 + sigma * torch.randn(y0.shape, generator=g, dtype=y0.dtype), sigma


def score(x_hat: torch.Tensor, x: torch.Tensor) -> float:
    """PSNR in dB (``MAX = 1``) of ``x_hat`` clipped to ``[0, 1]`` against ``x``."""
    x_hat = torch.as_tensor(x_hat).reshape(x.shape).to(torch.float64)
    x_hat = torch.nan_to_num(x_hat, nan=0.5, posinf=1.0, neginf=0.0)
    return float(tt.metrics.psnr(x_hat.clamp(0.0, 1.0), x.to(torch.float64), bits=None)[0])


def cell_parser(description: str):
    """An ``argparse`` parser with the cell options of the benchmark scripts that study
    ``auto`` on these problems: ``--n``, ``--sr``, ``--orders``, ``--scenes``, ``--noise``."""
    import argparse

    p = argparse.ArgumentParser(description=description)
    p.add_argument("--n", type=int, default=32)
    p.add_argument("--sr", type=float, nargs="+", default=[0.0625, 0.125, 0.25, 0.375])
    p.add_argument("--orders", nargs="+", default=["cake_cutting"], choices=ORDERS)
    p.add_argument("--scenes", nargs="+", default=list(SCENES), choices=SCENES + HELD_OUT_SCENES)
    p.add_argument("--noise", type=float, default=0.01)
    return p


def shard(v: str) -> tuple[int, int]:
    """``--shard I/K`` of the benchmark scripts: this run takes every K-th problem from I."""
    import argparse

    i, _, k = v.partition("/")
    if not (i.isdigit() and k.isdigit() and 0 <= int(i) < int(k)):
        raise argparse.ArgumentTypeError(f"expected I/K with 0 <= I < K, got {v!r}")
    return int(i), int(k)
