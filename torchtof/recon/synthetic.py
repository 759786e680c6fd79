"""Synthetic training scenes for the unrolled TVAL3, generated on the fly.

Three families, all ``n × n`` images in ``[0, 1]``, the kinds of object the paper
images (§3.1: a binary character, depth steps):

- ``"shapes"``: binary unions of random ellipses, rotated rectangles and triangles,
  some cut out of the others (holes);
- ``"strokes"``: character-like binary glyphs, 3–6 thick line segments (horizontal
  and vertical bars, diagonals) rasterised by a distance-to-segment test, the way
  :func:`torchtof.scenes.sky_character` draws 天;
- ``"depth"``: piecewise-constant depth maps, a background level and 2–5 occluding
  shapes at random levels (the ``depth_steps`` scenes with continuous levels).

A binary scene is inverted (``1 − x``) with probability 0.3: without the depth gate the
depth bucket gives a negative image (paper §3.1).

Every scene comes from its own ``torch.Generator`` seeded by :func:`scene_seed` from
``(seed, step, index)``, so a global batch is the same whether one process draws it or
several processes each draw a shard of it (data-parallel training, :mod:`.train`), and a
held-out set is a different ``seed`` (training never sees the scikit-image silhouettes of
:func:`torchtof.scenes.binary_scene` either).

Measurement noise (:func:`measurement_noise`) is a documented Gaussian approximation of
the ToF noise on a differential (±1 Hadamard) bucket: ``y = y⁺ − y⁻`` where the two DMD
halves together always light the whole scene, so the shot-noise variance
``var(y⁺) + var(y⁻) ∝ y⁺ + y⁻`` is the same for every pattern, and read noise adds a
constant too (Lange & Seitz 2001). Its standard deviation is a fraction ``level`` of the
measurement spread ``max(y) − min(y)`` (``level = 0.01``: 1 % of the spread).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch

from .._checks import check_in_range, check_rank, check_tensor

__all__ = ["KINDS", "scene_seed", "synthetic_scene", "synthetic_scenes", "measurement_noise"]

#: Scene families drawn by :func:`synthetic_scene` and their probabilities.
KINDS: dict[str, float] = {"shapes": 0.35, "strokes": 0.3, "depth": 0.35}


def scene_seed(seed: int, step: int, index: int) -> int:
    """Seed of scene ``index`` of the batch drawn at training ``step`` (32-bit).

    ``numpy.random.SeedSequence`` mixes the three integers (O'Neill's PCG seeding), so
    nearby ``(step, index)`` pairs give unrelated streams and ``seed`` separates training
    from held-out data.

    Args:
        seed: base seed of the run (training or evaluation), ``>= 0``.
        step: training step (or 0), ``>= 0``.
        index: position of the scene in the global batch, ``>= 0``.

    Returns:
        A seed in ``[0, 2³²)``.

    Raises:
        ValueError: if an argument is negative.

    Example:
        >>> scene_seed(0, 1, 2) == scene_seed(0, 1, 2) != scene_seed(0, 2, 1)
        True
    """
    for name, v in (("seed", seed), ("step", step), ("index", index)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0:
            raise ValueError(f"scene_seed: expected {name} to be an int >= 0, got {v!r}")
    return int(np.random.SeedSequence([int(seed), int(step), int(index)]).generate_state(1)[0])


class _Draw:
    """Uniform draws from one ``torch.Generator`` (float64 on CPU)."""

    def __init__(self, seed: int) -> None:
        self.g = torch.Generator().manual_seed(seed)

    def u(self, lo: float, hi: float) -> float:
        return lo + (hi - lo) * float(torch.rand((), generator=self.g, dtype=torch.float64))

    def i(self, lo: int, hi: int) -> int:
        """Integer in ``[lo, hi]``."""
        return int(torch.randint(lo, hi + 1, (), generator=self.g))


def _grid(n: int) -> tuple[torch.Tensor, torch.Tensor]:
    c = torch.arange(n, dtype=torch.float64) + 0.5
    return torch.meshgrid(c, c, indexing="ij")  # yy, xx


def _shape_mask(d: _Draw, n: int, yy: torch.Tensor, xx: torch.Tensor) -> torch.Tensor:
    """One random ellipse, rotated rectangle or triangle (bool ``(n, n)``)."""
    kind = d.i(0, 2)
    if kind == 2:  # triangle: same-sign cross products of the three edges
        p = [(d.u(0.05 * n, 0.95 * n), d.u(0.05 * n, 0.95 * n)) for _ in range(3)]
        s = [
            (x1 - x0) * (yy - y0) - (y1 - y0) * (xx - x0)
            for (x0, y0), (x1, y1) in zip(p, p[1:] + p[:1], strict=True)
        ]
        return ((s[0] >= 0) & (s[1] >= 0) & (s[2] >= 0)) | ((s[0] <= 0) & (s[1] <= 0) & (s[2] <= 0))
    cx, cy = d.u(0.15 * n, 0.85 * n), d.u(0.15 * n, 0.85 * n)
    a, b = d.u(0.08 * n, 0.32 * n), d.u(0.08 * n, 0.32 * n)
    th = d.u(0.0, math.pi) if d.u(0.0, 1.0) < 0.5 else 0.0
    dx, dy = xx - cx, yy - cy
    xr = dx * math.cos(th) + dy * math.sin(th)
    yr = -dx * math.sin(th) + dy * math.cos(th)
    if kind == 0:
        return (xr / a) ** 2 + (yr / b) ** 2 <= 1.0
    return (xr.abs() <= a) & (yr.abs() <= b)


def _shapes(d: _Draw, n: int, yy: torch.Tensor, xx: torch.Tensor) -> torch.Tensor:
    m = _shape_mask(d, n, yy, xx)
    for _ in range(d.i(0, 3)):
        s = _shape_mask(d, n, yy, xx)
        m = m & ~s if d.u(0.0, 1.0) < 0.25 else m | s
    return m


def _strokes(d: _Draw, n: int, yy: torch.Tensor, xx: torch.Tensor) -> torch.Tensor:
    half = 0.5 * max(1.0, n / 16) * d.u(0.8, 1.6)
    lo, hi = 0.1 * n, 0.9 * n
    m = torch.zeros_like(xx, dtype=torch.bool)
    for _ in range(d.i(3, 6)):
        kind = d.i(0, 2)
        if kind == 0:  # horizontal bar
            y0 = y1 = d.u(lo, hi)
            x0, x1 = d.u(lo, 0.5 * n), d.u(0.5 * n, hi)
        elif kind == 1:  # vertical bar
            x0 = x1 = d.u(lo, hi)
            y0, y1 = d.u(lo, 0.5 * n), d.u(0.5 * n, hi)
        else:  # diagonal
            x0, y0, x1, y1 = (d.u(lo, hi) for _ in range(4))
        ax, ay = x1 - x0, y1 - y0
        t = (((xx - x0) * ax + (yy - y0) * ay) / max(ax * ax + ay * ay, 1e-12)).clamp(0.0, 1.0)
        dist = torch.hypot(xx - (x0 + t * ax), yy - (y0 + t * ay))
        m = m | (dist <= half + 1e-6)
    return m


def _depth(d: _Draw, n: int, yy: torch.Tensor, xx: torch.Tensor) -> torch.Tensor:
    x = torch.full_like(xx, d.u(0.0, 1.0))
    for _ in range(d.i(2, 5)):
        x = torch.where(_shape_mask(d, n, yy, xx), d.u(0.0, 1.0), x)
    return x


def synthetic_scene(
    n: int, seed: int, kind: str | None = None, dtype: torch.dtype = torch.float32
) -> torch.Tensor:
    """One synthetic scene in ``[0, 1]`` drawn from its own seeded generator.

    Args:
        n: image side in pixels, ``>= 4``.
        seed: seed of the scene's generator (see :func:`scene_seed`).
        kind: one of :data:`KINDS`, or ``None`` to draw the family with the
            probabilities of :data:`KINDS`.
        dtype: floating dtype of the result.

    Returns:
        The scene; binary for ``"shapes"``/``"strokes"``, piecewise constant for ``"depth"``.

    Raises:
        ValueError: if ``n < 4`` or ``kind`` is unknown.

    Shape:
        - Output: :math:`(1, 1, n, n)`.

    Example:
        >>> x = synthetic_scene(16, seed=3, kind="strokes")
        >>> x.shape, sorted(x.unique().tolist()) in ([0.0, 1.0], [0.0], [1.0])
        (torch.Size([1, 1, 16, 16]), True)
    """
    if isinstance(n, bool) or not isinstance(n, int) or n < 4:
        raise ValueError(f"synthetic_scene: expected n to be an int >= 4, got {n!r}")
    if kind is not None and kind not in KINDS:
        raise ValueError(f"synthetic_scene: expected kind in {tuple(KINDS)} or None, got {kind!r}")
    d = _Draw(seed)
    r = d.u(0.0, 1.0)
    if kind is None:
        cum = 0.0
        for kind, p in KINDS.items():  # noqa: B007 - the last kind catches rounding
            cum += p
            if r < cum:
                break
    yy, xx = _grid(n)
    if kind == "depth":
        x = _depth(d, n, yy, xx)
    else:
        x = (_shapes if kind == "shapes" else _strokes)(d, n, yy, xx).to(torch.float64)
        if d.u(0.0, 1.0) < 0.3:
            x = 1.0 - x
    return x.to(dtype)[None, None]


def synthetic_scenes(
    n: int,
    seed: int,
    step: int,
    indices: Sequence[int],
    kind: str | None = None,
    dtype: torch.dtype = torch.float32,
) -> torch.Tensor:
    """The scenes ``indices`` of the global batch drawn at ``step`` of a run seeded ``seed``.

    Scene ``i`` is ``synthetic_scene(n, scene_seed(seed, step, i), kind)``, so any split of
    the indices over processes yields, together, the same global batch.

    Args:
        n: image side in pixels, ``>= 4``.
        seed: base seed of the run.
        step: training step.
        indices: positions in the global batch (non-empty).
        kind: family (see :func:`synthetic_scene`) or ``None`` for the mix.
        dtype: floating dtype of the result.

    Returns:
        The scenes stacked along the batch axis.

    Raises:
        ValueError: if ``indices`` is empty or an argument is invalid.

    Shape:
        - Output: :math:`(\\text{len(indices)}, 1, n, n)`.

    Example:
        >>> synthetic_scenes(16, seed=0, step=0, indices=range(3)).shape
        torch.Size([3, 1, 16, 16])
    """
    if len(indices) == 0:
        raise ValueError("synthetic_scenes: expected a non-empty indices, got 0 indices")
    return torch.cat(
        [synthetic_scene(n, scene_seed(seed, step, int(i)), kind, dtype) for i in indices]
    )


def measurement_noise(
    y: torch.Tensor, level: torch.Tensor | float, generator: torch.Generator | None = None
) -> torch.Tensor:
    """Add Gaussian noise of standard deviation ``level · (max y − min y)`` per measurement
    vector (the ToF bucket noise approximation of the module docstring).

    .. math::
        \\tilde y_i = y_i + \\ell\\,(\\max_j y_j - \\min_j y_j)\\,\\varepsilon_i,
        \\qquad \\varepsilon_i \\sim \\mathcal N(0, 1)

    Args:
        y: measurements.
        level: noise level ``ℓ >= 0``: a number, or a tensor broadcastable to ``(B, C, 1)``.
        generator: optional generator of the draws (CPU generator for CPU tensors).

    Returns:
        Noisy measurements (a new tensor; ``y`` is not modified).

    Raises:
        TypeError: if ``y`` is not a floating tensor.
        ValueError: if ``y`` is not ``(B, C, M)`` or ``level`` is negative.

    Shape:
        - y: :math:`(B, C, M)`; output: the same.

    Example:
        >>> y = torch.zeros(2, 1, 8)
        >>> bool((measurement_noise(y, 0.01) == 0).all())
        True
    """
    func = "measurement_noise"
    check_tensor(y, "y", func)
    check_rank(y, 3, "y", func, "(B, C, M)")
    if isinstance(level, torch.Tensor):
        if bool((level < 0).any()):
            raise ValueError(f"{func}: expected level >= 0, got a negative entry")
        level = level.to(y)
    else:
        check_in_range(level, 0.0, math.inf, "level", func)
    spread = y.amax(dim=-1, keepdim=True) - y.amin(dim=-1, keepdim=True)
    eps = torch.randn(y.shape, generator=generator, dtype=y.dtype, device=y.device)
    return y + level * spread * eps
