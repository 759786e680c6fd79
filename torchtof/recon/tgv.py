"""Total generalised variation of order 2 (TGV²): a prior for piecewise-affine images.

First-order TV favours piecewise-constant images, so a sloped plane (a depth map of a tilted
wall, the ToF camera's natural scene) comes back as a staircase. TGV² (Bredies, Kunisch &
Pock 2010, SIAM J. Imaging Sci. 3, "Total generalized variation"; the minimum over ``w`` is
its characterisation of TGV² as an infimal convolution)

.. math::
    \\mathrm{TGV}^2_\\alpha(x) = \\min_w\\ \\alpha_1 \\|\\nabla x - w\\|_1
    + \\alpha_0 \\|\\mathcal E w\\|_1

balances the first derivative against a vector field ``w`` whose symmetrised gradient
``E w`` is penalised: an affine image has ``w = ∇x`` constant, ``E w = 0``, and costs
nothing; jumps cost ``α₁`` per unit height and length, kinks ``α₀`` per unit slope change.
:func:`tgv` solves

.. math::
    \\min_{x,w}\\ \\alpha_1\\|\\nabla x - P w\\| + \\alpha_0 \\|\\mathcal E w\\|
    + \\tfrac{\\mu}{2}\\|A x - b\\|^2 \\quad (\\text{TV-L2})
    \\qquad\\text{or}\\qquad \\text{s.t. } A x = b \\quad (\\text{constrained}),

(and ``lo ≤ x ≤ hi``) by the primal-dual algorithm of Chambolle & Pock 2011 (J. Math. Imaging
Vis. 40, Algorithm 1, ``θ = 1``), with only ``A`` and ``Aᵀ``. Discretisation: ``∇`` is
:func:`~torchtof.recon.tv.grad2`, ``E`` :func:`~torchtof.recon.tv.sym_grad2` (both with the
chosen boundary rule); ``P`` keeps the entries of ``w`` where ``∇`` has a difference (with
Neumann boundaries the last column of ``w_x`` and the last row of ``w_y`` are dropped from
the first term), so a constant ``w`` is the exact slope of an affine image up to the border
and the prior of an affine image is exactly 0. Norms per pixel: isotropic (Euclidean over the
2 components of ``∇x − Pw`` and the Frobenius norm of ``E w``) or anisotropic (sums of
absolute values).

**Iteration** (dual variables ``p`` for the first term, ``q`` for the second, ``r`` for the
data when it is dualised; ``proj_α`` the projection onto the dual ball of the norm):

.. math::
    p &\\leftarrow \\mathrm{proj}_{\\alpha_1}(p + σ(\\nabla \\bar x - P\\bar w)),\\quad
    q \\leftarrow \\mathrm{proj}_{\\alpha_0}(q + σ \\mathcal E \\bar w),\\quad
    r \\leftarrow (r + σ(A\\bar x - b)) / (1 + σ/μ)\\\\
    x^+ &= \\mathrm{prox}_{τG}(x - τ(\\nabla^T p + A^T r)),\\quad
    w^+ = w + τ(P p - \\mathcal E^T q),\\quad
    \\bar x = 2x^+ - x,\\ \\bar w = 2w^+ - w

(``1/μ = 0`` for the constrained model: the prox of the conjugate of the indicator of
``{z = b}``). Two ways to treat the data:

- ``AᵀA`` a projection (``A.orthonormal_rows``: Hadamard rows; also their row-masked
  copies, :class:`~torchtof.recon.tval3.MaskedRows`) and no bounds: the data term is ``G``
  itself, with the closed-form prox ``x⁺ = v + θ Aᵀ(b − A v)``, ``θ = τμ/(1 + τμ)``
  (``θ = 1``: the projection onto ``{Ax = b}``), ``(I + c AᵀA)⁻¹ = I − c/(1+c) AᵀA``;
  ``‖K‖² ≤ (17 + √33)/2 < 12`` (from ``‖∇‖² ≤ 8``, Chambolle 2004, J. Math. Imaging Vis.
  20, and ``‖E‖² ≤ 8``: the largest eigenvalue of ``[[8, √8], [√8, 9]]``).
- otherwise the data term is dualised (``r``), ``G`` is the box (``x⁺`` its projection), and
  ``‖K‖² ≤ 12 + ‖A‖² ≤ 13`` after the scaling below.

Steps ``τ = s/L``, ``σ = 1/(sL)`` with ``L² = 12`` or 13 (so ``τσ L² ≤ 1``, the condition
of Chambolle & Pock's Thm. 1 up to the bound's slack) and a per-sample primal/dual balance
``s = BALANCE · RMS(Aᵀb) / α₁`` (the primal variable's scale against the radius of the dual
ball; the factor :data:`BALANCE` was measured, it changes the speed, not the solution).

**Scaling** (as :func:`~torchtof.recon.tval3.tval3`, so that ``μ`` means the same across
scales and :func:`~torchtof.recon.auto`'s weight grid applies): for orthonormal rows the
buckets are scaled to a spread ``max b − min b = 1.5`` and the image scaled back; otherwise
``A`` is divided by ``√s₂`` (``s₂`` the largest eigenvalue of ``AᵀA``, when ``> 1``) and the
buckets follow TVAL3's published ``Scaleb`` rule. ``μ`` weighs ``‖A u − b‖²`` in those units
against ``α₁ = 1``; ``tgv(c·y) = c·tgv(y)`` for orthonormal rows and any ``c > 0``.

**Weights.** ``α₀/α₁`` is a length (in pixels): a kink that changes the slope by ``s``
costs as much as a jump of height ``s·α₀/α₁``. ``alpha="auto"`` sets it to ``n/√M``, the
size in pixels of a cell of the ``√M × √M`` grid that ``M`` low-order rows resolve: ``2`` at
25 % sampling (the common choice ``α₀ = 2α₁`` on a unit grid), larger at lower sampling,
where the measured resolution is coarser. On the piecewise-planar scene (1 % noise,
cake-cutting rows, best weight and prior per ratio, ``docs/tgv.md``) ``n/√M`` was the best
of the ratios tried (1–8) at n = 32 and SR 6.25, 12.5, 25 and 37.5 %, and within 0.1 dB of
the best at n = 64 (SR 25, 37.5 %); against the fixed ratio 2 it gained 2.2 dB at n = 32,
SR 6.25 % and was within 0.11 dB elsewhere.

**Stopping**: a sample stops when the relative change ``‖x_k − x_{k−1}‖ ≤ tol ‖x_{k−1}‖``;
the test is read on the host only every ``check_every`` iterations (``adaptive=True``) or
never (``adaptive=False``: exactly ``max_iter`` iterations, no host reads in the loop; that
form exports to ONNX, ``torchtof export tgv``).
"""

