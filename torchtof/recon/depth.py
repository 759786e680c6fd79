"""Depth-resolved ghost imaging: a per-pixel depth map from per-tap buckets.

The four correlation taps of a CW-ToF pixel are linear in the light that reaches it
(paper Eq. 6: ``c_k = B + ½ Re(P e^{jτ_k})``), so the per-tap buckets
``C_{k,i} = Σ_{p∈ROI} c_{k,i}(p)`` (:func:`~torchtof.bucket.tap_buckets`) obey
``y_k = A x_k``: each tap image ``x_k`` is a ghost image. With the Fig. 1 tap order of the
package (``τ = 0, π, π/2, 3π/2``, see :func:`~torchtof.sensor.tap_phase`) the differences

.. math::
    I = c_1 - c_2 = \\operatorname{Re} P, \\qquad Q = c_4 - c_3 = \\operatorname{Im} P

(the operands of Eq. 7; 0-based channels ``I = y[:, 0] − y[:, 1]``, ``Q = y[:, 3] − y[:, 2]``)
are the real and imaginary parts of the phasor image; the offset ``B`` (ambient light, the
unmodulated part of the signal) cancels. Reconstructing ``I`` and ``Q`` (or the four tap
images) with any reconstructor and applying Eq. 7 (phase), Eq. 8 (amplitude) and Eq. 1
(depth) per DMD pixel gives a depth map of a 3-D object at DMD resolution.

- :func:`iq_buckets` — taps ``(B, 4, M)`` → I/Q buckets ``(B, 2, M)`` (exact, linear).
- :func:`tap_noise_sigma` — noise std of the I/Q buckets from the null combination
  ``c₁ + c₂ − c₃ − c₄`` (zero signal, see there).
- :func:`joint_tv` / :class:`JointTV` — TV reconstruction of several images that share their
  edges (vectorial TV of I and Q), or the same solver with separate TV per image.
- :func:`depth_resolved` / :class:`DepthResolved` — buckets → :class:`DepthResult`
  (depth, amplitude, phase, mask, images).
- :func:`dual_frequency_depth` / :class:`DualFrequencyDepth` — two modulation frequencies,
  phase unwrapping beyond the unambiguous range.

**Amplitude mask.** A pixel is kept when its Eq. 8 amplitude ``Â = ½|P̂|`` exceeds

.. math::
    t = \\max\\big(k \\cdot \\tfrac12 σ_y \\sqrt{M/N},\\; r \\cdot \\max_u Â(u)\\big)

with ``σ_y`` the noise std of the I/Q buckets, ``M/N`` the sampling rate and defaults
``k = 3``, ``r = 0.1``. ``σ_y √(M/N)`` is the noise std of each of ``Î, Q̂`` on a pixel for
the pseudo-inverse of orthonormal Hadamard rows (entries ``±1/n``: ``Σ_i A_{iu}² = M/N``);
an empty pixel then has a Rayleigh amplitude and passes with probability
``exp(−k²/2) ≈ 1.1 %``. The noise term is computed at the scale of the reconstructor's
images, which it needs to know (with ``A`` its operator, of orthonormal rows):

- images in the units of ``A⁺y`` (PseudoInverse, TVAL3, BasisPursuit, :class:`JointTV`, …,
  every reconstructor but the correlation family): ``√(M/N)`` as above. Regularised
  reconstructors leave less noise, so the rule is conservative for them;
- TGI, ``Aᵀ(y − ⟨y⟩)/M`` (``1/M`` of the pseudo-inverse's scale): its pixel noise variance
  ``σ_y² ‖C a_u‖²/M²`` (``a_u`` the column of ``A``, ``C`` the centring) averages, over the
  pixels, to ``σ_y² (‖A‖_F² − ‖Aᵀ1‖²/M)/(N M²) = σ_y² (M − 1)/(N M²)`` (orthonormal rows:
  ``‖A‖_F² = M``, ``‖Aᵀ1‖² = ‖1‖² = M``), so the noise term uses ``√((M − 1)/N)/M``.

Any other operator (TGI on the DMD buckets of :class:`~torchtof.operators.DMDSplit`, operators
without orthonormal rows) leaves the scale of the image noise unknown: the relative floor
alone applies. The relative floor ``r`` removes dim returns that are not the object
(multipath spill, a 35 % copy in the experiment, lands mostly below it).

**Masked pixels.** By default every pixel reports the Eq. 1 depth of its phase, and the
mask (``DepthResult.mask``) says which of them are empty: there the phase is noise or
round-off. The mask is a statistical decision (a dim object pixel, e.g. an edge pixel the
object half covers, may fall below the relative floor), so the depth is kept for the caller
to judge. ``no_photon_m=d`` instead reports a fixed depth ``d`` on masked pixels, like the
camera's pixels "without receiving any photon" (paper §2.2,
:func:`~torchtof.sensor.camera_rules`), so that the depth map alone
(``DepthResolved.forward``, the exported model) tells which pixels are empty: the camera's
own value is the far end of its range, ``no_photon_m=5.0`` (outside ``[0, c/(2f))`` at
30 MHz, beyond a 3 m gate); ``0.0`` passes a depth gate. The phase and amplitude of a masked
pixel are left as Eqs. 7 and 8 give them.
"""

from __future__ import annotations

import functools
import math
from fractions import Fraction
from statistics import NormalDist
from typing import NamedTuple

import torch
from torch import nn

from .._checks import (
    check_bool,
    check_finite,
    check_positive,
    check_real,
    check_shape,
    check_tensor,
    check_weight_range,
    is_tracing,
)
from .._memory import check_memory, format_bytes
from ..operators.base import LinearOperator
from ..sensor.functional import SPEED_OF_LIGHT, phase_to_depth, tap_amplitude, tap_phase
from .base import relative_residual
from .tv import BOUNDARIES, admm_tv, box_bounds, check_exact_memory, scale_a
from .tval3 import (
    AUTO_CV_FACTOR,
    AUTO_CV_MAX_ITER,
    AUTO_MU_MAX,
    B_SPREAD,
    NOISE_QUANTILE,
    MaskedRows,
    apply_holdout,
    auto_weights,
    bucket_noise_sigma,
    check_buckets,
    default_split,
    holdout_choice,
    holdout_split,
)

__all__ = [
    "MODES",
    "DepthResult",
    "iq_buckets",
    "tap_noise_sigma",
    "iq_phase_amplitude",
    "joint_tv",
    "JointTV",
    "JointTVResult",
    "depth_resolved",
    "DepthResolved",
    "dual_frequency_depth",
    "hypothesis_spacing",
    "common_range",
    "CommonRange",
    "DualFrequencyDepth",
]

#: What :func:`depth_resolved` reconstructs: the two I/Q images or the four tap images.
MODES = ("iq", "taps")
#: Defaults of the amplitude mask (module docstring): ``k`` noise stds, fraction ``r`` of the peak.
MASK_K_SIGMA, MASK_REL = 3.0, 0.1


class DepthResult(NamedTuple):
    """Output of :func:`depth_resolved` (all ``(B, 1, n, n)`` unless noted).

    Attributes:
        depth: depth in metres, Eq. 1 of the per-pixel phase, in ``[0, c/(2f))``; with
            ``no_photon_m`` given, that depth where ``mask`` is ``False`` (module docstring).
        amplitude: Eq. 8 amplitude ``½|P̂|`` in the units of the buckets.
        phase: Eq. 7 phase in ``[0, 2π)``.
        mask: bool, ``True`` where the amplitude is above the mask threshold (module doc);
            for :class:`DualFrequencyDepth` also where the two frequencies agree.
        images: the reconstructed I/Q ``(B, 2, n, n)`` or tap images ``(B, 4, n, n)``.
        threshold: the mask threshold per image ``(B,)``.
        x: the depth again (the reconstructor contract's name for the output).
        n_iter, residual, converged, stop_reason: the reconstructor's ``solve`` result per
            image channel ``(B, C)`` (``None``/``()`` for a reconstructor without ``solve``).
    """

    depth: torch.Tensor
    amplitude: torch.Tensor
    phase: torch.Tensor
    mask: torch.Tensor
    images: torch.Tensor
    threshold: torch.Tensor
    x: torch.Tensor | None = None
    n_iter: torch.Tensor | None = None
    residual: torch.Tensor | None = None
    converged: torch.Tensor | None = None
    stop_reason: tuple = ()


