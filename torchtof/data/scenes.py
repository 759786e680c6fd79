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
  may give it one);
- ``"user"``: random crops, as ``"natural"``, of the caller's own images
  (:func:`load_images`: image files, ``.npy``/``.npz`` arrays, folders of them), for adapting
  the network to a domain (probability 0 in :data:`FAMILIES`; a run that passes images
  gives it one).

A binary scene is inverted (``1 − x``) with probability 0.3 and gets random levels with
probability 0.3 (the ungated depth bucket gives negative images, paper §3.1).

Every scene comes from its own ``torch.Generator`` seeded by
:func:`~torchtof.recon.synthetic.scene_seed` of ``(seed, step, index)``: a global batch is the
same whichever process draws it (data-parallel training). Evaluation sets draw their scenes
from raw seeds :data:`EVAL_SEED_BASE` and up; a training seed is a 32-bit hash, which can land
there too (15 of the shipped run's 96,000 scene seeds are below 10⁶, three in
``[10⁶, 1.1·10⁶)``), so the separation is checked, not built in:
``benchmarks/eval_learned.py`` verifies that no scene seed of the shipped run is one of its
evaluation seeds.
"""

from __future__ import annotations

import functools
import math
import operator
import os
import weakref
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from .._checks import check_float_dtype, check_int
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
    "load_images",
    "image_files",
    "IMAGE_SUFFIXES",
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
    "user": 0.0,
}
#: scikit-image images drawn for training (bundled with scikit-image, no download): 15
#: names, 14 photographs (``cat`` and ``chelsea`` are the same image in scikit-image, so that
#: one is drawn twice as often; kept so that the shipped weights' recipe is unchanged).
TRAIN_IMAGES: tuple[str, ...] = (
    "coins", "moon", "text", "page", "clock", "coffee", "chelsea", "rocket", "grass",
    "gravel", "brick", "cell", "hubble_deep_field", "immunohistochemistry", "cat",
)
#: scikit-image images kept for evaluation only.
HELD_OUT_IMAGES: tuple[str, ...] = ("camera", "astronaut", "horse", "shepp_logan_phantom")
#: First raw seed of the evaluation sets (``draw_scene(n, EVAL_SEED_BASE + k)``); training's
#: hashed seeds are not kept below it, so evaluations check disjointness (module doc).
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
    return torch.from_numpy(_grey_np(name).copy())  # the cached array is never handed out


#: File types :func:`load_images` reads (the image formats through ``skimage.io.imread``).
IMAGE_SUFFIXES: tuple[str, ...] = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".npy",
                                   ".npz")


def image_files(path: str | os.PathLike, func: str = "image_files") -> list[Path]:
    """The files :func:`load_images` reads for one path: the file itself, or a folder's files
    ending in :data:`IMAGE_SUFFIXES`, sorted by name (``FileNotFoundError``/``ValueError``
    naming the path otherwise)."""
    path = Path(path)
    if path.is_dir():
        files = sorted(f for f in path.iterdir()
                       if f.is_file() and f.suffix.lower() in IMAGE_SUFFIXES)
        if not files:
            raise ValueError(f"{func}: expected images in folder {os.fspath(path)!r} "
                             f"(files ending {', '.join(IMAGE_SUFFIXES)}), found none")
        return files
    if not path.is_file():
        raise FileNotFoundError(f"{func}: no such image file or folder: {os.fspath(path)!r}")
    if path.suffix.lower() not in IMAGE_SUFFIXES:
        raise ValueError(f"{func}: expected an image file ending {', '.join(IMAGE_SUFFIXES)}, "
                         f"got {os.fspath(path)!r}")
    return [path]


def _arrays_of(f: Path) -> list[tuple[str, np.ndarray]]:
    """``(label, 2-D or 3-D array)`` of one file; a 3-D ``.npy``/``.npz`` array is a stack."""
    suffix = f.suffix.lower()
    if suffix == ".npy":
        a = np.load(f, allow_pickle=False)
        return [(os.fspath(f), a)]
    if suffix == ".npz":
        with np.load(f, allow_pickle=False) as z:
            return [(f"{os.fspath(f)}[{k}]", z[k]) for k in sorted(z.files)]
    import skimage.color
    import skimage.io

    img = np.asarray(skimage.io.imread(f))
    if img.ndim == 3 and img.shape[-1] == 2:  # grey + alpha: the grey channel
        img = img[..., 0]
    if img.ndim == 3 and img.shape[-1] == 4:
        img = skimage.color.rgba2rgb(img)
    if img.ndim == 3 and img.shape[-1] == 3:
        img = skimage.color.rgb2gray(img)
    if img.ndim != 2:
        raise ValueError(f"load_images: expected one grey, grey+alpha, RGB or RGBA image in "
                         f"{os.fspath(f)!r}, got an array of shape {img.shape} (store stacks as "
                         ".npy or .npz)")
    return [(os.fspath(f), img)]


def load_images(paths: str | os.PathLike | Sequence[str | os.PathLike],
                func: str = "load_images") -> tuple[torch.Tensor, ...]:
    """The caller's own scenes for the ``"user"`` family, each a float32 ``(H, W)`` tensor
    min–max normalised to ``[0, 1]``.

    ``paths``: files or folders (a folder's files ending in :data:`IMAGE_SUFFIXES`, sorted,
    not recursive). Image files are read with ``skimage.io.imread`` (RGB(A) made grey as for
    the bundled images; grey+alpha: the grey channel); a ``.npy`` holds one 2-D image or a 3-D
    stack ``(K, H, W)``; a ``.npz`` any number of them. Values are any real units (depth in
    metres, counts, intensities): the network is scale-equivariant, so only the shape of the
    image matters. An image file holds one image (a multi-page TIFF stack is refused, or read
    as colour channels by the image reader: store stacks as ``.npy``/``.npz``); keep 16-bit
    depth maps grey (an image reader may reduce 16-bit RGBA to 8 bits) or in ``.npy``.

    Raises:
        FileNotFoundError: for a path that does not exist.
        OSError: for an image file the reader cannot decode.
        ValueError: for an unsupported file, an empty folder, an array that is not 2-D or 3-D,
            a side below 8 pixels, a value that is not finite (mark invalid depth pixels by
            filling them first) or a constant image; the message names the file.

    Example:
        >>> import tempfile, numpy as np
        >>> f = tempfile.NamedTemporaryFile(suffix=".npy", delete=False).name
        >>> np.save(f, np.arange(200.0).reshape(10, 20))
        >>> [tuple(t.shape) for t in load_images(f)], float(load_images(f)[0].max())
        ([(10, 20)], 1.0)
    """
    if isinstance(paths, (str, os.PathLike)):
        paths = [paths]
    if isinstance(paths, (bytes, torch.Tensor)) or not isinstance(paths, Sequence) or not paths:
        raise TypeError(f"{func}: expected paths to be a path or a non-empty sequence of paths, "
                        f"got {type(paths).__name__}")
    out = []
    for path in paths:
        if not isinstance(path, (str, os.PathLike)):
            raise TypeError(f"{func}: expected paths of str or os.PathLike, "
                            f"got {type(path).__name__}")
        for f in image_files(Path(path), func):
            arrays = _arrays_of(f)
            if not arrays:
                raise ValueError(f"{func}: expected at least one image in {os.fspath(f)!r}, "
                                 "got none")
            for label, a in arrays:
                if a.dtype.kind not in "biuf" or a.ndim not in (2, 3):
                    raise ValueError(f"{func}: expected a real 2-D image or 3-D stack in "
                                     f"{label!r}, got dtype {a.dtype} and shape {a.shape}")
                for k, img in enumerate(a if a.ndim == 3 else a[None]):
                    name = label if a.ndim == 2 else f"{label}[{k}]"
                    img = img.astype(np.float64)
                    if min(img.shape) < 8:
                        raise ValueError(f"{func}: expected images of side >= 8, got shape "
                                         f"{img.shape} in {name!r}")
                    if not np.isfinite(img).all():
                        raise ValueError(f"{func}: expected finite values in {name!r} (fill "
                                         "invalid pixels first), got NaN or inf")
                    lo, hi = img.min(), img.max()
                    if not hi > lo:
                        raise ValueError(f"{func}: expected a non-constant image, {name!r} is "
                                         f"constant ({lo:g})")
                    # halves first: hi − lo of values near ±1.8e308 would overflow to inf
                    img = (img / 2 - lo / 2) / (hi / 2 - lo / 2)
                    out.append(torch.from_numpy(img).to(torch.float32))
    return tuple(out)


def _check_user_images(user_images, func: str) -> tuple[torch.Tensor, ...]:
    if isinstance(user_images, torch.Tensor) or not isinstance(user_images, Sequence):
        raise TypeError(f"{func}: expected user_images to be a sequence of (H, W) tensors, "
                        f"got {type(user_images).__name__}")
    for i, t in enumerate(user_images):
        if (not isinstance(t, torch.Tensor) or t.ndim != 2 or not t.is_floating_point()
                or min(t.shape) < 8):
            raise ValueError(f"{func}: expected user_images of floating (H, W) tensors with "
                             f"H, W >= 8 (torchtof.data.load_images), got "
                             f"{getattr(t, 'shape', type(t).__name__)}")
        if not _finite_once(t):
            raise ValueError(f"{func}: expected finite values in user_images[{i}] (fill "
                             "invalid pixels first), got NaN or inf")
    return tuple(user_images)


#: ``id(tensor) -> (weak reference, its _version)`` of user images found finite: a training
#: run draws from the same tensors every step, so each is scanned once (again only if it was
#: modified in place since, which bumps ``_version``).
_FINITE: dict[int, tuple] = {}


def _finite_once(t: torch.Tensor) -> bool:
    seen = _FINITE.get(id(t))
    if seen is not None and seen[0]() is t and seen[1] == t._version:
        return True
    if not bool(torch.isfinite(t).all()):
        return False
    key = id(t)
    _FINITE[key] = (weakref.ref(t, lambda _: _FINITE.pop(key, None)), t._version)
    return True


def _check_seed(seed: object, name: str, func: str, lo: int = 0,
                hi: int | None = 2**64 - 1) -> int:
    """:func:`~torchtof._checks.check_int` (a Python or numpy integer, not a bool nor a float:
    1.5 was truncated to 1), by default in ``[0, 2⁶⁴)``: ``torch.Generator.manual_seed`` also
    takes negative seeds but wraps them (−1 is 2⁶⁴ − 1), so two seeds would give one scene."""
    return check_int(seed, name, func, lo, hi)


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
    return _crop(d, n, grey_image(images[d.i(0, len(images) - 1)]))


def _crop(d: _Draw, n: int, img: torch.Tensor) -> torch.Tensor:
    """A random square crop of ``img (H, W)`` (a quarter of its shorter side to all of it),
    resized to ``n × n`` with anti-aliasing, turned by a random quarter, flipped with
    probability ½, min–max normalised, then given a random contrast span in [0.6, 1]."""
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
    user_images: Sequence[torch.Tensor] = (),
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
        user_images: the ``"user"`` family's images, ``(H, W)`` tensors in ``[0, 1]``
            (:func:`load_images`); needed only where that family can be drawn.

    Returns:
        The scene, shape ``(1, 1, n, n)``.

    Raises:
        TypeError: if ``seed`` is not an int or ``dtype`` not a floating dtype.
        ValueError: if ``n < 8``, ``family`` is unknown, ``images`` is empty, the
            ``"user"`` family can be drawn without ``user_images``, or a user image holds
            NaN/Inf.

    Example:
        >>> draw_scene(32, seed=1, family="planar").shape
        torch.Size([1, 1, 32, 32])
    """
    _check_seed(seed, "seed", "draw_scene")
    probs, user = _check_scene_args(n, family, images, families, user_images, dtype,
                                    "draw_scene")
    return _draw_scene(n, seed, family, images, dtype, probs, user)


