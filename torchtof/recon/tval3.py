"""TVAL3: total-variation minimisation by an augmented Lagrangian (Li, Yin, Jiang, Zhang 2013).

The solver is a batched transcription of TVAL3's ``ftvcs_alp`` (v1.0; C. Li, Rice MS thesis
2009). It solves

.. math::

    \\min_u \\sum_i \\|D_i u\\| \\quad \\text{s.t.} \\quad A u = b \\quad (\\text{and } u \\ge 0)

by splitting ``w_i = D_i u`` and minimising the augmented Lagrangian

.. math::

    \\mathcal L(w, u) = \\sum_i \\|w_i\\| - \\sigma^T (Du - w) + \\tfrac{\\beta}{2}\\|Du - w\\|^2
    - \\delta^T (Au - b) + \\tfrac{\\mu}{2}\\|Au - b\\|^2

by alternating a shrinkage ``w``-step with one steepest-descent ``u``-step (Barzilai–Borwein
length, Barzilai & Borwein 1988; nonmonotone Armijo search, Zhang & Hager 2004) until the inner
relative change drops below ``tol_inner``, then updating the multipliers
``σ ← σ − β(Du − w)``, ``δ ← δ − μ(Au − b)``. The TV-L2 model
``min Σ‖D_i u‖ + μ/2‖Au − b‖²`` (TVAL3's ``ftvcs_al_TVL2p``) is the same iteration with
``δ ≡ 0``; it is what ``mu="auto"`` uses on noisy buckets (see :func:`tval3`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
from torch import nn

from .._checks import (
    check_bool,
    check_broadcast,
    check_finite,
    check_positive,
    check_real,
    check_shape,
    check_tensor,
    check_weight_range,
    is_tracing,
    run_loop,
)
from ..constants import DISCREPANCY_TAU
from ..operators.base import LinearOperator
from .base import pow2_scale, relative_residual
from .noise import abs_quantile_sigma, tail_noise_sigma
from .tv import (
    BOUNDARIES,
    box_bounds,
    bucket_spread,
    check_exact_memory,
    exact_factors,
    exact_solve,
    largest_eig_normal,
    loop_differences,
    project_box,
    scale_a,
    scaled_loop_pair,
    shrink,
)

__all__ = ["TVAL3", "TVAL3Result", "tval3", "bucket_noise_sigma", "STOP_REASONS", "MaskedRows",
           "holdout_split", "default_split"]

#: Spread ``max(b) − min(b)`` that the buckets are scaled to (TVAL3's ``Scaleb`` keeps spreads in
#: ``[0.5, 1.5]`` and maps larger ones to 1.5; we always map to 1.5, see :func:`tval3`).
B_SPREAD = 1.5
#: Published ``Scaleb`` lifts spreads below this to it (operators without orthonormal rows).
B_SPREAD_MIN = 0.5
#: ``mu="auto"``: TV-L2 weight ``μ = AUTO_KAPPA · σ_s^(−AUTO_POWER)``, ``σ_s`` the noise std of the
#: buckets scaled to spread 1.5 (calibration: see :func:`tval3`).
AUTO_KAPPA = 0.7
AUTO_POWER = 1.3
#: ``mu="auto"`` keeps the equality-constrained model with this ``μ`` (TVAL3's default ``2⁸``) when
#: the TV-L2 weight would exceed it (negligible noise).
AUTO_MU_MAX = 2.0**8
#: TV-L2 samples (``tvl2`` or ``mu="auto"``'s TV-L2 choice) use this multiple of ``beta`` (TVAL3's
#: TV-L2 solver wants a larger splitting weight: 4× gave +0.05–0.15 dB and ~15 % fewer
#: iterations in the calibration).
AUTO_TVL2_BETA = 4.0
#: ``mu="auto"``: the constrained model is kept when its hold-out error is within this relative
#: slack of the better TV-L2 model's (fewer training rows bias hold-out towards smoothing).
AUTO_CV_SLACK = 0.1
#: ``mu="auto"``: iteration cap of the hold-out solves (bounds the check's cost).
AUTO_CV_MAX_ITER = 300
#: ``mu="auto"``: the hold-out check also tries the TV-L2 model at this multiple of the
#: estimated weight (the tail estimate can only over-read the noise, so the weight it gives can
#: only be too small; see :func:`tval3`).
AUTO_CV_FACTOR = 4.0
#: :func:`bucket_noise_sigma`: fraction of the measurements (from the end) and the quantile used.
NOISE_TAIL = 0.25
NOISE_QUANTILE = 0.2
#: ``TVAL3Result.stop_reason`` codes: index into this tuple (``discrepancy``: Morozov's rule).
STOP_REASONS = ("tol", "max_outer", "discrepancy", "max_iter")
#: Morozov's safety factor ``τ`` of the ``discrepancy`` stop: ``‖A x − y‖² ≤ τ M σ²``.
_N_BACKTRACK = 5  # ftvcs_alp gives up after 5 backtracks


class TVAL3Result(NamedTuple):
    """Output of :func:`tval3`.

    Attributes:
        x: reconstruction ``(B, C, n, n)``.
        n_iter: inner iterations run per sample ``(B, C)`` (int64).
        residual: ``‖A x − y‖ / ‖y‖`` per sample ``(B, C)`` (0 for an all-zero ``y``).
        converged: ``(B, C)`` bool, ``True`` where the outer stopping rule was met before
            ``max_iter``.
        stop_reason: per sample names ``[b][c]`` from :data:`STOP_REASONS` (``"tol"``,
            ``"max_outer"``, ``"discrepancy"``, ``"max_iter"``); empty while tracing.
        stop_code: the same as a ``(B, C)`` int64 index into :data:`STOP_REASONS` (a tensor:
            it survives tracing and export).
    """

    x: torch.Tensor
    n_iter: torch.Tensor
    residual: torch.Tensor
    converged: torch.Tensor
    stop_reason: tuple = ()
    stop_code: torch.Tensor | None = None

    def reasons(self) -> list[list[str]]:
        """``stop_reason`` as lists, ``[b][c]``."""
        return [list(r) for r in self.stop_reason]


# -- small helpers ----------------------------------------------------------------------------


def _i(s: torch.Tensor) -> torch.Tensor:  # per-sample scalar (B, C) -> image broadcast
    return s[..., None, None]


def _f(s: torch.Tensor) -> torch.Tensor:  # per-sample scalar -> gradient-field broadcast
    return s[..., None, None, None]


def _dot_i(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return (a * b).sum(dim=(-2, -1))


def _dot_f(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return (a * b).sum(dim=(-3, -2, -1))


def _dot_v(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return (a * b).sum(dim=-1)


def _tv_of_w(w: torch.Tensor, isotropic: bool) -> torch.Tensor:
    """``Σ_i ‖w_i‖`` of a gradient field ``(B, C, 2, n, n) -> (B, C)``."""
    if isotropic:
        return torch.sqrt((w * w).sum(dim=-3)).sum(dim=(-2, -1))
    return w.abs().sum(dim=(-3, -2, -1))


def bucket_noise_sigma(
    y: torch.Tensor, tail: float = NOISE_TAIL, quantile: float = NOISE_QUANTILE
) -> torch.Tensor:
    """Noise std of the buckets from a low quantile of their high-order tail: TVAL3's
    ``mu="auto"`` estimate, :func:`torchtof.recon.noise.tail_noise_sigma` with TVAL3's
    ``tail`` and ``quantile`` (the one implementation; see it for the rule and its bias).

    Example:
        >>> y = 0.5 * torch.randn(1, 1, 65536, generator=torch.Generator().manual_seed(0))
        >>> round(float(bucket_noise_sigma(y)), 1)
        0.5
    """
    return tail_noise_sigma(y, tail, quantile)


def _tail_sigma(y: torch.Tensor, m: int, tail: float, quantile: float) -> torch.Tensor:
    """:func:`bucket_noise_sigma` with the number of measurements ``m`` as a Python int (all
    indices static, so tracing records no Python values); the quantile rule is
    :func:`~torchtof.recon.noise.abs_quantile_sigma`."""
    k = min(m, max(8, int(math.ceil(tail * m))))
    return abs_quantile_sigma(y[..., m - k :], quantile)


# -- the solver --------------------------------------------------------------------------------


def _where(mask: torch.Tensor, new: torch.Tensor, old: torch.Tensor) -> torch.Tensor:
    """``torch.where`` with a per-sample ``(B, C)`` mask (logical ops for bool state: ONNX
    Runtime has no boolean ``Where``)."""
    if new.dtype == torch.bool:
        return (mask & new) | (~mask & old)
    return torch.where(mask.reshape(mask.shape + (1,) * (new.ndim - mask.ndim)), new, old)


def check_buckets(y: torch.Tensor, A: LinearOperator, fn: str) -> None:
    """The checks of TVAL3-family solvers: ``A`` a :class:`LinearOperator`, ``y`` a finite
    float32/float64 tensor ``(B, C, A.m)`` (clear ``TypeError``/``ValueError`` naming ``fn``)."""
    check_tensor(y, "y", fn)
    if not isinstance(A, LinearOperator):
        raise TypeError(f"{fn}: expected A to be a LinearOperator, got {type(A).__name__}")
    check_shape(y, (None, None, A.m), "y", fn, "(B, C, M)")
    if y.is_complex() or y.dtype not in (torch.float32, torch.float64):
        raise TypeError(f"{fn}: expected y of dtype float32 or float64, got {y.dtype}")
    check_finite(y, "y", fn)


def auto_weights(
    sigma_s: torch.Tensor, beta: float
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``mu="auto"``: per-sample ``(μ, β, constrained)`` from the noise std ``σ_s`` of the
    buckets scaled to spread 1.5 (rule and calibration in :func:`tval3`):
    ``μ = 0.7 σ_s^−1.3``; above ``2⁸`` the constrained model with ``μ = 2⁸`` and ``β``,
    else TV-L2 with ``4β``."""
    mu_auto = AUTO_KAPPA * sigma_s.clamp_min(torch.finfo(sigma_s.dtype).tiny) ** (-AUTO_POWER)
    constrained = mu_auto > AUTO_MU_MAX
    mu = torch.where(constrained, torch.full_like(mu_auto, AUTO_MU_MAX), mu_auto)
    beta_t = torch.where(
        constrained, torch.full_like(mu, beta), torch.full_like(mu, AUTO_TVL2_BETA * beta)
    )
    return mu, beta_t, constrained


