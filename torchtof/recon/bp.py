"""Basis pursuit reconstruction in an orthonormal sparsity basis (DCT-II or Haar).

Basis pursuit (Chen, Donoho & Saunders 1998), the "BP" of ghost-imaging papers
(l1-MAGIC, Candès & Romberg): with ``Ψ`` an orthonormal basis (:mod:`.dct`) and ``z = Ψᵀx``,

.. math:: \\min_x \\|\\Psi^\\top x\\|_1 \\quad \\text{s.t.}\\quad A x = y,

solved by ADMM (Boyd et al. 2011, §6.2) on ``min I_C(x) + ‖z‖₁ s.t. Ψᵀx − z = 0``
with ``C = {x : Ax = y}`` and the scaled dual ``u``:

.. math::
    x^{k+1} = P_C\\big(\\Psi(z^k - u^k)\\big),\\quad
    \\hat w = \\alpha \\Psi^\\top x^{k+1} + (1 - \\alpha) z^k,\\quad
    z^{k+1} = S_{1/\\rho}(\\hat w + u^k),\\quad
    u^{k+1} = u^k + \\hat w - z^{k+1},

``S_t(v) = sign(v) max(|v| − t, 0)``, ``α ∈ (0, 2)`` the over-relaxation (Boyd §3.4.3;
default 1.6), stopped per sample when the primal residual ``‖Ψᵀx − z‖`` and the dual residual
``ρ‖z^{k+1} − z^k‖`` fall below ``tol`` times ``max(‖Ψᵀx‖, ‖z‖)`` and ``‖ρu‖`` (Boyd §3.3.1
with ``ε_abs = 0``). ``rho`` is the initial penalty: every 10 iterations during the first half
of the run, ``ρ`` is doubled (halved) per sample when the relative primal (dual) residual
exceeds 10 times the other, with ``u`` rescaled (residual balancing, Boyd §3.4.1; He, Yang &
Wang 2000); the second half keeps ``ρ`` fixed, so the usual ADMM convergence applies.
The projection is exact, ``P_C(v) = v − Aᵀ(AAᵀ)⁺(Av − y)``: ``v − Aᵀ(Av − y)`` when
``AAᵀ = I`` (Hadamard), otherwise through the eigen-decomposition ``AAᵀ = U diag(s²) Uᵀ``
(float64, once per operator; eigenvalues below ``M·eps₆₄·max s²`` are dropped, so a
rank-deficient pattern set projects onto its least-squares set). The returned ``x`` is the
projected iterate: ``Ax = y`` to rounding.

**Noise-aware variants.**

- ``eps``: BPDN in constraint form ``min ‖Ψᵀx‖₁ s.t. ‖Ax − y‖₂ ≤ ε`` (van den Berg &
  Friedlander 2008), the same ADMM with ``P_C`` the exact projection onto that set. For
  ``AAᵀ = I`` it is closed form, ``r = Av − y``, ``x = v − Aᵀ r · max(0, 1 − ε/‖r‖)``;
  otherwise ``x = v − Aᵀ U diag(λ/(1 + λs²)) Uᵀ r`` with ``λ ≥ 0`` the root of the secular
  equation ``1/‖diag(1/(1 + λs²)) Uᵀr‖ = 1/ε`` (Newton from ``λ = 0``, monotone and
  exact in one step when all ``s²`` are equal; Moré & Sorensen 1983). ``eps="auto"`` sets
  ``ε = √M·σ̂`` with the robust noise estimate ``σ̂ = median|y_tail| / 0.6745`` (Donoho &
  Johnstone 1994) over the last quarter of the measurements: valid for orthonormal rows in a
  low-frequency-first order (Hadamard cake-cutting, sequency, Russian-doll), whose last rows
  see little signal; it over-estimates ``σ`` when they do. With fewer than
  :data:`AUTO_EPS_MIN_TAIL` tail buckets (``M < 13``) there is no noise estimate and the exact
  constraint is solved; the radius is capped at :data:`AUTO_EPS_CAP` ``·‖y‖`` (a radius
  ``≥ ‖y‖`` admits ``x = 0``), with a warning when the cap binds.
- ``lam``: the Lagrangian form ``min ½‖Ax − y‖² + λ‖Ψᵀx‖₁`` by FISTA (Beck & Teboulle 2009)
  with step ``1/L``, ``L = max s²`` (1 for ``AAᵀ = I``), stopped when
  ``‖z^{k+1} − z^k‖ ≤ tol·‖z^{k+1}‖``.

**Scaling.** Each sample is solved for ``y/‖y‖₂`` and rescaled, so ``rho`` and ``tol`` are
scale-free and ``basis_pursuit(c·y) = c·basis_pursuit(y)`` (``eps`` and ``lam`` are in the
units of ``y``; scale them with ``y``). An all-zero ``y`` returns an all-zero image.

**Modes.** ``adaptive=True`` (default) freezes converged samples and leaves the loop once all
have converged (checked every 10 iterations). ``adaptive=False`` runs exactly ``n_iter``
iterations with no data-dependent Python control flow and no ``.item()`` (only the operator's
eager-mode NaN checks read back): the mode :class:`BasisPursuit` exports to ONNX.

**Cost.** One iteration is one ``A``, one ``Aᵀ`` and two basis transforms. With Hadamard
rows at n = 32, SR 25 %, ``tol=1e-5`` takes about 150–1000 iterations (0.1–0.6 s per image on
one CPU core); generic Gaussian rows with a non-sparse scene can need thousands.
"""

