"""Built-in scenes: the paper's character 天, depth steps, scikit-image images.

Every scene is built on the fly, deterministically and offline: the character
天 ("sky", the paper's §3.1 object) is rasterised from line segments, the depth
steps come from a seeded generator, and the natural images and the Middlebury
disparity map are the files bundled inside the scikit-image wheel (nothing is
downloaded).

Images are ``(1, 1, n, n)`` tensors, float32 unless ``dtype`` says otherwise. A
:class:`Scene` pairs a reflectance map in ``[0, 1]`` with a depth map in metres;
reflectance 0 means "no return" (the ToF pixel sees no light there).

**Return types** (one rule, checked by the tests): a function that builds what the camera
looks at — :func:`get_scene`, :func:`depth_scene`, :func:`depth_steps`,
:func:`slanted_plane` — returns a :class:`Scene` ``(reflectance, depth_m)``; a function
that draws one image — :func:`sky_character`, :func:`skimage_scene`, :func:`binary_scene`
(reflectance) and :func:`motorcycle_depth` (depth in metres) — returns that ``Tensor``.
Turn an image into a scene with :func:`depth_scene` (a 0/1 mask) or
``Scene(reflectance=x, depth_m=torch.full_like(x, 2.0))``; :func:`get_scene` does so for
every name it knows.

Example:
    >>> scene = get_scene("sky", n=32)
    >>> scene.reflectance.shape, float(scene.depth_m.max())
    (torch.Size([1, 1, 32, 32]), 2.0)
"""

from __future__ import annotations

import numbers
from typing import NamedTuple

import numpy as np
import torch

from torchtof._checks import check_float_dtype, check_int, check_positive, check_rank
from torchtof._memory import check_memory

__all__ = [
    "Scene",
    "SCENES",
    "SKIMAGE_NAMES",
    "sky_character",
    "depth_steps",
    "depth_scene",
    "slanted_plane",
    "skimage_scene",
    "binary_scene",
    "motorcycle_depth",
    "get_scene",
]

#: Names accepted by :func:`get_scene` besides the ``"skimage:<name>"`` and
#: ``"binary:<name>"`` forms (``<name>`` from :data:`SKIMAGE_NAMES`).
SCENES: tuple[str, ...] = ("sky", "steps", "motorcycle", "slanted", "steps_far")

#: Depth levels of the ``"steps_far"`` scene: beyond the 5 m range of 30 MHz (two-frequency
#: unwrapping, :func:`torchtof.recon.dual_frequency_depth`).
FAR_LEVELS: tuple[float, ...] = (3.5, 5.5, 6.5, 8.0)

#: 2-D images whose files ship inside the scikit-image wheel (no download).
SKIMAGE_NAMES: tuple[str, ...] = (
    "astronaut",
    "brick",
    "camera",
    "cell",
    "chelsea",
    "checkerboard",
    "clock",
    "coffee",
    "coins",
    "colorwheel",
    "grass",
    "gravel",
    "horse",
    "hubble_deep_field",
    "immunohistochemistry",
    "logo",
    "microaneurysms",
    "moon",
    "page",
    "retina",
    "rocket",
    "shepp_logan_phantom",
    "text",
)


class Scene(NamedTuple):
    """A scene seen by the ToF camera through the DMD.

    Attributes:
        reflectance: ``(B, 1, H, W)`` in ``[0, 1]``; 0 = no return (no light reaches the sensor).
        depth_m: ``(B, 1, H, W)`` distance in metres; meaningless (set to 0) where reflectance is 0.
    """

    reflectance: torch.Tensor
    depth_m: torch.Tensor


def _check_n(n: object, func: str, lo: int = 8) -> int:
    if isinstance(n, bool) or not isinstance(n, int):
        raise TypeError(f"{func}: expected n to be an int, got {type(n).__name__}")
    if n < lo:
        raise ValueError(f"{func}: expected n >= {lo}, got {n}")
    # the rasterisers hold a few float64 n x n grids (coordinates, masks, the image)
    check_memory(8 * n * n * 8, f"a {n}x{n} scene", func)
    return n


def _check_dtype(dtype: object, func: str) -> None:
    """``None`` (float32) or a floating ``torch.dtype``: an integer or bool dtype would
    truncate the ``[0, 1]`` images and fractional depths."""
    if dtype is not None:
        check_float_dtype(dtype, "dtype", func)


