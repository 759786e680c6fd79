"""Bucket noise for training and evaluation: Gaussian, shot and stray light, seeded per sample.

Three sources, all on the orthonormal measurements ``y = A x`` of a
:class:`~torchtof.operators.Hadamard` operator:

- **Gaussian** (read noise and the differential shot noise together): std ``level · (max y −
  min y)`` per measurement vector, the package's convention
  (:func:`~torchtof.recon.synthetic.measurement_noise`): with complementary DMD frames
  ``y⁺ + y⁻`` lights the whole scene for every pattern, so the shot variance of ``y⁺ − y⁻``
  is the same for every pattern;
- **shot**: the two DMD frames ``y^± = (Σx ± n·(Ax))/2``
  (:class:`~torchtof.operators.DMDSplit`) are photon counts ``photons · y^±`` plus the stray
  count, drawn by the Gaussian approximation of the Poisson law (variance = mean), then
  combined into ``(y⁺ − y⁻)/n``;
- **stray light**: a count ``stray · photons · Σx / 2`` added to both frames of every
  pattern (light that does not come through the DMD: it cancels in ``y⁺ − y⁻`` but adds its
  shot noise).

:func:`training_noise` draws a sample's noise recipe (clean with probability ``p_clean``,
else a log-uniform Gaussian level and sometimes shot noise with stray light) from the
sample's own generator.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch

from .._checks import check_in_range, check_positive, check_rank
from ..operators.hadamard import Hadamard
from ..operators.split import DMDSplit, combine_split

__all__ = ["NoiseRecipe", "noisy_buckets", "training_noise", "TRAIN_LEVELS"]

#: Gaussian levels (fraction of the measurement spread) drawn log-uniformly for training.
TRAIN_LEVELS = (0.002, 0.06)


class NoiseRecipe(NamedTuple):
    """Noise of one sample.

    Attributes:
        level: Gaussian std as a fraction of the measurement spread (``>= 0``).
        photons: photo-electrons per unit of scene per pixel (``None``: no shot noise).
        stray: stray-light count per frame as a fraction of the mean frame (``>= 0``).
    """

    level: float = 0.0
    photons: float | None = None
    stray: float = 0.0


def _check_recipe(r: object, name: str, func: str) -> None:
    """``r`` a :class:`NoiseRecipe` with finite ``level >= 0``, ``stray >= 0`` and ``photons``
    ``None`` or finite ``> 0`` (a NaN level gave clean buckets, an inf one inf buckets)."""
    if not isinstance(r, NoiseRecipe):
        raise TypeError(f"{func}: expected {name} to be a NoiseRecipe, got {type(r).__name__}")
    check_positive(r.level, f"{name}.level", func, strict=False)
    check_positive(r.stray, f"{name}.stray", func, strict=False)
    if r.photons is not None:
        check_positive(r.photons, f"{name}.photons", func)


def noisy_buckets(
    A: Hadamard, x: torch.Tensor, recipes: list[NoiseRecipe], generators: list[torch.Generator]
) -> torch.Tensor:
    """``A x`` with each sample's noise (module docstring), in the units of ``A x``.

    Args:
        A: the Hadamard operator.
        x: scenes ``(B, C, n, n)``.
        recipes: one :class:`NoiseRecipe` per sample.
        generators: one CPU generator per sample (its noise stream).

    Returns:
        ``(B, C, M)`` noisy orthonormal measurements.

    Raises:
        TypeError: if ``A`` is not a :class:`Hadamard`, ``x`` not a floating tensor, a
            recipe not a :class:`NoiseRecipe` or a generator not a ``torch.Generator``.
        ValueError: if the list lengths differ from ``B`` or a recipe is invalid (a NaN or
            infinite field, ``level``/``stray`` < 0, ``photons`` <= 0).

    Example:
        >>> A = Hadamard(8, sr=0.5)
        >>> x = torch.rand(2, 1, 8, 8)
        >>> g = [torch.Generator().manual_seed(i) for i in range(2)]
        >>> torch.equal(noisy_buckets(A, x, [NoiseRecipe()] * 2, g), A(x))
        True
    """
    func = "noisy_buckets"
    if not isinstance(A, Hadamard):
        raise TypeError(f"{func}: expected A to be a Hadamard operator, got {type(A).__name__}")
    check_rank(x, 4, "x", func, "(B, C, n, n)")
    if len(recipes) != x.shape[0] or len(generators) != x.shape[0]:
        raise ValueError(
            f"{func}: expected {x.shape[0]} recipes and generators, "
            f"got {len(recipes)} and {len(generators)}"
        )
    for i, r in enumerate(recipes):
        _check_recipe(r, f"recipes[{i}]", func)
    for i, g in enumerate(generators):
        if not isinstance(g, torch.Generator):
            raise TypeError(f"{func}: expected generators[{i}] to be a torch.Generator, "
                            f"got {type(g).__name__}")
    if x.shape[0] == 0:  # an empty batch: the empty measurements (split(1) gives one chunk)
        return A(x)
    out = []
    for xi, r, g in zip(x.split(1), recipes, generators, strict=True):
        if r.photons is None:
            y = A(xi)
        else:
            frames = DMDSplit(A)(xi)  # (1, C, 2M) in scene units
            counts = r.photons * (frames + r.stray * xi.sum(dim=(-2, -1))[..., None] / 2)
            eps = torch.randn(counts.shape, generator=g, dtype=counts.dtype)
            frames = (counts + counts.clamp_min(0).sqrt() * eps) / r.photons
            y = combine_split(frames, A.n)
        if r.level > 0:
            spread = y.amax(dim=-1, keepdim=True) - y.amin(dim=-1, keepdim=True)
            eps = torch.randn(y.shape, generator=g, dtype=y.dtype)
            y = y + r.level * spread * eps
        out.append(y)
    return torch.cat(out)


def training_noise(
    g: torch.Generator,
    p_clean: float = 0.2,
    levels: tuple[float, float] = TRAIN_LEVELS,
    p_shot: float = 0.25,
) -> NoiseRecipe:
    """Draw a sample's noise recipe: clean with probability ``p_clean``; else a Gaussian level
    log-uniform in ``levels`` and, with probability ``p_shot``, shot noise at ``photons``
    log-uniform in ``[3, 300]`` per pixel with stray light uniform in ``[0, 2]``.

    Raises:
        TypeError: if ``g`` is not a ``torch.Generator`` or a probability or level not a
            number.
        ValueError: if ``p_clean`` or ``p_shot`` is not in ``[0, 1]`` or ``levels`` is not two
            finite levels ``0 < lo <= hi`` (a log-uniform draw needs ``lo > 0``).

    Example:
        >>> r = training_noise(torch.Generator().manual_seed(0))
        >>> r.level >= 0
        True
    """
    func = "training_noise"
    if not isinstance(g, torch.Generator):
        raise TypeError(f"{func}: expected g to be a torch.Generator, got {type(g).__name__}")
    check_in_range(p_clean, 0.0, 1.0, "p_clean", func)
    check_in_range(p_shot, 0.0, 1.0, "p_shot", func)
    if not isinstance(levels, (tuple, list)) or len(levels) != 2:
        raise TypeError(f"{func}: expected levels to be a pair (lo, hi), got {levels!r}")
    check_positive(levels[0], "levels[0]", func)
    check_positive(levels[1], "levels[1]", func)
    if levels[0] > levels[1]:
        raise ValueError(f"{func}: expected levels[0] <= levels[1], got {tuple(levels)}")

    def u() -> float:
        return float(torch.rand((), generator=g, dtype=torch.float64))

    if u() < p_clean:
        return NoiseRecipe()
    lo, hi = levels
    level = math.exp(math.log(lo) + (math.log(hi) - math.log(lo)) * u())
    if u() < p_shot:
        return NoiseRecipe(level, math.exp(math.log(3.0) + math.log(100.0) * u()), 2 * u())
    return NoiseRecipe(level)