def _check_buckets(y: object, func: str, channels: tuple[int, ...] = (2, 4)) -> torch.Tensor:
    check_tensor(y, "y", func)
    if y.is_complex():
        raise TypeError(f"{func}: expected y to be a real tensor, got dtype {y.dtype}")
    lay = " or ".join(f"(B, {c}, M)" for c in channels)
    if y.ndim != 3 or y.shape[1] not in channels or y.shape[-1] < 1:
        raise ValueError(f"{func}: expected y of shape {lay}, got {tuple(y.shape)}")
    check_finite(y, "y", func)
    return y


def iq_buckets(y: torch.Tensor) -> torch.Tensor:
    """I/Q buckets from the four tap buckets: ``I = C₁ − C₂``, ``Q = C₄ − C₃`` (Eq. 7 operands).

    Linear, so ``A`` commutes with it: ``iq_buckets(A x_taps) = A iq(x_taps)``. The tap order
    is Fig. 1's (``τ = 0, π, π/2, 3π/2``), the order of
    :func:`~torchtof.sensor.correlation_taps` and :func:`~torchtof.bucket.tap_buckets`.
    Works on ``(B, 4, M)`` measurements and on DMD-split buckets ``(B, 4, 2M)`` alike.

    Args:
        y: tap buckets.

    Returns:
        I/Q buckets, channel 0 ``I = Re P``, channel 1 ``Q = Im P``.

    Raises:
        TypeError: if ``y`` is not a real floating tensor.
        ValueError: if ``y`` is not ``(B, 4, M)`` or holds NaN/Inf.

    Shape:
        - y: :math:`(B, 4, M)`; output: :math:`(B, 2, M)`.

    Example:
        >>> iq_buckets(torch.tensor([[[5.0], [1.0], [2.0], [4.0]]])).flatten().tolist()
        [4.0, 2.0]
    """
    _check_buckets(y, "iq_buckets", (4,))
    return torch.stack((y[:, 0] - y[:, 1], y[:, 3] - y[:, 2]), dim=1)


def tap_noise_sigma(y: torch.Tensor) -> torch.Tensor:
    """Noise std of the I/Q buckets from the null combination ``N = C₁ + C₂ − C₃ − C₄``.

    Every tap carries the same offset and ``c₁ + c₂ = c₃ + c₄ = 2B`` (Eq. 6 at
    ``τ`` and ``τ + π``), so ``N`` holds no signal at all, only noise. With independent
    noise on the taps, ``Var N = Σ_k Var C_k = Var I + Var Q``, and for Poisson shot noise
    plus equal read noise ``Var I = Var Q`` exactly (each pair sums to ``2B``). Hence

    .. math::
        \\hat σ_{I} = \\hat σ_{Q} = \\sqrt{\\tfrac{1}{2M} \\sum_i N_i^2}

    over every measurement (unlike the tail estimate of
    :func:`~torchtof.recon.bucket_noise_sigma`, no scene signal leaks into it).

    Args:
        y: tap buckets ``(B, 4, M)`` (differential Hadamard measurements or DMD buckets of
            complementary patterns alike: ``N`` has zero mean in both).

    Returns:
        ``(B,)`` noise std of each I/Q bucket, in the units of ``y``.

    Raises:
        TypeError, ValueError: as :func:`iq_buckets`.

    Example:
        >>> g = torch.Generator().manual_seed(0)
        >>> y = 10 + 2.0 * torch.randn(1, 4, 20000, generator=g)  # Var I = 2 · 2²
        >>> round(float(tap_noise_sigma(y)), 1)
        2.8
    """
    _check_buckets(y, "tap_noise_sigma", (4,))
    null = y[:, 0] + y[:, 1] - y[:, 2] - y[:, 3]
    return (null * null).mean(dim=-1).div(2).sqrt()


def _iq_as_taps(iq: torch.Tensor) -> torch.Tensor:
    """Taps ``(I/2, −I/2, −Q/2, Q/2)`` with ``c₁ − c₂ = I``, ``c₄ − c₃ = Q`` (Fig. 1 order), so
    the package's Eq. 7/8 functions (with their NaN-free guards) apply to I/Q images."""
    i, q = iq[:, 0:1] / 2, iq[:, 1:2] / 2
    return torch.cat((i, -i, -q, q), dim=1)