def _check_scene_args(n, family, images, families, user_images, dtype,
                      func: str) -> tuple[dict[str, float], tuple[torch.Tensor, ...]]:
    """The checks of :func:`draw_scene` and :func:`draw_scenes` (once per call); returns the
    family probabilities and the user images."""
    if isinstance(n, bool) or not isinstance(n, int) or n < 8:
        raise ValueError(f"{func}: expected n to be an int >= 8, got {n!r}")
    check_float_dtype(dtype, "dtype", func)
    if family is not None and family not in FAMILIES:
        raise ValueError(f"{func}: expected family in {tuple(FAMILIES)} or None, got {family!r}")
    if isinstance(images, str) or not all(isinstance(v, str) for v in images):
        raise TypeError(f"{func}: expected images to be a sequence of image names (e.g. "
                        f"('coins',)), got {images!r}")
    if len(images) == 0:
        raise ValueError(f"{func}: expected a non-empty images, got {images!r}")
    probs = FAMILIES if families is None else check_families(families, func)
    user = _check_user_images(user_images, func)
    if not user and (family == "user" if family is not None else probs.get("user", 0) > 0):
        raise ValueError(f"{func}: expected user_images for the 'user' family "
                         "(torchtof.data.load_images), got none")
    return probs, user


def _draw_scene(n: int, seed: int, family: str | None, images: Sequence[str],
                dtype: torch.dtype, probs: dict[str, float],
                user_images: tuple[torch.Tensor, ...] = ()) -> torch.Tensor:
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
    elif family == "user":
        x = _crop(d, n, user_images[d.i(0, len(user_images) - 1)].to(torch.float32))
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
    user_images: Sequence[torch.Tensor] = (),
) -> torch.Tensor:
    """Scenes ``indices`` of the global batch of ``step`` in a run seeded ``seed``.

    Scene ``i`` is ``draw_scene(n, scene_seed(seed, step, i), family, images, dtype,
    families, user_images)``
    (:func:`~torchtof.recon.synthetic.scene_seed` mixes the three integers), so any split of
    the indices over processes draws the same global batch.

    Returns:
        ``(len(indices), 1, n, n)``.

    Raises:
        TypeError: if ``seed``, ``step`` or an index is not an int (or as :func:`draw_scene`).
        ValueError: if ``indices`` is empty, ``seed``, ``step`` or an index is negative (or
            as :func:`draw_scene`).

    Example:
        >>> draw_scenes(32, seed=0, step=0, indices=range(4)).shape
        torch.Size([4, 1, 32, 32])
    """
    func = "draw_scenes"
    if len(indices) == 0:
        raise ValueError(f"{func}: expected a non-empty indices, got 0 indices")
    seed = _check_seed(seed, "seed", func, lo=0, hi=None)
    step = _check_seed(step, "step", func, lo=0, hi=None)
    idx = []
    for i in indices:
        try:
            idx.append(operator.index(i))
        except TypeError:
            raise TypeError(f"{func}: expected indices of ints, got {i!r}") from None
        if idx[-1] < 0:
            raise ValueError(f"{func}: expected indices >= 0, got {i!r}")
    probs, user = _check_scene_args(n, family, images, families, user_images, dtype, func)
    return torch.cat(
        [_draw_scene(n, scene_seed(seed, step, i), family, images, dtype, probs, user)
         for i in idx]
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
    g = torch.Generator().manual_seed(_check_seed(seed, "seed", "planar_depth"))
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
