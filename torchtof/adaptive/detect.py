"""Which stages a scene needs: a scattering veil (Eq. 15) and far returns behind the gate.

Both detectors read the first DMD pair of a run, the all-on frame ``φ⁺ = 1`` and the dark
frame ``φ⁻ = 0`` of the constant Hadamard row (the first row of every order torchtof uses),
as raw (interleaved, unsigned) buckets ``D`` (ungated depth, Eq. 10), ``G`` (3 m gate, §3.1)
and ``S`` (intensity, Eq. 8 amplitudes), each summed over the ``P`` ROI pixels.

**Veil** (:func:`detect_veil`). A sheet between camera and DMD adds light that does not
depend on the pattern, at the sheet's distance, and attenuates what passes it (paper Eq. 15,
``D' = αD + Dˢ``). The dark frame sees only pattern-independent light, so it is compared with
the dark frame of the clear set-up (:class:`DarkReference`, measured once without the sheet;
:func:`dark_reference` simulates it). Per pixel, with ``d̄ = D/P`` and ``s̄ = S/P``:

.. math::

    \\hat\\alpha = \\bar s'_{dark} / \\bar s_{ref}, \\qquad
    \\hat D^s = \\bar d'_{dark} - \\hat\\alpha\\, \\bar d_{ref}
    \\quad (\\text{Eq. 15 on the dark frame}),

and a veil is reported when the dark frame moved towards the camera by more than
``shift_m`` (0.2 m) or lost more than ``1 − alpha_max`` (10 %) of its light. ``α̂`` is the
transmittance of the pattern-independent light: exact for the phasor model when the
backscatter adds little amplitude; for the depth-domain Eq. 15 alone (which leaves the
amplitudes alone) ``α̂ = 1`` and ``D̂ˢ`` carries the whole depth shift.

A clear set-up whose dark frame holds no light at all (``s̄_ref = 0``: no stray light, a
noise-free reading) gives no intensity to compare with, so ``α`` cannot be estimated from
the intensities: ``α̂ = 1`` (the depth-domain reading of Eq. 15 above) and the veil is
decided from the depth shift alone.

**Far returns** (:func:`detect_far_background`). The gate matters when light that *does*
depend on the pattern comes from beyond ``gate_m`` (a far background, multipath). A pixel
that lights up at depth ``z`` from the dark value ``d₀`` changes the ungated bucket by
``z − d₀`` and the gated one by ``z`` if ``z ≤ gate_m`` (and ``d₀`` beyond it), else by 0.
With ``d₀ = 5`` m ("no photon", §2.2) and ``z ≥ 1`` m (the camera's near limit) near light
gives ``R = ΔG / (−ΔD) = z / (5 − z) ≥ 1/4``; light beyond the gate gives ``R ≤ 0``. A far
background is reported when the pattern-dependent light is significant
(``|ΔS| > k_sigma·σ_S``) and ``R < r_min = 1/4``: the light beyond the gate outweighs the
near light. A far background behind a large near object is not flagged (``R`` stays above
1/4); the gate then costs nothing to keep, which is what happens when it is flagged.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import torch

from .._checks import check_finite, check_int, check_number, check_positive, check_tensor

__all__ = ["DarkReference", "VeilEstimate", "FarEstimate", "GateTest", "dark_reference",
           "detect_veil", "detect_far_background", "gate_changes_image"]

RAW_KINDS = ("depth", "depth_gated", "intensity")
#: fewest signed buckets :func:`gate_changes_image` tests (``K = m − 1 >= 7`` non-DC ones).
GATE_MIN_BUCKETS = 8


@dataclass(frozen=True)
class DarkReference:
    """Per-pixel means of the clear set-up's dark frame (mirrors off, no sheet): depth ``m``,
    gated depth ``m`` and intensity (amplitude units of the buckets).

    Fields are stored as Python floats (a NumPy scalar or a one-element tensor is converted).
    ``intensity`` is an amplitude, ``>= 0``: ``0`` is a real reading (a clear set-up with
    no stray light and no noise), with which :func:`detect_veil` cannot estimate ``α`` from
    the intensities and takes ``α̂ = 1`` (module docstring).

    Raises:
        TypeError, ValueError: a field that is not a finite real number, a negative
            ``intensity``.
    """

    depth_m: float
    gated_m: float
    intensity: float

    def __post_init__(self) -> None:
        for name in ("depth_m", "gated_m", "intensity"):
            v = getattr(self, name)
            if isinstance(v, torch.Tensor) and v.numel() == 1 and not v.is_complex():
                v = v.item()
            elif isinstance(v, numbers.Real) and not isinstance(v, bool):
                v = float(v)
            object.__setattr__(self, name, check_number(v, name, "DarkReference"))
        if self.intensity < 0:
            raise ValueError(f"DarkReference: expected intensity >= 0 (an amplitude), got "
                             f"{self.intensity}")


@dataclass(frozen=True)
class VeilEstimate:
    """:func:`detect_veil`: ``present``, ``alpha`` (α̂), ``ds_m`` (D̂ˢ per pixel, m),
    ``shift_m`` (how far the dark frame moved towards the camera, m)."""

    present: bool
    alpha: float
    ds_m: float
    shift_m: float


@dataclass(frozen=True)
class FarEstimate:
    """:func:`detect_far_background`: ``present``, ``ratio`` (``R = ΔG/(−ΔD)``),
    ``significance`` (``|ΔS|/σ_S``; NaN where no noise level was known and the test was not
    made, ``intensity_sigma=None``, e.g. in :func:`~torchtof.adaptive.run_adaptive` with
    ``noise="repeat"`` and no repeat: ``present`` is then ``False``)."""

    present: bool
    ratio: float
    significance: float


def _pair(raw: dict[str, torch.Tensor], fn: str, frames: int = 2) -> dict[str, torch.Tensor]:
    if not isinstance(raw, dict):
        raise TypeError(f"{fn}: expected a dict of raw buckets, got {type(raw).__name__}")
    out = {}
    for k in RAW_KINDS:
        if k not in raw:
            raise ValueError(f"{fn}: expected raw buckets with keys {RAW_KINDS}, got {sorted(raw)}")
        v = raw[k]
        check_tensor(v, f"raw[{k!r}]", fn)
        if v.ndim != 3 or v.shape[1] != 1 or v.shape[-1] < frames:
            raise ValueError(f"{fn}: expected raw[{k!r}] of shape (B, 1, F >= {frames}), got "
                             f"{tuple(v.shape)}")
        check_finite(v, f"raw[{k!r}]", fn)
        out[k] = v.to(torch.float64)
    return out


def dark_reference(config, frames: int = 8, seed: int = 0) -> DarkReference:
    """Simulate the clear set-up's dark frame (all mirrors off, no sheet) ``frames`` times.

    On hardware: record the dark frame once with the sheet removed and build
    :class:`DarkReference` from its per-pixel means.

    Args:
        config: :class:`~torchtof.experiment.ExperimentConfig` of the set-up.
        frames: frames averaged (an int ``>= 1``).
        seed: noise seed (an int).

    Raises:
        TypeError: ``config`` not an ``ExperimentConfig``, ``frames`` or ``seed`` not an int.
        ValueError: ``frames < 1``.
    """
    from dataclasses import replace

    from ..bucket import depth_bucket, intensity_bucket
    from ..experiment import ExperimentConfig, simulate_frames, stray_light
    from ..scenes import Scene

    fn = "dark_reference"
    if not isinstance(config, ExperimentConfig):
        raise TypeError(f"{fn}: expected config to be an ExperimentConfig, got "
                        f"{type(config).__name__}")
    check_int(frames, "frames", fn, lo=1)
    check_int(seed, "seed", fn)
    cfg = replace(config, scattering=False)
    n, p2 = cfg.n, cfg.roi_px**2
    zero = torch.zeros(1, 1, n, n, dtype=torch.float64)
    stray = stray_light(cfg, torch.float64) if cfg.stray_e > 0 else None
    pats = torch.zeros(frames, n, n, dtype=torch.float64)
    fr = simulate_frames(Scene(zero, zero), pats, cfg, torch.Generator().manual_seed(seed),
                         None, stray)
    depth = fr.depth[:, 0][None]
    return DarkReference(
        depth_m=float(depth_bucket(depth).mean()) / p2,
        gated_m=float(depth_bucket(depth, gate_m=cfg.gate_m).mean()) / p2,
        intensity=float(intensity_bucket(fr.amplitude[:, 0][None]).mean()) / p2,
    )


def detect_veil(raw: dict[str, torch.Tensor], reference: DarkReference, roi_pixels: int,
                shift_m: float = 0.2, alpha_max: float = 0.9) -> VeilEstimate:
    """Detect a scattering veil from the dark frame and estimate α and Dˢ (module docstring).

    Args:
        raw: raw interleaved buckets ``{"depth", "depth_gated", "intensity"}`` ``(B, 1, F ≥ 2)``
            whose frames 0 and 1 are the all-on and the dark frame (realisations averaged).
        reference: the clear set-up's dark frame.
        roi_pixels: ``P``, the number of ROI pixels summed into a bucket (an int ``>= 1``).
        shift_m: depth shift of the dark frame that counts as a veil (m, ``>= 0``, finite).
        alpha_max: ``α̂`` below this counts as a veil (in ``[0, 1]``).

    Returns:
        :class:`VeilEstimate`. With ``reference.intensity == 0`` (a dark clear set-up) ``α``
        cannot be estimated from the intensities: ``alpha`` is 1 and ``present`` depends on
        the depth shift alone (module docstring). ``alpha`` is ``<= 0`` only when the dark
        frame holds no light (or a negative reading) against a reference that does: a veil
        (``present``) whose Eq. 15 compensation ``y/α̂`` is undefined.

    Raises:
        TypeError, ValueError: bad buckets (missing keys, shape, NaN), ``reference`` not a
            :class:`DarkReference`, ``roi_pixels`` not an int ``>= 1``, ``shift_m`` or
            ``alpha_max`` out of range or NaN.
    """
    fn = "detect_veil"
    if not isinstance(reference, DarkReference):
        raise TypeError(f"{fn}: expected reference to be a DarkReference, got "
                        f"{type(reference).__name__}")
    check_int(roi_pixels, "roi_pixels", fn, lo=1)
    check_positive(shift_m, "shift_m", fn, strict=False)
    if not 0.0 <= check_number(alpha_max, "alpha_max", fn) <= 1.0:
        raise ValueError(f"{fn}: expected alpha_max in [0, 1], got {alpha_max}")
    b = _pair(raw, fn)
    d_dark = float(b["depth"][..., 1].mean()) / roi_pixels
    s_dark = float(b["intensity"][..., 1].mean()) / roi_pixels
    if reference.intensity > 0:
        alpha = min(1.0, s_dark / max(reference.intensity, 1e-12))
    else:  # no light in the clear dark frame: no intensity ratio, the depth shift decides
        alpha = 1.0
    ds = d_dark - alpha * reference.depth_m  # Eq. 15 on the dark frame
    shift = reference.depth_m - d_dark
    return VeilEstimate(present=bool(shift > shift_m or alpha < alpha_max), alpha=alpha,
                        ds_m=ds, shift_m=shift)


def detect_far_background(raw: dict[str, torch.Tensor], intensity_sigma: float | None,
                          k_sigma: float = 5.0, r_min: float = 0.25) -> FarEstimate:
    """Detect pattern-dependent light beyond the depth gate from the all-on/dark pair.

    Args:
        raw: raw interleaved buckets ``{"depth", "depth_gated", "intensity"}`` ``(B, 1, F ≥ 2)``.
        intensity_sigma: noise std of one difference ``S_on − S_off`` (``n·σ`` of the signed
            intensity buckets ``(y⁺ − y⁻)/n``): a number ``> 0`` and finite. ``None``: no
            noise level is known, so the significance cannot be judged and the test is not
            made: ``present=False``, ``significance`` NaN (``ratio`` is still reported).
        k_sigma: significance of the pattern-dependent light (``>= 0``, finite).
        r_min: ``R`` below this means the light is mostly beyond the gate (module docstring;
            finite).

    Returns:
        :class:`FarEstimate`.

    Raises:
        TypeError, ValueError: bad buckets; ``intensity_sigma`` not a number ``> 0`` (``0``,
            negative, NaN or Inf), ``k_sigma`` negative or not finite, ``r_min`` not finite.
    """
    fn = "detect_far_background"
    k_sigma = check_positive(k_sigma, "k_sigma", fn, strict=False)
    r_min = check_number(r_min, "r_min", fn)
    if intensity_sigma is None:  # no noise level: no test, R only
        ratio, _ = _far_ratio(_pair(raw, fn))
        return FarEstimate(present=False, ratio=ratio, significance=math.nan)
    if isinstance(intensity_sigma, torch.Tensor):
        if intensity_sigma.numel() != 1 or intensity_sigma.is_complex():
            raise ValueError(f"{fn}: expected intensity_sigma to be one real number, got a "
                             f"tensor of shape {tuple(intensity_sigma.shape)}")
        intensity_sigma = float(intensity_sigma)
    sigma = check_positive(intensity_sigma, "intensity_sigma", fn)
    ratio, ds = _far_ratio(_pair(raw, fn))
    sig = abs(ds) / max(sigma, 1e-12)
    return FarEstimate(present=bool(sig > k_sigma and ratio < r_min), ratio=ratio,
                       significance=sig)


def _far_ratio(b: dict[str, torch.Tensor]) -> tuple[float, float]:
    """``R = ΔG/(−ΔD)`` and ``ΔS`` of the all-on/dark pair of checked raw buckets."""

    def diff(k):
        return float((b[k][..., 0] - b[k][..., 1]).mean())

    dd, dg, ds = diff("depth"), diff("depth_gated"), diff("intensity")
    ratio = dg / (-dd) if dd < 0 else (0.0 if dg <= 0 else float("inf"))
    return ratio, ds



@dataclass(frozen=True)
class GateTest:
    """:func:`gate_changes_image`: ``present`` (the gate changes the image beyond noise),
    ``rho`` (affine residual over its noise), ``slope`` ``a``."""

    present: bool
    rho: float
    slope: float


def gate_changes_image(y_depth: torch.Tensor, y_gated: torch.Tensor, d_depth: torch.Tensor,
                       d_gated: torch.Tensor, level: float = 0.99,
                       dof: int | None = None) -> GateTest:
    """Does the depth gate change the image beyond an affine map and the noise?

    Without returns beyond the gate, every pixel that lights up moves both buckets in
    proportion (``5 − z`` down, ``z`` up, §3.1), so the ungated coefficients are an affine
    image of the gated ones: ``y_u ≈ a·y_g`` on every non-DC coefficient (orthonormal rows:
    the offset lives in the DC only). Far returns (background, multipath halo) break it. With
    ``a`` the least-squares slope over the ``K`` non-DC coefficients and ``σ_r`` the noise of
    ``y_u − a·y_g`` from repeated measurements ``d = y − y'`` of some coefficients
    (``σ_r² = ‖d_u − a d_g‖²/(2B)``; both kinds come from the same frames, so their noise is
    correlated and measured together),

    .. math:: \\rho = \\frac{\\|y_u - a y_g\\|^2}{K \\sigma_r^2},

    and the gate is needed when ``ρ`` exceeds the ``level`` quantile of Fisher's ``F(K, B)``
    (Snedecor): ``ρ`` is a ratio of two χ² variables over their degrees of freedom under the
    no-far-return hypothesis (``σ_r²`` is itself estimated from ``B`` values). Differences
    that are not independent (successive differences of pair sums share a sum: lag-one
    correlation −1/2) carry fewer degrees of freedom than values: pass them as ``dof``
    (:func:`~torchtof.adaptive.noise.pair_noise_dof` with ``robust=False``), else the F
    quantile is too small and the gate is kept on noise.

    One test, on one sample: a batch of buckets is refused (test each sample on its own).

    Args:
        y_depth, y_gated: signed ungated and gated buckets ``(1, 1, m)``, ``m >= 8`` (same
            patterns).
        d_depth, d_gated: differences of two measurements of the same ``B`` patterns,
            ``(1, 1, B)`` with ``B >= 1``.
        level: confidence level of the F test, in ``(0, 1)``.
        dof: degrees of freedom of ``σ_r²`` (default: the number of differences ``B``).

    Returns:
        :class:`GateTest`.

    Raises:
        TypeError: an input not a floating-point tensor, ``dof`` not an int (a Python or
            NumPy integer) or ``None``.
        ValueError: not one sample ``(1, 1, ·)``, fewer than 8 coefficients, no differences,
            mismatched shapes, NaN/Inf, ``level`` outside ``(0, 1)``, ``dof < 1``.
    """
    fn = "gate_changes_image"
    if dof is not None:
        dof = check_int(dof, "dof", fn, lo=1)
    if not 0.0 < check_number(level, "level", fn) < 1.0:
        raise ValueError(f"{fn}: expected level in (0, 1), got {level}")
    for name, v in (("y_depth", y_depth), ("y_gated", y_gated), ("d_depth", d_depth),
                    ("d_gated", d_gated)):
        check_tensor(v, name, fn)
        if v.ndim != 3 or v.shape[:2] != (1, 1):
            raise ValueError(f"{fn}: expected {name} of one sample, shape (1, 1, *), got "
                             f"{tuple(v.shape)} (test each sample on its own)")
    if y_depth.shape != y_gated.shape or y_depth.shape[-1] < GATE_MIN_BUCKETS:
        raise ValueError(f"{fn}: expected y_depth and y_gated of one shape with >= "
                         f"{GATE_MIN_BUCKETS} buckets, "
                         f"got {tuple(y_depth.shape)} and {tuple(y_gated.shape)}")
    if d_depth.shape != d_gated.shape or d_depth.shape[-1] < 1:
        raise ValueError(f"{fn}: expected d_depth and d_gated of one shape with >= 1 "
                         f"difference, got {tuple(d_depth.shape)} and {tuple(d_gated.shape)}")
    for name, v in (("y_depth", y_depth), ("y_gated", y_gated), ("d_depth", d_depth),
                    ("d_gated", d_gated)):
        check_finite(v, name, fn)
    yu, yg = y_depth.flatten()[1:].double(), y_gated.flatten()[1:].double()
    a = float((yu @ yg) / (yg @ yg).clamp_min(1e-300))
    du, dg = d_depth.flatten().double(), d_gated.flatten().double()
    s2 = float(((du - a * dg) ** 2).sum() / (2 * du.numel()))
    k = yu.numel()
    rho = float(((yu - a * yg) ** 2).sum()) / max(k * s2, 1e-300)
    from scipy.stats import f as fisher  # lazy: import torchtof.adaptive stays light

    return GateTest(present=bool(rho > fisher.ppf(level, k, dof or du.numel())), rho=rho,
                    slope=a)