def _check_depth_range(near_m, far_m, func: str) -> tuple[float, float]:
    """Positive ``near_m < far_m`` (metres), as floats; else a ``ValueError`` naming ``func``."""
    lo = check_positive(near_m, "near_m", func)
    hi = check_positive(far_m, "far_m", func)
    if hi <= lo:
        raise ValueError(f"{func}: expected far_m > near_m, got near_m={near_m}, far_m={far_m}")
    return lo, hi


def _to_tensor(a: np.ndarray, dtype: torch.dtype | None, device) -> torch.Tensor:
    t = torch.as_tensor(np.ascontiguousarray(a), dtype=torch.float64)
    return t.to(dtype=dtype or torch.float32, device=device)[None, None]


def _segments_mask(n: int, segments: np.ndarray, half_width: float) -> np.ndarray:
    """Pixels of an ``n×n`` grid whose centre lies within ``half_width`` of a segment.

    ``segments`` is ``(S, 4)`` rows ``(x0, y0, x1, y1)`` in pixel units (pixel ``i``
    spans ``[i, i + 1)``, its centre is ``i + 0.5``). Vectorised over pixels and segments.
    """
    c = np.arange(n, dtype=np.float64) + 0.5
    py, px = np.meshgrid(c, c, indexing="ij")
    p = np.stack([px, py], -1)[..., None, :]  # (n, n, 1, 2)
    a, b = segments[:, :2], segments[:, 2:]  # (S, 2)
    ab = b - a
    t = np.clip(((p - a) * ab).sum(-1) / (ab * ab).sum(-1), 0.0, 1.0)  # (n, n, S)
    dist = np.linalg.norm(p - (a + t[..., None] * ab), axis=-1)
    return (dist <= half_width + 1e-6).any(-1)


def sky_character(
    n: int = 32, dtype: torch.dtype | None = None, device: torch.device | str | None = None
) -> torch.Tensor:
    """The Chinese character 天 ("sky"), the binary object of the paper (§3.1, Fig. 5a).

    Drawn procedurally from five strokes rasterised by a distance-to-segment test
    on the pixel grid: a short upper bar, a long middle bar, a vertical stroke from
    the upper bar down to the middle bar, and two legs spreading left-down and
    right-down from the crossing point. Stroke width ``w = max(1, round(n / 16))`` px
    (the vertical stroke is ``w + 1`` px when ``n - w`` is odd, to stay centred); the
    glyph is centred with a margin of about ``n / 10`` and is left-right symmetric.

    Args:
        n: image side in pixels, ``>= 8`` (the paper uses 32).
        dtype: floating dtype (default float32).
        device: target device.

    Returns:
        Binary image, 1 on the strokes and 0 elsewhere.

    Raises:
        TypeError: if ``n`` is not an int or ``dtype`` is not a floating dtype.
        ValueError: if ``n < 8``.

    Shape:
        - Output: :math:`(1, 1, n, n)`.

    Example:
        >>> x = sky_character(32)
        >>> x.shape, sorted(x.unique().tolist())
        (torch.Size([1, 1, 32, 32]), [0.0, 1.0])
    """
    _check_n(n, "sky_character")
    _check_dtype(dtype, "sky_character")
    w = max(1, round(n / 16))
    # Axis-aligned bars are snapped so that they cover exactly w rows: to a pixel
    # boundary for even w, to a pixel centre for odd w.
    off = 0.0 if w % 2 == 0 else 0.5

    def row(u: float) -> float:
        return float(np.floor(u * n)) + off

    xc = n / 2.0
    y_top, y_mid, y_bot = row(0.2), row(0.46), 0.86 * n
    segments = np.array(
        [
            [0.26 * n, y_top, n - 0.26 * n, y_top],  # upper bar (shorter)
            [0.10 * n, y_mid, n - 0.10 * n, y_mid],  # middle bar
            [xc, y_top, xc, y_mid],  # vertical, upper bar to crossing
            [xc, y_mid, 0.14 * n, y_bot],  # left leg
            [xc, y_mid, n - 0.14 * n, y_bot],  # right leg
        ],
        dtype=np.float64,
    )
    return _to_tensor(_segments_mask(n, segments, w / 2.0), dtype, device)