from __future__ import annotations

import math
from functools import partial
from typing import NamedTuple

import torch
from torch import nn

from .._checks import (
    check_bool,
    check_positive,
    check_weight_range,
    is_tracing,
    run_loop,
)
from ..operators.base import LinearOperator
from .base import pow2_scale, relative_residual
from .tv import (
    BOUNDARIES,
    TV_NORMS,
    box_bounds,
    bucket_spread,
    grad2,
    largest_eig_normal,
    loop_differences,
    project_box,
    scale_a,
    scaled_loop_pair,
    sym_grad2,
)
from .tval3 import B_SPREAD, B_SPREAD_MIN, check_buckets

__all__ = ["tgv", "TGV", "TGVResult", "TGV_STOP_REASONS", "tgv_prior", "auto_ratio",
           "DEFAULT_RATIO"]

#: ``stop_reason`` codes of :class:`TGVResult` (index into this tuple).
TGV_STOP_REASONS = ("tol", "max_iter")
#: ``α₀/α₁`` of ``alpha="auto"`` where no operator is known yet (``TGV``'s checks): the
#: common choice ``α₀ = 2α₁`` on a unit pixel grid, which ``n/√M`` gives at 25 % sampling.
DEFAULT_RATIO = 2.0
#: Bounds of ``‖K‖²`` (module doc): closed-form data prox / dualised data.
_L2_PROX = 12.0
_L2_DUAL = 13.0
#: Primal/dual balance: ``τ/σ = (BALANCE · RMS(Aᵀb) / α₁)²`` (module doc). Measured on the
#: 32×32 and 64×64 piecewise-planar scenes at 25 % SR (``docs/tgv.md``): 0.03–0.1 reach the
#: converged PSNR (±0.07 dB) in ~300 iterations; 1 (plain ``τ = σ``) needed 1 000–3 000.
BALANCE = 0.05