def iq_phase_amplitude(iq: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Eq. 7 phase and Eq. 8 amplitude of I/Q images: ``θ = atan2(Q, I) mod 2π``, ``½ hypot``.

    Args:
        iq: ``(B, 2, H, W)``, channel 0 ``I``, channel 1 ``Q``.

    Returns:
        ``(phase, amplitude)``, each ``(B, 1, H, W)``; a pixel with ``I = Q = 0`` has phase
        0 and amplitude 0 with zero gradients (see :func:`~torchtof.sensor.tap_phase`).

    Raises:
        TypeError: if ``iq`` is not a real floating tensor.
        ValueError: if ``iq`` is not ``(B, 2, H, W)`` or holds NaN/Inf.

    Example:
        >>> th, a = iq_phase_amplitude(torch.tensor([0.0, 2.0]).view(1, 2, 1, 1))
        >>> round(th.item(), 4), a.item()
        (1.5708, 1.0)
    """
    func = "iq_phase_amplitude"
    check_real(iq, "iq", func)
    if not iq.is_floating_point():
        raise TypeError(f"{func}: expected iq a real floating-point tensor, got {iq.dtype}")
    check_shape(iq, (None, 2, None, None), "iq", func, "(B, 2, H, W)")
    check_finite(iq, "iq", func)
    taps = _iq_as_taps(iq)
    return tap_phase(taps), tap_amplitude(taps)


# -- joint (vectorial) TV ----------------------------------------------------------------------


#: What to change when the exact u-step's factorisation does not fit (JointTV has no other).
_JTV_MEMORY_HINT = ("JointTV always factors it: use a smaller n or sampling rate, or TVAL3 "
                    "with u_step='bb' per channel")


def joint_tv(
    y: torch.Tensor,
    A: LinearOperator,
    joint: bool = True,
    mu: float | str = "auto",
    beta: float = 2.0**5,
    n_iter: int = 300,
    tol: float = 1e-6,
    noise_sigma: float | torch.Tensor | None = None,
    adaptive: bool = True,
    return_result: bool = False,
    *,
    boundary: str = "periodic",
    bounds: tuple[float | None, float | None] | None = None,
) -> torch.Tensor:
    """Reconstruct ``C`` images that share their edges: vectorial TV by ADMM.

    .. math::
        \\min_{u_1..u_C} \\sum_i \\Big(\\sum_c \\|D_i u_c\\|^2\\Big)^{1/2}
        \\;\\text{s.t.}\\; A u_c = b_c \\quad\\text{or}\\quad
        + \\frac{μ}{2} \\sum_c \\|A u_c - b_c\\|^2

    The coupled TV (Blomgren & Chan, IEEE TIP 7, 1998; Bresson & Chan, Inverse Probl.
    Imaging 2, 2008) of the I/Q pair is the complex TV ``Σ_i |D_i P|`` of the phasor image
    ``P = I + jQ``: invariant to a global phase ``P → e^{jφ}P`` (separate TV of I and Q is
    not), and it shrinks the gradient of I and Q together, so an edge seen in either image
    survives in both. ``joint=False`` runs the same solver with isotropic TV per image (the
    fair "separate" baseline: same model, weights, scaling and iterations).

    Solver: TVAL3's splitting ``w_i = D_i u`` (Li, Yin, Jiang, Zhang 2013) solved by ADMM
    with the exact u-step of :func:`~torchtof.recon.tval3` (``u_step="exact"``): per iteration

    .. math::
        w &= \\operatorname{shrink}(Du - σ/β,\\ 1/β) \\quad (\\text{group shrinkage})\\\\
        (D^TD + ρA^TA)\\,u &= D^T(w + σ/β) + ρA^T(b + δ/μ), \\quad ρ = μ/β\\\\
        σ &\\leftarrow σ - β(Du - w), \\qquad δ \\leftarrow δ - μ(Au - b)

    (``δ ≡ 0`` for the TV-L2 model). The u-step separates over the channels; only the
    shrinkage couples them. Scaling as TVAL3's ``Scaleb`` (buckets to a spread of 1.5), with
    one gain for all channels so that the group norm weighs them alike, ``b = 1.5 y / s``,
    ``s = max_i ‖y_{·,i}‖₂`` (largest norm over the channels of one measurement: for one
    channel of Hadamard data ``max |y|``, the DC bucket, about the spread). It is invariant
    to a rotation of the channel vector, so with ``joint=True`` the solution commutes with a
    global phase ``P → e^{jφ}P`` (a tested property).

    ``mu="auto"`` picks the model from the noise as :func:`~torchtof.recon.tval3` does
    (``μ = 0.7 σ_s^{-1.3}`` on the scaled buckets; above ``2⁸`` the constrained model with
    ``μ = 2⁸``, else TV-L2 with ``4β``), with one ``σ`` per sample: ``noise_sigma`` (e.g.
    :func:`tap_noise_sigma`) or the tail estimate of
    :func:`~torchtof.recon.bucket_noise_sigma` applied to the length ``‖y_{·,i}‖₂`` of the
    channel vector of each measurement (invariant to a rotation of the channel vector, as the
    gain is, so that the global-phase invariance also holds with ``mu="auto"``): with the
    same white noise ``σ`` on the ``C`` channels that length is ``σ`` times a chi variable
    with ``C`` degrees of freedom, whose ``q``-quantile replaces the half-normal one
    (:func:`_channel_noise_sigma`).

    Args:
        y: measurements ``(B, C, M)``, ``M = A.m``, float32/float64.
        A: the operator (orthonormal rows or any; others are scaled as TVAL3's ``ScaleA``).
        joint: vectorial TV over the ``C`` channels (``True``) or TV per channel; a bool.
        mu: data weight ``> 0`` (constrained model) or ``"auto"``.
        beta: splitting weight ``β > 0``.
        n_iter: iterations (``≥ 1``); the exact u-step makes each one an exact ADMM step.
        tol: ``adaptive`` stops a sample when ``‖u_k − u_{k−1}‖ ≤ tol ‖u_{k−1}‖``.
        noise_sigma: bucket noise std ``(B,)`` tensor (or one entry) or float, ``>= 0`` and
            finite, for ``mu="auto"``.
        adaptive: early stop (``False``: exactly ``n_iter`` iterations, no Python branch
            on tensor values); a bool.
        return_result: return a :class:`JointTVResult` instead of the images.
        boundary: ``"periodic"`` or ``"neumann"`` differences (:mod:`~torchtof.recon.tv`).
        bounds: ``(lo, hi)`` box on the images, projected in every u-step (units of ``A⁺y``).
            Physics: the four tap images are correlation values with the offset ``B`` of
            Eq. 6 and cannot be negative (``(0, None)`` in ``mode="taps"``); the I/Q images are
            signed (``Re P``, ``Im P``) and take no bound.

    Returns:
        ``(B, C, n, n)`` images in the units of ``A⁺y``.

    Raises:
        TypeError: if ``y`` is not a real floating tensor, ``A`` not a LinearOperator, a flag
            (``joint``, ``adaptive``, ``return_result``) not a bool, or an option of the
            wrong type.
        ValueError: on a wrong shape, NaN/Inf, or invalid options (a ``noise_sigma`` tensor
            with a NaN/Inf or negative entry or neither one nor ``B`` entries, ``bounds`` not
            a pair ``lo < hi`` of finite numbers or ``None``).

    Shape:
        ``(B, C, M) -> (B, C, n, n)``.

    Example:
        >>> from torchtof.operators import Hadamard
        >>> A = Hadamard(8, sr=0.5)
        >>> x = torch.zeros(1, 2, 8, 8); x[:, 0, 2:6, 2:6] = 1.0; x[:, 1, 2:6, 2:6] = -0.5
        >>> bool((joint_tv(A(x), A, mu=2**8) - x).abs().max() < 1e-2)
        True
    """
    fn = "joint_tv"
    check_buckets(y, A, fn)
    _check_jtv_options(fn, mu, beta, n_iter, tol, joint, adaptive, boundary, bounds)
    check_bool(return_result, "return_result", fn)
    for name, v in (("mu", mu), ("beta", beta)):
        if not isinstance(v, str):
            check_weight_range(v, name, fn, y.dtype)
    ratio_max = 1.0 / torch.finfo(y.dtype).eps  # the exact u-step solves DᵀD + (μ/β)AᵀA
    if not isinstance(mu, str) and mu / beta > ratio_max:
        raise ValueError(f"{fn}: expected mu/beta <= 2^{round(math.log2(ratio_max))} for "
                         f"{y.dtype} buckets (beyond it the exact u-step loses the TV term "
                         f"to rounding: NaN), got {mu / beta:g}")
    box = box_bounds(False, bounds, fn)
    check_exact_memory(A, y, boundary, fn, _JTV_MEMORY_HINT)
    if y.shape[0] * y.shape[1] == 0:  # empty batch: empty result
        x = y.new_zeros(*y.shape[:2], A.n, A.n)
        per = y.shape[:2]
        res = JointTVResult(x, torch.zeros(per, dtype=torch.int64, device=y.device),
                            y.new_zeros(per), torch.ones(per, dtype=torch.bool, device=y.device),
                            ())
        return res if return_result else x
    inv_s2 = scale_a(A, y, fn)
    sq = math.sqrt(inv_s2)
    # one gain for all channels, invariant to rotations of the channel vector (module doc)
    spread = y.norm(dim=1).amax(dim=-1)  # (B,)
    zero = spread == 0
    gain = B_SPREAD / torch.where(zero, torch.ones_like(spread), spread)
    b = y * gain[:, None, None]
    if mu == "auto":
        if noise_sigma is None:
            sigma = _channel_noise_sigma(y)
        elif isinstance(noise_sigma, torch.Tensor):
            sigma = _noise_tensor(noise_sigma, y, fn)
        else:
            sigma = y.new_full((y.shape[0],), check_positive(noise_sigma, "noise_sigma", fn, False))
        mu_b, beta_b, constrained = auto_weights(sigma * gain, beta)  # TVAL3's rule
        if noise_sigma is None and adaptive and A.m >= 8 and not is_tracing() \
                and y.device.type != "meta" and bool((~constrained & ~zero).any()):
            # one host read at entry: TVAL3's hold-out check of the estimate's TV-L2 choice
            keep, mu_cv = _validate_constrained(b, A, mu_b, beta_b, beta, joint, boundary,
                                                box, gain / sq, inv_s2, n_iter)
            mu_b, beta_b, constrained = apply_holdout(mu_b, beta_b, constrained, keep, mu_cv,
                                                      beta)
    else:
        mu_b = y.new_full((y.shape[0],), float(mu))
        beta_b = y.new_full((y.shape[0],), float(beta))
        constrained = torch.ones_like(zero)
    c = y.shape[1]
    per = (y.shape[0], c)
    out = admm_tv(  # (in inference mode where no gradient can flow: admm_tv)
        b, A, mu_b[:, None].expand(per), beta_b[:, None].expand(per),
        constrained[:, None].expand(per), tv="isotropic", boundary=boundary, joint=joint,
        bounds=tuple(None if v is None else float(v) * (gain / sq).reshape(-1, 1, 1, 1)
                     for v in box),
        inv_s2=inv_s2, max_iter=n_iter, tol=tol, adaptive=adaptive,
        done=zero[:, None].expand(per), stop_over_channels=True,
    )
    x = out.u * (sq / gain).reshape(-1, 1, 1, 1)
    if not return_result:
        return x
    residual = relative_residual(x, y, A)
    names = () if is_tracing() else tuple(
        tuple("tol" if d else "max_iter" for d in row) for row in out.converged.tolist())
    return JointTVResult(x, out.n_iter, residual, out.converged, names)


def _validate_constrained(b, A, mu_b, beta_b, beta, joint, boundary, box, scale, inv_s2,
                          n_iter) -> tuple[torch.Tensor, torch.Tensor]:
    """``(keep, mu)``, each ``(B,)``: TVAL3's hold-out check of ``mu="auto"``
    (:func:`torchtof.recon.tval3._validate_constrained`, the same folds, models and slack)
    for the joint model: ``keep`` where the constrained model predicts the held-out buckets
    (all channels) within :data:`~torchtof.recon.tval3.AUTO_CV_SLACK` of the better of the
    TV-L2 weights ``μ`` and ``4μ`` around the noise estimate's; ``mu`` the better of the two.
    ``b``: the scaled buckets, ``scale = gain/√s₂`` the image's factor into ``u``. A tail
    estimate reads signal as noise when few high-order rows carry no signal (e.g. n = 16): its
    TV-L2 weight is then so small that the image came out flat."""
    bsz, c, m = b.shape
    held, train = holdout_split(A, 3, b, 0, default_split(A))  # (F, M)
    nm = 3  # models: constrained, TV-L2 μ, TV-L2 4μ (model-major blocks of the batch)
    mus = torch.cat((torch.full_like(mu_b, AUTO_MU_MAX), mu_b, AUTO_CV_FACTOR * mu_b))
    betas = torch.cat((torch.full_like(beta_b, float(beta)), beta_b, beta_b))
    cons = torch.zeros(nm * bsz, dtype=torch.bool, device=b.device)
    cons[:bsz] = True
    per = (nm * bsz, c)
    bounds = tuple(None if v is None else float(v) * scale.repeat(nm).reshape(-1, 1, 1, 1)
                   for v in box)
    err = b.new_zeros(nm * bsz)
    sq = math.sqrt(inv_s2)
    for f in range(held.shape[0]):
        op = MaskedRows(A, train[f : f + 1])
        bt = b.repeat(nm, 1, 1) * train[f].to(b.dtype)
        out = admm_tv(bt, op, mus[:, None].expand(per), betas[:, None].expand(per),
                      cons[:, None].expand(per), tv="isotropic", boundary=boundary,
                      joint=joint, bounds=bounds, inv_s2=inv_s2,
                      max_iter=min(n_iter, AUTO_CV_MAX_ITER), stop_over_channels=True)
        pred = A(out.u) * sq  # the scaled buckets' prediction, all rows
        err = err + ((pred - b.repeat(nm, 1, 1)) * held[f].to(b.dtype)).pow(2).sum(dim=(1, 2))
    err = err.reshape(nm, bsz)
    return holdout_choice(err[0], err[1], err[2], mu_b)


class JointTVResult(NamedTuple):
    """Output of :meth:`JointTV.solve` (and ``joint_tv(..., return_result=True)``).

    Attributes:
        x: images ``(B, C, n, n)``.
        n_iter: iterations per sample ``(B, C)`` (channels of one sample stop together).
        residual: ``‖A x − y‖ / ‖y‖`` per sample ``(B, C)``.
        converged: ``(B, C)`` bool (the change test met before ``n_iter``).
        stop_reason: ``"tol"`` or ``"max_iter"`` per sample ``[b][c]``.
    """

    x: torch.Tensor
    n_iter: torch.Tensor
    residual: torch.Tensor
    converged: torch.Tensor
    stop_reason: tuple


def _chi_cdf(x: float, c: int) -> float:
    """CDF of the chi distribution with ``c`` degrees of freedom at ``x >= 0``: the regularised
    lower incomplete gamma function ``P(c/2, x²/2)``, by the recurrence
    ``P(a + 1, t) = P(a, t) − tᵃ e^{−t}/Γ(a + 1)`` from ``P(1, t) = 1 − e^{−t}`` or
    ``P(½, t) = erf(√t)`` (Abramowitz & Stegun, *Handbook of Mathematical Functions*,
    §6.5)."""
    t = 0.5 * x * x
    a, p = (1.0, -math.expm1(-t)) if c % 2 == 0 else (0.5, math.erf(math.sqrt(t)))
    while a < 0.5 * c:
        p -= math.exp(a * math.log(t) - t - math.lgamma(a + 1.0)) if t > 0 else 0.0
        a += 1.0
    return p


@functools.lru_cache(maxsize=32)
def _chi_quantile(c: int, q: float) -> float:
    """The ``q``-quantile of the chi distribution with ``c`` degrees of freedom (bisection on
    :func:`_chi_cdf`; ``c = 1``: the half-normal ``Φ⁻¹((1+q)/2)``, ``c = 2``: the Rayleigh
    ``√(−2 ln(1 − q))``)."""
    lo, hi = 0.0, 1.0
    while _chi_cdf(hi, c) < q:
        hi *= 2.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if _chi_cdf(mid, c) < q:
            lo = mid
        else:
            hi = mid
        if hi - lo <= 1e-15 * hi:
            break
    return 0.5 * (lo + hi)


def _channel_noise_sigma(y: torch.Tensor) -> torch.Tensor:
    """Noise std ``(B,)`` of buckets ``(B, C, M)`` with the same white noise on every channel,
    invariant to a rotation of the channel vector (e.g. a global phase of the I/Q pair).

    The tail rule of :func:`~torchtof.recon.bucket_noise_sigma` (a low quantile ``q`` of the
    high-order measurements) applied to the length ``r_i = ‖y_{·,i}‖₂`` of each measurement's
    channel vector: noise alone makes ``r = σχ_C`` (chi with ``C`` degrees of freedom), so
    ``σ̂ = Q_q(r) / χ_C⁻¹(q)``. One channel: :func:`~torchtof.recon.bucket_noise_sigma` itself.

    Example:
        >>> g = torch.Generator().manual_seed(0)
        >>> y = 0.5 * torch.randn(1, 2, 65536, generator=g)
        >>> round(float(_channel_noise_sigma(y)), 1)
        0.5
    """
    if y.shape[1] == 1:
        return bucket_noise_sigma(y)[:, 0]
    q = NOISE_QUANTILE
    half_normal = NormalDist().inv_cdf((1.0 + q) / 2)  # what bucket_noise_sigma divides by
    r = y.norm(dim=1, keepdim=True)
    return bucket_noise_sigma(r)[:, 0] * (half_normal / _chi_quantile(int(y.shape[1]), q))


def _noise_tensor(noise_sigma: torch.Tensor, y: torch.Tensor, fn: str) -> torch.Tensor:
    """``(B,)`` noise std from a tensor ``noise_sigma`` of one or ``B`` entries, checked (a real
    float tensor, finite and ``>= 0``: one host read, eager mode)."""
    check_real(noise_sigma, "noise_sigma", fn)
    b = y.shape[0]
    if noise_sigma.numel() not in (1, b):
        raise ValueError(f"{fn}: expected noise_sigma a float or a tensor of one or B = {b} "
                         f"entries (one per sample), got shape {tuple(noise_sigma.shape)}")
    s = noise_sigma.to(dtype=y.dtype, device=y.device).reshape(-1)
    if not is_tracing() and s.device.type != "meta":
        neg, bad = torch.stack(((s < 0).any(), ~s.isfinite().all())).tolist()  # one read
        if bad or neg:
            raise ValueError(f"{fn}: expected noise_sigma >= 0 and finite, got "
                             f"{noise_sigma.tolist()}")
    return s.expand(b)


def _check_jtv_options(fn: str, mu, beta, n_iter, tol, joint=True, adaptive=True,
                       boundary="periodic", bounds=None) -> None:
    check_bool(joint, "joint", fn)
    check_bool(adaptive, "adaptive", fn)
    if boundary not in BOUNDARIES:
        raise ValueError(f"{fn}: expected boundary in {BOUNDARIES}, got {boundary!r}")
    box_bounds(False, bounds, fn)
    if isinstance(mu, str):
        if mu != "auto":
            raise ValueError(f"{fn}: expected mu to be a positive number or 'auto', got {mu!r}")
    else:
        check_positive(mu, "mu", fn)
    check_positive(beta, "beta", fn)
    check_positive(tol, "tol", fn)
    if isinstance(n_iter, bool) or not isinstance(n_iter, int):
        raise TypeError(f"{fn}: expected n_iter to be an int, got {type(n_iter).__name__}")
    if n_iter < 1:
        raise ValueError(f"{fn}: expected n_iter >= 1, got {n_iter}")


class JointTV(nn.Module):
    """Module of :func:`joint_tv`: ``forward(y (B, C, M)) -> (B, C, n, n)``.

    The noise level of the buckets (for ``mu="auto"``) is a second input: give it to the
    constructor (``noise_sigma``, e.g. :func:`tap_noise_sigma` of the tap buckets) or per call
    as ``forward(y, noise_sigma)`` / ``solve(y, noise_sigma)`` (which
    :class:`DepthResolved` does with the I/Q noise it measures); the per-call value wins.

    Args:
        A: the operator (a submodule). joint, mu, beta, n_iter, tol, adaptive, noise_sigma,
            boundary, bounds: as :func:`joint_tv`.

    Example:
        >>> from torchtof.operators import Hadamard
        >>> JointTV(Hadamard(8, sr=0.5))(torch.zeros(2, 2, 32)).shape
        torch.Size([2, 2, 8, 8])
    """

    #: :class:`DepthResolved` passes the noise std of the I/Q buckets to ``forward``.
    accepts_noise_sigma = True

    def __init__(self, A: LinearOperator, joint: bool = True, mu: float | str = "auto",
                 beta: float = 2.0**5, n_iter: int = 300, tol: float = 1e-6,
                 adaptive: bool = True, noise_sigma: float | None = None,
                 boundary: str = "periodic", bounds: tuple | None = None) -> None:
        super().__init__()
        if not isinstance(A, LinearOperator):
            raise TypeError(f"JointTV: expected A to be a LinearOperator, got {type(A).__name__}")
        _check_jtv_options("JointTV", mu, beta, n_iter, tol, joint, adaptive, boundary, bounds)
        check_exact_memory(A, torch.empty(0), boundary, "JointTV", _JTV_MEMORY_HINT)
        if noise_sigma is not None:
            check_positive(noise_sigma, "noise_sigma", "JointTV", strict=False)
        self.A = A
        self.noise_sigma = noise_sigma
        self.options = dict(joint=joint, mu=mu, beta=beta, n_iter=n_iter, tol=tol,
                            adaptive=adaptive, boundary=boundary, bounds=bounds)

    def solve(self, y: torch.Tensor, noise_sigma: torch.Tensor | float | None = None
              ) -> JointTVResult:
        ns = self.noise_sigma if noise_sigma is None else noise_sigma
        return joint_tv(y, self.A, noise_sigma=ns, return_result=True, **self.options)

    def forward(self, y: torch.Tensor, noise_sigma: torch.Tensor | float | None = None
                ) -> torch.Tensor:
        return self.solve(y, noise_sigma).x

    def extra_repr(self) -> str:
        o = self.options
        return f"joint={o['joint']}, mu={o['mu']!r}, beta={o['beta']}, n_iter={o['n_iter']}"


# -- depth-resolved reconstruction -------------------------------------------------------------


def _check_reconstructor(reconstructor: object, func: str) -> nn.Module:
    if not isinstance(reconstructor, nn.Module):
        raise TypeError(f"{func}: expected reconstructor to be an nn.Module, got "
                        f"{type(reconstructor).__name__}")
    from .correlation import CGI, DGI

    if isinstance(reconstructor, (CGI, DGI)):
        raise ValueError(
            f"{func}: {type(reconstructor).__name__} divides each channel by its own mean bucket "
            f"(g2 Eq. 9, DGI), so the tap or I/Q images lose their common scale and Eq. 7 fails "
            f"(2.4 m depth error, noise-free, SR 100 %); use TGI (linear) for the correlation "
            f"family"
        )
    return reconstructor


def _operator_of(reconstructor: nn.Module) -> LinearOperator | None:
    A = getattr(reconstructor, "A", None)
    return A if isinstance(A, LinearOperator) else None


def _noise_gain(reconstructor: nn.Module, n_pix: int) -> float | None:
    """Noise std of an image pixel per unit noise std of the buckets, at the scale of the
    reconstructor's images, or ``None`` where it is not known (module docstring, "Amplitude
    mask"): ``√(M/N)`` for images in the units of ``A⁺y``, ``√((M − 1)/N)/M`` (RMS over the
    pixels) for TGI, both for an operator with orthonormal rows."""
    from .correlation import TGI

    A = _operator_of(reconstructor)
    if A is None or not A.orthonormal_rows:
        return None
    if isinstance(reconstructor, TGI):  # Aᵀ(y − ⟨y⟩)/M
        return math.sqrt((A.m - 1) / n_pix) / A.m
    return math.sqrt(min(A.m, n_pix) / n_pix)


def depth_resolved(
    y: torch.Tensor,
    reconstructor: nn.Module,
    freq_hz: float = 30e6,
    mode: str = "iq",
    k_sigma: float = MASK_K_SIGMA,
    rel_floor: float = MASK_REL,
    noise_sigma: torch.Tensor | float | None = None,
    no_photon_m: float | None = None,
) -> DepthResult:
    """Depth, amplitude and phase per DMD pixel from per-tap (or I/Q) buckets.

    ``mode="iq"``: four tap buckets are turned into I/Q buckets (:func:`iq_buckets`), the
    reconstructor makes the images ``Î, Q̂`` (two channels in one call, so a joint
    reconstructor such as :class:`JointTV` sees both), then per pixel Eq. 7
    ``θ = atan2(Q̂, Î)``, Eq. 8 ``Â = ½ hypot(Î, Q̂)`` and Eq. 1 ``d = cθ/(4πf)``.
    ``mode="taps"``: the four tap images are reconstructed (four channels) and Eqs. 7/8
    take their differences; for a linear reconstructor both modes agree.

    Args:
        y: tap buckets ``(B, 4, M')`` in the Fig. 1 order, or I/Q buckets ``(B, 2, M')``
            (``mode="iq"`` only); ``M'`` is what the reconstructor takes (``M`` for the
            ±1 operators, ``2M`` for the correlation family on DMD buckets).
        reconstructor: any module ``(B, C, M') -> (B, C, n, n)`` that treats the channels
            alike up to a scale per channel: PseudoInverse, TGI (the correlation family on
            DMD buckets), TVAL3, BasisPursuit, UnrolledTVAL3, :class:`JointTV` … Not g2/CGI
            or DGI: they divide each channel by its own mean bucket (raises). One that sets
            ``accepts_noise_sigma`` gets ``noise_sigma=`` too.
        freq_hz: modulation frequency in Hz (30 MHz: range ``c/(2f) ≈ 5.0 m``).
        mode: ``"iq"`` or ``"taps"``.
        k_sigma, rel_floor: the mask rule (module docstring); ``k_sigma ≥ 0``,
            ``rel_floor ∈ [0, 1)``.
        noise_sigma: noise std of the I/Q buckets, ``(B,)`` or a float; ``None``: from the
            taps (:func:`tap_noise_sigma`) for four-tap input, else no noise term in the mask.
            A reconstructor that takes ``noise_sigma`` gets it when it is given or measured
            from the taps; with I/Q input and ``None`` it estimates the noise itself (a zero
            would make :class:`JointTV` fit the noise exactly).
        no_photon_m: depth reported by masked pixels, metres ``>= 0`` (module docstring;
            the camera's rule is 5 m); ``None``: the Eq. 1 depth on every pixel.

    Returns:
        :class:`DepthResult`.

    Raises:
        TypeError: if ``y`` is not a real floating tensor or ``reconstructor`` not a module.
        ValueError: on a wrong shape, NaN/Inf, an unknown ``mode``, I/Q input with
            ``mode="taps"``, or a reconstructor output of the wrong shape.

    Shape:
        - y: :math:`(B, 4, M')` or :math:`(B, 2, M')`.
        - Output: depth, amplitude, phase, mask :math:`(B, 1, n, n)`.

    The noise term of the mask needs the scale of the reconstructor's images: known for the
    pseudo-inverse scale and for TGI on an operator with orthonormal rows (module docstring);
    for any other the relative floor alone applies.

    Example:
        >>> from torchtof.operators import Hadamard
        >>> from torchtof.recon import PseudoInverse
        >>> from torchtof.sensor import correlation_taps, phasor_from_depth
        >>> A = Hadamard(8, sr=1.0)
        >>> taps = correlation_taps(phasor_from_depth(100.0, torch.full((1, 1, 8, 8), 2.0),
        ...                                           30e6), offset=50.0)
        >>> res = depth_resolved(A(taps), PseudoInverse(A))
        >>> round(float(res.depth.mean()), 4), bool(res.mask.all())
        (2.0, True)
    """
    func = "depth_resolved"
    _check_buckets(y, func)
    _check_reconstructor(reconstructor, func)
    f = check_positive(freq_hz, "freq_hz", func)
    if mode not in MODES:
        raise ValueError(f"{func}: expected mode in {MODES}, got {mode!r}")
    k = check_positive(k_sigma, "k_sigma", func, strict=False)
    r = check_positive(rel_floor, "rel_floor", func, strict=False)
    if r >= 1:
        raise ValueError(f"{func}: expected rel_floor in [0, 1), got {rel_floor}")
    fill = (None if no_photon_m is None
            else check_positive(no_photon_m, "no_photon_m", func, strict=False))
    taps_in = y.shape[1] == 4
    if mode == "taps" and not taps_in:
        raise ValueError(f"{func}: mode='taps' needs tap buckets (B, 4, M), got {tuple(y.shape)}")
    if noise_sigma is None:
        sigma = tap_noise_sigma(y) if taps_in else y.new_zeros(y.shape[0])
    elif isinstance(noise_sigma, torch.Tensor):
        sigma = _noise_tensor(noise_sigma, y, func)
    else:
        sigma = y.new_full((y.shape[0],), check_positive(noise_sigma, "noise_sigma", func, False))
    meas = iq_buckets(y) if (mode == "iq" and taps_in) else y
    known = noise_sigma is not None or taps_in  # else sigma is a zero placeholder (mask only)
    accepts = getattr(reconstructor, "accepts_noise_sigma", False)
    kw = {"noise_sigma": sigma} if (known and accepts) else {}
    solve = getattr(reconstructor, "solve", None)
    sol = solve(meas, **kw) if callable(solve) else None
    images = reconstructor(meas, **kw) if sol is None else sol.x
    ok = isinstance(images, torch.Tensor) and images.ndim == 4
    if not ok or images.shape[:2] != meas.shape[:2]:
        got = tuple(images.shape) if isinstance(images, torch.Tensor) else type(images).__name__
        raise ValueError(f"{func}: expected the reconstructor to return (B, {meas.shape[1]}, n, n),"
                         f" got {got}")
    if mode == "iq":
        phase, amplitude = iq_phase_amplitude(images)
    else:
        phase, amplitude = tap_phase(images), tap_amplitude(images)
    n_pix = images.shape[-1] * images.shape[-2]
    gain = _noise_gain(reconstructor, n_pix)
    if gain is not None:  # pixel noise, e.g. σ_y √(M/N) (module docstring)
        noise_amp = 0.5 * sigma * gain
    else:  # unknown scale of the image noise: the relative floor alone
        noise_amp = torch.zeros_like(sigma)
    peak = amplitude.flatten(1).amax(dim=1)
    threshold = torch.maximum(k * noise_amp, r * peak)
    mask = amplitude > threshold.reshape(-1, 1, 1, 1)
    depth = phase_to_depth(phase, f)
    if fill is not None:  # masked pixels: the no-photon depth (module docstring)
        depth = torch.where(mask, depth, torch.full_like(depth, fill))
    if sol is None:
        return DepthResult(depth, amplitude, phase, mask, images, threshold, depth)
    return DepthResult(depth, amplitude, phase, mask, images, threshold, depth, sol.n_iter,
                       sol.residual, sol.converged, getattr(sol, "stop_reason", ()))


class DepthResolved(nn.Module):
    """Depth-resolved ghost imaging (:func:`depth_resolved`) with the reconstructor inside.

    ``solve(y)`` returns the :class:`DepthResult`; ``forward(y)`` returns the depth map
    ``(B, 1, n, n)`` (tensor in, tensor out, for export; with ``no_photon_m`` given, masked
    pixels report it, so the map carries the mask); ``depth_amplitude(y)`` returns
    ``(depth, amplitude)``.

    Args:
        reconstructor: any reconstructor module (see :func:`depth_resolved`).
        freq_hz: modulation frequency in Hz.
        mode, k_sigma, rel_floor, no_photon_m: as :func:`depth_resolved`.

    Example:
        >>> from torchtof.operators import Hadamard
        >>> from torchtof.recon import PseudoInverse
        >>> net = DepthResolved(PseudoInverse(Hadamard(8, sr=0.5)), freq_hz=30e6)
        >>> net(torch.rand(2, 4, 32)).shape
        torch.Size([2, 1, 8, 8])
    """

    def __init__(self, reconstructor: nn.Module, freq_hz: float = 30e6, mode: str = "iq",
                 k_sigma: float = MASK_K_SIGMA, rel_floor: float = MASK_REL,
                 no_photon_m: float | None = None) -> None:
        super().__init__()
        func = "DepthResolved"
        _check_reconstructor(reconstructor, func)
        check_positive(freq_hz, "freq_hz", func)
        if mode not in MODES:
            raise ValueError(f"{func}: expected mode in {MODES}, got {mode!r}")
        check_positive(k_sigma, "k_sigma", func, strict=False)
        if not 0 <= check_positive(rel_floor, "rel_floor", func, strict=False) < 1:
            raise ValueError(f"{func}: expected rel_floor in [0, 1), got {rel_floor}")
        self.reconstructor = reconstructor
        self.freq_hz = float(freq_hz)
        self.mode = mode
        self.k_sigma, self.rel_floor = float(k_sigma), float(rel_floor)
        self.no_photon_m = (None if no_photon_m is None
                            else check_positive(no_photon_m, "no_photon_m", func, strict=False))

    def solve(self, y: torch.Tensor, noise_sigma: torch.Tensor | float | None = None
              ) -> DepthResult:
        return depth_resolved(y, self.reconstructor, self.freq_hz, self.mode, self.k_sigma,
                              self.rel_floor, noise_sigma, self.no_photon_m)

    def depth_amplitude(self, y: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        res = self.solve(y)
        return res.depth, res.amplitude

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        return self.solve(y).depth

    def extra_repr(self) -> str:
        return f"freq_hz={self.freq_hz:g}, mode={self.mode!r}"


# -- two frequencies ---------------------------------------------------------------------------


def _unambiguous(freq_hz: float) -> float:
    return SPEED_OF_LIGHT / (2.0 * freq_hz)


#: :func:`dual_frequency_depth` takes ``f₁/f₂`` as the ratio ``p/q`` of two coprime integers
#: when the two phases then realign at the common range to within this fraction of the
#: hypothesis spacing (see :func:`common_range`).
RATIO_TOL = 1e-3
#: At most this many wrap-count pairs ``(n₁, n₂)`` per pixel in :func:`dual_frequency_depth`.
MAX_HYPOTHESES = 1 << 16


class CommonRange(NamedTuple):
    """Output of :func:`common_range`."""

    p: int  #: ``f₁ ≈ p·f_E``
    q: int  #: ``f₂ ≈ q·f_E``
    freq_hz: float  #: the common (beat) frequency ``f_E = (f₁ + f₂)/(p + q)``
    range_m: float  #: the common unambiguous range ``c/(2f_E)``
    spacing_m: float  #: the hypothesis spacing ``c/(2f_E·p·q)``


def _pairs(p: int, q: int) -> int:
    return (p + 2) * (q + 2)  # wrap counts -1 … p and -1 … q (dual_frequency_depth)


def common_range(freq_1_hz: float, freq_2_hz: float) -> CommonRange:
    """Common unambiguous range of two modulation frequencies.

    With ``f₁ = p·f_E`` and ``f₂ = q·f_E`` for coprime integers ``p, q`` the two phases
    repeat together every ``c/(2f_E)``: the dual-frequency range of Jongenelen, Bailey,
    Payne, Dorrington & Carnegie, "Analysis of errors in ToF range imaging with
    dual-frequency modulation", IEEE Trans. Instrum. Meas. 60(5), 2011 (``f_E`` the greatest
    common divisor of the two frequencies); two wrap-count pairs then differ by a multiple of
    the hypothesis spacing ``c/(2f_E·p·q)`` (``|n₁R₁ − n₂R₂| = (c/2f_E)|n₁q − n₂p|/(pq)``,
    ``R_k = c/(2f_k)``).

    Real frequencies are not exact multiples of a round one (the OPT8241's PLL makes
    19 999 992.37 Hz for 20 MHz; the greatest common divisor of the rounded frequencies is
    then 8 Hz, an 18 750 km range and 10¹³ hypotheses). ``p/q`` is therefore the first
    continued-fraction convergent of ``f₁/f₂`` (the best rational approximations, Hardy &
    Wright, *An Introduction to the Theory of Numbers*, Thm. 181) for which the two phases
    realign at the common range to within :data:`RATIO_TOL` of the spacing:
    ``(c/2)|p/f₁ − q/f₂| ≤ RATIO_TOL · c/(2f_E·p·q)``, with ``f_E = (f₁ + f₂)/(p + q)``
    (exact when ``f₁/f₂ = p/q``). The mismatch moves an unwrapped depth by at most that
    much: 2.5 mm for the PLL's 30 + 19.999 992 MHz, which give 3/2 like 30 + 20 MHz.

    Raises:
        ValueError: if a frequency is not ``> 0``, if the two are equal to within the
            tolerance (``p = q = 1``: nothing to unwrap), or if no ratio with at most
            :data:`MAX_HYPOTHESES` wrap-count pairs ``(p + 2)(q + 2)`` meets the tolerance.

    Example:
        >>> r = common_range(30e6, 19_999_992.37)
        >>> (r.p, r.q), round(r.range_m, 3), round(r.spacing_m, 3)
        ((3, 2), 14.99, 2.498)
    """
    return _common_range(freq_1_hz, freq_2_hz, "common_range")


def _common_range(freq_1_hz: float, freq_2_hz: float, func: str) -> CommonRange:
    f1 = check_positive(freq_1_hz, "freq_1_hz", func)
    f2 = check_positive(freq_2_hz, "freq_2_hz", func)
    x = Fraction(f1) / Fraction(f2)
    p0, p = 0, 1  # convergent numerators h_{k-2}, h_{k-1}
    q0, q = 1, 0  # denominators
    while True:
        a = math.floor(x)
        p0, p = p, a * p + p0
        q0, q = q, a * q + q0
        if _pairs(p, q) > MAX_HYPOTHESES:
            raise ValueError(
                f"{func}: {f1:.10g} and {f2:.10g} Hz have no common range within "
                f"{MAX_HYPOTHESES} wrap-count pairs per pixel: the ratio {p}/{q} needs "
                f"{_pairs(p, q)} pairs, about {format_bytes(2 * 4 * _pairs(p, q))} per float32 "
                f"pixel (choose frequencies with a small-integer ratio, such as 30 and 20 MHz)")
        if p > 0:
            fe = (f1 + f2) / (p + q)
            if abs(p / f1 - q / f2) * fe * p * q <= RATIO_TOL:
                break
        if x == a:  # pragma: no cover - an exact ratio meets the tolerance above
            break
        x = 1 / (x - a)
    if p == q:
        raise ValueError(f"{func}: expected two different frequencies, got {f1:.10g} and "
                         f"{f2:.10g} Hz (ratio 1/1 to within RATIO_TOL = {RATIO_TOL:g}, see "
                         f"common_range)")
    rng = _unambiguous(fe)
    return CommonRange(p, q, fe, rng, rng / (p * q))


def dual_frequency_depth(
    phase_1: torch.Tensor,
    phase_2: torch.Tensor,
    freq_1_hz: float,
    freq_2_hz: float,
    max_m: float | None = None,
    return_gap: bool = False,
) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
    """Unwrapped depth from the phases at two modulation frequencies (hypothesis search).

    Each phase gives a depth up to a whole number of its unambiguous range
    ``R_k = c/(2f_k)``: ``d = R_k (θ_k/2π + n_k)``. Every pair ``(n₁, n₂)`` with both
    depths in ``[0, max_m)`` is a hypothesis; the pair whose two depths agree best wins
    and the depth is their inverse-variance mean (equal phase noise: weights ``∝ f_k²``),
    wrapped into ``[0, max_m)`` (the hypothesis search of multi-frequency ToF unwrapping,
    e.g. Järemo Lawin, Forssén & Ovrén, ECCV 2016, without their spatial voting). The
    default ``max_m`` is the common range of :func:`common_range` (``c/(2f_E)`` with
    ``f₁ = p·f_E``, ``f₂ = q·f_E``, ``p/q`` the ratio of the frequencies to within a
    tolerance): 15 m for 30 + 20 MHz. Vectorised over the hypotheses (no Python loop over
    pixels) and free of data-dependent control flow; it holds ``2·(p + 2)(q + 2)`` values per
    pixel (memory checked first, :func:`torchtof.set_memory_limit`).

    Args:
        phase_1, phase_2: phases in ``[0, 2π)`` at ``freq_1_hz``/``freq_2_hz``, same shape
            (Eq. 7 as :func:`~torchtof.sensor.tap_phase` wraps it; ``2π`` itself, which a
            rounded ``remainder`` can return, is accepted).
        freq_1_hz, freq_2_hz: the two frequencies in Hz, different, ``> 0``.
        max_m: the range to unwrap into, metres, ``≤`` the common range (default it).
        return_gap: also return the disagreement ``|d₁ − d₂|`` of the chosen pair (metres),
            a confidence: wrong pairs differ by a multiple of the hypothesis spacing
            ``c/(2f_E·p·q)`` (2.5 m for 30 + 20 MHz, :func:`hypothesis_spacing`), so a gap
            near half of it flags a pixel whose two phases do not describe one depth (noise,
            mixed pixels).

    Returns:
        Depth in metres, the shape of ``phase_1`` (and the gap, same shape).

    Raises:
        TypeError: if a phase is not a real floating tensor.
        ValueError: on different shapes, a phase outside ``[0, 2π]``, equal or non-positive
            frequencies, frequencies without a common range of at most
            :data:`MAX_HYPOTHESES` hypotheses, ``max_m`` outside ``(0, common range]``, or
            hypotheses that exceed the memory limit.

    Example:
        >>> d = torch.tensor([0.5, 4.0, 6.2, 11.0])
        >>> th = [(4 * math.pi * f * d / SPEED_OF_LIGHT) % (2 * math.pi) for f in (30e6, 20e6)]
        >>> [round(v, 4) for v in dual_frequency_depth(th[0], th[1], 30e6, 20e6).tolist()]
        [0.5, 4.0, 6.2, 11.0]
    """
    func = "dual_frequency_depth"
    for name, p in (("phase_1", phase_1), ("phase_2", phase_2)):
        check_tensor(p, name, func)
        if p.is_complex():
            raise TypeError(f"{func}: expected {name} to be a real tensor, got {p.dtype}")
        check_finite(p, name, func)
        _check_phase_range(p, name, func)
    if phase_1.shape != phase_2.shape:
        raise ValueError(f"{func}: expected phase_1 and phase_2 of the same shape, got "
                         f"{tuple(phase_1.shape)} and {tuple(phase_2.shape)}")
    cr = _common_range(freq_1_hz, freq_2_hz, func)
    f1, f2 = float(freq_1_hz), float(freq_2_hz)
    common = cr.range_m
    top = common if max_m is None else check_positive(max_m, "max_m", func)
    if top > common * (1 + 1e-9):
        raise ValueError(f"{func}: expected max_m <= the common range {common:.4g} m of "
                         f"{f1:g} and {f2:g} Hz, got {max_m}")
    r1, r2 = _unambiguous(f1), _unambiguous(f2)
    # wrap counts from -1 (a phase just below 2π for a depth just above 0) to past max_m
    # (the relative 1e-12: max_m = p·R₁ in floating point must give p, not p + 1)
    k1 = math.ceil(top / r1 * (1 - 1e-12)) + 2
    k2 = math.ceil(top / r2 * (1 - 1e-12)) + 2
    check_memory(2 * phase_1.numel() * k1 * k2 * phase_1.element_size(),
                 f"{k1}x{k2} wrap-count hypotheses for {phase_1.numel()} phases", func,
                 "unwrap fewer pixels at a time or give a smaller max_m")
    n1 = torch.arange(-1, k1 - 1, dtype=phase_1.dtype, device=phase_1.device)
    n2 = torch.arange(-1, k2 - 1, dtype=phase_1.dtype, device=phase_1.device)
    two_pi = 2.0 * math.pi
    d1 = r1 * (phase_1.unsqueeze(-1) / two_pi + n1)  # (..., N1)
    d2 = r2 * (phase_2.unsqueeze(-1) / two_pi + n2)  # (..., N2)
    gap = (d1.unsqueeze(-1) - d2.unsqueeze(-2)).abs()  # (..., N1, N2)
    best = gap.flatten(-2).argmin(dim=-1, keepdim=True)  # (..., 1)
    i1 = torch.div(best, n2.numel(), rounding_mode="floor")
    i2 = best - i1 * n2.numel()
    w1, w2 = f1 * f1, f2 * f2
    a1, a2 = d1.gather(-1, i1).squeeze(-1), d2.gather(-1, i2).squeeze(-1)
    depth = torch.remainder((w1 * a1 + w2 * a2) / (w1 + w2), top)
    return (depth, (a1 - a2).abs()) if return_gap else depth


def _check_phase_range(p: torch.Tensor, name: str, func: str) -> None:
    """Raise ``ValueError`` unless the phases lie in ``[0, 2π]`` (one host read at entry; eager
    mode only, as :func:`~torchtof._checks.check_finite`). The upper end has a slack of the
    dtype's rounding: ``remainder(θ, 2π)`` in float32 can return ``float32(2π) > 2π``."""
    if p.numel() == 0 or p.is_meta or is_tracing():
        return
    lo, hi = (float(v) for v in torch.aminmax(p.detach()))
    top = 2.0 * math.pi * (1.0 + 4 * torch.finfo(p.dtype).eps)
    if lo < 0 or hi > top:
        raise ValueError(f"{func}: expected {name} in [0, 2π) (Eq. 7 wrapped, e.g. "
                         f"torch.remainder(θ, 2π)), got values in [{lo:.6g}, {hi:.6g}]")


def hypothesis_spacing(freq_1_hz: float, freq_2_hz: float) -> float:
    """Smallest non-zero ``|n₁R₁ − n₂R₂|`` of :func:`dual_frequency_depth`'s hypotheses,
    ``c/(2f_E·p·q)`` metres (:func:`common_range`; 2.5 m for 30 + 20 MHz)."""
    return _common_range(freq_1_hz, freq_2_hz, "hypothesis_spacing").spacing_m


class DualFrequencyDepth(nn.Module):
    """Depth-resolved reconstructions at two frequencies, unwrapped (:func:`dual_frequency_depth`).

    ``forward(y_1, y_2)``: tap buckets at ``freq_1_hz`` and ``freq_2_hz`` (each
    ``(B, 4, M')``) → unwrapped depth ``(B, 1, n, n)``.

    Args:
        reconstructor: used for both frequencies (the same patterns are shown twice).
        freq_1_hz, freq_2_hz: the frequencies (default 30 and 20 MHz: 15 m range).
        mode: as :func:`depth_resolved`.
        max_m: as :func:`dual_frequency_depth`.
    """

    def __init__(self, reconstructor: nn.Module, freq_1_hz: float = 30e6,
                 freq_2_hz: float = 20e6, mode: str = "iq", max_m: float | None = None) -> None:
        super().__init__()
        self.rec_1 = DepthResolved(reconstructor, freq_1_hz, mode)
        self.rec_2 = DepthResolved(reconstructor, freq_2_hz, mode)
        dual_frequency_depth(torch.zeros(1), torch.zeros(1), freq_1_hz, freq_2_hz, max_m)
        self.freqs_hz = (float(freq_1_hz), float(freq_2_hz))
        self.max_m = max_m

    def solve(self, y_1: torch.Tensor, y_2: torch.Tensor) -> DepthResult:
        """:class:`DepthResult` with the unwrapped depth; amplitude, phase and images of the
        first frequency; the mask: both amplitude masks, and the two depths of the chosen
        hypothesis agree within a quarter of the hypothesis spacing (0.62 m for 30 + 20 MHz;
        wrong pairs differ by a multiple of the spacing). Unlike :func:`depth_resolved` the
        depth is not filled where the mask is off: it is the unwrapped depth of the two phases
        on every pixel (the mask says which to trust)."""
        a, b = self.rec_1.solve(y_1), self.rec_2.solve(y_2)
        depth, gap = dual_frequency_depth(a.phase, b.phase, *self.freqs_hz, self.max_m,
                                          return_gap=True)
        ok = gap < 0.25 * hypothesis_spacing(*self.freqs_hz)
        return a._replace(depth=depth, x=depth, mask=a.mask & b.mask & ok)

    def forward(self, y_1: torch.Tensor, y_2: torch.Tensor) -> torch.Tensor:
        return self.solve(y_1, y_2).depth

