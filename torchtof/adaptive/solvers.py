"""Solvers stopped at the noise level (discrepancy principle), each saying why it stopped.

Morozov's discrepancy principle (Morozov 1966): an iterative solver that fits ``y = Ax + e``,
``‖e‖² ≈ Mσ²``, should stop at the first iterate with ``‖A x − y‖² ≤ τ M σ²`` — fitting
further only fits the noise. ``σ`` comes from repeated frames
(:func:`~torchtof.adaptive.noise.noise_from_repeats`) or from the high-order coefficients
(:func:`~torchtof.adaptive.noise.noise_from_blocks`).

- **TVAL3**: :func:`~torchtof.recon.tval3.tval3` with ``discrepancy=σ`` (stops at an inner
  convergence whose residual is within the bound instead of updating its multipliers) and
  ``noise_sigma=σ`` for its μ rule; reasons ``"discrepancy"``, ``"tol"``, ``"max_outer"``,
  ``"max_iter"``.
- **BP**: basis pursuit denoising with the discrepancy radius ``ε = √(τM)·σ``
  (``‖Ax − y‖ ≤ ε``, the constrained form of Morozov's rule); every ADMM iterate already
  satisfies the bound (exact projection), so it stops on its own tolerance: ``"tol"`` or
  ``"max_iter"``.
- **DIP**: :func:`~torchtof.recon.dip.fit_dip` with ``early_stop="discrepancy"`` on the
  calibrated residual; ``"discrepancy"`` or ``"max_iter"``.
- ``tau`` (Morozov's ``τ`` of the TVAL3 and BP bounds) below 1 uses a lower confidence limit
  of an estimated ``σ̂²`` (:func:`~torchtof.adaptive.noise.variance_lower_factor`), so that
  an over-estimate does not stop the solver before it fits the signal; ``model_sigma=False``
  keeps ``σ`` out of TVAL3's ``mu="auto"`` model choice (the residual bound only).
- **PINV** (``"direct"``) and the unrolled TVAL3 (``"fixed"``) have no iterations to stop.
- ``σ = 0`` means noise-free data, for every method: TVAL3 gets the published
  equality-constrained model (``μ_auto → ∞``, with ``model_sigma``) and a zero bound, met only
  by an exact fit; BP solves the exact constraint ``Ax = y`` (``eps=None``); the DIP runs
  without an early stop (``max_iter`` steps); PINV and the unrolled TVAL3 ignore ``σ``.
"""

from __future__ import annotations

import time
import warnings
from typing import NamedTuple

import torch

from .._checks import (
    check_bool,
    check_broadcast,
    check_finite,
    check_int,
    check_nonnegative,
    check_number,
    check_positive,
    check_real,
)
from ..constants import DISCREPANCY_TAU
from ..operators.base import LinearOperator
from ..recon import registry
from ..recon.base import relative_residual, renamed_option

__all__ = ["SolveResult", "solve_at_noise", "SOLVERS"]

#: registry labels of the solvers that :func:`solve_at_noise` stops at the noise level.
SOLVERS = tuple(registry.get(k).label for k in ("pinv", "bp", "tval3", "unrolled", "dip"))
#: Morozov's safety factor ``τ`` (the same as TVAL3's and the DIP's).
TAU = DISCREPANCY_TAU


class SolveResult(NamedTuple):
    """``x`` ``(B, C, n, n)``; per sample ``(B, C)``: ``n_iter`` (int64), ``residual``
    (``‖A x − y‖ / ‖y‖``), ``converged`` (stopped by its own rule, not by the iteration cap)
    and ``stop_reason`` (``[b][c]`` names); the ``method``, the ``noise_sigma`` used and the
    wall ``time_s``."""

    x: torch.Tensor
    n_iter: torch.Tensor
    residual: torch.Tensor
    converged: torch.Tensor
    stop_reason: tuple[tuple[str, ...], ...]
    method: str
    noise_sigma: float | None
    time_s: float


def _per_sample(v, shape) -> torch.Tensor:
    return torch.as_tensor(v, dtype=torch.float64).expand(shape)