class TGVResult(NamedTuple):
    """Output of :func:`tgv`.

    Attributes:
        x: reconstruction ``(B, C, n, n)``.
        n_iter: iterations run per sample ``(B, C)`` (int64).
        residual: ``‖A x − y‖ / ‖y‖`` per sample ``(B, C)`` (0 for an all-zero ``y``).
        converged: ``(B, C)`` bool, the relative-change test met before ``max_iter``.
        stop_reason: names ``[b][c]`` from :data:`TGV_STOP_REASONS`; empty while tracing.
        stop_code: the same as a ``(B, C)`` int64 index.
        w: the vector field ``(B, C, 2, n, n)`` (the slope of the affine pieces), in the
            units of ``x`` per pixel.
    """

    x: torch.Tensor
    n_iter: torch.Tensor
    residual: torch.Tensor
    converged: torch.Tensor
    stop_reason: tuple = ()
    stop_code: torch.Tensor | None = None
    w: torch.Tensor | None = None


def _support(w: torch.Tensor, boundary: str) -> torch.Tensor:
    """``P w``: zero the entries where :func:`grad2` has no difference (Neumann: the last
    column of ``w_x``, the last row of ``w_y``); the identity for periodic boundaries."""
    if boundary == "periodic":
        return w
    wx = torch.nn.functional.pad(w[..., 0, :, :-1], (0, 1))
    wy = torch.nn.functional.pad(w[..., 1, :-1, :], (0, 0, 0, 1))
    return torch.stack((wx, wy), dim=-3)


def _support_nb(w: torch.Tensor) -> torch.Tensor:
    """``_support(w, "neumann")`` bit for bit, written into one copy (no ``pad``/``stack``;
    the in-place twin of :func:`~torchtof.recon.tv.grad2_nb`, with its autograd fallback)."""
    if w.requires_grad:
        return _support(w, "neumann")
    out = w.clone()
    out[..., 0, :, -1] = 0.0
    out[..., 1, -1, :] = 0.0
    return out


def _proj_ball(v: torch.Tensor, radius: float, isotropic: bool) -> torch.Tensor:
    """Projection onto the dual ball ``{‖v_i‖ ≤ radius}`` of the per-pixel norm over the
    channel axis ``-3`` (Euclidean: scale; anisotropic, the ℓ∞ ball: clamp)."""
    if not isotropic:
        return v.clamp(-radius, radius)
    # max(‖v‖/r, 1), with √ never taken at 0: its infinite derivative made the gradient
    # through the solver NaN wherever a dual variable was 0 (the values are unchanged)
    norm = _safe_norm((v * v).sum(dim=-3, keepdim=True))
    return v / torch.clamp(norm / radius, min=1.0)


def _safe_norm(sq: torch.Tensor) -> torch.Tensor:
    """``√sq`` with the gradient 0 where ``sq = 0`` (a subgradient of the norm), not NaN."""
    pos = sq > 0
    return torch.where(pos, torch.sqrt(torch.where(pos, sq, 1.0)), 0.0)


def tgv_prior(x: torch.Tensor, w: torch.Tensor, alpha: tuple[float, float] = (1.0, 2.0),
              tv: str = "isotropic", boundary: str = "neumann") -> torch.Tensor:
    """``α₁‖∇x − P w‖ + α₀‖E w‖`` per image, ``x (B, C, H, W)``, ``w (B, C, 2, H, W)`` ->
    ``(B,)`` summed over the channels (the objective of :func:`tgv` without the data term;
    its minimum over ``w`` is ``TGV²_α(x)``).

    Example:
        >>> i, j = torch.meshgrid(torch.arange(4.0), torch.arange(4.0), indexing="ij")
        >>> x = (1 + 0.5 * j - 0.25 * i)[None, None]       # an affine image
        >>> w = torch.tensor([0.5, -0.25])[None, None, :, None, None].expand(1, 1, 2, 4, 4)
        >>> tgv_prior(x, w).item()
        0.0
    """
    a1, a0 = alpha
    iso = tv == "isotropic"
    g = grad2(x, boundary) - _support(w, boundary)
    e = sym_grad2(w, boundary)
    if iso:  # √ of a zero sum has an infinite derivative: 0 there, a subgradient instead
        n1, n0 = _safe_norm((g * g).sum(dim=-3)), _safe_norm((e * e).sum(dim=-3))
    else:
        n1, n0 = g.abs().sum(dim=-3), e.abs().sum(dim=-3)
    return (a1 * n1.flatten(1).sum(1)) + (a0 * n0.flatten(1).sum(1))