from __future__ import annotations

import warnings
from typing import NamedTuple

import torch
from torch import nn

from .._checks import (
    check_bool,
    check_finite,
    check_in_range,
    check_positive,
    check_power_of_two,
    check_shape,
    is_tracing,
    run_loop,
)
from ..operators.base import LinearOperator
from .base import relative_residual
from .dct import dct2, dct_matrix, haar2, idct2, ihaar2
from .noise import abs_quantile_sigma

__all__ = ["BASES", "BPResult", "gram_factor", "basis_pursuit", "BasisPursuit"]

BASES = ("dct", "haar", "identity")
_CHECK_EVERY = 10
_NEWTON_STEPS = 20
_BALANCE_EVERY, _MU, _TAU = 10, 10.0, 2.0
_GRAM_NAMES = ("gram_u", "gram_s2", "gram_s2inv")
#: ``eps="auto"`` needs at least this many tail buckets (``⌈M/4⌉``, so ``M >= 13``); with fewer,
#: the lower median of one to three magnitudes is one of the buckets itself, no noise estimate
#: (with ``M = 1`` the radius ``|y|/0.6745`` always exceeds ``‖y‖``), and the exact constraint
#: (``eps=None``) is solved instead.
AUTO_EPS_MIN_TAIL = 4
#: ``eps="auto"`` radius cap, as a fraction of ``‖y‖₂``: a radius ``ε ≥ ‖y‖`` makes ``x = 0``
#: feasible and so the ℓ1 minimiser, whatever the buckets hold. The MAD estimate gets there when
#: the tail is no noise sample (buckets of equal magnitude, signal in the tail) or the buckets
#: are noise-dominated; the cap keeps the fit to at least 1 % of ``‖y‖`` and
#: :func:`basis_pursuit` warns.
AUTO_EPS_CAP = 0.99


class BPResult(NamedTuple):
    """Result of :func:`basis_pursuit`.

    Attributes:
        x: reconstruction ``(B, C, n, n)``.
        n_iter: iterations used per sample ``(B, C)`` (int64).
        residual: ``‖Ax − y‖₂ / ‖y‖₂`` per sample ``(B, C)`` (0 for ``y = 0``), as every
            reconstructor's result (with ``eps``, the active constraint gives ``ε / ‖y‖``).
        converged: ``(B, C)`` bool, stopping test met (at the last iteration when
            ``adaptive=False``).
        stop_reason: per sample ``"tol"`` (converged) or ``"max_iter"``, ``[b][c]``.
    """

    x: torch.Tensor
    n_iter: torch.Tensor
    residual: torch.Tensor
    converged: torch.Tensor
    stop_reason: tuple = ()