# -- hold-out validation (mu="auto" and torchtof.recon.auto) -------------------------------


class MaskedRows(LinearOperator):
    """An operator with a 0/1 row mask per channel (a measurement operator for hold-out
    validation, not a reconstructor): ``forward(u) = m ⊙ inner(u)``,
    ``adjoint(r) = innerᵀ(m ⊙ r)``, ``mask (C, M)``.

    ``normal`` is ``inner``'s own (an upper bound of the masked one), so TVAL3's ``ScaleA``
    uses ``inner``'s largest eigenvalue. ``orthonormal_rows`` is ``inner``'s too, although
    ``A Aᵀ = diag(mask)``: a fold's fit is the full problem with some buckets removed, so it
    is scaled as the full problem is (``Scaleb``'s spread 1.5), and its kept rows are
    orthonormal. ``mask`` has one row per channel; the dense helpers (``matrix``, ``gram``)
    describe one channel's operator and need ``C = 1``.
    """

    def __init__(self, inner: LinearOperator, mask: torch.Tensor) -> None:
        super().__init__(inner.n, inner.m)
        self.inner = inner
        self.orthonormal_rows = inner.orthonormal_rows
        self.register_buffer("mask", mask)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.inner(x) * self.mask.to(x.dtype)

    def adjoint(self, y: torch.Tensor) -> torch.Tensor:
        return self.inner.adjoint(y * self.mask.to(y.dtype))

    def normal(self, x: torch.Tensor) -> torch.Tensor:
        return self.inner.normal(x)

    def loop_pair(self, like: torch.Tensor):
        fwd, adj = self.inner.loop_pair(like)
        mask = self.mask.to(like.dtype)
        return (lambda x: fwd(x) * mask), (lambda y: adj(y * mask))