# -- validation --------------------------------------------------------------------------------


def auto_ratio(A: LinearOperator) -> float:
    """``alpha="auto"``: ``α₀/α₁ = n/√M`` (module doc, "Weights")."""
    return A.n / math.sqrt(A.m)


def _alpha(alpha, fn: str, A: LinearOperator | None = None) -> tuple[float, float]:
    """``(α₁, α₀)`` from ``"auto"``, a ratio ``α₀/α₁`` (``α₁ = 1``) or a pair."""
    if isinstance(alpha, str):
        if alpha != "auto":
            raise ValueError(f"{fn}: expected alpha 'auto', a positive number or a pair, "
                             f"got {alpha!r}")
        return 1.0, (DEFAULT_RATIO if A is None else auto_ratio(A))
    if isinstance(alpha, bool):
        raise TypeError(f"{fn}: expected alpha a positive number or a pair, got bool")
    if isinstance(alpha, (int, float)):
        check_positive(alpha, "alpha", fn)
        return 1.0, float(alpha)
    if isinstance(alpha, (tuple, list)) and len(alpha) == 2:
        for v in alpha:
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise TypeError(f"{fn}: expected alpha a pair of numbers, got {alpha!r}")
            check_positive(v, "alpha", fn)
        return float(alpha[0]), float(alpha[1])
    raise TypeError(f"{fn}: expected alpha a positive number (the ratio α0/α1) or a pair "
                    f"(α1, α0), got {type(alpha).__name__}")




def _check_options(fn, mu, alpha, tvl2, max_iter, tol, tv, boundary, nonneg, bounds,
                   check_every, A=None) -> dict:
    if isinstance(mu, torch.Tensor):
        if mu.is_complex() or not mu.is_floating_point():
            raise TypeError(f"{fn}: expected mu a float tensor, got {mu.dtype}")
        if mu.device.type != "meta" and not is_tracing() and not bool(
                ((mu > 0) & mu.isfinite()).all()):  # one host read, at entry
            raise ValueError(f"{fn}: expected every entry of mu > 0 and finite (the "
                             "constrained model is tvl2=False, not mu=inf)")
    elif isinstance(mu, bool) or not isinstance(mu, (int, float)):
        raise TypeError(f"{fn}: expected mu a positive number or a (B, C) tensor, "
                        f"got {type(mu).__name__}")
    else:
        check_positive(mu, "mu", fn)
        if not math.isfinite(mu):
            raise ValueError(f"{fn}: expected mu finite, got {mu}")
    if isinstance(tvl2, torch.Tensor):
        if tvl2.dtype != torch.bool:
            raise TypeError(f"{fn}: expected tvl2 a bool or a bool tensor, got {tvl2.dtype}")
    elif not isinstance(tvl2, bool):
        raise TypeError(f"{fn}: expected tvl2 a bool or a bool tensor, got {type(tvl2).__name__}")
    for name, v, lo in (("max_iter", max_iter, 1), ("check_every", check_every, 1)):
        if isinstance(v, bool) or not isinstance(v, int):
            raise TypeError(f"{fn}: expected {name} an int, got {type(v).__name__}")
        if v < lo:
            raise ValueError(f"{fn}: expected {name} >= {lo}, got {v}")
    check_positive(tol, "tol", fn)
    if tv not in TV_NORMS:
        raise ValueError(f"{fn}: expected tv in {TV_NORMS}, got {tv!r}")
    if boundary not in BOUNDARIES:
        raise ValueError(f"{fn}: expected boundary in {BOUNDARIES}, got {boundary!r}")
    return dict(alpha=_alpha(alpha, fn, A), box=box_bounds(nonneg, bounds, fn))


def _per_sample(v, shape, dtype, device, name: str, fn: str) -> torch.Tensor:
    t = torch.as_tensor(v, dtype=dtype, device=device)
    try:
        return torch.broadcast_to(t, shape)
    except RuntimeError:
        raise ValueError(f"{fn}: expected {name} broadcastable to (B, C) = {tuple(shape)}, got "
                         f"shape {tuple(t.shape)}") from None


# -- the solver --------------------------------------------------------------------------------


