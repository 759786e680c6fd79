"""Procedural training and evaluation scenes, seeded, no downloads.

Six families of ``n × n`` images in ``[0, 1]`` covering what a ToF ghost-imaging set-up
sees (a binary character, objects at several depths, the paper's §3.1) and natural texture:

- ``"planar"``: piecewise-planar depth maps: a tilted background plane and 2–4 objects
  (polygons, ellipses, rectangles), each with its own plane, painted far to near;
- ``"smooth"``: piecewise-smooth depth maps: the same with curved surfaces (a plane plus a
  quadratic and a Gaussian bump per object);
- ``"silhouette"``: binary unions of random polygons and ellipses, some cut out (holes);
- ``"strokes"``: character-like glyphs, 2–6 thick segments (bars, diagonals);
- ``"natural"``: random crops (scale, flips, quarter turns, contrast) of the grey images that
  scikit-image ships, only those in :data:`TRAIN_IMAGES`; :data:`HELD_OUT_IMAGES` are never
  drawn for training;
- ``"leaves"``: textured dead-leaves images (occluding discs of power-law sizes), a
  procedural stand-in for natural images (probability 0 in :data:`FAMILIES`; a training run
  may give it one).

A binary scene is inverted (``1 − x``) with probability 0.3 and gets random levels with
probability 0.3 (the ungated depth bucket gives negative images, paper §3.1).

Every scene comes from its own ``torch.Generator`` seeded by
:func:`~torchtof.recon.synthetic.scene_seed` of ``(seed, step, index)``: a global batch is the
same whichever process draws it (data-parallel training), and an evaluation set uses seeds
that training never uses (:data:`EVAL_SEED_BASE` and up).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence

import numpy as np
import torch
import torch.nn.functional as F

from ..recon.synthetic import scene_seed

__all__ = [
    "FAMILIES",
    "TRAIN_IMAGES",
    "HELD_OUT_IMAGES",
    "EVAL_SEED_BASE",
    "check_families",
    "draw_scene",
    "draw_scenes",
    "grey_image",
    "pick_family",
    "planar_depth",
    "power_law_radii",
]

#: Scene families and their training probabilities (the shipped weights' mixture; a run may
#: pass its own, e.g. with ``"leaves"``, which has probability 0 here).
FAMILIES: dict[str, float] = {
    "planar": 0.25,
    "smooth": 0.15,
    "silhouette": 0.2,
    "strokes": 0.15,
    "natural": 0.25,
    "leaves": 0.0,
}
#: scikit-image images drawn for training (bundled with scikit-image, no download).
TRAIN_IMAGES: tuple[str, ...] = (
    "coins", "moon", "text", "page", "clock", "coffee", "chelsea", "rocket", "grass",
    "gravel", "brick", "cell", "hubble_deep_field", "immunohistochemistry", "cat",
)
#: scikit-image images kept for evaluation only.
HELD_OUT_IMAGES: tuple[str, ...] = ("camera", "astronaut", "horse", "shepp_logan_phantom")
#: Training runs use seeds below this; evaluation sets use this and above.
EVAL_SEED_BASE = 1_000_000


def check_families(families: dict[str, float], func: str) -> dict[str, float]:
    """``families`` as a dict of probabilities in :data:`FAMILIES`' order: known names,
    non-negative finite values summing to 1 (within 1e-6), else a ``ValueError`` naming it."""
    if not isinstance(families, dict) or not families:
        raise TypeError(f"{func}: expected families to be a non-empty dict, got {families!r}")
    bad = [k for k in families if k not in FAMILIES]
    if bad:
        raise ValueError(f"{func}: expected families' names in {tuple(FAMILIES)}, got {bad}")
    vals = [float(v) for v in families.values()]
    if any(not math.isfinite(v) or v < 0 for v in vals) or abs(sum(vals) - 1) > 1e-6:
        raise ValueError(f"{func}: expected families' probabilities >= 0 summing to 1, "
                         f"got {families!r}")
    return {k: float(families[k]) for k in FAMILIES if k in families}


@functools.cache
def _grey_np(name: str) -> np.ndarray:
    import skimage.color
    import skimage.data
    import skimage.util

    img = np.asarray(getattr(skimage.data, name)())
    if img.ndim == 3 and img.shape[-1] == 4:
        img = skimage.color.rgba2rgb(img)
    if img.ndim == 3:
        img = skimage.color.rgb2gray(img)
    return skimage.util.img_as_float32(img)


def grey_image(name: str) -> torch.Tensor:
    """A bundled scikit-image image as a float32 grey ``(H, W)`` tensor in ``[0, 1]``.

    Raises:
        ValueError: if ``name`` is neither in :data:`TRAIN_IMAGES` nor in
            :data:`HELD_OUT_IMAGES`.
    """
    if name not in TRAIN_IMAGES + HELD_OUT_IMAGES:
        raise ValueError(
            f"grey_image: expected name in {TRAIN_IMAGES + HELD_OUT_IMAGES}, got {name!r}"
        )
    return torch.from_numpy(_grey_np(name))


class _Draw:
    """Uniform draws from one seeded ``torch.Generator``."""

    def __init__(self, seed: int) -> None:
        self.g = torch.Generator().manual_seed(int(seed))

    def u(self, lo: float, hi: float) -> float:
        return lo + (hi - lo) * float(torch.rand((), generator=self.g, dtype=torch.float64))

    def i(self, lo: int, hi: int) -> int:  # in [lo, hi]
        return int(torch.randint(lo, hi + 1, (), generator=self.g))


def _grid(n: int) -> tuple[torch.Tensor, torch.Tensor]:
    c = (torch.arange(n, dtype=torch.float32) + 0.5) / n * 2 - 1  # pixel centres in [-1, 1]
    return torch.meshgrid(c, c, indexing="ij")  # yy, xx


def _polygon(d: _Draw, yy: torch.Tensor, xx: torch.Tensor) -> torch.Tensor:
    """A random star-shaped polygon (3–8 vertices), even–odd rule on every edge at once."""
    v = d.i(3, 8)
    cx, cy, r = d.u(-0.6, 0.6), d.u(-0.6, 0.6), d.u(0.15, 0.6)
    ang = sorted(d.u(0, 2 * math.pi) for _ in range(v))
    px = torch.tensor([cx + r * d.u(0.4, 1.0) * math.cos(a) for a in ang])
    py = torch.tensor([cy + r * d.u(0.4, 1.0) * math.sin(a) for a in ang])
    x1, y1 = px[:, None, None], py[:, None, None]
    x2, y2 = px.roll(-1)[:, None, None], py.roll(-1)[:, None, None]
    crosses = ((y1 > yy) != (y2 > yy)) & (
        xx < (x2 - x1) * (yy - y1) / torch.where(y2 == y1, 1e-9, y2 - y1) + x1
    )
    return (crosses.sum(0) % 2) == 1


def _ellipse_or_rect(d: _Draw, yy: torch.Tensor, xx: torch.Tensor) -> torch.Tensor:
    cx, cy = d.u(-0.7, 0.7), d.u(-0.7, 0.7)
    a, b = d.u(0.1, 0.5), d.u(0.1, 0.5)
    th = d.u(0, math.pi)
    dx, dy = xx - cx, yy - cy
    xr = dx * math.cos(th) + dy * math.sin(th)
    yr = -dx * math.sin(th) + dy * math.cos(th)
    if d.u(0, 1) < 0.5:
        return (xr / a) ** 2 + (yr / b) ** 2 <= 1
    return (xr.abs() <= a) & (yr.abs() <= b)


def _mask(d: _Draw, yy: torch.Tensor, xx: torch.Tensor) -> torch.Tensor:
    return _polygon(d, yy, xx) if d.u(0, 1) < 0.5 else _ellipse_or_rect(d, yy, xx)


def _plane(d: _Draw, yy: torch.Tensor, xx: torch.Tensor, tilt: float) -> torch.Tensor:
    return d.u(0.05, 0.95) + d.u(-tilt, tilt) * xx + d.u(-tilt, tilt) * yy


def _surface(d: _Draw, yy: torch.Tensor, xx: torch.Tensor, smooth: bool) -> torch.Tensor:
    s = _plane(d, yy, xx, 0.3)
    if smooth:
        s = s + d.u(-0.3, 0.3) * (xx - d.u(-1, 1)) ** 2 + d.u(-0.3, 0.3) * (yy - d.u(-1, 1)) ** 2
        w = d.u(0.1, 0.5)
        s = s + d.u(-0.4, 0.4) * torch.exp(
            -((xx - d.u(-1, 1)) ** 2 + (yy - d.u(-1, 1)) ** 2) / (2 * w * w)
        )
    return s


def _depth(d: _Draw, yy: torch.Tensor, xx: torch.Tensor, smooth: bool) -> torch.Tensor:
    x = _surface(d, yy, xx, smooth)
    for _ in range(d.i(2, 4)):
        x = torch.where(_mask(d, yy, xx), _surface(d, yy, xx, smooth), x)
    lo, hi = x.amin(), x.amax()
    span = d.u(0.5, 1.0)
    off = d.u(0, 1 - span)
    return off + span * (x - lo) / (hi - lo).clamp_min(1e-6)


def _silhouette(d: _Draw, yy: torch.Tensor, xx: torch.Tensor) -> torch.Tensor:
    m = _mask(d, yy, xx)
    for _ in range(d.i(0, 2)):
        s = _mask(d, yy, xx)
        m = m & ~s if d.u(0, 1) < 0.3 else m | s
    return m


def _strokes(d: _Draw, yy: torch.Tensor, xx: torch.Tensor, n: int) -> torch.Tensor:
    half = max(1.0 / n, d.u(0.04, 0.12))
    m = torch.zeros_like(xx, dtype=torch.bool)
    for _ in range(d.i(2, 6)):
        kind = d.i(0, 2)
        if kind == 0:  # horizontal bar
            y0 = y1 = d.u(-0.8, 0.8)
            x0, x1 = d.u(-0.8, 0.0), d.u(0.0, 0.8)
        elif kind == 1:  # vertical bar
            x0 = x1 = d.u(-0.8, 0.8)
            y0, y1 = d.u(-0.8, 0.0), d.u(0.0, 0.8)
        else:
            x0, y0, x1, y1 = (d.u(-0.8, 0.8) for _ in range(4))
        ax, ay = x1 - x0, y1 - y0
        t = (((xx - x0) * ax + (yy - y0) * ay) / max(ax * ax + ay * ay, 1e-12)).clamp(0, 1)
        m = m | (torch.hypot(xx - (x0 + t * ax), yy - (y0 + t * ay)) <= half)
    return m


def _natural(d: _Draw, n: int, images: Sequence[str]) -> torch.Tensor:
    img = grey_image(images[d.i(0, len(images) - 1)])
    h, w = img.shape
    side = int(round(min(h, w) * d.u(0.25, 1.0)))
    side = max(side, min(n, h, w))
    top, left = d.i(0, h - side), d.i(0, w - side)
    crop = img[top : top + side, left : left + side][None, None]
    x = F.interpolate(crop, size=(n, n), mode="bilinear", antialias=True, align_corners=False)[0, 0]
    x = torch.rot90(x, d.i(0, 3))
    if d.u(0, 1) < 0.5:
        x = x.flip(-1)
    lo, hi = x.amin(), x.amax()
    x = (x - lo) / (hi - lo).clamp_min(1e-6)
    span = d.u(0.6, 1.0)
    return (d.u(0, 1 - span) + span * x).clamp(0, 1)


def power_law_radii(u: torch.Tensor, rmin: float, rmax: float) -> torch.Tensor:
    """Radii of density ``∝ r⁻³`` on ``[rmin, rmax]`` from uniform numbers ``u`` in [0, 1):
    the inverse of the CDF ``F(r) = (rmin⁻² − r⁻²) / (rmin⁻² − rmax⁻²)`` (the dead-leaves
    model's scale-invariant law, Lee, Mumford & Huang 2001)."""
    a, b = rmin ** -2, rmax ** -2
    return (a - u * (a - b)) ** -0.5


def _leaves(d: _Draw, n: int) -> torch.Tensor:
    """A dead-leaves image (Matheron 1968; Lee, Mumford & Huang 2001, "Occlusion models for
    natural images"): discs of power-law radii (density ``∝ r⁻³`` between one pixel and the
    image side, the scale-invariant law of natural images) dropped at uniform positions, each
    under those before it. Every leaf is textured (Achddou, Gousseau & Ladjal 2021: textured
    dead leaves train restoration networks close to natural images): a grey level, a linear
    gradient and, with probability 0.5, a sinusoid of random frequency and orientation.
    Rendered at twice the side and averaged 2 × 2 (anti-aliased edges)."""
    g, k = d.g, 256
    s = 2 * n
    c = (torch.arange(s, dtype=torch.float32) + 0.5) / s * 2 - 1
    yy, xx = torch.meshgrid(c, c, indexing="ij")

    def rand(*shape):
        return torch.rand(shape, generator=g, dtype=torch.float32)

    r = power_law_radii(rand(k), 2.0 / n, d.u(0.5, 1.5))
    cx, cy = rand(k) * 2.4 - 1.2, rand(k) * 2.4 - 1.2
    top = torch.full((s, s), k, dtype=torch.long)  # the background leaf where none covers
    for lo in range(k - 32, -32, -32):  # 32 leaves at a time, the last ones first
        sl = slice(lo, lo + 32)
        cover = ((xx - cx[sl, None, None]) ** 2 + (yy - cy[sl, None, None]) ** 2
                 <= (r[sl] * r[sl])[:, None, None])
        hit = cover.any(0)
        top = torch.where(hit, lo + cover.to(torch.uint8).argmax(0), top)  # earlier on top
    base, gx, gy = rand(k + 1), rand(k + 1) - 0.5, rand(k + 1) - 0.5
    amp = (rand(k + 1) < 0.5) * rand(k + 1) * 0.3
    freq, ang, ph = 2 + rand(k + 1) * (n / 4), rand(k + 1) * math.pi, rand(k + 1) * 2 * math.pi
    fx, fy = freq * torch.cos(ang), freq * torch.sin(ang)
    x = (base[top] + 0.3 * (gx[top] * xx + gy[top] * yy)
         + amp[top] * torch.sin(fx[top] * xx + fy[top] * yy + ph[top]))
    x = F.avg_pool2d(x[None, None], 2)[0, 0]
    lo, hi = x.amin(), x.amax()
    x = (x - lo) / (hi - lo).clamp_min(1e-6)
    span = d.u(0.6, 1.0)
    return d.u(0, 1 - span) + span * x


def pick_family(r: float, probs: dict[str, float]) -> str:
    """The family of a uniform number ``r`` in [0, 1): the first whose cumulative probability
    exceeds ``r``, in ``probs``' order; families of probability 0 are never picked (the last
    one with a positive probability catches rounding)."""
    cum, last = 0.0, None
    for family, p in probs.items():
        if p <= 0:
            continue
        cum, last = cum + p, family
        if r < cum:
            return family
    return last


def draw_scene(
    n: int,
    seed: int,
    family: str | None = None,
    images: Sequence[str] = TRAIN_IMAGES,
    dtype: torch.dtype = torch.float32,
    families: dict[str, float] | None = None,
) -> torch.Tensor:
    """One scene in ``[0, 1]`` from its own generator seeded ``seed``.

    Args:
        n: image side, ``>= 8``.
        seed: the scene's seed (see :func:`draw_scenes`).
        family: one of :data:`FAMILIES`, or ``None`` to draw it with the probabilities of
            ``families``.
        images: scikit-image names the ``"natural"`` family crops from.
        dtype: floating dtype of the result.
        families: probabilities of the families (keys from :data:`FAMILIES`, summing to 1);
            ``None``: :data:`FAMILIES`.

    Returns:
        The scene, shape ``(1, 1, n, n)``.

    Raises:
        ValueError: if ``n < 8``, ``family`` is unknown or ``images`` is empty.

    Example:
        >>> draw_scene(32, seed=1, family="planar").shape
        torch.Size([1, 1, 32, 32])
    """
    probs = _check_scene_args(n, family, images, families, "draw_scene")
    return _draw_scene(n, seed, family, images, dtype, probs)


def _check_scene_args(n, family, images, families, func: str) -> dict[str, float]:
    """The checks of :func:`draw_scene` and :func:`draw_scenes` (once per call); returns the
    family probabilities."""
    if isinstance(n, bool) or not isinstance(n, int) or n < 8:
        raise ValueError(f"{func}: expected n to be an int >= 8, got {n!r}")
    if family is not None and family not in FAMILIES:
        raise ValueError(f"{func}: expected family in {tuple(FAMILIES)} or None, got {family!r}")
    if len(images) == 0:
        raise ValueError(f"{func}: expected a non-empty images, got {images!r}")
    return FAMILIES if families is None else check_families(families, func)


def _draw_scene(n: int, seed: int, family: str | None, images: Sequence[str],
                dtype: torch.dtype, probs: dict[str, float]) -> torch.Tensor:
    """:func:`draw_scene` on checked arguments."""
    d = _Draw(seed)
    r = d.u(0, 1)
    if family is None:
        family = pick_family(r, probs)
    yy, xx = _grid(n)
    if family in ("planar", "smooth"):
        x = _depth(d, yy, xx, smooth=family == "smooth")
    elif family == "natural":
        x = _natural(d, n, images)
    elif family == "leaves":
        x = _leaves(d, n)
    else:
        m = _silhouette(d, yy, xx) if family == "silhouette" else _strokes(d, yy, xx, n)
        x = m.to(torch.float32)
        if d.u(0, 1) < 0.3:
            x = 1 - x
        if d.u(0, 1) < 0.3:
            lo, hi = d.u(0, 0.4), d.u(0.6, 1)
            x = lo + (hi - lo) * x
    return x.clamp(0, 1).to(dtype)[None, None]


def draw_scenes(
    n: int,
    seed: int,
    step: int,
    indices: Sequence[int],
    family: str | None = None,
    images: Sequence[str] = TRAIN_IMAGES,
    dtype: torch.dtype = torch.float32,
    families: dict[str, float] | None = None,
) -> torch.Tensor:
    """Scenes ``indices`` of the global batch of ``step`` in a run seeded ``seed``.

    Scene ``i`` is ``draw_scene(n, scene_seed(seed, step, i), family, images, dtype,
    families)``
    (:func:`~torchtof.recon.synthetic.scene_seed` mixes the three integers), so any split of
    the indices over processes draws the same global batch.

    Returns:
        ``(len(indices), 1, n, n)``.

    Raises:
        ValueError: if ``indices`` is empty (or as :func:`draw_scene`).

    Example:
        >>> draw_scenes(32, seed=0, step=0, indices=range(4)).shape
        torch.Size([4, 1, 32, 32])
    """
    if len(indices) == 0:
        raise ValueError("draw_scenes: expected a non-empty indices, got 0 indices")
    probs = _check_scene_args(n, family, images, families, "draw_scenes")
    return torch.cat(
        [_draw_scene(n, scene_seed(seed, step, int(i)), family, images, dtype, probs)
         for i in indices]
    )


def planar_depth(n: int, seed: int = 0, dtype: torch.dtype = torch.float64) -> torch.Tensor:
    """A fixed piecewise-planar depth map for evaluation: a tilted background plane and three
    tilted axis-aligned rectangles, min–max normalised to ``[0, 1]``, shape ``(1, 1, n, n)``.

    Unlike the ``"planar"`` family of :func:`draw_scene` (random polygons and ellipses, random
    span) the layout is simple and the range is always the full ``[0, 1]``; deterministic for
    a given ``(n, seed)``.

    Raises:
        ValueError: if ``n < 2``.

    Example:
        >>> planar_depth(16).shape
        torch.Size([1, 1, 16, 16])
    """
    if isinstance(n, bool) or not isinstance(n, int) or n < 2:
        raise ValueError(f"planar_depth: expected n to be an int >= 2, got {n!r}")
    g = torch.Generator().manual_seed(int(seed))
    yy, xx = torch.meshgrid(torch.linspace(0, 1, n, dtype=torch.float64),
                            torch.linspace(0, 1, n, dtype=torch.float64), indexing="ij")
    z = 0.8 - 0.2 * xx - 0.1 * yy
    for _ in range(3):
        r0, c0 = (torch.rand(2, generator=g) * 0.6).tolist()
        h, w = (0.2 + torch.rand(2, generator=g) * 0.3).tolist()
        a, b, c = (torch.rand(3, generator=g) * torch.tensor([0.4, 0.3, 0.3])).tolist()
        m = (yy >= r0) & (yy < r0 + h) & (xx >= c0) & (xx < c0 + w)
        z = torch.where(m, 0.1 + a + b * (xx - c0) + c * (yy - r0), z)
    return ((z - z.min()) / (z.max() - z.min()))[None, None].to(dtype)
