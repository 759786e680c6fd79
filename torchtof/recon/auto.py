"""Automatic TV reconstruction: prior, bounds and weight chosen from the buckets alone.

No single TV model wins everywhere: anisotropic TV suits binary, pixel-grid silhouettes,
isotropic TV natural grey images, a non-negativity or box constraint helps where the image
is known to obey it, and the data weight depends on the noise. :func:`auto` chooses among
these candidates by **cross-validation on the buckets** (Stone 1974, J. R. Stat. Soc. B 36;
for regularisation weights Golub, Heath & Wahba 1979, Technometrics 21): every candidate is
fitted on a training subset of the measurements with a reduced iteration budget and scored
by the squared prediction error on held-out measurements,

.. math::
    \\mathrm{CV}(c) = \\sum_{k} \\big\\|P_{k}\\,(A\\,\\hat x_c^{(k)} - y)\\big\\|^2,

then the chosen candidate is refitted on every measurement. No ground truth is used.

Which measurements are held out matters. For Hadamard rows in a low-to-high order (the
package's default cake-cutting order) the reconstruction's task is to predict the rows
*after* the measured ones, so the default ``split="tail"`` holds out the last rows and fits
on the rows before them (a forward, "rolling-origin" validation, Tashman 2000, Int. J.
Forecasting 16). A random partition (``split="random"``, the default for unordered patterns
such as random 0/1) held out rows of every sequency and, on textured scenes at low SR,
preferred the smoothest candidate (it predicts unpredictable coefficients as 0) and lost
up to 3 dB (``docs/auto.md``). Rows that alone carry the image mean (the all-ones Hadamard
row: TV does not see a constant) stay in every training set.

Candidates (per sample): TV ``{"isotropic", "anisotropic"}`` × bounds ``{none, x ≥ 0}``
(plus the caller's ``bounds`` box) × weights: the published equality-constrained TVAL3
(``μ = 2⁸``) and the TV-L2 model with ``μ ∈ 2^{10, 8, 6, 4}`` on the scaled buckets: 20
candidates (30 with a box).

Cost: each (TV, bounds) pair is one batched :func:`~torchtof.recon.tval3` call with
``F × 5`` channels per sample (``F`` folds: ``K − 1`` for ``"tail"``, ``K`` for
``"random"``) at ``cv_iter`` iterations, then the refit (one call per chosen (TV, bounds,
model) group). With the defaults (``K = 2`` tail split, ``cv_iter = 100``, 4 pairs): 4
batched calls of 5 channels × 100 iterations plus one TVAL3 solve: about 20 × 100 = 2000
single-image iterations besides the refit, i.e. about 20 default TVAL3 solves of ~100
iterations (measured times in ``docs/auto.md``).
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import nn

from .._checks import check_positive
from ..operators.base import LinearOperator
from .tval3 import STOP_REASONS, MaskedRows, check_buckets, default_split, holdout_split, tval3

__all__ = ["auto", "Auto", "AutoResult", "AUTO_WEIGHTS", "candidates"]

#: TV-L2 weights tried (on the buckets scaled as TVAL3's ``Scaleb``); ``inf``: the published
#: equality-constrained model with ``μ = 2⁸``.
AUTO_WEIGHTS = (float("inf"), 2.0**10, 2.0**8, 2.0**6, 2.0**4)
_CONSTRAINED_MU = 2.0**8


class AutoResult(NamedTuple):
    """Output of :func:`auto`.

    Attributes:
        x: reconstruction ``(B, C, n, n)`` (the refit of the chosen candidate).
        n_iter: refit iterations per sample ``(B, C)``.
        residual: ``‖A x − y‖ / ‖y‖`` per sample ``(B, C)``.
        converged: ``(B, C)`` bool.
        stop_reason: names ``[b][c]`` (see :data:`~torchtof.recon.tval3.STOP_REASONS`).
        choice: the chosen candidate per sample ``[b][c]``, a dict ``tv``, ``bounds``, ``mu``
            (``None``: the constrained model), ``cv``.
        cv_error: ``(B, C, len(candidates))`` cross-validation error of every candidate, in
            the squared units of ``y``.
        candidates: the candidate list, as dicts (same order as ``cv_error``).
    """

    x: torch.Tensor
    n_iter: torch.Tensor
    residual: torch.Tensor
    converged: torch.Tensor
    stop_reason: tuple
    choice: tuple
    cv_error: torch.Tensor
    candidates: tuple


def candidates(bounds: tuple | None = None) -> tuple[dict, ...]:
    """The candidate list of :func:`auto`: dicts ``tv``, ``bounds``, ``mu`` (``None``: the
    constrained model with ``μ = 2⁸``)."""
    boxes = [None, (0.0, None)] + ([tuple(bounds)] if bounds is not None else [])
    out = []
    for tv in ("isotropic", "anisotropic"):
        for box in boxes:
            for mu in AUTO_WEIGHTS:
                out.append(dict(tv=tv, bounds=box, mu=None if mu == float("inf") else mu))
    return tuple(out)


def _check(fn, folds, cv_iter, max_iter, bounds, split, slack):
    for name, v, lo in (("folds", folds, 2), ("cv_iter", cv_iter, 1), ("max_iter", max_iter, 1)):
        if isinstance(v, bool) or not isinstance(v, int):
            raise TypeError(f"{fn}: expected {name} to be an int, got {type(v).__name__}")
        if v < lo:
            raise ValueError(f"{fn}: expected {name} >= {lo}, got {v}")
    if bounds is not None:
        if not isinstance(bounds, (tuple, list)) or len(bounds) != 2:
            raise ValueError(f"{fn}: expected bounds to be a pair (lo, hi), got {bounds!r}")
        lo, hi = bounds
        if lo is not None and hi is not None and not float(lo) < float(hi):
            raise ValueError(f"{fn}: expected bounds with lo < hi, got {bounds!r}")
    if split not in (None, "random", "tail"):
        raise ValueError(f"{fn}: expected split in (None, 'random', 'tail'), got {split!r}")
    check_positive(slack, "slack", fn, strict=False)


def auto(
    y: torch.Tensor,
    A: LinearOperator,
    bounds: tuple[float | None, float | None] | None = None,
    folds: int = 2,
    cv_iter: int = 100,
    max_iter: int = 1025,
    *,
    split: str | None = None,
    slack: float = 0.0,
    seed: int = 0,
    return_result: bool = False,
) -> torch.Tensor | AutoResult:
    """TV reconstruction with prior, bounds and weight chosen by cross-validation (module doc).

    Choice: the candidate with the smallest CV error; with ``slack > 0`` the least
    regularised one (largest ``μ``; the constrained model counts as ``μ = ∞``) whose CV error
    is within ``1 + slack`` of the smallest (CV with fewer training rows tends to
    over-regularise, Shao 1993, JASA 88; but measured over the scenes of ``docs/auto.md``
    ``slack = 0.1`` lost up to 10 dB on smooth images, ``slack = 0`` is the default). The
    refit runs a chosen TV-L2 model to convergence (``max_iter``) and the constrained model
    with the ``cv_iter`` budget that was validated (its iteration count is its regulariser:
    run longer, it fits more noise).

    Args:
        y: buckets ``(B, C, M)``, ``M = A.m``, float32/float64; every sample chooses alone.
        A: the operator (any :class:`~torchtof.operators.LinearOperator`).
        bounds: a box ``(lo, hi)`` the caller knows (units of ``x``; e.g. ``(0, 1)`` for an
            image normalised by a calibration frame, ``(0, c/2f)`` for a depth image): added
            as a candidate beside none and ``x ≥ 0``.
        folds: ``K ≥ 2``. ``split="random"``: ``K`` folds of a random partition.
            ``split="tail"``: ``K − 1`` folds, fold ``j`` holding out the block of ``M/(2(K−1))``
            rows ending ``j`` blocks before the last row, trained on the rows before it.
        cv_iter: iteration budget of every cross-validation solve.
        max_iter: iteration budget of a TV-L2 refit.
        split: ``"random"``, ``"tail"`` or ``None`` (:func:`default_split`: ``"tail"`` for
            Hadamard rows in a low-to-high order, where the unmeasured rows that the
            reconstruction must predict follow the measured ones).
        slack: relative CV tolerance of the choice (``≥ 0``).
        seed: seed of the random fold assignment (deterministic by default).
        return_result: return an :class:`AutoResult` instead of ``x``.

    Returns:
        ``x (B, C, n, n)`` or :class:`AutoResult`.

    Raises:
        TypeError, ValueError: bad ``y``/``A`` (as :func:`~torchtof.recon.tval3`) or options.

    Example:
        >>> from torchtof.operators import Hadamard
        >>> A = Hadamard(16, sr=0.5)
        >>> x = torch.zeros(1, 1, 16, 16); x[..., 4:12, 3:9] = 1.0
        >>> bool((auto(A(x), A) - x).abs().max() < 0.05)
        True
    """
    fn = "auto"
    check_buckets(y, A, fn)
    _check(fn, folds, cv_iter, max_iter, bounds, split, slack)
    split = default_split(A) if split is None else split
    b, c, m = y.shape
    cands = candidates(bounds)
    if b * c == 0:
        x = y.new_zeros(b, c, A.n, A.n)
        res = AutoResult(x, torch.zeros(b, c, dtype=torch.int64, device=y.device),
                         y.new_zeros(b, c), torch.ones(b, c, dtype=torch.bool, device=y.device),
                         (), (), y.new_zeros(b, c, len(cands)), cands)
        return res if return_result else x
    ys = y.reshape(b * c, 1, m)
    nw = len(AUTO_WEIGHTS)
    boxes = [None, (0.0, None)] + ([tuple(bounds)] if bounds is not None else [])
    pairs = [(tv, box) for tv in ("isotropic", "anisotropic") for box in boxes]
    held, train = holdout_split(A, folds, y, seed, split)  # (F, M)
    nf = held.shape[0]
    mask = train.repeat_interleave(nw, dim=0)  # channel j: fold j // nw, weight j % nw
    op = MaskedRows(A, mask)
    wts = torch.tensor(AUTO_WEIGHTS, dtype=y.dtype, device=y.device)
    mus = torch.where(wts.isinf(), torch.full_like(wts, _CONSTRAINED_MU), wts).repeat(nf)
    tvl2 = (~wts.isinf()).repeat(nf)
    yt = ys * mask.to(y.dtype)  # (BC, F·W, M): rows outside the training set zeroed
    hm = held.repeat_interleave(nw, dim=0).to(y.dtype)
    cv = []
    for tv, box in pairs:
        r = tval3(yt, op, mu=mus.expand(b * c, -1), tvl2=tvl2.expand(b * c, -1),
                  max_iter=cv_iter, tv=tv, bounds=box)
        pred = (A(r.x) - ys) * hm
        cv.append((pred * pred).sum(-1).reshape(b * c, nf, nw).sum(1))  # (BC, W)
    cv_err = torch.stack(cv, dim=1).reshape(b * c, -1)  # (BC, pairs·W), order of `cands`
    wrank = wts.repeat(len(pairs))  # weight of each candidate (inf: constrained)
    ok = cv_err <= (1 + slack) * cv_err.amin(dim=1, keepdim=True)
    top = torch.where(ok, wrank, torch.full_like(wrank, -1.0)).amax(dim=1, keepdim=True)
    best = torch.where(ok & (wrank == top), cv_err, torch.full_like(cv_err, torch.inf)).argmin(1)
    best_l = best.tolist()  # one host read: the choice decides which solves run
    x = y.new_zeros(b * c, 1, A.n, A.n)
    n_iter = torch.zeros(b * c, 1, dtype=torch.int64, device=y.device)
    conv = torch.zeros(b * c, 1, dtype=torch.bool, device=y.device)
    codes = torch.zeros(b * c, 1, dtype=torch.int64, device=y.device)
    for p, (tv, box) in enumerate(pairs):
        for constrained in (True, False):
            rows = [i for i, k in enumerate(best_l)
                    if k // nw == p and (AUTO_WEIGHTS[k % nw] == float("inf")) == constrained]
            if not rows:
                continue
            w = torch.tensor([AUTO_WEIGHTS[best_l[i] % nw] for i in rows], dtype=y.dtype,
                             device=y.device)
            idx = torch.tensor(rows, device=y.device)
            if constrained:
                r = tval3(ys[idx], A, mu=_CONSTRAINED_MU, max_iter=cv_iter, tv=tv, bounds=box)
            else:
                r = tval3(ys[idx], A, mu=w[:, None], tvl2=True, max_iter=max_iter, tv=tv,
                          bounds=box)
            x[idx], n_iter[idx], conv[idx], codes[idx] = r.x, r.n_iter, r.converged, r.stop_code
    x = x.reshape(b, c, A.n, A.n)
    ynorm = y.norm(dim=-1)
    residual = (A(x) - y).norm(dim=-1) / torch.where(ynorm > 0, ynorm, torch.ones_like(ynorm))
    cv_l = cv_err.tolist()
    choice = tuple(
        tuple(dict(cands[best_l[i * c + j]], cv=cv_l[i * c + j][best_l[i * c + j]])
              for j in range(c)) for i in range(b))
    codes = codes.reshape(b, c)
    reasons = tuple(tuple(STOP_REASONS[k] for k in row) for row in codes.tolist())
    res = AutoResult(x, n_iter.reshape(b, c), residual, conv.reshape(b, c), reasons, choice,
                     cv_err.reshape(b, c, -1), cands)
    return res if return_result else x


class Auto(nn.Module):
    """Module of :func:`auto`: ``forward(y) -> x``, ``solve(y) -> AutoResult``.

    Args:
        A: the operator (a submodule). bounds, folds, cv_iter, max_iter, split, slack, seed:
            as :func:`auto`.

    Example:
        >>> from torchtof.operators import Hadamard
        >>> Auto(Hadamard(8, sr=0.5))(torch.zeros(2, 1, 32)).shape
        torch.Size([2, 1, 8, 8])
    """

    def __init__(self, A: LinearOperator, bounds: tuple | None = None, folds: int = 2,
                 cv_iter: int = 100, max_iter: int = 1025, split: str | None = None,
                 slack: float = 0.0, seed: int = 0) -> None:
        super().__init__()
        if not isinstance(A, LinearOperator):
            raise TypeError(f"Auto: expected A to be a LinearOperator, got {type(A).__name__}")
        _check("Auto", folds, cv_iter, max_iter, bounds, split, slack)
        self.A = A
        self.options = dict(bounds=bounds, folds=folds, cv_iter=cv_iter, max_iter=max_iter,
                            split=split, slack=slack, seed=seed)

    def solve(self, y: torch.Tensor) -> AutoResult:
        return auto(y, self.A, return_result=True, **self.options)

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        return self.solve(y).x

    def extra_repr(self) -> str:
        o = self.options
        return f"bounds={o['bounds']}, folds={o['folds']}, cv_iter={o['cv_iter']}"