def tgv(
    y: torch.Tensor,
    A: LinearOperator,
    mu: float | torch.Tensor = 2.0**8,
    alpha: float | tuple[float, float] | str = "auto",
    max_iter: int = 2000,
    tol: float = 1e-5,
    tv: str = "isotropic",
    nonneg: bool = False,
    *,
    boundary: str = "neumann",
    bounds: tuple[float | None, float | None] | None = None,
    tvl2: bool | torch.Tensor = False,
    adaptive: bool = True,
    check_every: int = 20,
    return_result: bool = False,
) -> torch.Tensor | TGVResult:
    """TGV² reconstruction (module doc): ``min TGV²_α(x) s.t. A x = y`` or TGV-L2.

    Args:
        y: buckets ``(B, C, M)``, ``M = A.m``; float32 or float64.
        A: measurement operator (any :class:`~torchtof.operators.LinearOperator`).
        mu: data weight of the TV-L2 model on the scaled buckets (as TVAL3's ``μ``; ignored
            by the constrained model), or a per-sample ``(B, C)`` tensor: with ``tvl2`` a
            ``(B, C)`` bool tensor one batched call tries several weights and models, as
            :func:`~torchtof.recon.auto` does with TVAL3. ``> 0`` and finite (every entry of a
            tensor, too: the constrained model is ``tvl2=False``).
        alpha: ``"auto"`` (``α₀/α₁ = n/√M``, module doc), the ratio ``α₀/α₁`` (``α₁ = 1``; a
            length in pixels: a kink of slope change ``s`` costs as much as a jump of height
            ``s·α₀/α₁``), or the pair ``(α₁, α₀)``.
        max_iter: iteration cap (``≥ 1``).
        tol: relative change per iteration at which a sample stops.
        tv: ``"isotropic"`` or ``"anisotropic"`` norm of both terms.
        nonneg: ``x ≥ 0`` by projection (an intensity image or a gated depth-bucket image is a
            sum of non-negative light, paper Eqs. 8, 10).
        boundary: ``"neumann"`` (default: no difference across the border, so planes may meet
            the border at any slope) or ``"periodic"``.
        bounds: ``(lo, hi)`` box in the units of ``x`` (either may be ``None``; a depth image
            lies in the camera's range ``[0, c/2f)``, paper Eq. 1), kept by projection.
        tvl2: ``False``: the equality-constrained model; ``True``: TV-L2 with weight ``mu``;
            or a ``(B, C)`` bool tensor choosing per sample.
        adaptive: stop each sample at ``tol`` (host read every ``check_every`` iterations);
            ``False``: exactly ``max_iter`` iterations, no host read in the loop.
        check_every: iterations between the host reads of the stopping test.
        return_result: return the :class:`TGVResult` (iterations, residual, convergence and stop
            reason per sample) instead of ``x``.

    Returns:
        ``x (B, C, n, n)``, or with ``return_result`` the :class:`TGVResult`.

    Raises:
        TypeError, ValueError: bad ``y``/``A`` (as :func:`~torchtof.recon.tval3.tval3`) or an
            option out of range (the message names it).

    Example:
        >>> from torchtof.operators import Hadamard
        >>> A = Hadamard(16, sr=0.25)
        >>> i, j = torch.meshgrid(torch.arange(16.0), torch.arange(16.0), indexing="ij")
        >>> x = (0.2 + 0.03 * j + 0.01 * i)[None, None]          # a tilted plane
        >>> res = tgv(A(x), A, return_result=True)
        >>> bool((res.x - x).abs().max() < 1e-2), res.stop_reason
        (True, (('tol',),))
    """
    fn = "tgv"
    check_buckets(y, A, fn)
    opts = _check_options(fn, mu, alpha, tvl2, max_iter, tol, tv, boundary, nonneg, bounds,
                          check_every, A)
    check_bool(adaptive, "adaptive", fn)
    check_bool(return_result, "return_result", fn)
    (a1, a0), (lo, hi) = opts["alpha"], opts["box"]
    for name, v in (("mu", mu), ("alpha", a1), ("alpha", a0)):
        check_weight_range(v, name, fn, y.dtype)
    b_, c_, _ = y.shape
    shape = (b_, c_)
    mu_t = _per_sample(mu, shape, y.dtype, y.device, "mu", fn)
    tvl2_t = _per_sample(tvl2, shape, torch.bool, y.device, "tvl2", fn)
    if b_ * c_ == 0:
        z = torch.zeros(shape, dtype=torch.int64, device=y.device)
        res = TGVResult(y.new_zeros(b_, c_, A.n, A.n), z, y.new_zeros(shape),
                        torch.ones(shape, dtype=torch.bool, device=y.device), (), z,
                        y.new_zeros(b_, c_, 2, A.n, A.n))
        return res if return_result else res.x

    # ScaleA and Scaleb as TVAL3 (module doc)
    inv_s2 = scale_a(A, y, fn)
    sq = math.sqrt(inv_s2)
    # an exact power of two per sample (1 at ordinary scales: bit for bit the same) brings
    # buckets near the ends of the dtype's range (3e38, 1e-40 in float32) to about 1, so
    # that their spread and its inverse stay finite: tgv(c·y) = c·tgv(y) at every scale
    # (eager only: the factor is built from IEEE bits, which the exporters cannot trace)
    k = torch.ones_like(y[..., :1]) if is_tracing() else pow2_scale(y)  # (B, C, 1)
    y = y * k
    spread = bucket_spread(y)
    zero = spread == 0
    safe = torch.where(zero, torch.ones_like(spread), spread)
    if A.orthonormal_rows:
        gain = B_SPREAD / safe
    else:
        s_scaled = safe * sq
        g = torch.where(s_scaled < B_SPREAD_MIN, B_SPREAD_MIN / s_scaled,
                        torch.where(s_scaled > B_SPREAD, B_SPREAD / s_scaled,
                                    torch.ones_like(s_scaled)))
        gain = g * sq
    b = y * gain[..., None]
    scale = gain / sq  # u = x · gain/√s2
    k4 = k[..., None]  # (B, C, 1, 1)
    box = None if lo is None and hi is None else (
        None if lo is None else (lo * k4) * scale[..., None, None],
        None if hi is None else (hi * k4) * scale[..., None, None])
    # y validated above: no check_finite per operator call in the loop; without a graph to
    # build, the loop runs in inference mode (the same bits, less overhead per op)
    u, w, n_iter, done = run_loop(_pdhg, b, A, sq, mu_t, ~tvl2_t, (a1, a0), tv == "isotropic",
                                  boundary, box, max_iter, tol, adaptive, check_every, zero,
                                  inputs=(b, mu_t, *(box or ())), module=A)
    unscale = (sq / gain)[..., None, None]
    # all-zero buckets: 0, projected onto the caller's box (a bound is kept for them too)
    x0 = project_box(torch.zeros_like(u), lo, hi) if box is not None else torch.zeros_like(u)
    x = torch.where(zero[..., None, None], x0, u * unscale / k4)
    w = torch.where(zero[..., None, None, None], torch.zeros_like(w),
                    w * unscale[..., None] / k4[..., None])
    residual = relative_residual(x, y / k, A)
    code = torch.where(done, 0, 1)
    names = () if is_tracing() or y.device.type == "meta" else tuple(
        tuple(TGV_STOP_REASONS[k] for k in row) for row in code.tolist())
    res = TGVResult(x, n_iter, residual, done, names, code, w)
    return res if return_result else res.x