def depth_scene(
    object_mask: torch.Tensor, object_m: float = 2.0, background_m: float | None = None
) -> Scene:
    r"""Put a binary object at a given distance, optionally in front of a background plane.

    .. math::
        z(u) = z_\text{obj}\,m(u) + z_\text{bg}\,(1 - m(u))

    With ``background_m=None`` nothing returns light outside the object (the
    paper's setting, §3.1: the DMD's dark pixels send no light to the camera): the
    reflectance is the mask itself and the depth is set to 0 there. With a
    background plane every pixel returns light (reflectance 1).

    Args:
        object_mask: binary mask (bool, or float with values 0/1), 1 on the object.
        object_m: object distance in metres, ``> 0``.
        background_m: background distance in metres, ``> 0``, or ``None`` for no return.

    Returns:
        :class:`Scene` with the dtype of ``object_mask`` (float32 for a bool mask).

    Raises:
        TypeError: if ``object_mask`` is not a tensor, or the distances are not numbers.
        ValueError: if ``object_mask`` is not rank 4 or holds values other than 0/1, or a
            distance is not positive.

    Shape:
        - object_mask: :math:`(B, 1, H, W)`.
        - Output: two tensors of shape :math:`(B, 1, H, W)`.

    Example:
        >>> s = depth_scene(sky_character(16), object_m=2.0, background_m=4.0)
        >>> sorted(s.depth_m.unique().tolist())
        [2.0, 4.0]
    """
    func = "depth_scene"
    if not isinstance(object_mask, torch.Tensor):
        raise TypeError(
            f"{func}: expected object_mask to be a torch.Tensor, got {type(object_mask).__name__}"
        )
    m = object_mask.to(torch.float32) if object_mask.dtype == torch.bool else object_mask
    check_rank(m, 4, "object_mask", func, "(B, 1, H, W)")
    if m.shape[1] != 1:
        raise ValueError(
            f"{func}: expected object_mask of shape (B, 1, H, W), got {tuple(object_mask.shape)}"
        )
    if not m.is_meta and not bool(((m == 0) | (m == 1)).all()):  # meta: shapes only
        raise ValueError(f"{func}: expected object_mask to hold only 0 and 1")
    z_obj = check_positive(object_m, "object_m", func)
    if background_m is None:
        return Scene(reflectance=m.clone(), depth_m=m * z_obj)
    z_bg = check_positive(background_m, "background_m", func)
    return Scene(reflectance=torch.ones_like(m), depth_m=m * z_obj + (1 - m) * z_bg)