def solve_at_noise(method: str, y: torch.Tensor, A, noise_sigma=None,
                   max_iter: int | None = None, sign: float = 1.0, seed: int = 0,
                   tau: float = TAU, model_sigma: bool = True,
                   n_iter: int | None = None) -> SolveResult:
    """Reconstruct ``y`` with ``method`` stopped by the discrepancy principle at ``noise_sigma``.

    Args:
        method: one of :data:`SOLVERS`.
        y: buckets ``(B, C, M)``.
        A: the orthonormal operator of ``y``.
        noise_sigma: noise std of ``y``, ``>= 0`` and finite (a number, or a tensor
            broadcastable to ``(B, C)``); ``0``: noise-free data (module docstring);
            ``None``: no discrepancy stop (each solver's own defaults).
        max_iter: iteration cap, an int ``>= 1`` (``None``: the solver's default; the
            unrolled TVAL3: its number of layers).
        sign: ``1``, or ``-1`` for negative-polarity buckets (the DIP fits ``−y``, see
            :mod:`torchtof.methods`).
        seed: DIP initialisation seed (an int).
        tau: Morozov's factor of the TVAL3 and BP bounds, ``‖Ax − y‖² ≤ τ M σ²`` (``τ < 1``:
            a lower confidence limit of ``σ̂²``, see
            :func:`~torchtof.adaptive.noise.variance_lower_factor`); the DIP keeps its own.
        model_sigma: TVAL3 only: also give ``noise_sigma`` to its ``mu="auto"`` model choice
            (``False``: TVAL3 picks the model from its own tail estimate, as without a
            noise level; only the discrepancy stop uses ``noise_sigma``).
        n_iter: old name of ``max_iter`` (``DeprecationWarning``; removed in the next release).

    The old argument order ``(method, A, y)`` still works for one release (with a
    ``DeprecationWarning``).

    Returns:
        :class:`SolveResult`.

    Raises:
        TypeError: ``y`` not a real floating-point tensor, ``A`` not a
            :class:`~torchtof.operators.LinearOperator`, ``max_iter`` or ``seed`` not an int,
            ``noise_sigma`` or ``tau`` not a number (or tensor), ``model_sigma`` not a bool.
        ValueError: unknown method, ``y`` not ``(B, C, M)``, ``noise_sigma`` negative, NaN/Inf
            or not broadcastable to ``(B, C)``, ``max_iter < 1``, ``tau`` not ``> 0`` and
            finite, ``sign`` not ``±1``; the solvers' own checks (``M = A.m``, NaN/Inf in
            ``y``).
    """
    from ..recon import PseudoInverse, UnrolledTVAL3, basis_pursuit, tval3
    from ..recon.dip import fit_dip

    fn = "solve_at_noise"
    if isinstance(y, LinearOperator) and isinstance(A, torch.Tensor):
        warnings.warn(f"{fn}: the argument order is now (method, y, A); (method, A, y) will "
                      "stop working in the next release", DeprecationWarning, stacklevel=2)
        y, A = A, y
    n_iter = renamed_option(fn, "n_iter", "max_iter", n_iter, max_iter, None)
    if method not in SOLVERS:
        raise ValueError(f"{fn}: expected method in {SOLVERS}, got {method!r}")
    check_positive(tau, "tau", fn)
    if not isinstance(y, torch.Tensor) or y.ndim != 3:
        raise ValueError(f"{fn}: expected y of shape (B, C, M), got "
                         f"{tuple(y.shape) if isinstance(y, torch.Tensor) else type(y)}")
    check_real(y, "y", fn)
    if not isinstance(A, LinearOperator):
        raise TypeError(f"{fn}: expected A to be a LinearOperator, got {type(A).__name__}")
    if n_iter is not None:
        check_int(n_iter, "max_iter", fn, lo=1)
    if check_number(sign, "sign", fn) not in (1.0, -1.0):
        raise ValueError(f"{fn}: expected sign 1 or -1, got {sign}")
    check_int(seed, "seed", fn)
    check_bool(model_sigma, "model_sigma", fn)
    b, c, m = y.shape
    if isinstance(noise_sigma, torch.Tensor):
        check_real(noise_sigma, "noise_sigma", fn)
        check_broadcast(noise_sigma, (b, c), "noise_sigma", fn, "(B, C)")
        check_finite(noise_sigma, "noise_sigma", fn)
        check_nonnegative(noise_sigma, "noise_sigma", fn)
    elif noise_sigma is not None:
        check_positive(noise_sigma, "noise_sigma", fn, strict=False)
    conv = None  # TVAL3, BP: their own flag; else: not stopped by the iteration cap
    sig = None if noise_sigma is None else _per_sample(noise_sigma, (b, c)).to(y.dtype)
    if y.device.type == "cuda":  # time the work, not its launch
        torch.cuda.synchronize(y.device)
    t0 = time.perf_counter()
    if method == "PINV":
        with torch.no_grad():
            x = PseudoInverse(A)(y)
        iters, reasons = [[0] * c for _ in range(b)], [["direct"] * c for _ in range(b)]
    elif method == "Unrolled":
        rec = UnrolledTVAL3(A) if n_iter is None else UnrolledTVAL3(A, n_layers=n_iter)
        with torch.no_grad():
            x = rec(y)
        iters = [[rec.n_layers] * c for _ in range(b)]
        reasons = [["fixed"] * c for _ in range(b)]
    elif method == "TVAL3":
        kw = {} if n_iter is None else {"max_iter": int(n_iter)}
        with torch.no_grad():
            disc = None if sig is None else sig * float(tau) ** 0.5  # τ M σ² = M (√τ σ)²
            res = tval3(y, A, noise_sigma=sig if model_sigma else None, discrepancy=disc, **kw,
                        return_result=True)
        x, iters, reasons, conv = res.x, res.n_iter.tolist(), res.reasons(), res.converged
    elif method == "BP":
        kw = {} if n_iter is None else {"n_iter": int(n_iter)}
        eps = "auto" if sig is None else None
        with torch.no_grad():
            if sig is None:
                res = basis_pursuit(y, A, eps=eps, **kw, return_result=True)
            else:  # per-sample radius: solve the samples one by one (eps is a float)
                # σ = 0: noise-free, the exact constraint Ax = y (eps=None)
                radii = ((tau * m) ** 0.5 * sig).tolist()  # one host read for all samples
                outs = [basis_pursuit(y[i : i + 1, j : j + 1], A,
                                      eps=float(radii[i][j]) if radii[i][j] > 0 else None,
                                      **kw, return_result=True)
                        for i in range(b) for j in range(c)]
                res = type(outs[0])(*(torch.cat([o[k] for o in outs]).reshape(
                    (b, c) + tuple(outs[0][k].shape[2:])) for k in range(4)))
        x = res.x
        iters = res.n_iter.tolist()
        reasons = [["tol" if ok else "max_iter" for ok in row] for row in res.converged.tolist()]
        conv = res.converged
    else:  # DIP, one sample at a time
        steps = 300 if n_iter is None else int(n_iter)
        xs, iters, reasons = [], [], []
        for i in range(b):
            xr, ir, rr = [], [], []
            for j in range(c):
                yi = sign * y[i : i + 1, j : j + 1]
                kw = dict(max_iter=steps, seed=seed)
                s_ij = None if sig is None else float(sig[i, j])
                if s_ij == 0.0:  # noise-free: no early stop, fit for max_iter steps
                    kw.update(early_stop=None)
                elif s_ij is not None:
                    kw.update(early_stop="discrepancy", noise_sigma=s_ij)
                r = fit_dip(yi, A, **kw)
                xr.append(sign * r.x_cal.detach())
                ir.append(r.n_iter)
                if s_ij == 0.0:
                    rr.append("max_iter")
                elif sig is None:
                    rr.append("wmv" if r.n_iter < steps else "max_iter")
                else:
                    res2 = float(((A(r.x_cal) - yi) ** 2).sum())
                    bound = DISCREPANCY_TAU * m * float(sig[i, j]) ** 2
                    rr.append("discrepancy" if (r.n_iter < steps or res2 <= bound) else "max_iter")
            xs.append(torch.cat(xr, dim=1))
            iters.append(ir)
            reasons.append(rr)
        x = torch.cat(xs)
    if x.device.type == "cuda":
        torch.cuda.synchronize(x.device)
    dt = time.perf_counter() - t0
    reasons = tuple(tuple(str(r) for r in row) for row in reasons)
    with torch.no_grad():
        res = relative_residual(x, y, A)
    if conv is None:
        conv = torch.tensor([[r != "max_iter" for r in row] for row in reasons],
                            dtype=torch.bool).reshape(b, c)
    return SolveResult(x=x, n_iter=torch.as_tensor(iters, dtype=torch.int64).reshape(b, c),
                       residual=res, converged=conv.to(x.device), stop_reason=reasons,
                       method=method, noise_sigma=None if sig is None else float(sig.max()),
                       time_s=dt)