def _pdhg(b, A, sq, mu, constrained, alpha, iso, boundary, box, max_iter, tol, adaptive,
          check_every, zero):
    """Chambolle–Pock iterations on the scaled problem (module doc); per-sample ``mu``,
    ``constrained`` ``(B, C)``. Returns ``(u, w, n_iter, converged)``."""
    a1, a0 = alpha
    fwd, adj = scaled_loop_pair(A, b, sq)

    # the closed-form data prox needs AᵀA to be a projection, and no box
    prox = bool(A.orthonormal_rows) and box is None
    lsq = math.sqrt(_L2_PROX if prox else _L2_DUAL)
    atb = adj(b)
    tiny = torch.finfo(b.dtype).tiny
    rms = atb.pow(2).mean(dim=(-2, -1)).sqrt()
    s = BALANCE * torch.where(rms > 0, rms / a1, torch.ones_like(rms))  # (B, C)
    tau = (s / lsq)[..., None, None]
    sigma = (1.0 / (s * lsq))[..., None, None]
    inv_mu = torch.where(constrained, torch.zeros_like(mu), 1.0 / mu)
    lo, hi = (None, None) if box is None else box
    x = project_box(atb, lo, hi)
    w = torch.zeros((*x.shape[:2], 2, *x.shape[2:]), dtype=x.dtype, device=x.device)
    p = torch.zeros_like(w)
    q = torch.zeros((*x.shape[:2], 4, *x.shape[2:]), dtype=x.dtype, device=x.device)
    r = torch.zeros_like(b)
    xb, wb = x, w
    if prox:  # θ = τμ/(1 + τμ) per sample; 1 for the constrained model
        c = tau[..., 0, 0] * mu
        theta = torch.where(constrained, torch.ones_like(mu), c / (1 + c))[..., None]
    else:
        sig_r = sigma[..., 0]  # (B, C, 1)
        r_den = 1.0 + sig_r * inv_mu[..., None]
    done = zero.clone()
    n_iter = torch.zeros(mu.shape, dtype=torch.int64, device=b.device)
    sf = sigma[..., None]
    tf = tau[..., None]
    vn = torch.linalg.vector_norm
    D, Dt, E, Et, in_place = loop_differences(boundary, b, A.n)
    P = _support_nb if in_place else partial(_support, boundary=boundary)
    for k in range(max_iter):
        p_n = _proj_ball(p + sf * (D(xb) - P(wb)), a1, iso)
        q_n = _proj_ball(q + sf * E(wb), a0, iso)
        v = x - tau * Dt(p_n)
        if prox:
            x_n = v + adj(theta * (b - fwd(v)))
            r_n = r
        else:
            r_n = (r + sig_r * (fwd(xb) - b)) / r_den
            x_n = project_box(v - tau * adj(r_n), lo, hi)
        w_n = w + tf * (P(p_n) - Et(q_n))
        change = vn(x_n - x, dim=(-2, -1)) / vn(x, dim=(-2, -1)).clamp_min(tiny)
        # a frozen sample keeps its x and w (the outputs); its other variables feed only its
        # own next iterates, which these masks discard, so they go unmasked
        keep = done[..., None, None]
        xb, wb, p, q, r = 2 * x_n - x, 2 * w_n - w, p_n, q_n, r_n
        x = torch.where(keep, x, x_n)
        w = torch.where(keep[..., None], w, w_n)
        n_iter = n_iter + (~done).to(torch.int64)
        if adaptive:
            done = done | (change <= tol)
            if (k + 1) % check_every == 0 and bool(done.all()):
                break
    return x, w, n_iter, done & ~zero | zero