def holdout_split(A: LinearOperator, k: int, like: torch.Tensor, seed: int, split: str = "random"
           ) -> tuple[torch.Tensor, torch.Tensor]:
    """``(held, train)``, each ``(F, M)`` bool, one row per fold.

    ``"random"``: ``k`` folds of a random partition (rows that alone carry the mean, i.e.
    ``A·1`` nonzero on at most a quarter of the rows, are never held out); train = the rest.
    ``"tail"``: for rows in a low-to-high order, fold ``j < k − 1`` holds out the block
    ``[M − (j+1)h, M − jh)``, ``h = ⌈M/(2(k−1))⌉``, trained on the rows before it only; each
    fold predicts the next rows of the order from the earlier ones, as the final
    reconstruction predicts the unmeasured rows from the measured ones.
    """
    m = A.m
    if split == "tail":
        nf = max(1, k - 1)
        h = max(1, -(-m // (2 * nf)))
        held = torch.zeros(nf, m, dtype=torch.bool, device=like.device)
        train = torch.zeros_like(held)
        for j in range(nf):
            # clamped: past the first row a fold is empty (a negative end would wrap around)
            lo, hi = max(1, m - (j + 1) * h), max(1, m - j * h)
            held[j, lo:hi] = True
            train[j, :lo] = True
        return held, train
    with torch.no_grad():
        ones = torch.ones(1, 1, A.n, A.n, dtype=like.dtype, device=like.device)
        a = A(ones).reshape(-1).abs()
    dc = a > 1e-6 * a.max()
    keep = dc if int(dc.sum()) <= m // 4 else torch.zeros_like(dc)
    idx = torch.nonzero(~keep).reshape(-1)
    g = torch.Generator().manual_seed(seed)
    perm = idx[torch.randperm(len(idx), generator=g).to(idx.device)]
    held = torch.zeros(k, m, dtype=torch.bool, device=like.device)
    for j in range(k):
        held[j, perm[j::k]] = True
    return held, ~held


#: Hadamard orders whose rows run from low to high sequency (cross-validation holds out the tail).
_ORDERED = ("cake_cutting", "sequency", "russian_doll")


def default_split(A: LinearOperator) -> str:
    """``"tail"`` for Hadamard rows in a low-to-high order, else ``"random"``."""
    return "tail" if getattr(A, "order", None) in _ORDERED else "random"


#: What to change when the exact u-step's factorisation does not fit.
_EXACT_MEMORY_HINT = "use u_step='bb' (no factorisation) or a smaller n or sampling rate"


def tval3(
    y: torch.Tensor,
    A: LinearOperator,
    mu: float | str = "auto",
    beta: float = 2.0**5,
    tol: float = 1e-6,
    tol_inner: float = 1e-3,
    max_iter: int = 1025,
    tv: str = "isotropic",
    nonneg: bool = False,
    *,
    boundary: str = "periodic",
    bounds: tuple[float | None, float | None] | None = None,
    tvl2: bool = False,
    noise_sigma: float | str | torch.Tensor | None = None,
    max_outer: int = 10,
    ctn_steps: int = 0,
    rate_ctn: float = 2.0,
    u_step: str = "bb",
    adaptive: bool = True,
    discrepancy: float | str | torch.Tensor | None = None,
    return_result: bool = False,
) -> torch.Tensor | TVAL3Result:
    """TVAL3 reconstruction ``min Σ‖D_i u‖ s.t. A u = y`` (Li, Yin, Jiang, Zhang 2013).

    One inner iteration of ``ftvcs_alp`` (TVAL3 v1.0), per sample, all ``B·C`` samples at once:

    1. step length: steepest descent ``τ = dᵀd / (‖Dd‖² + (μ/β)‖Ad‖²)`` on the first inner
       step, else Barzilai–Borwein ``τ = |sᵀs / max(sᵀy, ε)|`` with ``s = u_k − u_{k−1}``,
       ``y = Dᵀ(Du−w)_k − Dᵀ(Du−w)_{k−1} + (μ/β)(AᵀAu_k − AᵀAu_{k−1})``; the direction is
       ``d = Dᵀ(Du − w) + (μ/β)Aᵀ(Au − b) − (Dᵀσ + Aᵀδ)/β`` (gradient of ``ℒ`` over ``β``);
    2. ``u⁺ = u − τ d`` (``max(u⁺, 0)`` if ``nonneg``);
    3. nonmonotone Armijo search (Zhang & Hager 2004, Eq. 1.4): accept ``α ∈ {1, .6, …, .6⁵}``
       at the first ``f(u + α(u⁺ − u)) ≤ C − α · 10⁻⁵ β τ ‖d‖²``; ``f`` is quadratic in ``α``
       along the segment, so every trial costs a few scalars (cached ``Au``, ``AᵀAu``, ``Du``
       are updated linearly, as ``ftvcs_alp`` does). After 5 failures: ``γ_Q ← 0.9 γ_Q`` and a
       steepest-descent step from ``u``;
    4. shrinkage ``w = shrink(Du − σ/β, 1/β)`` (isotropic: per-pixel 2-vector; anisotropic:
       componentwise);
    5. reference value ``Q ← γ_Q Q + 1``, ``C ← (γ_Q Q_old C + f)/Q`` (``γ_Q = 0.9995``);
    6. if ``‖u_k − u_{k−1}‖/‖u_{k−1}‖ < tol_inner`` (not on a first step): stop when
       ``‖u − u_last‖/‖u_{k−1}‖ < tol`` (``u_last`` = ``u`` at the previous multiplier update)
       or after ``max_outer`` updates, else ``σ ← σ − β(Du − w)``, ``δ ← δ − μ(Au − b)``,
       continuation ``β ← min(2β, β_f)``, ``μ ← min(2μ, μ_f)``, reset ``C = f``, ``Q = 1``.

    The published algorithm is reproduced iterate by iterate (tested against an independent
    float64 transcription). Differences: the line-search trials evaluate ``f`` from the
    quadratic in ``α`` (same numbers up to rounding); the TV-L2 multiplier term is carried as
    ``(β/β⁺)(Dᵀσ/β − Dᵀ(Du − w))`` (``ftvcs_al_TVL2p`` reuses ``−(β/β⁺)d``, which also
    accumulates the data gradient although that model has no ``δ``); ``Scaleb`` as below.

    Scaling: nothing is done to ``A`` when ``A.orthonormal_rows`` (TVAL3 skips ``ScaleA`` after
    its ``A Aᵀ = I`` test); otherwise ``A`` and ``y`` are divided by ``√s₂``, ``s₂`` the largest
    eigenvalue of ``AᵀA`` (power iteration, cached per operator; ``ScaleA``), when ``s₂ > 1``
    as published and, unlike the published rule, also when ``s₂ < 1``
    (:func:`~torchtof.recon.tv.scale_a`: ``tval3(c·y, c·A)`` is the same image for every
    ``c > 0``).
    Each sample's buckets are then scaled and the image scaled back (``Scaleb``): the published
    rule maps a spread ``max b − min b`` below 0.5 to 0.5, above 1.5 to 1.5 and leaves spreads
    in ``[0.5, 1.5]`` alone; it is used as published for operators without orthonormal rows
    (on a 32×32 image with 256 random 0/1 patterns, ``μ = 2⁸``, it gains 0.8–2.8 dB over a fixed
    1.5). For orthonormal rows the spread is always mapped to 1.5, which makes
    ``tval3(c·y) = c·tval3(y)`` exact for every ``c > 0`` (Hadamard buckets of images in
    ``[0, 1]`` have spreads above 1.5 anyway, so this is the published rule there).
    A sample whose buckets are all equal uses ``max |y|`` as its spread; an all-zero sample
    returns zeros with ``n_iter = 0``, ``residual = 0``, ``converged = True``. The start is
    ``u₀ = Aᵀb`` (TVAL3 ``init = 1``).

    Noise (``mu="auto"``, the default). The equality-constrained model fits the noise, so each
    sample picks its model from its noise std ``σ`` (``noise_sigma``, in the units of ``y``, or
    :func:`bucket_noise_sigma` of ``y``) measured on the scaled buckets, ``σ_s = 1.5 σ /
    (max y − min y)``:

    .. math::

        \\mu_{auto} = 0.7\\, \\sigma_s^{-1.3}

    If ``μ_auto > 2⁸`` (negligible noise) the sample gets the published constrained model with
    ``μ = 2⁸`` and ``β``; otherwise the TV-L2 model ``min Σ‖D_i u‖ + μ_auto/2 ‖Au − b‖²``
    (TVAL3's ``TVL2`` option, ``δ ≡ 0``) with splitting weight ``4β`` (that solver wants a
    larger ``β``; ``4β`` gained 0.05–0.15 dB and ~15 % of the iterations). The constant 0.7,
    the power 1.3 and the switch at ``2⁸`` (the published constrained ``μ``) were fitted on
    64×64 and 32×32 Hadamard data (25 % SR; horse, camera, Shepp–Logan, coins, rectangles;
    noise 0–10 % of the spread) against the best ``μ`` on a ``2^{1/4}`` grid: mean loss
    0.5 dB with the true ``σ``, 1.0 dB with the estimated one (the estimate reads signal left
    in the tail as noise). Noise-free buckets of piecewise-constant scenes estimate
    ``σ ≈ 0`` and get the published model. Give ``mu`` a number for the published behaviour.

    Hold-out check (only when ``σ`` was *estimated* and chose TV-L2, ``adaptive=True``): signal
    left in the last rows only adds to the tail estimate, so ``μ_auto`` can only be too small
    (at low SR, on textured or smooth scenes). The constrained model and the TV-L2 models at
    ``μ_auto`` and ``4 μ_auto`` are fitted on the rows before a held-out block and scored on
    it (:func:`holdout_split`; for low-to-high orders the last quarter predicted from the rows
    before it and the quarter before from the first half; ≤ 300 iterations, one batched call);
    the constrained model is kept when its error is within 10 % of the better TV-L2 model's,
    else that model is used. When it runs, the call costs 2.8–5× one solve with ``μ = 2⁸``
    (n = 32–128, measured; ``docs/noise.md``). A ``noise_sigma``
    from the caller (e.g. :func:`~torchtof.recon.noise.noise_from_pairs`) is trusted as is.

    Args:
        y: buckets ``(B, C, M)``, ``M = A.m``; float32 or float64.
        A: measurement operator (:class:`~torchtof.operators.LinearOperator`).
        mu: data weight ``μ > 0`` (published default ``2⁸``) or ``"auto"`` (see above), or a
            per-sample ``(B, C)`` tensor of weights (with ``tvl2`` a bool or a ``(B, C)`` bool
            tensor choosing the model per sample; TV-L2 samples then use ``4β`` as ``"auto"``
            does): one batched call tries several weights, as :func:`~torchtof.recon.auto`.
        beta: TV splitting weight ``β > 0`` (TVAL3 default ``2⁵``) of the constrained model;
            the TV-L2 model (``tvl2``, or the TV-L2 choice of ``mu="auto"``) runs with
            :data:`AUTO_TVL2_BETA` ``· β``, whether ``mu`` is a float or a tensor.
        tol: outer tolerance on the relative change between multiplier updates.
        tol_inner: inner tolerance on the relative change of one step.
        max_iter: total number of inner iterations (``≥ 1``).
        tv: ``"isotropic"`` (TVAL3 ``TVnorm = 2``) or ``"anisotropic"`` (``TVnorm = 1``).
        nonneg: project ``u`` onto ``u ≥ 0`` after each step (projected gradient). Physics: a
            gated depth-bucket image and an intensity image are sums of non-negative light
            (paper Eq. 10 with the gate; Eq. 8 amplitude), so ``x ≥ 0`` holds there; an ungated
            depth bucket is a negative image (§3.1) and must not use it.
        boundary: ``"periodic"`` (TVAL3's ``defDDt``) or ``"neumann"`` (no difference across
            the border, :mod:`~torchtof.recon.tv`): better when the object touches the border.
        bounds: ``(lo, hi)`` box in the units of ``x`` (either may be ``None``), projected onto
            in each u-step like ``nonneg`` (combined with it: ``lo ≥ 0``). Physics: a depth
            image lies in the camera's range ``[0, c/2f)`` (Eq. 1; 5 m at 30 MHz); an image
            normalised by a calibration (all-on) frame, e.g. ``x / (y⁺ + y⁻)`` of complementary
            DMD pairs, lies in ``[0, 1]``; pass the bound the experiment knows.
        tvl2: with a numeric ``mu``, solve the TV-L2 model instead of the constrained one (a
            bool; a ``(B, C)`` bool tensor with a tensor ``mu``).
        noise_sigma: noise std of ``y`` for ``mu="auto"`` (float or tensor broadcastable to
            ``(B, C)``, ``>= 0`` and finite); ``None`` estimates it with
            :func:`bucket_noise_sigma`.
        max_outer: TVAL3 ``maxcnt``: the solve ends at the ``max_outer``-th inner convergence
            (at most ``max_outer − 1`` multiplier updates).
        ctn_steps: continuation: start at ``μ/2^k``, ``β/2^k`` (TVAL3 ``mu0``, ``beta0``) and
            double both at every multiplier update up to ``μ``, ``β`` (``rate_ctn = 2``).
        rate_ctn: continuation factor (``> 1``).
        u_step: ``"bb"`` (published: one BB step + nonmonotone search) or ``"exact"``:
            minimise ``ℒ`` over ``u`` exactly, ``(βDᵀD + μAᵀA)u = Dᵀ(βw + σ) + Aᵀ(μb + δ)``,
            by Woodbury around the FFT-diagonal ``DᵀD`` with a cached ``M × M``
            eigendecomposition (built once per operator: ``M`` adjoints and forwards and an
            ``eigh``; then one forward, one adjoint, two FFT solves and three ``M × M``
            matvecs per step; with ``nonneg`` the minimiser is projected, so no longer exact).
            Any operator; the ``M × M`` factor limits it to ``M`` up to a few thousand.
        adaptive: ``True``: early exit once every sample has converged and work for the
            steepest-descent/fallback branches only where some sample needs it. ``False``:
            exactly ``max_iter`` iterations with every branch computed and selected by masks,
            no ``.item()`` or Python ``if`` on tensor values, so ``torch.onnx.export`` and
            ``torch.jit.trace`` can record it (graph size grows with ``max_iter``). Both give
            the same iterates (converged samples stay frozen in both).
        discrepancy: ``None`` (default: off, the published stopping rules only) or the noise
            std ``σ`` of ``y`` (float, ``(B, C)`` tensor, or ``"auto"`` for
            :func:`bucket_noise_sigma`): Morozov's discrepancy principle (Morozov 1966; for
            augmented-Lagrangian/Bregman iterations Osher et al. 2005) — at an inner
            convergence, a sample whose residual satisfies ``‖A x − y‖² ≤ τ M σ²``
            (``τ =`` :data:`DISCREPANCY_TAU`) stops instead of updating its multipliers, which
            would only fit the noise. Checked at inner convergences only: the start
            ``u₀ = Aᵀb`` fits ``y`` exactly for orthonormal rows.
        return_result: return the :class:`TVAL3Result` (iterations, residual, convergence and stop
            reason per sample) instead of ``x``.

    Returns:
        ``x (B, C, n, n)``, or with ``return_result`` the :class:`TVAL3Result`
        ``(x, n_iter, residual, converged, stop_reason, stop_code)``.

    Raises:
        TypeError: ``y`` not a floating tensor, ``A`` not a ``LinearOperator``, bad option types
            (a flag ``nonneg``, ``tvl2``, ``adaptive``, ``return_result`` not a bool).
        ValueError: wrong shape of ``y``, NaN/Inf in ``y``, ``mu``/``beta``/tolerances not
            positive, ``max_iter < 1``, unknown ``tv``/``u_step``, ``tvl2`` with ``mu="auto"``,
            ``noise_sigma``/``discrepancy`` negative, NaN/Inf or not broadcastable to ``(B, C)``.

    Shape:
        ``y (B, C, M) -> x (B, C, n, n)``; ``n_iter``, ``residual``, ``converged``: ``(B, C)``.

    Example:
        >>> from torchtof.operators import Hadamard
        >>> A = Hadamard(8, sr=0.5)
        >>> x = torch.zeros(1, 1, 8, 8); x[..., 2:6, 2:6] = 1.0
        >>> res = tval3(A(x), A, mu=2**8, return_result=True)
        >>> bool((res.x - x).abs().max() < 1e-2), res.x.shape
        (True, torch.Size([1, 1, 8, 8]))
    """
    fn = "tval3"
    check_buckets(y, A, fn)
    opts = _check_options(
        fn, mu, beta, tol, tol_inner, max_iter, tv, tvl2, max_outer, ctn_steps, rate_ctn, u_step
    )
    check_bool(adaptive, "adaptive", fn)
    check_bool(return_result, "return_result", fn)
    for name, v in (("mu", mu), ("tvl2", tvl2)):  # per-sample tensors: one per (B, C) entry
        if isinstance(v, torch.Tensor):
            check_broadcast(v, y.shape[:2], name, fn, "(B, C)")
    ctn = float(rate_ctn) ** -ctn_steps if ctn_steps < 4096 else 0.0  # continuation's start
    for name, v in (("mu", mu), ("beta", beta), ("beta·rate_ctn^-ctn_steps", beta * ctn)):
        if not isinstance(v, str):
            check_weight_range(v, name, fn, y.dtype)
    if not isinstance(mu, str):
        check_weight_range(mu * ctn, "mu·rate_ctn^-ctn_steps", fn, y.dtype)

    _check_boundary(boundary, fn)
    if opts["u_step"] == "exact":
        check_exact_memory(A, y, boundary, fn, _EXACT_MEMORY_HINT)
    # ScaleA (skipped for orthonormal rows, as after TVAL3's A Aᵀ = I test) and Scaleb.
    inv_s2 = scale_a(A, y, fn)
    # An exact power of two per sample (1 at ordinary scales: bit for bit the same; eager
    # only, built from IEEE bits) brings buckets near the dtype's ends (2^127, subnormals in
    # float32) to about 1, so that their spread and its inverse stay finite. Quantities in
    # the units of y (a given noise std, a discrepancy, the box) are scaled with them.
    y0 = y
    k = torch.ones_like(y[..., 0]) if is_tracing() else pow2_scale(y)[..., 0]  # (B, C)
    y = y * k[..., None]
    spread = bucket_spread(y)
    zero = spread == 0
    safe = torch.where(zero, torch.ones_like(spread), spread)
    if A.orthonormal_rows:
        gain = B_SPREAD / safe  # b = gain·y, spread 1.5 (scale-invariant, see above)
    else:  # published Scaleb on the ScaleA-scaled buckets y/√s2
        sq = math.sqrt(inv_s2)
        s_scaled = safe * sq
        g = torch.where(s_scaled < B_SPREAD_MIN, B_SPREAD_MIN / s_scaled,
                        torch.where(s_scaled > B_SPREAD, B_SPREAD / s_scaled,
                                    torch.ones_like(s_scaled)))
        gain = g * sq
    b = y * gain[..., None]
    lo, hi = box_bounds(nonneg, bounds, fn)
    scale = gain / math.sqrt(inv_s2)  # u = x · gain/√s2
    box = (None if lo is None else (lo * k) * scale, None if hi is None else (hi * k) * scale)

    # Model and weights per sample.
    if isinstance(mu, torch.Tensor):  # per-sample weights (B, C) (e.g. a weight search)
        mu_f = torch.broadcast_to(mu.to(dtype=y.dtype, device=y.device), spread.shape)
        tl = torch.as_tensor(tvl2, device=y.device)
        constrained = torch.broadcast_to(~tl.to(torch.bool), spread.shape)
        beta_f = torch.where(constrained, torch.full_like(mu_f, float(beta)),
                             torch.full_like(mu_f, AUTO_TVL2_BETA * float(beta)))
    elif mu == "auto":
        if noise_sigma is None or isinstance(noise_sigma, str):
            sigma = _estimate_sigma(y, A, noise_sigma, fn)
        else:
            sigma = _sigma_tensor(noise_sigma, y0, "noise_sigma", fn) * k
        mu_f, beta_f, constrained = auto_weights(sigma * gain, beta)
        if (noise_sigma is None or isinstance(noise_sigma, str)) and adaptive and A.m >= 8 \
                and not is_tracing() and y.device.type != "meta" and bool((~constrained).any()):
            # one host read at entry: validate the estimate's TV-L2 choice on held-out rows
            keep, mu_cv = _validate_constrained(y0, A, mu_f, beta, tv, nonneg, bounds,
                                                boundary, max_iter)
            mu_f, beta_f, constrained = apply_holdout(mu_f, beta_f, constrained, keep, mu_cv,
                                                      beta)
    else:  # the same β rule as a per-sample weight: a float and a tensor solve alike
        mu_f = torch.full_like(spread, float(mu))
        if isinstance(tvl2, torch.Tensor):  # per sample
            constrained = torch.broadcast_to(~tvl2.to(device=y.device), spread.shape)
            beta_f = torch.where(constrained, torch.full_like(mu_f, float(beta)),
                                 torch.full_like(mu_f, AUTO_TVL2_BETA * float(beta)))
        else:  # no tensor from a Python value: tracing records no constant
            constrained = (torch.zeros_like if tvl2 else torch.ones_like)(spread,
                                                                          dtype=torch.bool)
            beta_f = torch.full_like(spread, (AUTO_TVL2_BETA if tvl2 else 1.0) * float(beta))

    bound = None
    if discrepancy is not None:  # τ M σ² in the scaled units of b (‖A_s u − b‖ = gain ‖Ax − y‖)
        if isinstance(discrepancy, str):
            if discrepancy != "auto":
                raise ValueError(f"{fn}: expected discrepancy None, a number, a tensor or "
                                 f"'auto', got {discrepancy!r}")
            sd = _tail_sigma(y, A.m, NOISE_TAIL, NOISE_QUANTILE)
        else:
            sd = _sigma_tensor(discrepancy, y0, "discrepancy", fn) * k
        bound = DISCREPANCY_TAU * A.m * (sd * gain) ** 2
    # y was validated above: operator calls in the loop skip check_finite; without a graph
    # to build the loop runs in inference mode (the same bits, less overhead per op)
    u = run_loop(_solve, b, A, mu_f, beta_f, constrained, zero, inv_s2, box, adaptive, **opts,
                 boundary=boundary, disc_bound=bound, inputs=(b, mu_f, beta_f, *box), module=A)
    x = u.x * (math.sqrt(inv_s2) / _i(gain)) / _i(k)  # A_s u = b <=> A (u/(√s2·gain)) = y
    if lo is not None or hi is not None:  # all-zero buckets: 0 projected onto the box (as tgv)
        x = torch.where(_i(zero), project_box(torch.zeros_like(x), lo, hi), x)
    residual = relative_residual(x, y0, A)
    code = torch.where(u.count > opts["max_outer"], 1, 0)
    code = torch.where(u.disc, 2, code)
    code = torch.where(u.converged, code, 3)
    res = TVAL3Result(x, u.n_iter, residual, u.converged, stop_names(code), code)
    return res if return_result else res.x


def stop_names(code: torch.Tensor) -> tuple:
    """``(B, C)`` stop codes -> ``stop_reason`` names ``[b][c]`` (one host read, after the
    solve; empty while tracing, where the codes stay a graph output)."""
    if is_tracing() or code.device.type == "meta":
        return ()
    return tuple(tuple(STOP_REASONS[k] for k in row) for row in code.tolist())


def holdout_choice(err_cons: torch.Tensor, err_mu: torch.Tensor, err_4mu: torch.Tensor,
                   mu: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``(keep, mu)`` of ``mu="auto"``'s hold-out check from the held-out errors of the
    constrained model and the TV-L2 weights ``μ`` and ``4μ``: ``keep`` where the constrained
    model is within :data:`AUTO_CV_SLACK` of the better TV-L2 one, ``mu`` that one's weight
    (shared by :func:`tval3` and :func:`~torchtof.recon.depth.joint_tv`)."""
    larger = err_4mu < err_mu
    best = torch.where(larger, err_4mu, err_mu)
    return err_cons <= (1 + AUTO_CV_SLACK) * best, torch.where(larger, AUTO_CV_FACTOR * mu, mu)


def apply_holdout(mu: torch.Tensor, beta_t: torch.Tensor, constrained: torch.Tensor,
                  keep: torch.Tensor, mu_cv: torch.Tensor, beta: float
                  ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(μ, β, constrained)`` after the hold-out check: the TV-L2 samples take the better
    weight ``mu_cv``, those where ``keep`` the published constrained model (``μ = 2⁸``, β)."""
    mu = torch.where(constrained, mu, mu_cv)
    mu = torch.where(keep, torch.full_like(mu, AUTO_MU_MAX), mu)
    beta_t = torch.where(keep, torch.full_like(beta_t, float(beta)), beta_t)
    return mu, beta_t, constrained | keep


def _validate_constrained(y, A, mu_f, beta, tv, nonneg, bounds, boundary, max_iter
                          ) -> tuple[torch.Tensor, torch.Tensor]:
    """``(keep, mu)``, each ``(B, C)``: ``keep`` where the published constrained model
    (``μ = 2⁸``) predicts held-out buckets within :data:`AUTO_CV_SLACK` of the better of the
    two TV-L2 models ``μ`` and ``4μ`` (:data:`AUTO_CV_FACTOR`) around the weight the noise
    estimate chose; ``mu`` the TV-L2 weight of the two that predicts them better.

    Hold-out folds of :func:`holdout_split` with ``k = 3`` (for low-to-high Hadamard orders
    the last quarter of the rows predicted from the rows before it, and the quarter before
    that from the first half; else three random folds), the three models fitted with the same
    options as the final solve and at most :data:`AUTO_CV_MAX_ITER` iterations, batched as
    channels of one call (cost: at most 9 × 300 batched iterations, run only when the
    estimate chose TV-L2). A tail noise estimate reads signal as noise where the high-order
    rows still carry signal (low SR, smooth or textured scenes), so the weight it gives is too
    small there; this check keeps the published model or the larger weight there
    (``docs/noise.md``: the loss on noise-free buckets).
    """
    b, c, m = y.shape
    held, train = holdout_split(A, 3, y, 0, default_split(A))  # (F, M), F = 2 or 3
    nf, nm = held.shape[0], 3  # models: constrained, TV-L2 μ, TV-L2 4μ
    op = MaskedRows(A, train.repeat_interleave(nm, dim=0))  # channel nm·f + j: fold f, model j
    ys = y.reshape(b * c, 1, m)
    yt = ys * train.repeat_interleave(nm, dim=0).to(y.dtype)
    mus = torch.stack((torch.full_like(mu_f, AUTO_MU_MAX), mu_f, AUTO_CV_FACTOR * mu_f),
                      dim=-1).reshape(b * c, nm)
    tl = torch.tensor([False, True, True], device=y.device).repeat(nf)
    budget = min(max_iter, AUTO_CV_MAX_ITER)
    r = tval3(yt, op, mu=mus.repeat(1, nf), tvl2=tl, beta=beta, max_iter=budget, tv=tv,
              nonneg=nonneg, bounds=bounds, boundary=boundary, return_result=True)
    hm = held.repeat_interleave(nm, dim=0).to(y.dtype)
    # the residuals times an exact power of two per sample (1 at ordinary scales): the
    # squares stay finite for buckets near the dtype's ends, and the comparison is the same
    k = pow2_scale(ys)  # (BC, 1, 1), repeated for the nf·nm fits of each sample
    res_ = (A(r.x) - ys) * k
    err = (res_ * hm).pow(2).sum(-1).reshape(b * c, nf, nm).sum(1)  # (BC, nm)
    keep, mu = holdout_choice(err[:, 0], err[:, 1], err[:, 2], mus[:, 1])
    return keep.reshape(b, c), mu.reshape(b, c)


def _check_boundary(boundary: str, fn: str) -> None:
    if boundary not in BOUNDARIES:
        raise ValueError(f"{fn}: expected boundary in {BOUNDARIES}, got {boundary!r}")




def _estimate_sigma(y: torch.Tensor, A: LinearOperator, name: str | None, fn: str
                    ) -> torch.Tensor:
    """The named noise estimator (``None`` and ``"auto"``: :func:`bucket_noise_sigma`)."""
    if name not in (None, "auto", "tail"):
        raise ValueError(f"{fn}: expected noise_sigma a number, a tensor, None or one of "
                         f"('auto', 'tail'), got {name!r}")
    return _tail_sigma(y, A.m, NOISE_TAIL, NOISE_QUANTILE)


def _sigma_tensor(value: float | torch.Tensor, y: torch.Tensor, name: str, fn: str
                  ) -> torch.Tensor:
    """A noise std ``value`` (the option ``name`` of ``fn``: a number or a tensor
    broadcastable to ``(B, C)``, ``>= 0`` and finite) as a ``(B, C)`` tensor."""
    hint = "" if name == "noise_sigma" else " (the noise std of y, as noise_sigma)"
    if isinstance(value, torch.Tensor):
        check_real(value, name, fn)
        s = value.to(dtype=y.dtype, device=y.device)
        try:
            out = torch.broadcast_to(s, y.shape[:-1])
        except RuntimeError:
            out = None
        if s.ndim > 2 or out is None:
            raise ValueError(f"{fn}: expected {name} broadcastable to (B, C) = "
                             f"{tuple(y.shape[:-1])}, got shape {tuple(s.shape)}")
        if not is_tracing() and s.numel() and s.device.type != "meta":
            neg, bad = torch.stack(((s < 0).any(), ~s.isfinite().all())).tolist()  # one read
            if neg or bad:
                raise ValueError(f"{fn}: expected {name} >= 0 and finite{hint}, got a "
                                 f"{'NaN or Inf' if bad else 'negative'} entry")
        return out
    try:
        check_positive(value, name, fn, strict=False)
    except ValueError as e:
        raise ValueError(f"{e}{hint}") from None
    if float(value) > torch.finfo(y.dtype).max:
        raise ValueError(f"{fn}: expected {name} representable in {y.dtype} (the dtype of y), "
                         f"got {value:g}")
    return y.new_full(y.shape[:-1], float(value))


def _check_options(fn, mu, beta, tol, tol_inner, max_iter, tv, tvl2, max_outer, ctn, rate, u_step):
    if isinstance(mu, str):
        if mu != "auto":
            raise ValueError(f"{fn}: expected mu to be a positive number or 'auto', got {mu!r}")
        if tvl2 is True:
            raise ValueError(f"{fn}: tvl2=True needs a numeric mu, got mu='auto'")
    elif isinstance(mu, torch.Tensor):
        if mu.ndim > 2 or (not is_tracing() and not bool((mu > 0).all() & mu.isfinite().all())):
            raise ValueError(f"{fn}: expected a mu tensor > 0 and finite, broadcastable to "
                             f"(B, C), got shape {tuple(mu.shape)}")
    else:
        check_positive(mu, "mu", fn)
    if isinstance(tvl2, torch.Tensor):
        if tvl2.dtype != torch.bool:
            raise TypeError(f"{fn}: expected tvl2 a bool or a bool tensor, got {tvl2.dtype}")
    else:
        check_bool(tvl2, "tvl2", fn)
    check_positive(beta, "beta", fn)
    check_positive(tol, "tol", fn)
    check_positive(tol_inner, "tol_inner", fn)
    check_positive(rate, "rate_ctn", fn)
    if rate <= 1:
        raise ValueError(f"{fn}: expected rate_ctn > 1, got {rate}")
    for name, val, lo in (
        ("max_iter", max_iter, 1),
        ("max_outer", max_outer, 1),
        ("ctn_steps", ctn, 0),
    ):
        if isinstance(val, bool) or not isinstance(val, int):
            raise TypeError(f"{fn}: expected {name} to be an int, got {type(val).__name__}")
        if val < lo:
            raise ValueError(f"{fn}: expected {name} >= {lo}, got {val}")
    if tv not in ("isotropic", "anisotropic"):
        raise ValueError(f"{fn}: expected tv in ('isotropic', 'anisotropic'), got {tv!r}")
    if u_step not in ("bb", "exact"):
        raise ValueError(f"{fn}: expected u_step in ('bb', 'exact'), got {u_step!r}")
    return dict(
        tol=float(tol),
        tol_inner=float(tol_inner),
        max_iter=max_iter,
        isotropic=tv == "isotropic",
        max_outer=max_outer,
        ctn_steps=ctn,
        rate_ctn=float(rate),
        u_step=u_step,
    )


class _Out(NamedTuple):
    x: torch.Tensor
    n_iter: torch.Tensor
    converged: torch.Tensor
    count: torch.Tensor
    disc: torch.Tensor


def _solve(
    b: torch.Tensor,
    A: LinearOperator,
    mu_f: torch.Tensor,
    beta_f: torch.Tensor,
    constrained: torch.Tensor,
    zero: torch.Tensor,
    inv_s2: float,
    box: tuple,
    adaptive: bool,
    *,
    boundary: str,
    tol: float,
    tol_inner: float,
    max_iter: int,
    isotropic: bool,
    max_outer: int,
    ctn_steps: int,
    rate_ctn: float,
    u_step: str,
    c: float = 1e-5,
    gamma: float = 0.6,
    gam0: float = 0.9995,
    rate_gam: float = 0.9,
    disc_bound: torch.Tensor | None = None,
    _eager: bool = False,
) -> _Out:
    """The ``ftvcs_alp`` iteration on scaled buckets ``b`` (see :func:`tval3`).

    With ``adaptive``, a step leaves out its fallback branch (a steepest-descent step after
    five failed backtracks) and is redone whole, from the state it started from, when the next
    host read finds that some sample needed it: the same arithmetic, without the branch's extra
    ``A``, ``Aᵀ`` and ``D`` on the steps that need none; and the steepest-descent length is
    computed only when some active sample is on a first step. ``_eager`` (the reference for
    tests): every step computes both lengths and takes its branch in place."""
    fwd, adj = scaled_loop_pair(A, b, math.sqrt(inv_s2))
    D, Dt = loop_differences(boundary, b, A.n)[:2]
    exact = u_step == "exact"
    lo_s, hi_s = box  # per-sample bounds in the scaled units of u, (B, C) tensors or None
    bounded = lo_s is not None or hi_s is not None

    def _project(u):
        return u.clamp(min=None if lo_s is None else _i(lo_s),
                       max=None if hi_s is None else _i(hi_s))
    if exact:
        factors = exact_factors(A, b, boundary)
    eps = torch.finfo(torch.float64).eps  # MATLAB eps in max(sy, eps)
    tiny = torch.finfo(b.dtype).tiny
    alphas = gamma ** torch.arange(_N_BACKTRACK + 1, dtype=b.dtype, device=b.device)

    def shrink_w(du, sig, bet):
        return shrink(du - sig / _f(bet), _f(1.0 / bet), isotropic)

    def objective(lam1, v, r, sig, dlt, bet, mu):
        return (
            lam1 + bet / 2 * _dot_f(v, v) + mu / 2 * _dot_v(r, r) - _dot_f(sig, v) - _dot_v(dlt, r)
        )

    ctn = rate_ctn ** (-ctn_steps)
    zeros = torch.zeros_like(mu_f)
    bet, mu = beta_f * ctn, mu_f * ctn
    mu_dlt = torch.where(constrained, torch.ones_like(mu_f), zeros)  # 0: TV-L2 (δ ≡ 0)
    atb = adj(b)
    u = atb
    du = D(u)
    sig = torch.zeros_like(du)
    dlt = torch.zeros_like(b)
    w = shrink_w(du, sig, bet)
    lam1 = _tv_of_w(w, isotropic)
    au = fwd(u)
    g = adj(au) - atb
    v = du - w
    g2 = Dt(v)
    f = objective(lam1, v, au - b, sig, dlt, bet, mu)
    st = dict(
        u=u,
        du=du,
        au=au,
        g=g,
        w=w,
        g2=g2,
        f=f,
        d=g2 + _i(mu / bet) * g,
        dts=torch.zeros_like(u),
        sig=sig,
        dlt=dlt,
        bet=bet,
        mu=mu,
        cref=f,
        q=torch.ones_like(f),
        gam=torch.full_like(f, gam0),
        tau_bb=torch.ones_like(f),
        first=torch.ones_like(zero),
        count=torch.ones_like(f, dtype=torch.int64),
        n_iter=torch.zeros_like(f, dtype=torch.int64),
        rcd=u,
        done=zero.clone(),
        disc=torch.zeros_like(zero),
        # the multiplier update of an outer iteration, applied at the start of the next step
        # (see ``multipliers``): its mask and the inner iteration's values it reads
        p_outer=torch.zeros_like(zero),
        p_lam1=lam1,
        p_v=v,
        p_r=au - b,
        # the samples whose last step needs the fallback branch it left out (see ``step``)
        p_fb=torch.zeros_like(zero),
    )

    def sd_length(d, rho):
        dd_ = D(d)
        ad = fwd(d)
        return _dot_i(d, d) / (_dot_f(dd_, dd_) + rho * _dot_v(ad, ad)).clamp_min(tiny)

    def line_search(st: dict, tau_sd: torch.Tensor | None) -> tuple:
        """Steps 1–3 of a BB step: ``(u, du, au, g, gam, fallback)``. ``tau_sd`` ``None``: no
        active sample is on a first step, so every length that can be taken is a BB one."""
        first, bet, mu, gam = st["first"], st["bet"], st["mu"], st["gam"]
        sig, dlt, d, f = st["sig"], st["dlt"], st["d"], st["f"]
        up, gp, aup, dup = st["u"], st["g"], st["au"], st["du"]
        # 1. step length: steepest descent on first steps, Barzilai-Borwein otherwise
        # (both lengths computed where needed: choosing by mask needs no host read)
        tau = st["tau_bb"] if tau_sd is None else torch.where(first, tau_sd, st["tau_bb"])
        # 2. trial step
        u1 = up - _i(tau) * d
        if bounded:
            u1 = _project(u1)
        du1 = D(u1)
        au1 = fwd(u1)
        g1 = adj(au1) - atb
        # 3. nonmonotone line search: f(up + a (u1 - up)) = f + a a1 + a^2 a2
        dU, dDU, dAu = u1 - up, du1 - dup, au1 - aup
        vp, rp = st["p_v"], st["p_r"]  # Du − w and Au − b at the last iterate (finish)
        a1 = bet * _dot_f(vp, dDU) + mu * _dot_v(rp, dAu) - _dot_f(sig, dDU) - _dot_v(dlt, dAu)
        a2 = bet / 2 * _dot_f(dDU, dDU) + mu / 2 * _dot_v(dAu, dAu)
        const = c * bet * tau * _dot_i(d, d)
        al = alphas.reshape(-1, *([1] * f.ndim))
        ok = f + al * a1 + al * al * a2 <= st["cref"] - al * const
        fallback = ~ok.any(dim=0)
        alpha = torch.where(fallback, zeros, alphas[torch.argmax(ok.to(f.dtype), dim=0)])
        u = up + _i(alpha) * dU
        du = dup + _f(alpha) * dDU
        au = aup + alpha[..., None] * dAu
        g = gp + _i(alpha) * (g1 - gp)
        gam = torch.where(fallback, gam * rate_gam, gam)
        return u, du, au, g, gam, fallback

    def sd_fallback(st: dict, fallback: torch.Tensor, tau_sd, u, du, au, g) -> tuple:
        """Five failed backtracks: the steepest-descent step from the last iterate where
        ``fallback`` (``ftvcs_alp``), ``(u, du, au, g)`` elsewhere (``tau_sd`` ``None``: its
        length is computed here)."""
        if tau_sd is None:
            tau_sd = sd_length(st["d"], st["mu"] / st["bet"])
        usd = st["u"] - _i(tau_sd) * st["d"]
        if bounded:
            usd = _project(usd)
        ausd = fwd(usd)
        return (_where(fallback, usd, u), _where(fallback, D(usd), du),
                _where(fallback, ausd, au), _where(fallback, adj(ausd) - atb, g))

    def step(st: dict, first_any: bool = True, defer: bool = False) -> dict:
        """One inner iteration from ``st``. ``first_any`` ``False``: no active sample is on a
        first step (its steepest-descent length is skipped). ``defer``: the fallback branch is
        left out and the samples that needed it are marked ``p_fb``, for ``redo`` to complete
        the step (few steps need the branch; computing it costs an ``A``, an ``Aᵀ`` and a
        ``D`` on every step)."""
        if exact:
            rho = st["mu"] / st["bet"]
            rhs = Dt(st["w"]) + _i(rho) * atb + st["dts"]
            u, au = exact_solve(rhs, rho, fwd, adj, factors, inv_s2)
            if bounded:
                u = _project(u)
                au = fwd(u)
            # AᵀAu − Aᵀb is only needed at a multiplier update (computed there)
            return finish(st, u, D(u), au, st["g"], st["gam"])
        tau_sd = sd_length(st["d"], st["mu"] / st["bet"]) if first_any else None
        u, du, au, g, gam, fallback = line_search(st, tau_sd)
        if defer:
            return dict(finish(st, u, du, au, g, gam), p_fb=fallback & ~st["done"])
        return finish(st, *sd_fallback(st, fallback, tau_sd, u, du, au, g), gam)

    def redo(st: dict, deferred: dict) -> dict:
        """The step from ``st`` that ``deferred`` took without its fallback branch, completed:
        its line search's result with the branch applied, then steps 4–6 again (the same
        arithmetic as the step with the branch, bit for bit)."""
        new = sd_fallback(st, deferred["p_fb"], None, deferred["u"], deferred["du"],
                          deferred["au"], deferred["g"])
        return dict(finish(st, *new, deferred["gam"]), p_fb=torch.zeros_like(zero))

    def finish(st: dict, u, du, au, g, gam) -> dict:
        """Steps 4–6 of an inner iteration at the new ``u`` (``du = Du``, ``au = Au``, ``g``
        the data gradient)."""
        active, first, bet, mu = ~st["done"], st["first"], st["bet"], st["mu"]
        sig, dlt, dts = st["sig"], st["dlt"], st["dts"]
        up, gp, g2p = st["u"], st["g"], st["g2"]
        rho = mu / bet
        # 4. shrinkage w-step at the new u
        w = shrink_w(du, sig, bet)
        lam1 = _tv_of_w(w, isotropic)
        v = du - w
        g2 = Dt(v)
        r = au - b
        s = u - up
        ss = _dot_i(s, s)
        out = dict(st, u=u, du=du, au=au, g=g, w=w, g2=g2, gam=gam)
        if not exact:
            f = objective(lam1, v, r, sig, dlt, bet, mu)
            # 5. Zhang-Hager reference value; BB length for the next step
            q = gam * st["q"] + 1
            out["cref"] = (gam * st["q"] * st["cref"] + f) / q
            out["q"], out["f"] = q, f
            sy = _dot_i(s, (g2 - g2p) + _i(rho) * (g - gp))
            out["tau_bb"] = (ss / sy.clamp_min(eps)).abs()
            out["d"] = g2 + _i(rho) * g - dts
        # 6. inner / outer stopping rules
        nrm_up = up.norm(dim=(-2, -1)).clamp_min(tiny)
        inner = active & ~first & (ss.sqrt() / nrm_up < tol_inner)
        count = st["count"] + inner.to(torch.int64)
        rel_out = (u - st["rcd"]).norm(dim=(-2, -1)) / nrm_up
        stop = inner & ((rel_out < tol) | (count > max_outer))
        if disc_bound is not None:  # discrepancy principle (see tval3)
            disc = inner & ~stop & (_dot_v(r, r) <= disc_bound)
            stop = stop | disc
            out["disc"] = st["disc"] | disc
        outer = inner & ~stop
        out.update(
            count=count,
            rcd=_where(inner, u, st["rcd"]),
            first=outer,
            done=st["done"] | stop,
            n_iter=st["n_iter"] + 1,
            p_outer=outer,
            p_lam1=lam1,
            p_v=v,
            p_r=r,
        )
        return out

    def multipliers(st: dict) -> dict:
        """The multiplier update, continuation and reset of the nonmonotone reference of the
        samples whose last step ended an outer iteration (``p_outer``; masked, no host read).
        It runs at the start of the next step, before anything reads what it changes, so the
        arithmetic is that of ``ftvcs_alp``; deferred, the loop's one host read can skip it
        when no sample needs it."""
        outer, lam1, v, r = st["p_outer"], st["p_lam1"], st["p_v"], st["p_r"]
        sig, dlt, dts, bet, mu, g2 = st["sig"], st["dlt"], st["dts"], st["bet"], st["mu"], st["g2"]
        if exact:
            g = adj(st["au"]) - atb
            d = g2 + _i(mu / bet) * g - dts
        else:
            g, d = st["g"], st["d"]
        sig_o = sig - _f(bet) * v
        dlt_o = dlt - (mu * mu_dlt)[..., None] * r
        bet_o = torch.minimum(bet * rate_ctn, beta_f)
        mu_o = torch.minimum(mu * rate_ctn, mu_f)
        ratio = _i(bet / bet_o)
        # constrained: (Dᵀσ⁺ + Aᵀδ⁺)/β⁺ = −(β/β⁺) d; TV-L2: (β/β⁺)(Dᵀσ/β − Dᵀ(Du − w))
        dts_o = torch.where(_i(constrained), -ratio * d, ratio * (dts - g2))
        d_o = g2 + _i(mu_o / bet_o) * g - dts_o
        out = dict(
            st,
            sig=_where(outer, sig_o, sig),
            dlt=_where(outer, dlt_o, dlt),
            bet=torch.where(outer, bet_o, bet),
            mu=torch.where(outer, mu_o, mu),
            dts=_where(outer, dts_o, dts),
            d=_where(outer, d_o, st["d"]),
        )
        if not exact:
            f_o = objective(lam1, v, r, sig_o, dlt_o, bet_o, mu_o)
            out.update(
                f=torch.where(outer, f_o, st["f"]),
                cref=torch.where(outer, f_o, st["cref"]),
                q=torch.where(outer, torch.ones_like(f_o), st["q"]),
                gam=torch.where(outer, torch.full_like(f_o, gam0), st["gam"]),
            )
        return out

    def merge(old: dict, new: dict, n_done: int) -> dict:
        """The state after a step: ``new`` where the sample was active, ``old`` where it is
        frozen (``n_done`` 0: ``new`` whole); entries the step left as they were (the same
        tensor) need no mask."""
        if n_done == 0:
            return new
        active = ~old["done"]
        return {k: v if new[k] is v else _where(active, new[k], v) for k, v in old.items()}

    n_samples = st["done"].numel() if adaptive else 0  # (no shape read while tracing)
    defer = adaptive and not exact and not _eager
    prev = (st, 0)  # the state before the last step and its n_done (for redo)
    for _ in range(max_iter):
        if adaptive:
            # the one host read per iteration: whether the last step skipped a fallback branch
            # that some sample needed (then it is redone first, and the other flags describe
            # the state it replaces), whether another iteration can change anything (converged
            # samples are frozen), whether any sample is frozen at all (if none is, the new
            # state is taken whole, unmasked), whether any has a multiplier update pending and
            # whether any active sample is on a first step (needs the steepest-descent length)
            n_fb, n_done, n_outer, n_first = torch.stack((
                st["p_fb"].sum(), st["done"].sum(), st["p_outer"].sum(),
                (st["first"] & ~st["done"]).sum(),
            )).tolist()
            if n_fb:
                st = merge(prev[0], redo(prev[0], st), prev[1])
                n_done, n_outer, n_first = -1, 1, 1  # unread: every mask and branch
            elif n_done == n_samples:
                break
            if n_outer:
                st = multipliers(st)
        else:
            n_done, n_first = -1, 1
            st = multipliers(st)
        prev = (st, n_done)
        st = merge(st, step(st, first_any=_eager or n_first > 0, defer=defer), n_done)
    else:  # max_iter steps: the last one's deferred fallback is still unread
        if defer and bool(st["p_fb"].any()):
            st = merge(prev[0], redo(prev[0], st), prev[1])
    return _Out(st["u"], st["n_iter"], st["done"], st["count"], st["disc"])


#: Keyword-only options of :func:`tval3` that :class:`TVAL3` accepts, with their defaults.
_KW_OPTIONS = dict(
    boundary="periodic",
    bounds=None,
    tvl2=False,
    noise_sigma=None,
    max_outer=10,
    ctn_steps=0,
    rate_ctn=2.0,
    u_step="bb",
    adaptive=True,
    discrepancy=None,
)


class TVAL3(nn.Module):
    """TVAL3 reconstructor: ``forward(y) -> x`` with the operator held inside (see :func:`tval3`).

    Args:
        A: measurement operator (registered as a submodule, so ``.to()`` moves its buffers).
        mu, beta, tol, tol_inner, max_iter, tv, nonneg: as in :func:`tval3`.
        **options: the keyword-only options of :func:`tval3` (``boundary``, ``bounds``,
            ``tvl2``, ``noise_sigma``,
            ``max_outer``, ``ctn_steps``, ``rate_ctn``, ``u_step``, ``adaptive``,
            ``discrepancy``).

    Shape:
        ``(B, C, M) -> (B, C, n, n)``.

    Example:
        >>> from torchtof.operators import Hadamard
        >>> rec = TVAL3(Hadamard(8, sr=0.5), mu=2**8)
        >>> rec(torch.zeros(2, 1, 32)).shape
        torch.Size([2, 1, 8, 8])
    """

    def __init__(
        self,
        A: LinearOperator,
        mu: float | str = "auto",
        beta: float = 2.0**5,
        tol: float = 1e-6,
        tol_inner: float = 1e-3,
        max_iter: int = 1025,
        tv: str = "isotropic",
        nonneg: bool = False,
        **options,
    ) -> None:
        super().__init__()
        if not isinstance(A, LinearOperator):
            raise TypeError(f"TVAL3: expected A to be a LinearOperator, got {type(A).__name__}")
        unknown = set(options) - set(_KW_OPTIONS)
        if unknown:
            raise TypeError(f"TVAL3: unexpected options {sorted(unknown)}")
        opts = {k: options.get(k, v) for k, v in _KW_OPTIONS.items()}
        _check_options(
            "TVAL3",
            mu,
            beta,
            tol,
            tol_inner,
            max_iter,
            tv,
            opts["tvl2"],
            opts["max_outer"],
            opts["ctn_steps"],
            opts["rate_ctn"],
            opts["u_step"],
        )
        _check_boundary(opts["boundary"], "TVAL3")
        check_bool(opts["adaptive"], "adaptive", "TVAL3")
        if opts["u_step"] == "exact":
            check_exact_memory(A, torch.empty(0), opts["boundary"], "TVAL3", _EXACT_MEMORY_HINT)
        box_bounds(nonneg, opts["bounds"], "TVAL3")
        self.A = A
        if not A.orthonormal_rows:  # ScaleA's s₂, cached now so that tracing never computes it
            largest_eig_normal(A, torch.zeros(1))
        self.options = dict(
            mu=mu,
            beta=beta,
            tol=tol,
            tol_inner=tol_inner,
            max_iter=max_iter,
            tv=tv,
            nonneg=nonneg,
            **opts,
        )

    def solve(self, y: torch.Tensor) -> TVAL3Result:
        """Run :func:`tval3`: the :class:`TVAL3Result` (no state is kept between calls)."""
        return tval3(y, self.A, **self.options, return_result=True)

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        return self.solve(y).x

    def extra_repr(self) -> str:
        o = self.options
        return (
            f"mu={o['mu']!r}, beta={o['beta']}, max_iter={o['max_iter']}, tv={o['tv']!r}, "
            f"u_step={o['u_step']!r}, adaptive={o['adaptive']}"
        )