def gram_factor(A: LinearOperator, device=None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Eigen-decomposition ``AAᵀ = U diag(s²) Uᵀ`` in float64 for the projections.

    Args:
        A: the operator (dense ``A.matrix()`` is formed: small problems, ``M ≤ ~10⁴``).
        device: device to build it on (that of ``A``'s buffers).

    Returns:
        ``(U (M, M), s² (M,), s⁻² (M,))``, ``s⁻² = 0`` for eigenvalues below
        ``M·eps₆₄·max s²`` (pseudo-inverse).
    """
    a = A.matrix(dtype=torch.float64, device=device)
    s2, u = torch.linalg.eigh(a @ a.T)
    info = torch.finfo(torch.float64)
    keep = s2 > s2.amax().clamp_min(info.tiny) * A.m * info.eps
    s2inv = torch.where(keep, 1.0 / torch.where(keep, s2, torch.ones_like(s2)), 0.0)
    return u, s2.clamp_min(0), s2inv


def _soft(v: torch.Tensor, t: torch.Tensor | float) -> torch.Tensor:
    """Soft threshold ``S_t(v) = sign(v) max(|v| − t, 0)`` (prox of ``t‖·‖₁``)."""
    return torch.sign(v) * torch.clamp(v.abs() - t, min=0)


def _norm(v: torch.Tensor) -> torch.Tensor:
    """Euclidean norm over the image axes: ``(B, C, n, n) -> (B, C)``."""
    return torch.linalg.vector_norm(v, dim=(-2, -1))


def _basis(basis: str, n: int, like: torch.Tensor):
    """``(Ψᵀ, Ψ)`` as callables on ``(B, C, n, n)``."""
    if basis == "dct":
        d = dct_matrix(n, like.dtype, like.device)
        return (lambda x: dct2(x, d)), (lambda c: idct2(c, d))
    if basis == "haar":
        return haar2, ihaar2
    return (lambda x: x), (lambda c: c)


def _projector(A, yn, gram, eps_n):
    """``P(v)``: exact projection onto ``{Ax = yn}`` (``eps_n`` None) or ``{‖Ax − yn‖ ≤ eps_n}``."""
    tiny = torch.finfo(yn.dtype).tiny
    a_fwd, a_adj = A.loop_pair(yn)

    def project(v: torch.Tensor) -> torch.Tensor:
        r = a_fwd(v) - yn
        if gram is None:  # A Aᵀ = I
            if eps_n is None:
                return v - a_adj(r)
            nr = torch.linalg.vector_norm(r, dim=-1, keepdim=True).clamp_min(tiny)
            return v - a_adj(r * torch.clamp(1 - eps_n / nr, min=0))
        u, s2, s2inv = gram
        c = r @ u
        if eps_n is None:
            return v - a_adj((c * s2inv) @ u.T)
        c = c * (s2inv > 0).to(c.dtype)
        lam = torch.zeros_like(eps_n)
        for _ in range(_NEWTON_STEPS):  # secular equation, Moré & Sorensen (1983)
            q = 1 + lam * s2
            rr = c / q
            f = torch.linalg.vector_norm(rr, dim=-1, keepdim=True)  # zero-safe gradient
            d = (s2 * rr * rr / q).sum(dim=-1, keepdim=True)
            step = f * f * (f - eps_n) / (eps_n * d).clamp_min(tiny)
            lam = torch.clamp(lam + step, min=0)
        return v - a_adj((c * lam / (1 + lam * s2)) @ u.T)

    return project


def _step(state, new, active, iters, done, k, adaptive):
    """Accept ``new`` for the active samples (all of them when not ``adaptive``)."""
    if not adaptive:
        return new, iters + 1, done, False
    keep = active[..., None, None]
    state = tuple(torch.where(keep, a, b) for a, b in zip(new, state, strict=True))
    iters = iters + active.to(iters.dtype)
    active = active & ~done
    stop = (k + 1) % _CHECK_EVERY == 0 and not bool(active.any())
    return state, iters, active, stop


def _admm(x, project, fwd, inv, n_iter, rho, alpha, tol, adaptive):
    """Over-relaxed scaled ADMM with residual balancing (Boyd et al. 2011, §3.3, §3.4, §6.2)."""
    z = fwd(x)
    u = torch.zeros_like(z)
    iters = torch.zeros(z.shape[:-2], dtype=torch.int64, device=z.device)
    flag = torch.ones_like(iters, dtype=torch.bool)  # active (adaptive) or converged (fixed)
    rho_t = torch.full_like(z[..., :1, :1], float(rho))
    tiny = torch.finfo(z.dtype).tiny
    for k in range(n_iter):
        x_new = project(inv(z - u))
        wx = fwd(x_new)
        w = alpha * wx + (1 - alpha) * z
        z_new = _soft(w + u, 1.0 / rho_t)
        u_new = u + w - z_new
        # relative residuals (§3.3.1, ε_abs = 0): ‖Ψᵀx − z‖ / max(‖Ψᵀx‖, ‖z‖), ρ‖Δz‖ / ‖ρu‖
        r_pri = _norm(wx - z_new) / torch.maximum(_norm(wx), _norm(z_new)).clamp_min(tiny)
        r_dual = _norm(z_new - z) / _norm(u_new).clamp_min(tiny)
        done = (r_pri <= tol) & (r_dual <= tol)
        if k % _BALANCE_EVERY == 0 and 2 * k < n_iter:  # §3.4.1, first half of the run only
            act = flag if adaptive else torch.ones_like(flag)
            one = torch.ones_like(r_pri)
            f = torch.where((r_pri > _MU * r_dual) & act, one * _TAU, one)
            f = torch.where((r_dual > _MU * r_pri) & act, one / _TAU, f)[..., None, None]
            rho_t, u_new = rho_t * f, u_new / f
        (x, z, u, rho_t), iters, flag, stop = _step(
            (x, z, u, rho_t), (x_new, z_new, u_new, rho_t), flag, iters, done, k, adaptive
        )
        if stop:
            break
    return x, iters, ~flag if adaptive else flag


def _fista(x, A, yn, fwd, inv, big_l, thresh, n_iter, tol, adaptive):
    """FISTA (Beck & Teboulle 2009) on ``½‖AΨz − y‖² + λ‖z‖₁`` with step ``1/L``."""
    a_fwd, a_adj = A.loop_pair(yn)
    z = fwd(x)
    z_prev, t = z, 1.0
    iters = torch.zeros(z.shape[:-2], dtype=torch.int64, device=z.device)
    flag = torch.ones_like(iters, dtype=torch.bool)
    for k in range(n_iter):
        t_next = (1 + (1 + 4 * t * t) ** 0.5) / 2
        w = z + ((t - 1) / t_next) * (z - z_prev)
        z_new = _soft(w - fwd(a_adj(a_fwd(inv(w)) - yn)) / big_l, thresh)
        done = _norm(z_new - z) <= tol * _norm(z_new)
        t = t_next
        (z_prev, z), iters, flag, stop = _step(
            (z_prev, z), (z, z_new), flag, iters, done, k, adaptive
        )
        if stop:
            break
    return inv(z), iters, ~flag if adaptive else flag


def _auto_eps(y: torch.Tensor) -> torch.Tensor:
    """``√M · median|y_tail| / 0.6745`` over the last ``⌈M/4⌉`` measurements ``(B, C, 1)``
    (uncapped; :func:`basis_pursuit` applies :data:`AUTO_EPS_CAP` and
    :data:`AUTO_EPS_MIN_TAIL`)."""
    m = int(y.shape[-1])
    # the plain MAD rule over the last quarter: the package's one tail estimator
    sigma = abs_quantile_sigma(y[..., m - (m + 3) // 4 :], 0.5, interpolation="lower")
    return sigma[..., None] * m**0.5


def _check_config(func, basis, n_iter, rho, alpha, tol, eps, lam, A, adaptive=True):
    if not isinstance(A, LinearOperator):
        raise TypeError(f"{func}: expected A to be a LinearOperator, got {type(A).__name__}")
    check_bool(adaptive, "adaptive", func)
    if basis not in BASES:
        raise ValueError(f"{func}: expected basis in {BASES}, got {basis!r}")
    if basis == "haar":
        check_power_of_two(A.n, "A.n (image side) for basis='haar'", func)
    if isinstance(n_iter, bool) or not isinstance(n_iter, int):
        raise TypeError(f"{func}: expected n_iter to be an int, got {type(n_iter).__name__}")
    if n_iter < 1:
        raise ValueError(f"{func}: expected n_iter >= 1, got {n_iter}")
    check_positive(rho, "rho", func)
    check_in_range(alpha, 0.0, 2.0, "alpha", func, lo_open=True, hi_open=True)
    check_positive(tol, "tol", func, strict=False)
    if eps is not None and lam is not None:
        raise ValueError(f"{func}: give eps (constraint form) or lam (Lagrangian form), not both")
    if isinstance(eps, str):
        if eps != "auto":
            raise ValueError(f"{func}: expected eps to be None, a number or 'auto', got {eps!r}")
        if not A.orthonormal_rows:
            raise ValueError(
                f"{func}: eps='auto' estimates the noise from the last measurements and needs "
                f"an operator with orthonormal rows (Hadamard); give eps as a number"
            )
    elif eps is not None:
        check_positive(eps, "eps", func)
    if lam is not None:
        check_positive(lam, "lam", func)


def basis_pursuit(
    y: torch.Tensor,
    A: LinearOperator,
    basis: str = "dct",
    n_iter: int = 5000,
    rho: float = 100.0,
    alpha: float = 1.6,
    tol: float = 1e-5,
    eps: float | str | None = None,
    lam: float | None = None,
    adaptive: bool = True,
    gram: tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None = None,
    *,
    return_result: bool = False,
) -> torch.Tensor | BPResult:
    """Basis pursuit ``min ‖Ψᵀx‖₁ s.t. Ax = y`` by ADMM, or BPDN (see the module docstring).

    Args:
        y: measurements ``(B, C, M)``, float32 or float64; all samples are solved together.
        A: the operator (``A Aᵀ = I`` uses the closed-form projection).
        basis: sparsity basis ``Ψ``: ``"dct"`` (orthonormal DCT-II, default), ``"haar"``
            (multilevel Haar, ``n`` a power of two) or ``"identity"`` (pixels).
        n_iter: maximum (``adaptive=False``: exact) number of iterations, ``>= 1``.
        rho: initial ADMM penalty ``ρ > 0`` for ``y`` scaled to unit norm (threshold
            ``1/ρ``; adapted by residual balancing, see the module docstring).
        alpha: over-relaxation ``α ∈ (0, 2)`` (Boyd et al. 2011, §3.4.3).
        tol: relative tolerance ``>= 0`` of the stopping tests.
        eps: ``None`` (exact constraint), a noise radius ``ε > 0`` (``‖Ax − y‖ ≤ ε``, units
            of ``y``) or ``"auto"`` (``√M·σ̂``, orthonormal rows only; the exact constraint
            when ``M < 13``, at most :data:`AUTO_EPS_CAP` ``·‖y‖``, module docstring).
        lam: weight ``λ > 0`` of the Lagrangian form (FISTA) instead of the constraint.
        adaptive: per-sample early stopping (``True``) or exactly ``n_iter`` iterations; a
            bool.
        gram: cached :func:`gram_factor` of ``A`` (computed here when ``None`` and
            ``A Aᵀ ≠ I``).
        return_result: return the :class:`BPResult` (iterations, residual, convergence and stop
            reason per sample) instead of ``x``.

    Returns:
        ``x (B, C, n, n)``, or with ``return_result`` the :class:`BPResult`
        ``(x, n_iter, residual, converged, stop_reason)``.

    Raises:
        TypeError: ``A`` not a :class:`LinearOperator`, ``y`` not a float32/float64 tensor,
            ``n_iter`` not an int, ``adaptive`` or ``return_result`` not a bool.
        ValueError: ``y`` not ``(B, C, M)`` with ``M = A.m``; NaN/Inf in ``y``; unknown
            ``basis``; ``n_iter < 1``; ``rho``/``eps``/``lam`` not ``> 0``; ``alpha`` outside
            ``(0, 2)``; ``tol < 0``; both ``eps`` and ``lam``; ``eps="auto"`` without
            orthonormal rows.

    Shape:
        ``y (B, C, M) -> x (B, C, n, n)``; ``n_iter``, ``residual``, ``converged``: ``(B, C)``.

    Example:
        >>> from torchtof.operators import Hadamard
        >>> A = Hadamard(n=8, sr=0.5)
        >>> x = torch.zeros(1, 1, 8, 8, dtype=torch.float64)
        >>> x[..., 2:6, 2:6] = 1.0
        >>> res = basis_pursuit(A(x), A, return_result=True)
        >>> res.x.shape, bool(res.converged.all()), float(res.residual.max()) < 1e-10
        (torch.Size([1, 1, 8, 8]), True, True)
    """
    func = "basis_pursuit"
    _check_config(func, basis, n_iter, rho, alpha, tol, eps, lam, A, adaptive)
    check_bool(return_result, "return_result", func)
    check_shape(y, (None, None, A.m), "y", func, "(B, C, M)")
    if y.dtype not in (torch.float32, torch.float64):
        raise TypeError(f"{func}: expected y of dtype float32 or float64, got {y.dtype}")
    check_finite(y, "y", func)
    if A.orthonormal_rows:
        gram = None
    else:
        gram = gram_factor(A, y.device) if gram is None else gram
        big = float(gram[2].abs().max()) if (gram[2].numel() and not is_tracing()
                                                and gram[2].device.type != "meta") else 0.0
        if big > torch.finfo(y.dtype).max:  # one host read, at entry: s⁻² would be inf
            raise ValueError(f"{func}: A's rows are too small for {y.dtype} buckets (AAᵀ has "
                             f"eigenvalues down to {1 / big:.3g}, whose inverses overflow); "
                             "scale A (and y) up, or use float64 buckets")
        gram = tuple(g.to(dtype=y.dtype, device=y.device) for g in gram)
    n = A.n
    fwd, inv = _basis(basis, n, y)

    peak = y.abs().amax(dim=-1, keepdim=True)  # ‖y‖₂ = peak·‖y/peak‖₂: no over/underflow
    peak = torch.where(peak > 0, peak, torch.ones_like(peak))
    s = peak * torch.linalg.vector_norm(y / peak, dim=-1, keepdim=True)  # (B, C, 1)
    s = torch.where(s > 0, s, torch.ones_like(s))
    yn = y / s
    auto = isinstance(eps, str)
    if auto and (A.m + 3) // 4 < AUTO_EPS_MIN_TAIL:  # M is static: no sync, traces the same
        eps = auto = None  # too few tail buckets for a noise estimate: the exact constraint
    eps_n = capped = None
    if eps is not None:
        e = _auto_eps(y) if auto else torch.full_like(s, float(eps))
        eps_n = (e / s).clamp_min(torch.finfo(y.dtype).eps)
        if auto:  # ε/‖y‖ ≤ AUTO_EPS_CAP (bit for bit the estimate below it)
            capped = eps_n > AUTO_EPS_CAP
            eps_n = eps_n.clamp_max(AUTO_EPS_CAP)
    project = _projector(A, yn, gram, eps_n)

    # y was validated above: operator calls in the loop skip check_finite; without a graph to
    # build, the loop runs in inference mode (the same bits, less overhead per op)
    def solve():
        x0 = project(y.new_zeros(*y.shape[:-1], n, n))  # A⁺ y (or its ε-projection)
        if lam is None:
            return _admm(x0, project, fwd, inv, n_iter, rho, alpha, tol, adaptive)
        big_l = 1.0 if gram is None else gram[1].amax()
        thresh = lam / (s[..., None] * big_l)
        return _fista(x0, A, yn, fwd, inv, big_l, thresh, n_iter, tol, adaptive)

    x, iters, done = run_loop(solve, inputs=(yn, eps_n, *(gram or ())), module=A)
    x = x * s[..., None]
    residual = relative_residual(x, y, A)
    names = _stop_names(done)
    if eps is None and lam is None and adaptive and any(
            r == "max_iter" for row in names for r in row):  # one check per call, after the loop
        warnings.warn(
            "basis_pursuit: the equality-constrained model (eps=None) ran out of iterations "
            f"({n_iter}) without converging; raise n_iter, or, if the buckets are noisy (the "
            "exact fit then fits the noise, slowly), pass eps='auto' (noise from the buckets' "
            "tail) or eps=<noise radius>", UserWarning, stacklevel=2)
    if capped is not None and not is_tracing() and y.device.type != "meta" and bool(
            capped.any()):  # one check per call, after the loop
        warnings.warn(
            f"basis_pursuit: eps='auto' estimated a noise radius above {AUTO_EPS_CAP}·‖y‖ "
            f"for {int(capped.sum())} sample(s) (the buckets' tail is about as large as the "
            "whole signal: noise-dominated, or no noise sample) and capped it there; pass "
            "eps=None for the exact fit or eps=<noise radius>", UserWarning, stacklevel=2)
    res = BPResult(x, iters, residual, done, names)
    return res if return_result else res.x


def _stop_names(done: torch.Tensor) -> tuple:
    """Per-sample ``"tol"`` / ``"max_iter"`` names ``[b][c]`` (one host read after the solve;
    empty while tracing)."""
    if is_tracing() or done.device.type == "meta":
        return ()
    return tuple(tuple("tol" if d else "max_iter" for d in row) for row in done.tolist())


class BasisPursuit(nn.Module):
    """Module of :func:`basis_pursuit`: ``forward(y (B, C, M)) -> x (B, C, n, n)``.

    Holds the operator and, for ``A Aᵀ ≠ I``, its :func:`gram_factor` as non-persistent
    buffers (computed once here). :meth:`solve` returns the full :class:`BPResult`.
    Use ``adaptive=False`` for ONNX export (fixed ``n_iter`` iterations).

    Args:
        A: the operator.
        basis, n_iter, rho, alpha, tol, eps, lam, adaptive: as in :func:`basis_pursuit`.

    Raises:
        TypeError, ValueError: invalid configuration (as :func:`basis_pursuit`).

    Shape:
        ``(B, C, M) -> (B, C, n, n)``.

    Example:
        >>> from torchtof.operators import Hadamard
        >>> bp = BasisPursuit(Hadamard(n=8, sr=0.5), n_iter=50, adaptive=False)
        >>> bp(torch.rand(2, 1, 32)).shape
        torch.Size([2, 1, 8, 8])
    """

    def __init__(
        self,
        A: LinearOperator,
        basis: str = "dct",
        n_iter: int = 5000,
        rho: float = 100.0,
        alpha: float = 1.6,
        tol: float = 1e-5,
        eps: float | str | None = None,
        lam: float | None = None,
        adaptive: bool = True,
    ) -> None:
        super().__init__()
        _check_config("BasisPursuit", basis, n_iter, rho, alpha, tol, eps, lam, A, adaptive)
        self.A = A
        self.basis, self.n_iter, self.rho, self.alpha, self.tol = basis, n_iter, rho, alpha, tol
        self.eps, self.lam, self.adaptive = eps, lam, adaptive
        self._set_gram()
        # patterns loaded into A (PatternOperator state_dict): factor their Gram matrix again
        self.register_load_state_dict_post_hook(BasisPursuit._loaded)

    @staticmethod
    def _loaded(module: BasisPursuit, incompatible_keys) -> None:
        module._set_gram()

    def _set_gram(self) -> None:
        if not self.A.orthonormal_rows:
            dev = next((b.device for b in self.A.buffers()), None)
            for name, t in zip(_GRAM_NAMES, gram_factor(self.A, dev), strict=True):
                self.register_buffer(name, t, persistent=False)

    def _gram(self):
        if self.A.orthonormal_rows:
            return None
        return tuple(getattr(self, name) for name in _GRAM_NAMES)

    def solve(self, y: torch.Tensor) -> BPResult:
        """Full :class:`BPResult` for ``y (B, C, M)``."""
        return basis_pursuit(
            y, self.A, self.basis, self.n_iter, self.rho, self.alpha, self.tol,
            self.eps, self.lam, self.adaptive, self._gram(), return_result=True
        )  # fmt: skip

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        return self.solve(y).x

    def extra_repr(self) -> str:
        return (
            f"basis={self.basis!r}, n_iter={self.n_iter}, rho={self.rho}, alpha={self.alpha}, "
            f"tol={self.tol}, eps={self.eps!r}, lam={self.lam}, adaptive={self.adaptive}"
        )