class TGV(nn.Module):
    """TGV² reconstructor: ``forward(y) -> x``, ``solve(y) -> TGVResult`` (see :func:`tgv`).

    Args:
        A: measurement operator (a submodule, so ``.to()`` moves its buffers).
        mu, alpha, max_iter, tol, tv, nonneg, boundary, bounds, tvl2, adaptive, check_every:
            as :func:`tgv` (a tensor ``mu``/``tvl2`` must match the batch).

    Example:
        >>> from torchtof.operators import Hadamard
        >>> TGV(Hadamard(8, sr=0.5))(torch.zeros(2, 1, 32)).shape
        torch.Size([2, 1, 8, 8])
    """

    def __init__(self, A: LinearOperator, mu: float | torch.Tensor = 2.0**8,
                 alpha: float | tuple[float, float] | str = "auto", max_iter: int = 2000,
                 tol: float = 1e-5, tv: str = "isotropic", nonneg: bool = False, *,
                 boundary: str = "neumann", bounds: tuple | None = None,
                 tvl2: bool | torch.Tensor = False, adaptive: bool = True,
                 check_every: int = 20) -> None:
        super().__init__()
        if not isinstance(A, LinearOperator):
            raise TypeError(f"TGV: expected A to be a LinearOperator, got {type(A).__name__}")
        _check_options("TGV", mu, alpha, tvl2, max_iter, tol, tv, boundary, nonneg, bounds,
                       check_every)
        check_bool(adaptive, "adaptive", "TGV")
        if not A.orthonormal_rows:  # s₂ cached now (one power iteration per operator)
            largest_eig_normal(A, torch.zeros(1))
        self.A = A
        self.options = dict(mu=mu, alpha=alpha, max_iter=max_iter, tol=tol, tv=tv,
                            nonneg=nonneg, boundary=boundary, bounds=bounds, tvl2=tvl2,
                            adaptive=adaptive, check_every=check_every)

    def solve(self, y: torch.Tensor) -> TGVResult:
        return tgv(y, self.A, **self.options, return_result=True)

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        return self.solve(y).x

    def extra_repr(self) -> str:
        o = self.options
        return (f"alpha={o['alpha']}, tvl2={o['tvl2']}, mu={o['mu']}, tv={o['tv']!r}, "
                f"boundary={o['boundary']!r}, max_iter={o['max_iter']}")