def depth_steps(
    n: int = 32,
    levels: tuple[float, ...] = (1.5, 2.0, 2.5, 3.0),
    seed: int = 0,
    dtype: torch.dtype | None = None,
    device: torch.device | str | None = None,
) -> Scene:
    """A piecewise-constant depth scene: rectangles and disks at different distances.

    The farthest level is the background plane; each other level gets one shape
    (rectangles and disks alternate, nearest drawn last so it occludes the others),
    with size and position drawn from ``numpy.random.default_rng(seed)``. Every pixel
    returns light (reflectance 1).

    Args:
        n: image side in pixels, ``>= 8``.
        levels: at least two positive distances in metres.
        seed: seed of the generator; the same seed gives the same scene.
        dtype: floating dtype (default float32).
        device: target device.

    Returns:
        :class:`Scene` with reflectance 1 and depth values taken from ``levels``.

    Raises:
        TypeError: if ``n`` is not an int or ``dtype`` is not a floating dtype.
        ValueError: if ``n < 8``, fewer than two levels, or a level is not positive.

    Shape:
        - Output: two tensors of shape :math:`(1, 1, n, n)`.

    Example:
        >>> s = depth_steps(32)
        >>> sorted(s.depth_m.unique().tolist())
        [1.5, 2.0, 2.5, 3.0]
    """
    func = "depth_steps"
    _check_n(n, func)
    _check_dtype(dtype, func)
    if len(levels) < 2:
        raise ValueError(f"{func}: expected at least two levels, got {tuple(levels)}")
    lv = sorted((check_positive(v, "levels", func) for v in levels), reverse=True)
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral):
        raise TypeError(f"{func}: expected seed to be an int, got {type(seed).__name__}")
    if seed < 0:
        raise ValueError(f"{func}: expected seed >= 0, got {seed}")
    rng = np.random.default_rng(seed)
    c = np.arange(n, dtype=np.float64) + 0.5
    yy, xx = np.meshgrid(c, c, indexing="ij")
    depth = np.full((n, n), lv[0])
    for k, z in enumerate(lv[1:]):
        if k % 2 == 0:
            h, w = rng.integers(n // 4, n // 2 + 1, size=2)
            top, left = rng.integers(0, n - h + 1), rng.integers(0, n - w + 1)
            mask = (yy > top) & (yy < top + h) & (xx > left) & (xx < left + w)
        else:
            r = rng.uniform(n / 8, n / 4)
            cy, cx = rng.uniform(r, n - r, size=2)
            mask = (yy - cy) ** 2 + (xx - cx) ** 2 <= r * r
        depth[mask] = z
    return Scene(
        reflectance=_to_tensor(np.ones((n, n)), dtype, device),
        depth_m=_to_tensor(depth, dtype, device),
    )


def slanted_plane(
    n: int = 32,
    near_m: float = 1.5,
    far_m: float = 3.5,
    angle_deg: float = 30.0,
    dtype: torch.dtype | None = None,
    device: torch.device | str | None = None,
) -> Scene:
    r"""A tilted plane: depth rises linearly across the image along a direction.

    .. math::
        z(u) = z_\text{near} + (z_\text{far} - z_\text{near})\,
        \frac{s(u) - \min s}{\max s - \min s}, \quad s(u) = x\cos α + y\sin α

    over the pixel centres, so the nearest corner is at ``near_m`` and the farthest at
    ``far_m``. Reflectance 1 everywhere.

    Args:
        n: image side in pixels, ``>= 8``.
        near_m, far_m: depth range in metres, ``0 < near_m < far_m``.
        angle_deg: direction ``α`` of the depth gradient (0: left to right, 90: top down).
        dtype: floating dtype (default float32).
        device: target device.

    Returns:
        :class:`Scene`.

    Raises:
        TypeError: if ``n`` is not an int or ``dtype`` is not a floating dtype.
        ValueError: if ``n < 8`` or the range is invalid.

    Shape:
        - Output: two tensors of shape :math:`(1, 1, n, n)`.

    Example:
        >>> s = slanted_plane(16, 1.0, 2.0, angle_deg=0.0)
        >>> s.depth_m[0, 0, 0, 0].item(), s.depth_m[0, 0, 0, -1].item()
        (1.0, 2.0)
    """
    func = "slanted_plane"
    _check_n(n, func)
    _check_dtype(dtype, func)
    lo, hi = _check_depth_range(near_m, far_m, func)
    if isinstance(angle_deg, bool) or not isinstance(angle_deg, (int, float)):
        raise TypeError(f"{func}: expected angle_deg to be a number, got {angle_deg!r}")
    if not np.isfinite(angle_deg):
        raise ValueError(f"{func}: expected a finite angle_deg, got {angle_deg}")
    a = np.deg2rad(float(angle_deg))
    c = np.arange(n, dtype=np.float64)
    yy, xx = np.meshgrid(c, c, indexing="ij")
    s = xx * np.cos(a) + yy * np.sin(a)
    z = lo + (hi - lo) * (s - s.min()) / (s.max() - s.min())
    return Scene(
        reflectance=_to_tensor(np.ones((n, n)), dtype, device),
        depth_m=_to_tensor(z, dtype, device),
    )


def _load_grey(name: str, func: str) -> np.ndarray:
    """A bundled scikit-image image as a float64 grey array in [0, 1]."""
    import skimage.color
    import skimage.data
    import skimage.util

    if name not in SKIMAGE_NAMES:
        raise ValueError(f"{func}: expected name in {SKIMAGE_NAMES}, got {name!r}")
    img = np.asarray(getattr(skimage.data, name)())
    if img.ndim == 3 and img.shape[-1] == 4:
        img = skimage.color.rgba2rgb(img)
    if img.ndim == 3:
        img = skimage.color.rgb2gray(img)
    return skimage.util.img_as_float64(img)


def _square_resize(img: np.ndarray, n: int) -> np.ndarray:
    """Centre-crop to a square, then resize to ``n×n`` with anti-aliasing.

    Large images are first reduced by an integer factor ``s // (2n)`` with a block
    mean (a box anti-aliasing filter, exact and fast), then resized by
    ``skimage.transform.resize(..., anti_aliasing=True)``.
    """
    from skimage.transform import downscale_local_mean, resize

    h, w = img.shape
    s = min(h, w)
    top, left = (h - s) // 2, (w - s) // 2
    img = img[top : top + s, left : left + s]
    f = s // (2 * n)
    if f > 1:
        img = downscale_local_mean(img[: s - s % f, : s - s % f], (f, f))
    return resize(img, (n, n), anti_aliasing=True)


def skimage_scene(
    name: str = "camera",
    n: int = 32,
    dtype: torch.dtype | None = None,
    device: torch.device | str | None = None,
) -> torch.Tensor:
    """A grey scikit-image sample image, centre-cropped to a square and resized to ``n×n``.

    Colour images are converted with ``skimage.color.rgb2gray`` (alpha composited on
    white first); resizing uses ``skimage.transform.resize`` with anti-aliasing.

    Args:
        name: one of :data:`SKIMAGE_NAMES` (files bundled with scikit-image, no download).
        n: image side in pixels, ``>= 8``.
        dtype: floating dtype (default float32).
        device: target device.

    Returns:
        Grey image in ``[0, 1]``.

    Raises:
        TypeError: if ``n`` is not an int or ``dtype`` is not a floating dtype.
        ValueError: if ``name`` is unknown or ``n < 8``.

    Shape:
        - Output: :math:`(1, 1, n, n)`.

    Example:
        >>> skimage_scene("camera", 32).shape
        torch.Size([1, 1, 32, 32])
    """
    func = "skimage_scene"
    _check_n(n, func)
    _check_dtype(dtype, func)
    img = np.clip(_square_resize(_load_grey(name, func), n), 0.0, 1.0)
    return _to_tensor(img, dtype, device)


def binary_scene(
    name: str = "horse",
    n: int = 32,
    dtype: torch.dtype | None = None,
    device: torch.device | str | None = None,
) -> torch.Tensor:
    """A binary silhouette from a scikit-image sample image.

    The grey image is resized as in :func:`skimage_scene` and thresholded with Otsu's
    method (Otsu, 1979); the class that covers most of the image border is the
    background, so the object is 1 whatever its brightness (``horse`` is a dark
    horse on white).

    Args:
        name: one of :data:`SKIMAGE_NAMES`.
        n: image side in pixels, ``>= 8``.
        dtype: floating dtype (default float32).
        device: target device.

    Returns:
        Binary image, 1 on the object.

    Raises:
        TypeError: if ``n`` is not an int or ``dtype`` is not a floating dtype.
        ValueError: if ``name`` is unknown, ``n < 8``, or the image is constant.

    Shape:
        - Output: :math:`(1, 1, n, n)`.

    Example:
        >>> x = binary_scene("horse", 32)
        >>> sorted(x.unique().tolist())
        [0.0, 1.0]
    """
    from skimage.filters import threshold_otsu

    func = "binary_scene"
    _check_n(n, func)
    _check_dtype(dtype, func)
    img = _square_resize(_load_grey(name, func), n)
    if np.ptp(img) == 0:
        raise ValueError(f"{func}: image {name!r} is constant at n={n}, nothing to threshold")
    mask = img > threshold_otsu(img)
    border = np.concatenate([mask[0], mask[-1], mask[1:-1, 0], mask[1:-1, -1]])
    if border.mean() > 0.5:
        mask = ~mask
    return _to_tensor(mask, dtype, device)


def motorcycle_depth(
    n: int = 32,
    near_m: float = 1.0,
    far_m: float = 4.0,
    dtype: torch.dtype | None = None,
    device: torch.device | str | None = None,
) -> torch.Tensor:
    """A real depth map: the Middlebury "motorcycle" disparity bundled with scikit-image.

    ``skimage.data.stereo_motorcycle()`` gives the left view's disparity ``δ`` (pixels;
    invalid pixels are ``inf``). Invalid or non-positive disparities take the value
    of the nearest valid pixel (Euclidean distance transform), depth follows
    triangulation ``z = f B / δ`` (Scharstein et al., 2014), is centre-cropped to a
    square, resized with anti-aliasing, and mapped affinely onto ``[near_m, far_m]``
    (nearest point → ``near_m``, farthest → ``far_m``).

    Args:
        n: image side in pixels, ``>= 8``.
        near_m: distance of the nearest point in metres, ``> 0``.
        far_m: distance of the farthest point in metres, ``> near_m``.
        dtype: floating dtype (default float32).
        device: target device.

    Returns:
        Depth map in metres, within ``[near_m, far_m]``, no NaN.

    Raises:
        TypeError: if ``n`` is not an int or ``dtype`` is not a floating dtype.
        ValueError: if ``n < 8`` or the range is invalid.

    Shape:
        - Output: :math:`(1, 1, n, n)`.

    Example:
        >>> z = motorcycle_depth(32)
        >>> 1.0 <= float(z.min()) and float(z.max()) <= 4.0
        True
    """
    import skimage.data
    from scipy.ndimage import distance_transform_edt

    func = "motorcycle_depth"
    _check_n(n, func)
    _check_dtype(dtype, func)
    lo, hi = _check_depth_range(near_m, far_m, func)
    disp = np.asarray(skimage.data.stereo_motorcycle()[2], dtype=np.float64)
    invalid = ~np.isfinite(disp) | (disp <= 0)
    idx = distance_transform_edt(invalid, return_distances=False, return_indices=True)
    disp = disp[tuple(idx)]
    z = _square_resize(1.0 / disp, n)
    z = (z - z.min()) / (z.max() - z.min())
    return _to_tensor(lo + (hi - lo) * z, dtype, device)


def get_scene(
    name: str = "sky",
    n: int = 32,
    object_m: float = 2.0,
    dtype: torch.dtype | None = None,
    device: torch.device | str | None = None,
) -> Scene:
    """Scene registry used by the experiment, the CLI and the examples.

    - ``"sky"``: the binary 天 at ``object_m``, no return elsewhere (the paper's object).
    - ``"steps"``: :func:`depth_steps` with its defaults.
    - ``"motorcycle"``: :func:`motorcycle_depth` in ``[1, 4]`` m, reflectance 1.
    - ``"slanted"``: :func:`slanted_plane` from 1.5 to 3.5 m.
    - ``"steps_far"``: :func:`depth_steps` at :data:`FAR_LEVELS` (3.5–8 m, beyond 30 MHz's 5 m).
    - ``"skimage:<name>"``: :func:`skimage_scene` as reflectance, flat at ``object_m``.
    - ``"binary:<name>"``: :func:`binary_scene` at ``object_m``, no return elsewhere.

    Args:
        name: a name from :data:`SCENES` or a prefixed form above.
        n: image side in pixels, ``>= 8``.
        object_m: distance in metres of the flat scenes (``sky``, ``skimage:``, ``binary:``).
        dtype: floating dtype (default float32).
        device: target device.

    Returns:
        :class:`Scene`.

    Raises:
        TypeError: if ``dtype`` is not a floating dtype.
        ValueError: for an unknown name or invalid ``n``.

    Shape:
        - Output: two tensors of shape :math:`(1, 1, n, n)`.

    Example:
        >>> get_scene("skimage:camera", 16).reflectance.shape
        torch.Size([1, 1, 16, 16])
    """
    check_int(n, "n", "get_scene", lo=8)  # named here, not as the builder's
    check_positive(object_m, "object_m", "get_scene")
    _check_dtype(dtype, "get_scene")
    kw = {"dtype": dtype, "device": device}
    if name == "sky":
        return depth_scene(sky_character(n, **kw), object_m=object_m)
    if name == "steps":
        return depth_steps(n, **kw)
    if name == "motorcycle":
        z = motorcycle_depth(n, **kw)
        return Scene(reflectance=torch.ones_like(z), depth_m=z)
    if name == "slanted":
        return slanted_plane(n, **kw)
    if name == "steps_far":
        return depth_steps(n, levels=FAR_LEVELS, **kw)
    if isinstance(name, str) and name.startswith("skimage:"):
        x = skimage_scene(name.split(":", 1)[1], n, **kw)
        return Scene(reflectance=x, depth_m=torch.full_like(x, object_m))
    if isinstance(name, str) and name.startswith("binary:"):
        return depth_scene(binary_scene(name.split(":", 1)[1], n, **kw), object_m=object_m)
    raise ValueError(
        f"get_scene: expected name in {SCENES} or 'skimage:<name>'/'binary:<name>' with <name> "
        f"in SKIMAGE_NAMES, got {name!r}"
    )
