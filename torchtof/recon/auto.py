"""Automatic reconstruction: TV/TGV or Gaussian prior, bounds and weight chosen from the buckets
alone, stacked with the learned network where it applies.

No single TV model wins everywhere: anisotropic TV suits binary, pixel-grid silhouettes,
isotropic TV natural grey images, second-order TGV² piecewise-planar depth maps, a
non-negativity or box constraint helps where the image is known to obey it, and the data
weight depends on the noise. :func:`auto` chooses among these candidates by
**cross-validation on the buckets** (Stone 1974, J. R. Stat. Soc. B 36; for regularisation
weights Golub, Heath & Wahba 1979, Technometrics 21): every candidate is fitted on a
training subset of the measurements with a reduced iteration budget and scored by the
squared prediction error on held-out measurements, fold by fold,

.. math::
    \\mathrm{CV}_k(c) = \\big\\|P_{k}\\,(A\\,\\hat x_c^{(k)} - y)\\big\\|^2, \\qquad
    S(c) = \\sum_k \\frac{\\mathrm{CV}_k(c)}{\\min_{c'} \\mathrm{CV}_k(c')},

and the candidate with the smallest score ``S`` is refitted on every measurement. No ground
truth is used.

Which measurements are held out matters. For Hadamard rows in a low-to-high order (the
package's default cake-cutting order) the reconstruction's task is to predict the rows
*after* the measured ones, so the default ``split="tail"`` holds out the last rows and fits
on the rows before them (a forward, "rolling-origin" validation, Tashman 2000, Int. J.
Forecasting 16); by default each of the last three eighths of the rows is predicted from
all rows before it, i.e. from 7/8, 3/4 and 5/8 of them. A random partition
(``split="random"``, the default for unordered patterns such as random 0/1) held out rows of
every sequency and, on textured scenes at low SR, preferred the smoothest candidate and lost
up to 3 dB (``docs/auto.md``). Rows that alone carry the image mean (the all-ones Hadamard
row: TV does not see a constant) stay in every training set.

**Every fold counts alike.** Held-out rows of lower sequency carry more energy, so summed
raw errors follow the fold trained on the fewest rows, the one least like the full problem.
Where a prior recovers the image exactly from all rows (anisotropic TV on a binary image on
the pixel grid) it may not yet do so from half of them: its error is then largest in the
early folds and smallest by far in the late ones. Dividing each fold's error by that fold's
best makes every fold a relative error (scale-free, ``≥ 1``) and the score prefers the
candidate that is never far from the best in any fold. The fold trained on half of the
rows is left out by default (measured: no better with it, at 4/3 the cost). Measured
(``docs/auto.md``): on the paper's character, n = 64, SR 37.5 % the choice went from
isotropic TV (30.6 dB) to anisotropic TV; the fold trained on 7/8 of the rows sees it.

**Discrepancy bound.** On a textured scene the held-out rows are barely predictable and the
smoothest candidate, which predicts them as almost 0, scores best while it misfits the rows
it was fitted on. A candidate whose misfit of its own training rows exceeds
``FIT_TAU2 · (training rows) · σ̂²`` (``FIT_TAU2 = 1``) is therefore dropped (Morozov's
discrepancy principle, Morozov 1966, Soviet Math. Dokl. 7, as a bound, not as the choice);
``σ̂`` is :func:`~torchtof.recon.tval3.bucket_noise_sigma`, which over-estimates σ (it reads
signal in the tail rows as noise), so the bound errs towards keeping candidates. If every
candidate exceeds it, none is dropped.

Candidates (per sample): two priors, first-order TV (:func:`~torchtof.recon.tval3.tval3`)
and second-order TGV² (:func:`~torchtof.recon.tgv.tgv`, Bredies, Kunisch & Pock 2010, SIAM
J. Imaging Sci. 3: piecewise-affine images such as depth maps of tilted planes, which TV
turns into staircases), each with the norms ``{"isotropic", "anisotropic"}`` and Neumann
boundaries (no difference across the image border, the discrete gradient of Chambolle 2004,
J. Math. Imaging Vis. 20) × bounds ``{none, x ≥ 0}`` (plus the caller's ``bounds`` box) ×
weights: the equality-constrained model (TVAL3 as published, ``μ = 2⁸``) and the TV-L2 model
with ``μ ∈ 2^{12, 10, 8, 6, 4, 2}`` on the scaled buckets (stage 1: 56 candidates, 84 with a
box); then (stage 2) the stage-1 TV-L2 choice is compared with its neighbours ``μ·2`` and
``μ/2`` on the same folds.

**The TV-L2 solver** (``tv_solver``). The weights are chosen by comparing fits, and a fit
stopped early is regularised by its iteration count as well as by its weight. TVAL3's TV-L2
iteration stops by its published rule (``tol_inner = 10⁻³``, ``max_outer = 10``) after some
60–75 iterations; on the piecewise-planar map at n = 64, SR 6.25 %, μ = 2¹², its objective
was then 11 % (isotropic) and 39 % (anisotropic) above the minimum, and the anisotropic one
still 6 % above it after 20 000 iterations (``benchmarks/tvl2_convergence.py``,
``docs/auto.md``). ``tv_solver="split"`` fits the TV-L2 candidates of the TV prior, for
operators with orthonormal rows (and their row-masked folds), by
:func:`~torchtof.recon.tv.split_tv` instead, an ADMM whose every step is exact (SALSA,
Afonso, Bioucas-Dias & Figueiredo 2010): within 2 % of the minimum after the ``cv_iter`` =
100 iterations of a fit, within 0.3 % after 300; the refit runs ``max_iter`` of them. The
default stays ``"tval3"``: on the 90 cells of the peers benchmark the split fits changed the
result in 44 cells, from +1.52 dB (the planar map, n = 128, SR 12.5 %) to −2.15 dB (the horse
silhouette, n = 128, SR 12.5 %), −0.07 dB on average. They gain where the TV-L2 weight is the
question; they lose mostly where TGV², whose fits keep their 100 primal–dual iterations, was
the better model: the folds then compare converged TV fits with unconverged TGV² fits (on
some cells the converged fits also move the TV-L2 weight to a worse one).

**The fits' budget** (``fit_iter``). The TV-L2 and TGV-L2 fits on the folds may get their own
iteration budget, ``fit_iter`` (default ``None``: ``cv_iter``), while the constrained fits
and the constrained refit keep ``cv_iter``: the constrained model's iteration count is its
regulariser (run longer, it fits more noise), a TV-L2 fit's is not. TGV² by primal–dual
iterations is far from converged after 100 of them: on the planar map at n = 64, SR 6.25 %,
its best weight scores 29.6 dB after 100 iterations and 31.6 dB after 300 (isotropic;
anisotropic 28.7 → 31.4, 32.1 after 1000), so with 100 the folds prefer TV there (30.36 dB)
and with ``fit_iter=300`` TGV² (31.68 dB). Measured on the 90 peers cells
(``docs/auto.md``, "The fits' budget"): ``fit_iter=300`` gains +0.05 dB on average (33 cells
changed, −2.67 to +2.10 dB) at about twice the time, so it is an option, not the default;
with ``tv_solver="split"`` as well it loses (−0.03 dB; 天 n = 64, SR 37.5 % −7.11 dB, where the
converged TV-L2 fit with the inferred box scores better over the folds than the constrained
model, but not against the truth).

**The box alone.** Given a finite box ``(lo, hi)``, the image may be determined by the box
and the measurements without any prior: a binary image is a vertex of the box, and a
vertex is the unique box-feasible solution from fewer measurements than a smooth image needs
(Donoho & Tanner 2010, Discrete Comput. Geom. 43; Mangasarian & Recht 2011, Eur. J. Oper.
Res. 214). Cross-validation cannot see this (with a quarter of the rows held out the box no
longer determines the image: ``docs/auto.md``), so it is tested directly: box-constrained
least squares is solved from two starts that differ only in the null space of ``A``; if the
two solutions agree to ``BOX_UNIQUE`` (1 %) of the box width (RMS), the data and the box
leave no freedom and that solution is returned (``choice["prior"] == "box"``) — unless the
cross-validated choice, refitted on all rows, agrees with it to the same tolerance: then the
image it describes is the box's, and the choice is kept (measured on the paper's character,
n = 64, SR 37.5 %, box [0, 1]: box-only 46.4 dB, the anisotropic TV choice 50.5 dB).

**The inferred box** (no ``bounds`` given, ``infer_box=True``). A binary or two-level image
(a silhouette, a character, a gated depth image of one object before a background) obeys a
box that the caller may not know: its two levels. After the refit, the pixels of the
reconstruction are split at the midpoint of their range and the median of each side taken
as a level ``lo < hi``; if at least ``TWO_LEVEL`` (half) of the pixels lie within
``TWO_LEVEL_TOL`` (5 %) of ``hi − lo`` of one of the levels, the image is taken to be
two-level and the choice is made again with ``bounds=(lo, hi)`` added as a bound of the
chosen prior and norm: the weights of that prior and norm with the box are fitted on the same
folds and scored with every other candidate (whose errors are reused), and
``choice["inferred"]`` is ``True``. The box refines the choice; it does not reopen the choice
of prior and norm: letting the box candidates of every prior and norm compete was measured
worse (the paper's character 天 at n = 64, SR 37.5 %: 50.6 dB without the box, 47.9 dB
choosing TGV² with it, 50.5 dB refining the chosen anisotropic TV; 12 binary cells at
n = 32 and 64: +1.0 dB on average for the refinement, +0.6 dB for the open choice, the
n = 32 horse below aside). The box-only test is not run with an inferred box: the levels of
a noisy refit are biased inwards by a few per cent (TV's loss of contrast, Strong & Chan 2003,
Inverse Problems 19), and the box-only solution, exact only for the exact box, was measured to
lose 3–8 dB with such a box on a noisy binary square (16 × 16, SR 50 %) where the
cross-validated choice did not. Measured (``docs/auto.md``): the binary silhouette at
n = 32, SR 37.5 %, sequency rows went from 28.8 to 44.0 dB; grey images and depth maps are
not two-level by this test and do not change. It costs one more solve of one candidate group
(the chosen prior and norm with the box; stage 1 solves 8), its stage 2 and, if the choice
changes, a refit: only for two-level images.
The inferred box is the fragile part of the choice: on scenes held out from its design (a
thin-stroked character and a binary silhouette at SR 12.5 %, ``docs/peers.md``, "Held-out
scenes") the refit's dark level came out biased (0.14 instead of 0) or the refinement kept
isotropic TV where TGV² with the same box was 11 dB better, and the call lost 6–7 dB to a
box-projected gradient given the true box; three other rules for the box were measured and
were worse elsewhere (``docs/auto.md``). When the levels are known (an image normalised by a
calibration frame), pass ``bounds``.

**The Gaussian prior** (``gauss=True``, the default, where it applies: a
:class:`~torchtof.operators.Hadamard` operator, ``n ≥ 32``, ``M ≤ 1024``, the tail split).
On textured grey images at low SR (coins at 6.25–12.5 %) no TV/TGV candidate is the best
model: a smooth Gaussian prior completes the unmeasured rows better (the tuned Tikhonov and
DCT peers beat the TV choice there by up to 1.5 dB, ``docs/peers.md``). The prior is the
separable exponential (first-order Markov) covariance, the classical model of image
correlation (Jain, *Fundamentals of Digital Image Processing*, 1989),
``Cov(x_{ij}, x_{i'j'}) ∝ exp(−|i − i'|/ℓ) exp(−|j − j'|/ℓ)``, i.e. ``Σ = S ⊗ S``, around a
constant mean ``m``; the estimate is its posterior mean under white noise (the Bayesian
linear model, Kay 1993, *Estimation Theory*, Thm. 10.3; the Tikhonov/Wiener solution),

.. math::
    \\hat x = \\hat m + Σ Aᵀ α, \\qquad (A Σ Aᵀ + γ \\bar λ I)\\, α = y - \\hat m\\, A\\mathbf 1,

with ``m̂`` the least-squares constant of the buckets (the image mean, from the all-ones row)
and ``λ̄`` the mean eigenvalue of ``K = A Σ Aᵀ`` (so that ``γ`` is a noise-to-signal ratio
that does not depend on ``n`` or ``M``). For Sylvester Hadamard rows ``K`` separates,
``K[(a, b), (a', b')] = T[a, a'] T[b, b']`` with ``T = Ĥ S Ĥᵀ`` (:func:`gauss_covariance`),
and a fold's held-out predictions ``A x̂ = m̂ A1 + K[:, t] α`` need no image: one
eigendecomposition of ``K[t, t]`` per ``(ℓ, fold)`` gives every ``γ``. The ``5 × 12``
candidates ``ℓ ∈`` :data:`GAUSS_ELLS`, ``γ ∈`` :data:`GAUSS_GAMMAS` are scored on the same
tail folds as the TV/TGV choice (after the inferred box), with the same relative score over
the choice and them; where the best of them predicts the held-out rows of **every** fold
better than the choice (a win in each fold, not only in the sum: with three folds of a few
rows the summed score is noisy, and a 3 % lower sum let it replace TGV² on the smooth ``moon``
image at n = 32, SR 6.25 % with a 2.4 dB loss), its posterior mean from all rows
replaces the choice (``choice["prior"] == "gauss"``, with ``ell`` and ``gamma``; projected
onto the caller's ``bounds``; ``n_iter`` 0, ``stop_reason`` ``"tol"``: a direct solve). It
competes with the one chosen candidate, not with each TV/TGV candidate, so the TV/TGV choice
itself is unchanged; the box-only solution is never replaced. Measured (``docs/auto.md``):
on coins at n = 32, sequency rows, 1 % noise, it took 6.25 % from 17.66 to 18.44 dB and
12.5 % from 20.38 to 20.84 dB; binary and piecewise-planar scenes kept their TV/TGV choice.
Its cost is ``O(M³)``: at ``M ≤ 1024`` a few per cent of the TV/TGV stages at n = 32 and up
to a third at n = 64 (``docs/auto.md``).

**Stacking with the learned network** (``learned=True``, the default, where it applies:
a :class:`~torchtof.operators.Hadamard` operator, ``n ≥ 32``, the tail split). The shipped
learned reconstructor (:func:`~torchtof.recon.learned`, a network trained on procedural
scenes) is better than every TV/TGV candidate on some images and worse on others, and
cross-validation scoring it as one more candidate rarely saw where (its fold score was
3–5× the best TV candidate's on images where it was 2.5–5.7 dB better: ``docs/auto.md``).
So it is not chosen *instead* of the TV/TGV choice but combined *with* it (stacked
generalisation, Wolpert 1992, Neural Networks 5; Breiman 1996, Machine Learning 24): the
chosen candidate and the network are both fitted on each tail fold (the network on the
first ``k`` rows of the same order, a plain ``Hadamard(n, m=k)``), and the network's
weight in the convex combination of the two is the least-squares weight of their held-out
predictions, in closed form and clipped to ``[0, 1]``: the smaller of that of the fold
trained on the most rows and that of all folds with each fold's rows divided by the
choice's error there (:func:`stack_weight`; a plainly pooled weight follows the fold with
the fewest rows and was measured to cost 6 dB on the paper's character at n = 64, SR
37.5 %, where the TV choice with the inferred box is almost exact from all rows). The
result is ``(1 − w) x̂ + w x̂_learned`` of the two full-row reconstructions (projected onto
the caller's ``bounds`` if given: the image obeys them); ``choice["learned_weight"]`` is
``w`` (``0``: the TV/TGV choice alone; ``None``: not stacked). The box-only solution is
never stacked. ``learned=PATH`` stacks another weights file's network the same way (e.g.
one trained with ``torchtof train`` on the caller's own scenes). The rule was chosen among
seven on the peers benchmark's cells and checked on the cells of
``benchmarks/auto_eval.py``, which it was not chosen on (``docs/auto.md``).

Cost (defaults: tail split, 3 folds, ``cv_iter=100``): stage 1 is one batched solve per
(prior, norm, bounds) group — 8 calls (12 with a box) of 3 folds × 7 weights = 21 channels ×
100 iterations; stage 2 one call of 6 channels for the chosen group; with a finite box two
projected-gradient solves of ``BOX_ITER = 100`` steps (``A`` and ``Aᵀ`` only); then one
refit. That is 17,400 (25,800 with a box; 20,100 and a second refit for a two-level image
whose box is inferred) single-channel iterations (TVAL3 or TGV primal-dual, each one ``A``,
one ``Aᵀ`` and a few differences) besides the refit; stacking adds 300 (the choice on the
3 folds) and four passes of the learned network (3 folds and all rows; each 6 steps of one
``A``, one ``Aᵀ`` and a small CNN); the Gaussian prior (where it applies) 15 symmetric
eigendecompositions of at most ``M × M`` (5 lengths × 3 folds; the 300 iterations of the
choice on the folds are shared with the stacking) and one ``M × M`` solve where it wins;
bounded and independent of the data (3/4 of the same
candidates on 4 eighth-folds; a random split also has 3 folds); the measured time against
one default TVAL3 solve is in ``docs/auto.md``.
"""

from __future__ import annotations

import inspect
import math
import os
import warnings
from pathlib import Path
from typing import NamedTuple

import torch
from torch import nn

from .._checks import check_bool, check_int, check_positive, run_loop
from ..operators.base import LinearOperator
from ..operators.hadamard import Hadamard
from . import learned as _learned_mod
from .base import pow2_scale, relative_residual
from .gauss import markov_covariance
from .learned import learned as learned_recon
from .tgv import TGV_STOP_REASONS, tgv
from .tv import box_bounds, bucket_spread, largest_eig_normal, project_box, split_tv
from .tval3 import (
    STOP_REASONS,
    MaskedRows,
    bucket_noise_sigma,
    check_buckets,
    default_split,
    holdout_split,
    tval3,
)

__all__ = [
    "auto", "Auto", "AutoResult", "AUTO_WEIGHTS", "AUTO_PRIORS", "AUTO_TVS", "AUTO_BOUNDARIES",
    "candidates", "cv_folds", "stackable", "stack_predictions", "stack_weight",
    "LEARNED_MIN_N", "GAUSS_ELLS", "GAUSS_GAMMAS", "GAUSS_MIN_N", "GAUSS_MAX_M", "gauss_applies",
    "gauss_covariance", "gauss_cv", "gauss_fit", "choice_predictions",
]

#: First-stage TV-L2 weights (on the buckets scaled as TVAL3's ``Scaleb``), a factor 4 apart;
#: ``inf``: the published equality-constrained model with ``μ = 2⁸``.
AUTO_WEIGHTS = (float("inf"), 2.0**12, 2.0**10, 2.0**8, 2.0**6, 2.0**4, 2.0**2)
#: Second stage: the first stage's TV-L2 choice is compared with ``μ·REFINE`` and ``μ/REFINE``.
REFINE = 2.0
#: Priors tried: first-order TV (:func:`~torchtof.recon.tval3.tval3`) and second-order TGV²
#: (:func:`~torchtof.recon.tgv.tgv`, piecewise-affine images such as depth maps of planes).
AUTO_PRIORS = ("tv", "tgv")
#: Norms (of both TGV terms) and boundary conditions tried with each prior.
AUTO_TVS = ("isotropic", "anisotropic")
AUTO_BOUNDARIES = ("neumann",)
#: Discrepancy bound: a candidate whose misfit of its own training rows exceeds
#: ``FIT_TAU2 · (training rows) · σ̂²`` (``σ̂``: :func:`~torchtof.recon.tval3.bucket_noise_sigma`)
#: under-fits and is dropped, unless every candidate does.
FIT_TAU2 = 1.0
#: Iterations of the box-only candidate (projected gradient, only with a finite box).
BOX_ITER = 100
#: The box alone is taken to determine the image when two box-only solves from starts that
#: differ in the null space of ``A`` agree to this fraction of the box width (RMS).
BOX_UNIQUE = 0.01
#: Default ``folds`` per split: ``"tail"`` 5 (blocks of one eighth of the rows, each trained on
#: all rows before it), of which the latest :data:`TAIL_USE` are used; ``"random"`` 3.
TAIL_FOLDS = 5
#: Tail folds used by default: the 3 trained on the most rows (7/8, 3/4 and 5/8 of them).
TAIL_USE = 3
RANDOM_FOLDS = 3
#: The inferred box (no ``bounds`` given): a refit is two-level when at least this fraction
#: of its pixels lies within ``TWO_LEVEL_TOL`` of its level gap of one of its two levels.
TWO_LEVEL = 0.5
TWO_LEVEL_TOL = 0.05
#: Smallest ``n`` at which the learned network is stacked (the sizes it was trained and
#: evaluated on: 32–256).
LEARNED_MIN_N = 32
#: The Gaussian prior (module doc): correlation lengths ``ℓ`` (pixels) and weights ``γ``
#: relative to the mean eigenvalue of the prior covariance in the measurements, ``4^{-1…-12}``.
GAUSS_ELLS = (1.0, 2.0, 4.0, 8.0, 16.0)
GAUSS_GAMMAS = tuple(4.0**-j for j in range(1, 13))
#: It is tried for Hadamard rows at ``n ≥ GAUSS_MIN_N`` and ``M ≤ GAUSS_MAX_M`` (its cost
#: grows as ``M³``; it won only at low SR, ``docs/auto.md``).
GAUSS_MIN_N = 32
GAUSS_MAX_M = 1024
_CONSTRAINED_MU = 2.0**8
#: The TGV fits run this many pixels (rows × columns × image) per call at most on the CPU:
#: their primal-dual state then stays in the caches (1.3–1.5× faster at n = 64 and 128 than
#: the 21 columns of a fold at once).
_TGV_CHUNK_PIXELS = 1 << 15
#: Solvers of the TV-L2 candidates (:func:`auto`'s ``tv_solver``).
TV_SOLVERS = ("tval3", "split")
_INF = float("inf")


class AutoResult(NamedTuple):
    """Output of :func:`auto`.

    Attributes:
        x: reconstruction ``(B, C, n, n)`` (the refit of the chosen candidate).
        n_iter: refit iterations per sample ``(B, C)``.
        residual: ``‖A x − y‖ / ‖y‖`` per sample ``(B, C)``.
        converged: ``(B, C)`` bool.
        stop_reason: names ``[b][c]`` (see :data:`~torchtof.recon.tval3.STOP_REASONS`).
        choice: the chosen candidate per sample ``[b][c]``, a dict ``prior`` (``"tv"``,
            ``"tgv"``, ``"box"``: the box-only candidate, or ``"gauss"``: the Gaussian prior,
            with its ``ell`` and ``gamma``), ``tv`` (the norm; ``None`` for the box-only and
            Gaussian choices), ``boundary``, ``bounds``, ``mu`` (``None``: the
            constrained model or the box-only candidate), ``cv``, ``score``, ``inferred``
            (``True``: chosen again with the inferred box ``bounds``; ``cv`` and ``score``
            are then that choice's, while ``cv_error``, ``score`` and the other fields below
            remain those of the candidates without the box).
        cv_error: ``(B, C, len(candidates))`` cross-validation error of every candidate, in
            the squared units of ``y``; ``nan`` for a second-stage weight that was not fitted
            for that sample (only the neighbours of its first-stage choice are). In squared
            units these errors (and ``fit_error``, ``fit_bound``) overflow to ``inf`` or
            underflow to 0 for float32 buckets beyond about ``1e±19``; the choice itself is
            made on ``score``, which is scale-free and finite at every scale.
        candidates: the candidate list, as dicts (same order as ``cv_error``).
        fit_error: ``(B, C, len(candidates))`` each candidate's misfit of its own training
            rows, summed over the folds (``nan`` where not fitted).
        fit_bound: ``(B, C)`` the discrepancy bound on ``fit_error``; candidates above it
            are not chosen unless all are (module doc).
        score: ``(B, C, len(candidates))`` the score the choice minimises: each fold's
            held-out error over that fold's smallest, summed over the folds (``inf`` where
            not fitted or dropped by the bound).
        cv_fold: ``(B, C, F, len(candidates))`` the held-out error of every fold (``cv_error``
            is its sum over the ``F`` folds).
    """

    x: torch.Tensor
    n_iter: torch.Tensor
    residual: torch.Tensor
    converged: torch.Tensor
    stop_reason: tuple
    choice: tuple
    cv_error: torch.Tensor
    candidates: tuple
    fit_error: torch.Tensor | None = None
    fit_bound: torch.Tensor | None = None
    score: torch.Tensor | None = None
    cv_fold: torch.Tensor | None = None


def _finite_box(bounds) -> bool:
    return bounds is not None and bounds[0] is not None and bounds[1] is not None


def _boxes(bounds) -> list:
    """The bound groups: none, ``x ≥ 0`` and the caller's box unless it is one of those two
    (``(0, None)`` or ``(None, None)`` would fit the same candidates twice)."""
    out = [None, (0.0, None)]
    if bounds is not None:
        lo, hi = (None if v is None else float(v) for v in bounds)
        if (lo, hi) not in ((None, None), (0.0, None)):
            out.append((lo, hi))
    return out


def _groups(bounds, priors=AUTO_PRIORS) -> list:
    return [(pr, tv, bd, box) for pr in priors for tv in AUTO_TVS for bd in AUTO_BOUNDARIES
            for box in _boxes(bounds)]


def _fit(group: tuple, y: torch.Tensor, A: LinearOperator, mu, tvl2, max_iter: int,
         solver: str = "tval3", l2_iter: int | None = None):
    """One batched solve of a candidate group ``(prior, tv, boundary, bounds)``: ``(x, n_iter,
    converged, stop code in STOP_REASONS)``; ``mu`` per sample (constrained: ignored).
    ``max_iter`` is the budget of the constrained columns and, unless ``l2_iter`` is given, of
    the TV-L2 ones too. ``solver="split"``: the TV-L2 candidates of the TV prior on an
    operator with orthonormal rows are solved by :func:`~torchtof.recon.tv.split_tv`
    (:func:`_split_fit`). Where the columns need different solvers or budgets, the
    constrained and the TV-L2 columns are solved apart."""
    prior = group[0]
    l2_iter = max_iter if l2_iter is None else l2_iter
    use_split = solver == "split" and prior == "tv" and A.orthonormal_rows
    if isinstance(tvl2, torch.Tensor) and (use_split or l2_iter != max_iter):
        r_, k_ = y.shape[0], y.shape[1]
        mu_t = torch.as_tensor(mu, dtype=y.dtype, device=y.device).expand(r_, k_)
        l2 = torch.as_tensor(tvl2, device=y.device).expand(r_, k_)[0].tolist()
        x = y.new_zeros(r_, k_, A.n, A.n)
        n_iter = torch.zeros(r_, k_, dtype=torch.int64, device=y.device)
        conv = torch.zeros(r_, k_, dtype=torch.bool, device=y.device)
        codes = torch.zeros(r_, k_, dtype=torch.int64, device=y.device)
        for flag, iters in ((False, max_iter), (True, l2_iter)):
            cols = [j for j, v in enumerate(l2) if bool(v) == flag]
            if cols:
                out = _fit1(group, y[:, cols], _columns(A, cols), mu_t[:, cols], flag, iters,
                            use_split)
                x[:, cols], n_iter[:, cols], conv[:, cols], codes[:, cols] = out
        return x, n_iter, conv, codes
    return _fit1(group, y, A, mu, tvl2, l2_iter if tvl2 is True else max_iter, use_split)


def _columns(A: LinearOperator, cols) -> LinearOperator:
    """``A`` for the columns ``cols`` (a list or a slice) of a batch: a :class:`MaskedRows`
    keeps their row masks."""
    return MaskedRows(A.inner, A.mask[cols]) if isinstance(A, MaskedRows) else A


def _fit1(group: tuple, y: torch.Tensor, A: LinearOperator, mu, tvl2, max_iter: int,
          use_split: bool):
    """:func:`_fit` with one solver and one budget for every column."""
    prior, tv, bd, box = group
    if prior == "tgv":
        return _tgv_fit(group, y, A, mu, tvl2, max_iter)
    if use_split and tvl2 is True:
        return _split_fit(group, y, A, mu, max_iter)
    r = tval3(y, A, mu=mu, tvl2=tvl2, max_iter=max_iter, tv=tv, boundary=bd, bounds=box,
              return_result=True)
    return r.x, r.n_iter, r.converged, r.stop_code


def _tgv_fit(group: tuple, y: torch.Tensor, A: LinearOperator, mu, tvl2, max_iter: int):
    """The TGV fits of :func:`_fit1`, at most :data:`_TGV_CHUNK_PIXELS` pixels per call on the
    CPU: the columns are independent solves, so a few at a time run the same iterates, bit
    for bit, with their state in the caches."""
    _, tv, bd, box = group
    to = torch.tensor([STOP_REASONS.index(k) for k in TGV_STOP_REASONS], device=y.device)

    def solve(y, A, mu, tvl2):
        r = tgv(y, A, mu=mu, tvl2=tvl2, max_iter=max_iter, tv=tv, boundary=bd, bounds=box,
                return_result=True)
        return r.x, r.n_iter, r.converged, to[r.stop_code]

    r_, k_ = y.shape[0], y.shape[1]
    step = max(1, _TGV_CHUNK_PIXELS // max(1, r_ * A.n * A.n))
    if y.device.type != "cpu" or k_ <= step:
        return solve(y, A, mu, tvl2)

    def cols_of(v, cols):
        return torch.broadcast_to(v, (r_, k_))[:, cols] if isinstance(v, torch.Tensor) else v

    outs = [solve(y[:, c], _columns(A, c), cols_of(mu, c), cols_of(tvl2, c))
            for c in (slice(j, j + step) for j in range(0, k_, step))]
    return tuple(torch.cat(t, dim=1) for t in zip(*outs))


def _split_fit(group: tuple, y: torch.Tensor, A: LinearOperator, mu, max_iter: int):
    """The TV-L2 fits of :func:`_fit` by :func:`~torchtof.recon.tv.split_tv`. ``μ`` weighs
    the buckets scaled to spread 1.5 as in TVAL3 (``Scaleb``), so the split solve minimises
    TVAL3's TV-L2 objective: ``TV(x) + (μ g/2)‖Ax − y‖²``, ``g = 1.5/spread``. The split
    solve runs its fixed budget: ``n_iter = max_iter``, ``converged`` false, stop reason
    ``"max_iter"``."""
    _, tv, bd, box = group
    r_, k_ = y.shape[0], y.shape[1]
    mu_t = torch.as_tensor(mu, dtype=y.dtype, device=y.device).expand(r_, k_)
    spread = bucket_spread(y)
    gain = 1.5 / torch.where(spread > 0, spread, torch.ones_like(spread))  # y = 0: x = 0
    lo, hi = box if box is not None else (None, None)
    x = split_tv(y, A, mu_t * gain, tv=tv, boundary=bd, bounds=(lo, hi), max_iter=max_iter)
    n_iter = torch.full((r_, k_), max_iter, dtype=torch.int64, device=y.device)
    conv = torch.zeros(r_, k_, dtype=torch.bool, device=y.device)
    codes = torch.full((r_, k_), STOP_REASONS.index("max_iter"), dtype=torch.int64,
                       device=y.device)
    return x, n_iter, conv, codes


def _fine(w: float) -> tuple:
    return () if w == _INF else (w * REFINE, w / REFINE)


def candidates(bounds: tuple | None = None, priors: tuple = AUTO_PRIORS) -> tuple[dict, ...]:
    """The candidate list of :func:`auto`: dicts ``prior`` (``"tv"``, ``"tgv"``; ``"box"``
    for the box-only candidate), ``tv`` (the norm), ``boundary``, ``bounds``, ``mu``
    (``None``: the constrained model with ``μ = 2⁸``) and ``stage`` (1: fitted for every
    sample; 2: a factor-``REFINE`` neighbour of a first-stage weight, fitted only around a
    sample's first-stage choice), for each prior in ``priors``. Given a finite box, one more
    candidate ``prior="box"``: least
    squares on the box alone, no TV (projected gradient); it is not cross-validated (its
    ``cv_error`` is ``nan``) but chosen when the box alone determines the image (module doc)."""
    out = []
    for pr, tv, bd, box in _groups(bounds, priors):
        for mu in AUTO_WEIGHTS:
            out.append(dict(prior=pr, tv=tv, boundary=bd, bounds=box,
                            mu=None if mu == _INF else mu, stage=1))
        fine = sorted({f for w in AUTO_WEIGHTS for f in _fine(w)} - set(AUTO_WEIGHTS),
                      reverse=True)
        for mu in fine:
            out.append(dict(prior=pr, tv=tv, boundary=bd, bounds=box, mu=mu, stage=2))
    if _finite_box(bounds):
        out.append(dict(prior="box", tv=None, boundary=None, bounds=tuple(bounds), mu=None,
                        stage=1))
    return tuple(out)


def _check_folds(fn: str, folds: int | None, A: LinearOperator) -> None:
    """At most ``M`` folds: each holds out at least one row and trains on at least one
    (more made the tail folds wrap around to the first rows, the random ones empty)."""
    if folds is not None and folds > A.m:
        raise ValueError(f"{fn}: expected folds <= M = {A.m} (one held-out row per fold at "
                         f"least), got {folds}")


def _check(fn, folds, cv_iter, max_iter, bounds, split, slack, priors=AUTO_PRIORS,
           infer_box=True, learned=True, gauss=True, tv_solver="tval3", fit_iter=None, seed=0):
    check_int(seed, "seed", fn, 0, 2**64 - 1)  # a torch.Generator seed
    if tv_solver not in TV_SOLVERS:
        raise ValueError(f"{fn}: expected tv_solver in {TV_SOLVERS}, got {tv_solver!r}")
    for name, v in (("infer_box", infer_box), ("gauss", gauss)):
        if not isinstance(v, bool):
            raise TypeError(f"{fn}: expected {name} to be a bool, got {type(v).__name__}")
    if not isinstance(learned, (bool, str, os.PathLike)):
        raise TypeError(f"{fn}: expected learned to be a bool or a weights file path, got "
                        f"{type(learned).__name__}")
    if not isinstance(learned, bool):  # read now: a wrong file fails before any fit
        if not Path(learned).is_file():
            raise ValueError(f"{fn}: expected learned to be a bool or an existing weights "
                             f"file (Learned.save_weights, torchtof train), got "
                             f"{os.fspath(learned)!r}")
        try:
            _learned_mod.check_weights_file(learned, fn)
        except ValueError as exc:
            raise ValueError(f"{fn}: expected learned to be a learned weights file: "
                             f"{str(exc).partition(': ')[2]}") from None
    if (not isinstance(priors, (tuple, list)) or not priors
            or any(p not in AUTO_PRIORS for p in priors) or len(set(priors)) != len(priors)):
        raise ValueError(f"{fn}: expected priors a non-empty tuple of distinct names from "
                         f"{AUTO_PRIORS}, got {priors!r}")
    for name, v, lo in (("folds", folds, 2), ("cv_iter", cv_iter, 1), ("max_iter", max_iter, 1),
                        ("fit_iter", fit_iter, 1)):
        if v is None and name in ("folds", "fit_iter"):
            continue
        if isinstance(v, bool) or not isinstance(v, int):
            raise TypeError(f"{fn}: expected {name} to be an int, got {type(v).__name__}")
        if v < lo:
            raise ValueError(f"{fn}: expected {name} >= {lo}, got {v}")
    box_bounds(False, bounds, fn)
    if split not in (None, "random", "tail"):
        raise ValueError(f"{fn}: expected split in (None, 'random', 'tail'), got {split!r}")
    check_positive(slack, "slack", fn, strict=False)


def _box_ls(y: torch.Tensor, A: LinearOperator, lo: float, hi: float, iters: int,
            lip: float, x0: torch.Tensor | None = None) -> torch.Tensor:
    """``argmin ½‖Ax − y‖²`` over the box ``lo ≤ x ≤ hi`` by FISTA with projection (Beck &
    Teboulle 2009, SIAM J. Imaging Sci. 2, Eq. 4.1–4.3; step ``1/L``, ``L = λ_max(AᵀA)``),
    ``iters`` steps from ``x0`` (default: the box's centre). ``y (B, C, M)`` ->
    ``x (B, C, n, n)``."""
    x = y.new_full((*y.shape[:2], A.n, A.n), 0.5 * (float(lo) + float(hi))) if x0 is None else x0
    z, t = x, 1.0
    fwd, adj = A.loop_pair(y)
    for _ in range(iters):
        xn = project_box(z - adj(fwd(z) - y) / lip, float(lo), float(hi))
        tn = 0.5 * (1.0 + math.sqrt(1.0 + 4.0 * t * t))
        z = xn + ((t - 1.0) / tn) * (xn - x)
        x, t = xn, tn
    return x


def _box_alone(ys: torch.Tensor, A: LinearOperator, lo: float, hi: float, lip: float,
               seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Box-only least squares from two starts that differ only in the null space of ``A``:
    ``c ± r``, ``c`` the box's centre, ``r = P_null(s)`` scaled to ``max|r| = (hi − lo)/2``,
    ``s`` a seeded ±1 pattern. ``ys (R, 1, M)`` -> (their mean ``(R, 1, n, n)``, ``(R,)`` bool:
    the two agree to :data:`BOX_UNIQUE` of the box width, RMS)."""
    g = torch.Generator().manual_seed(int(seed))
    s = (torch.randint(0, 2, (1, 1, A.n, A.n), generator=g) * 2 - 1).to(ys.dtype).to(ys.device)
    r = s - A.pinv(A(s))  # the part of s that no measurement sees
    r = r * (0.5 * (hi - lo) / r.abs().amax().clamp_min(torch.finfo(ys.dtype).tiny))
    x0 = torch.cat([0.5 * (lo + hi) + r, 0.5 * (lo + hi) - r], dim=1).expand(ys.shape[0], -1, -1,
                                                                             -1)
    xs = _box_ls(ys.expand(-1, 2, -1), A, lo, hi, BOX_ITER, lip, x0)
    gap = _rms_gap(xs[:, 0] - xs[:, 1], hi - lo, (-2, -1))
    return xs.mean(dim=1, keepdim=True), gap <= BOX_UNIQUE


def _group_of(cand: dict) -> tuple:
    return cand["prior"], cand["tv"], cand["boundary"], cand["bounds"]


def _key(cand: dict) -> tuple:
    return (*_group_of(cand), cand["mu"])


def _rank(cands: tuple, like: torch.Tensor) -> torch.Tensor:
    """Least-regularised first: the weight, ``inf`` for the constrained and box-only models."""
    return torch.tensor([_INF if c["mu"] is None else c["mu"] for c in cands], dtype=like.dtype,
                        device=like.device)


def _score(cv: torch.Tensor, fit: torch.Tensor, fit_max: torch.Tensor) -> torch.Tensor:
    """The cross-validation score of every candidate: ``cv (R, F, K)`` held-out errors per fold
    (``nan`` where not fitted) -> ``(R, K)``: each fold's error divided by that fold's smallest
    over the fitted candidates, summed over the folds (module doc); ``inf`` where not fitted
    and, in every row where some candidate meets the discrepancy bound ``fit ≤ fit_max``
    (``fit (R, K)``), for the candidates that do not."""
    tiny = torch.finfo(cv.dtype).tiny
    best = torch.nan_to_num(cv, nan=_INF).amin(dim=-1, keepdim=True).clamp_min(tiny)
    rel = (cv / best).sum(dim=1)  # nan where not fitted
    ok = fit <= fit_max  # nan (not fitted) compares False
    drop = ok.any(dim=1, keepdim=True) & ~ok
    return torch.where(drop | rel.isnan(), torch.full_like(rel, _INF), rel)


def _pick(cv: torch.Tensor, rank: torch.Tensor, slack: float) -> torch.Tensor:
    """Per row of ``cv (R, K)`` (``inf`` where not fitted): the least regularised candidate
    whose CV error is within ``1 + slack`` of the row's smallest, ties to the smallest CV."""
    ok = cv <= (1 + slack) * cv.amin(dim=1, keepdim=True)
    r = rank.expand_as(cv)
    top = torch.where(ok, r, torch.full_like(r, -1.0)).amax(dim=1, keepdim=True)
    return torch.where(ok & (r == top), cv, torch.full_like(cv, _INF)).argmin(1)


#: The options every stage of :func:`auto` reads (its ``opts`` dict).
STAGE_OPTIONS = ("folds", "cv_iter", "max_iter", "split", "slack", "seed", "priors",
                 "tv_solver", "fit_iter")


def auto_options(**given) -> dict:
    """The ``opts`` dict of :func:`auto`'s stages at :func:`auto`'s defaults, updated by
    ``given`` (for studies that run one stage alone, e.g. ``benchmarks/auto_stack_rules.py``:
    the keys follow :func:`auto`'s signature, so a new option cannot be left out)."""
    sig = inspect.signature(auto).parameters
    unknown = set(given) - set(STAGE_OPTIONS)
    if unknown:
        raise ValueError(f"auto_options: expected options among {STAGE_OPTIONS}, got "
                         f"{sorted(unknown)}")
    out = {k: sig[k].default for k in STAGE_OPTIONS}
    out.update(given)
    out["priors"] = tuple(out["priors"])
    return out


def auto(
    y: torch.Tensor,
    A: LinearOperator,
    bounds: tuple[float | None, float | None] | None = None,
    folds: int | None = None,
    cv_iter: int = 100,
    max_iter: int = 1025,
    *,
    split: str | None = None,
    slack: float = 0.0,
    seed: int = 0,
    priors: tuple[str, ...] = AUTO_PRIORS,
    infer_box: bool = True,
    gauss: bool = True,
    learned: bool | str | os.PathLike = True,
    tv_solver: str = "tval3",
    fit_iter: int | None = None,
    return_result: bool = False,
) -> torch.Tensor | AutoResult:
    """TV or TGV² reconstruction with prior, bounds and weight chosen by cross-validation (module
    doc).

    Choice: the candidate with the smallest score (each fold's held-out error over that
    fold's smallest, summed over the folds); with ``slack > 0`` the least
    regularised one (largest ``μ``; the constrained and the box-only models count as
    ``μ = ∞``) whose score is within ``1 + slack`` of the smallest (CV with fewer
    training rows tends to over-regularise, Shao 1993, JASA 88; measured in
    ``docs/auto.md``, ``slack = 0`` is the default). Candidates that break the discrepancy
    bound are dropped first, and the box-only model overrides the choice when the box alone
    determines the image (module doc). The refit runs a chosen TV-L2 model to
    convergence (``max_iter``) and the constrained model with the ``cv_iter`` budget that
    was validated (its iteration count is its regulariser: run longer, it fits more noise);
    the box-only solution is the test's own (``BOX_ITER`` steps, ``stop_reason``
    ``"max_iter"``).

    Args:
        y: buckets ``(B, C, M)``, ``M = A.m``, float32/float64; every sample chooses alone.
            The choice does not depend on the scale of ``y``: the squared errors it compares
            are those of the sample's buckets times an exact power of two (1 at ordinary
            scales), so that they neither overflow nor underflow at any scale the dtype holds.
        A: the operator (any :class:`~torchtof.operators.LinearOperator`).
        bounds: a box ``(lo, hi)`` the caller knows (units of ``x``; e.g. ``(0, 1)`` for an
            image normalised by a calibration frame, ``(0, c/2f)`` for a depth image): added
            as a bound beside none and ``x ≥ 0``; a finite box also adds the box-only
            candidate (module doc).
        folds: ``K ≥ 2`` or ``None``. ``split="random"``: ``K`` folds of a random partition
            (``None``: :data:`RANDOM_FOLDS` = 3). ``split="tail"``: ``K − 1`` folds, fold
            ``j`` holding out the block of ``M/(2(K−1))`` rows ending ``j`` blocks before
            the last row, trained on the rows before it (``None``: ``K = 5``, eighths, of
            which the latest :data:`TAIL_USE` = 3, trained on 7/8, 3/4 and 5/8 of the rows).
        cv_iter: iteration budget of every cross-validation solve (unless ``fit_iter``)
            and of the constrained model's refit.
        max_iter: iteration budget of a TV-L2 refit.
        split: ``"random"``, ``"tail"`` or ``None`` (:func:`default_split`: ``"tail"`` for
            Hadamard rows in a low-to-high order, where the unmeasured rows that the
            reconstruction must predict follow the measured ones).
        slack: relative CV tolerance of the choice (``≥ 0``).
        seed: seed of the random fold assignment, an int ``≥ 0`` (deterministic by default).
        priors: the priors tried, a subset of :data:`AUTO_PRIORS` (``("tv", "tgv")``):
            ``("tv",)`` halves the cost where no piecewise-affine image is expected,
            ``("tgv",)`` for depth maps of planes.
        infer_box: without ``bounds``, choose again with the box of the image's two levels
            when the refit is two-level (module doc, "The inferred box").
        gauss: let the Gaussian-prior posterior mean replace the TV/TGV choice where it
            predicts every fold's held-out rows better, where it applies
            (:func:`gauss_applies`: a Hadamard operator, ``n ≥ 32``, ``M ≤ 1024``, the tail
            split; module doc, "The Gaussian prior"); ``choice["prior"]`` is then ``"gauss"``
            with its ``ell`` and ``gamma``.
        learned: stack the shipped learned network (:func:`~torchtof.recon.learned`) with the
            choice, weighted by cross-validation, where it applies (:func:`stackable`: a
            Hadamard operator, ``n ≥ 32``, the tail split; module doc, "Stacking");
            ``choice["learned_weight"]`` is the weight (``None`` where not stacked). A path
            stacks the network of that weights file instead (one written by
            :meth:`~torchtof.recon.learned.Learned.save_weights` or ``torchtof train``, e.g.
            trained on the caller's own scenes); ``False`` does not stack.
        tv_solver: ``"tval3"`` (every TV fit by TVAL3) or ``"split"`` (the TV-L2 fits of
            the TV prior by :func:`~torchtof.recon.tv.split_tv` where ``A`` has orthonormal
            rows, else by TVAL3); module doc, "The TV-L2 solver". A split refit runs its fixed
            budget: its ``n_iter`` is the budget, ``converged`` is false and ``stop_reason``
            ``"max_iter"``.
        fit_iter: iteration budget of the TV-L2 (and TGV-L2) cross-validation fits
            (``None``: ``cv_iter``); the constrained fits and their refit keep ``cv_iter``
            (module doc, "The fits' budget").
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
    check_bool(return_result, "return_result", fn)
    _check(fn, folds, cv_iter, max_iter, bounds, split, slack, priors, infer_box, learned,
           gauss, tv_solver, fit_iter, seed)
    _check_folds(fn, folds, A)
    opts = auto_options(folds=folds, cv_iter=cv_iter, max_iter=max_iter, split=split,
                        slack=slack, seed=seed, priors=priors, tv_solver=tv_solver,
                        fit_iter=fit_iter)
    # no graph to build: the same bits, less overhead (the stages check their operator calls)
    res = run_loop(_auto_stages, y, A, bounds, infer_box, gauss, learned, opts, inputs=(y,),
                   module=A, checks=True)
    return res if return_result else res.x


def _auto_stages(y: torch.Tensor, A: LinearOperator, bounds, infer_box: bool, gauss: bool,
                 learned, opts: dict) -> AutoResult:
    """The stages of :func:`auto` for validated inputs."""
    fn, split = "auto", opts["split"]
    res, errs = _auto(y, A, bounds, **opts)
    nonempty = y.shape[0] * y.shape[1] > 0
    if bounds is None and infer_box and nonempty:
        res = _with_inferred_box(res, errs, y, A, opts)
    pa = None
    if gauss and gauss_applies(A, split) and nonempty:
        res, pa = _with_gauss(res, y, A, bounds, opts)
    if learned is not False and stackable(A, split) and nonempty:
        weights = _learned_mod.WEIGHTS_FILE if learned is True else Path(learned)
        if weights.is_file():
            res = _with_learned(res, y, A, bounds, opts, pa, weights)
        else:
            warnings.warn(f"{fn}: the learned network's weights "
                          f"({weights}) are missing: returning the TV/TGV "
                          "choice without stacking (learned=False does so silently)",
                          stacklevel=3)
    return res


def _auto(y, A, bounds, folds, cv_iter, max_iter, split, slack, seed, priors, tv_solver,
          fit_iter, known=None) -> tuple[AutoResult, tuple[torch.Tensor, torch.Tensor]]:
    """The choice of :func:`auto` for validated inputs: the result and the held-out and fit
    errors ``(cv (BC, F, K), fit (BC, K))`` in the units of :func:`_unit` (for a call with
    ``known``). ``known``: ``(result, cv, fit)`` of an earlier call on the same ``y (1, 1, M)``
    without ``bounds``; its stage-1 errors and its refit are reused where this call's
    candidates and choice coincide with it, and the box-only test is not run (the inferred
    box, module doc)."""
    split = default_split(A) if split is None else split
    b, c, m = y.shape
    cands = candidates(bounds, priors)
    if b * c == 0:
        x = y.new_zeros(b, c, A.n, A.n)
        res = AutoResult(x, torch.zeros(b, c, dtype=torch.int64, device=y.device),
                         y.new_zeros(b, c), torch.ones(b, c, dtype=torch.bool, device=y.device),
                         (), (), y.new_zeros(b, c, len(cands)), cands,
                         y.new_zeros(b, c, len(cands)), y.new_zeros(b, c),
                         y.new_zeros(b, c, len(cands)), y.new_zeros(b, c, 0, len(cands)))
        return res, (y.new_zeros(0, 0, len(cands)), y.new_zeros(0, len(cands)))
    bc = b * c
    ys = y.reshape(bc, 1, m)
    unit = _unit(ys)  # (BC, 1, 1): the errors below are computed on (A x - y)·unit
    index = {_key(k): i for i, k in enumerate(cands)}
    held, train = cv_folds(A, y, folds, seed, split)  # (F, M), latest fold first
    nf = held.shape[0]
    hm, tm = held.to(y.dtype), train.to(y.dtype)
    cv_err = y.new_full((bc, nf, len(cands)), float("nan"))  # per fold
    fit_err = y.new_full((bc, len(cands)), float("nan"))
    # the discrepancy bound on a candidate's misfit of its own training rows (module doc)
    sig = bucket_noise_sigma(y).reshape(bc, 1) * unit[:, 0]
    fit_max = FIT_TAU2 * float(train.sum()) * sig * sig

    # -- stage 1: every group at the coarse weights, batched over folds × weights
    wts = torch.tensor(AUTO_WEIGHTS, dtype=y.dtype, device=y.device)
    mus1 = torch.where(wts.isinf(), torch.full_like(wts, _CONSTRAINED_MU), wts)
    tvl2_1 = ~wts.isinf()
    mask1 = train.repeat_interleave(len(wts), dim=0)
    yt1 = ys * mask1.to(y.dtype)  # (BC, F·W, M): rows outside the training set zeroed
    hm1, tm1 = hm.repeat_interleave(len(wts), dim=0), tm.repeat_interleave(len(wts), dim=0)
    if known is not None:  # the call without the box: its candidates and its choice
        known, known_cv, known_fit = known
        at = {_key(k): i for i, k in enumerate(known.candidates)}
        chosen = (known.choice[0][0]["prior"], known.choice[0][0]["tv"])
    for g in _groups(bounds, priors):
        cols = [index[(*g, None if w == _INF else w)] for w in AUTO_WEIGHTS]
        if known is not None and g[3] in _boxes(None):  # fitted by the call without the box
            kc = [at[_key(cands[i])] for i in cols]
            cv_err[:, :, cols] = known_cv[:, :, kc]
            fit_err[:, cols] = known_fit[:, kc]
            continue
        if known is not None and (g[0], g[1]) != chosen:
            continue  # the inferred box refines the chosen prior and norm only
        xg = _fit(g, yt1, MaskedRows(A, mask1), mus1.repeat(nf).expand(bc, -1),
                  tvl2_1.repeat(nf).expand(bc, -1), cv_iter, tv_solver, fit_iter)[0]
        r2 = ((A(xg) - ys) * unit).square()
        cv_err[:, :, cols] = (r2 * hm1).sum(-1).reshape(bc, nf, len(wts))  # (BC, F, W)
        fit_err[:, cols] = (r2 * tm1).sum(-1).reshape(bc, nf, len(wts)).sum(1)
    lip, unique = 1.0, None
    if _finite_box(bounds) and known is None:  # does the box alone determine the image?
        lip = 1.0 if A.orthonormal_rows else largest_eig_normal(A, y)
        xb, unique = _box_alone(ys, A, float(bounds[0]), float(bounds[1]), lip, seed)
    rank = _rank(cands, y)
    first = _pick(_score(cv_err, fit_err, fit_max), rank, slack).tolist()  # one host read:
    # the first stage's choice decides which solves run next

    # -- stage 2: the factor-REFINE neighbours of each sample's first-stage TV-L2 weight
    for g in _groups(bounds, priors):
        rows = [i for i, k in enumerate(first) if _group_of(cands[k]) == g
                and cands[k]["mu"] is not None]
        if not rows:
            continue
        fine = [_fine(cands[first[i]]["mu"]) for i in rows]
        mus2 = torch.tensor(fine, dtype=y.dtype, device=y.device)  # (R, 2)
        mask2 = train.repeat_interleave(2, dim=0)
        idx = torch.tensor(rows, device=y.device)
        xg = _fit(g, ys[idx] * mask2.to(y.dtype), MaskedRows(A, mask2), mus2.repeat(1, nf),
                  True, cv_iter, tv_solver, fit_iter)[0]
        r2 = ((A(xg) - ys[idx]) * unit[idx]).square()
        e = (r2 * hm.repeat_interleave(2, dim=0)).sum(-1).reshape(len(rows), nf, 2)
        f = (r2 * tm.repeat_interleave(2, dim=0)).sum(-1).reshape(len(rows), nf, 2).sum(1)
        for j, i in enumerate(rows):
            for q, w in enumerate(fine[j]):
                cv_err[i, :, index[(*g, w)]] = e[j, :, q]
                fit_err[i, index[(*g, w)]] = f[j, q]
    score = _score(cv_err, fit_err, fit_max)
    best_l = _pick(score, rank, slack).tolist()

    # -- refit the choice on every row: one call per (group, model)
    x = y.new_zeros(bc, 1, A.n, A.n)
    n_iter = torch.zeros(bc, 1, dtype=torch.int64, device=y.device)
    conv = torch.zeros(bc, 1, dtype=torch.bool, device=y.device)
    codes = torch.zeros(bc, 1, dtype=torch.int64, device=y.device)
    for g in _groups(bounds, priors):
        for constrained in (True, False):
            rows = [i for i, k in enumerate(best_l)
                    if _group_of(cands[k]) == g and (cands[k]["mu"] is None) == constrained]
            if not rows:
                continue
            idx = torch.tensor(rows, device=y.device)
            if known is not None and _key(cands[best_l[0]]) == _key(known.choice[0][0]):
                # the same choice as the call without the box: its refit
                out = (known.x.reshape(1, 1, A.n, A.n), known.n_iter.reshape(1, 1),
                       known.converged.reshape(1, 1),
                       torch.tensor([[STOP_REASONS.index(known.stop_reason[0][0])]],
                                    device=y.device))
            elif constrained:
                out = _fit(g, ys[idx], A, _CONSTRAINED_MU, False, cv_iter, tv_solver)
            else:
                w = torch.tensor([cands[best_l[i]]["mu"] for i in rows], dtype=y.dtype,
                                 device=y.device)
                out = _fit(g, ys[idx], A, w[:, None], True, max_iter, tv_solver)
            x[idx], n_iter[idx], conv[idx], codes[idx] = out
    if unique is not None:  # the box alone determines the image: the box-only solution
        # replaces a refitted choice that does not agree with it (module doc)
        lo, hi = float(bounds[0]), float(bounds[1])
        gap = _rms_gap(x - xb, hi - lo, (-3, -2, -1))
        k_box = index[("box", None, None, tuple(bounds), None)]
        best_l = [k_box if u and gp > BOX_UNIQUE else k
                  for k, u, gp in zip(best_l, unique.tolist(), gap.tolist())]
    rows = [i for i, k in enumerate(best_l) if cands[k]["prior"] == "box"]
    if rows:
        idx = torch.tensor(rows, device=y.device)
        x[idx] = xb[idx]
        n_iter[idx] = BOX_ITER  # its fixed budget (the validated regulariser), not a tolerance
        conv[idx] = False
        codes[idx] = STOP_REASONS.index("max_iter")
    x = x.reshape(b, c, A.n, A.n)
    residual = relative_residual(x, y, A)
    back = unit[:, :, 0].reciprocal().square()  # (BC, 1): to the squared units of y
    cv_sum = cv_err.sum(dim=1) * back  # nan where not fitted
    cv_l, sc_l = cv_sum.tolist(), score.tolist()
    choice = tuple(
        tuple(dict(cands[best_l[i * c + j]], cv=cv_l[i * c + j][best_l[i * c + j]],
                   score=sc_l[i * c + j][best_l[i * c + j]], inferred=False,
                   learned_weight=None)
              for j in range(c)) for i in range(b))
    codes = codes.reshape(b, c)
    reasons = tuple(tuple(STOP_REASONS[k] for k in row) for row in codes.tolist())
    res = AutoResult(x, n_iter.reshape(b, c), residual, conv.reshape(b, c), reasons, choice,
                     cv_sum.reshape(b, c, -1), cands, (fit_err * back).reshape(b, c, -1),
                     (fit_max * back).reshape(b, c), score.reshape(b, c, -1),
                     (cv_err * back[:, :, None]).reshape(b, c, nf, -1))
    return res, (cv_err, fit_err)


def _unit(ys: torch.Tensor) -> torch.Tensor:
    """``(R, 1, 1)`` exact power-of-two factors for the buckets ``ys (R, 1, M)``
    (:func:`~torchtof.recon.base.pow2_scale`): squared errors of ``(A x − y)·unit`` neither
    overflow nor underflow, so the scores, the discrepancy bound and the stacking weight are
    scale-free (``auto(c·y) = c·auto(y)`` up to rounding) for any ``y`` the dtype holds, and
    the factor is 1 (nothing changes) at ordinary scales."""
    return pow2_scale(ys)


def _rms_gap(d: torch.Tensor, width: float, dims: tuple) -> torch.Tensor:
    """``RMS(d) / width`` over ``dims`` without over/underflow of ``d²``: ``d`` and ``width``
    are first multiplied by the power of two of :func:`~torchtof.recon.base.pow2_scale` for
    ``width`` (exact; 1 at ordinary scales)."""
    u = float(pow2_scale(torch.tensor([width], dtype=d.dtype)))
    return (d * u).pow(2).mean(dim=dims).sqrt() / (width * u)


def cv_folds(A: LinearOperator, like: torch.Tensor, folds: int | None, seed: int,
             split: str) -> tuple[torch.Tensor, torch.Tensor]:
    """``(held, train)`` ``(F, M)`` bool: :func:`auto`'s folds for ``folds`` (``None``: the
    defaults, :data:`TAIL_FOLDS` of which the latest :data:`TAIL_USE` for the tail split,
    :data:`RANDOM_FOLDS` for a random one), the latest fold first."""
    k = (TAIL_FOLDS if split == "tail" else RANDOM_FOLDS) if folds is None else folds
    held, train = holdout_split(A, k, like, seed, split)
    if folds is None and split == "tail":
        held, train = held[:TAIL_USE], train[:TAIL_USE]
    return held, train


def _two_level(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Per sample of ``x (R, 1, n, n)``: two levels ``lo, hi`` (the medians of the pixels below
    and above the midpoint of the range) and the fraction of pixels within
    ``TWO_LEVEL_TOL · (hi − lo)`` of one of them (0 for a constant image)."""
    v = x.flatten(1)
    mid = 0.5 * (v.amin(1, keepdim=True) + v.amax(1, keepdim=True))
    nan = torch.full_like(v, float("nan"))
    lo = torch.where(v < mid, v, nan).nanmedian(1).values
    hi = torch.where(v >= mid, v, nan).nanmedian(1).values
    d = torch.minimum((v - lo[:, None]).abs(), (v - hi[:, None]).abs())
    frac = (d <= TWO_LEVEL_TOL * (hi - lo)[:, None]).to(v.dtype).mean(1)  # nan compares False
    return lo, hi, frac


def _sample(res: AutoResult, i: int, c: int) -> AutoResult:
    """Sample ``i`` (flat index over ``(B, C)``) of ``res`` as a one-sample result."""
    b, j = divmod(i, c)
    one = lambda t: t[b, j][None, None]  # noqa: E731
    return res._replace(x=one(res.x), n_iter=one(res.n_iter), residual=one(res.residual),
                        converged=one(res.converged), stop_reason=((res.stop_reason[b][j],),),
                        choice=((res.choice[b][j],),), cv_error=one(res.cv_error),
                        fit_error=one(res.fit_error), fit_bound=one(res.fit_bound),
                        score=one(res.score), cv_fold=one(res.cv_fold))


def _nest(v: list, b: int, c: int) -> tuple:
    """A flat per-sample list over ``(B, C)`` as a tuple of tuples ``[b][c]``."""
    return tuple(tuple(v[k * c:(k + 1) * c]) for k in range(b))


def _with_inferred_box(res: AutoResult, errs: tuple, y: torch.Tensor, A: LinearOperator,
                       opts: dict) -> AutoResult:
    """Stage 3 of :func:`auto` without ``bounds`` (module doc, "The inferred box"): every
    sample whose refit is two-level chooses again with the box of its two levels. ``errs``:
    the held-out and fit errors of :func:`_auto` for ``res``."""
    b, c, m = y.shape
    bc = b * c
    lo, hi, frac = _two_level(res.x.reshape(bc, 1, A.n, A.n))
    rows = [i for i, (lo_i, hi_i, f) in enumerate(zip(lo.tolist(), hi.tolist(), frac.tolist()))
            if f >= TWO_LEVEL and hi_i > lo_i]
    if not rows:
        return res
    x, n_iter = res.x.reshape(bc, 1, A.n, A.n).clone(), res.n_iter.reshape(bc).clone()
    residual, conv = res.residual.reshape(bc).clone(), res.converged.reshape(bc).clone()
    reasons = [r for row in res.stop_reason for r in row]
    choice = [ch for row in res.choice for ch in row]
    ys = y.reshape(bc, 1, m)
    for i in rows:
        box = (float(lo[i]), float(hi[i]))
        known = (_sample(res, i, c), errs[0][i:i + 1], errs[1][i:i + 1])
        r = _auto(ys[i:i + 1], A, box, known=known, **opts)[0]
        x[i], n_iter[i], residual[i], conv[i] = r.x[0], r.n_iter[0, 0], r.residual[0, 0], \
            r.converged[0, 0]
        reasons[i], choice[i] = r.stop_reason[0][0], dict(r.choice[0][0], inferred=True)
    return res._replace(x=x.reshape(b, c, A.n, A.n), n_iter=n_iter.reshape(b, c),
                        residual=residual.reshape(b, c), converged=conv.reshape(b, c),
                        stop_reason=_nest(reasons, b, c), choice=_nest(choice, b, c))


def gauss_applies(A: LinearOperator, split: str | None = None) -> bool:
    """Whether :func:`auto` tries the Gaussian prior for ``A`` (module doc, "The Gaussian
    prior"): a :class:`~torchtof.operators.Hadamard` operator with ``n ≥``
    :data:`GAUSS_MIN_N` and ``M ≤`` :data:`GAUSS_MAX_M` rows, cross-validated on the tail
    split."""
    split = default_split(A) if split is None else split
    return (isinstance(A, Hadamard) and split == "tail" and A.n >= GAUSS_MIN_N
            and A.m <= GAUSS_MAX_M)


def gauss_covariance(A: Hadamard, ell: float) -> tuple[torch.Tensor, torch.Tensor]:
    """The separable exponential covariance of the Gaussian prior and its image in the
    measurements, float64: ``(S, K)`` with ``S[i, j] = exp(−|i − j| / ℓ)`` ``(n, n)`` (the
    pixel covariance is ``S ⊗ S``) and ``K = A (S ⊗ S) Aᵀ`` ``(M, M)``.

    Row ``a·n + b`` of the Sylvester Hadamard operator is the pattern
    ``H[a, i] H[b, j] / n`` (:func:`~torchtof.operators.hadamard_forward`: the coefficients of
    ``H X H / n``), so with ``Ĥ = H / √n`` and ``T = Ĥ S Ĥᵀ`` the covariance of rows
    ``r = a·n + b`` and ``r' = a'·n + b'`` separates, ``K[r, r'] = T[a, a'] T[b, b']``: ``O(M²)``
    to build, no ``n² × n²`` matrix."""
    n = A.n
    s, tt = markov_covariance(n, ell, torch.float64, A.index.device)
    a, b = A.index // n, A.index % n
    return s, tt[a][:, a] * tt[b][:, b]


def _ones_row(A: Hadamard, device) -> torch.Tensor:
    """``A·1`` ``(M,)`` in float64: the buckets of a constant image."""
    return A(torch.ones(1, 1, A.n, A.n, dtype=torch.float64, device=device)).reshape(-1)


def _gauss_mean(ys: torch.Tensor, ones: torch.Tensor) -> torch.Tensor:
    """``(R, 1)`` least-squares constant ``m̂`` of ``ys (R, k) ≈ m̂ · ones (k,)`` (0 where no
    row sees a constant)."""
    den = (ones * ones).sum()
    return torch.where(den > 0, (ys @ ones)[:, None] / den.clamp_min(1e-300),
                       torch.zeros_like(ys[:, :1]))


def _gauss_fold_preds(ys: torch.Tensor, A: Hadamard, train: torch.Tensor, ell: float,
                      gammas: tuple) -> torch.Tensor:
    """Predictions ``A x̂`` ``(R, F, G, M)`` (float64) of the Gaussian prior with length ``ell``
    and each relative weight in ``gammas``, fitted on each fold's training rows alone (its own
    mean and ``γ`` scale) for buckets ``ys (R, M)``: ``A x̂ = m̂ A·1 + K[:, t] α`` in closed
    form, one eigendecomposition of ``K[t, t]`` per fold serving every ``γ`` and sample."""
    y64 = ys.to(torch.float64)
    ones = _ones_row(A, ys.device)
    g = torch.tensor(gammas, dtype=torch.float64, device=ys.device)
    k_full = gauss_covariance(A, ell)[1]
    out = []
    for f in range(train.shape[0]):
        t = torch.nonzero(train[f]).reshape(-1)
        lam, q = torch.linalg.eigh(k_full[t][:, t])
        mh = _gauss_mean(y64[:, t], ones[t])
        z = (y64[:, t] - mh * ones[t]) @ q  # (R, k)
        alpha = (z[:, None, :] / (lam + g[:, None] * lam.mean())) @ q.T  # (R, G, k)
        out.append(alpha @ k_full[:, t].T + mh[:, :, None] * ones)  # (R, G, M)
    return torch.stack(out, dim=1)


def gauss_cv(ys: torch.Tensor, A: Hadamard, held: torch.Tensor, train: torch.Tensor
             ) -> torch.Tensor:
    """Held-out errors of every Gaussian-prior candidate on every fold, ``(R, F, L·G)``
    (``ℓ``-major over :data:`GAUSS_ELLS` × :data:`GAUSS_GAMMAS`), for buckets ``ys (R, M)``
    and the folds ``held``, ``train`` ``(F, M)`` of :func:`cv_folds`."""
    y64 = ys.to(torch.float64)[:, None, None, :]
    hm = held.to(torch.float64)[None, :, None, :]
    errs = [((_gauss_fold_preds(ys, A, train, ell, GAUSS_GAMMAS) - y64).square() * hm).sum(-1)
            for ell in GAUSS_ELLS]
    return torch.cat(errs, dim=-1).to(ys.dtype)


def gauss_fit(ys: torch.Tensor, A: Hadamard, ell: float, gamma: float) -> torch.Tensor:
    """The Gaussian-prior posterior mean from every row (module doc, "The Gaussian prior"):
    ``x̂ = m̂ + (S ⊗ S) Aᵀ α``, ``(K + γ λ̄ I) α = y − m̂ A·1`` (``λ̄`` the mean eigenvalue of
    ``K``), for buckets ``ys (R, M)`` -> ``(R, 1, n, n)`` in the dtype of ``ys``."""
    s, k = gauss_covariance(A, ell)
    y64 = ys.to(torch.float64)
    ones = _ones_row(A, ys.device)
    mh = _gauss_mean(y64, ones)
    lam_bar = torch.diagonal(k).mean()  # the trace over M: the mean eigenvalue
    reg = k + float(gamma) * lam_bar * torch.eye(k.shape[0], dtype=k.dtype, device=k.device)
    alpha = torch.linalg.solve(reg, (y64 - mh * ones).T).T  # (R, M)
    img = A.adjoint(alpha[:, None, :])  # (R, 1, n, n)
    return (mh[:, :, None, None] + s @ img @ s).to(ys.dtype)


def _with_gauss(res: AutoResult, y: torch.Tensor, A: Hadamard, bounds, opts: dict
                ) -> tuple[AutoResult, torch.Tensor]:
    """Stage 4 of :func:`auto` (module doc, "The Gaussian prior"): every sample whose best
    Gaussian-prior candidate (smallest relative score) predicts the held-out rows of every
    tail fold better than its TV/TGV choice takes the Gaussian posterior mean instead.
    Returns the result and the held-out predictions ``(R, F, M)`` of each sample's (possibly
    new) choice, for the stacking."""
    b, c, m = y.shape
    bc, n = b * c, A.n
    held, train = cv_folds(A, y, opts["folds"], opts["seed"], "tail")
    ys = y.reshape(bc, 1, m)
    choice = [ch for row in res.choice for ch in row]
    pa = choice_predictions(ys, A, choice, train, opts["cv_iter"], opts["tv_solver"],
                            opts["fit_iter"])
    hm = held.to(y.dtype)
    unit = _unit(ys)  # exact: the errors in units free of over/underflow (1 at ordinary scales)
    err_a = (((pa - ys) * unit).square() * hm).sum(-1)  # (R, F)
    err_g = gauss_cv(ys[:, 0] * unit[:, 0], A, held, train)  # (R, F, L·G)
    tiny = torch.finfo(y.dtype).tiny
    best = torch.minimum(err_a, err_g.amin(-1)).clamp_min(tiny)  # (R, F)
    s_g = (err_g / best[:, :, None]).sum(1)  # (R, L·G)
    sg_min, j = s_g.min(-1)
    # it replaces the choice only where it predicts every fold's held-out rows better
    every = (err_g.gather(-1, j[:, None, None].expand(-1, err_g.shape[1], 1))[..., 0]
             < err_a).all(-1)
    boxed = torch.tensor([ch["prior"] == "box" for ch in choice], device=y.device)
    win = (every & ~boxed).tolist()  # one host read: which samples change
    if not any(win):
        return res, pa
    ng = len(GAUSS_GAMMAS)
    x = res.x.reshape(bc, 1, n, n).clone()
    n_iter, conv = res.n_iter.reshape(bc).clone(), res.converged.reshape(bc).clone()
    reasons = [r for row in res.stop_reason for r in row]
    cv_g = err_g.sum(1) * unit[:, 0].reciprocal().square()  # in the squared units of y
    js, cv_l, sc_l = j.tolist(), cv_g.tolist(), sg_min.tolist()
    groups: dict = {}
    for i, w in enumerate(win):
        if w:
            groups.setdefault(js[i], []).append(i)
    for jj, rows in groups.items():
        ell, gamma = GAUSS_ELLS[jj // ng], GAUSS_GAMMAS[jj % ng]
        idx = torch.tensor(rows, device=y.device)
        xg = gauss_fit(ys[idx, 0], A, ell, gamma)
        if bounds is not None:  # the image obeys the caller's box
            xg = project_box(xg, bounds[0], bounds[1])
        x[idx] = xg
        n_iter[idx], conv[idx] = 0, True
        for i in rows:
            reasons[i] = "tol"
            choice[i] = dict(prior="gauss", tv=None, boundary=None, bounds=bounds, mu=None,
                             stage=1, cv=cv_l[i][jj], score=sc_l[i], inferred=False,
                             learned_weight=None, ell=ell, gamma=gamma)
        # the held-out predictions of the new choice, for the stacking: the same closed form
        pa[idx] = _gauss_fold_preds(ys[idx, 0], A, train, ell, (gamma,))[:, :, 0].to(y.dtype)
    x = x.reshape(b, c, n, n)
    residual = relative_residual(x, y, A)
    return res._replace(x=x, n_iter=n_iter.reshape(b, c), residual=residual,
                        converged=conv.reshape(b, c), stop_reason=_nest(reasons, b, c),
                        choice=_nest(choice, b, c)), pa


def stackable(A: LinearOperator, split: str | None = None) -> bool:
    """Whether :func:`auto` stacks the learned network for ``A`` (module doc, "Stacking"):
    a :class:`~torchtof.operators.Hadamard` operator with ``n ≥`` :data:`LEARNED_MIN_N`
    cross-validated on the tail split (every training set a prefix of its rows)."""
    split = default_split(A) if split is None else split
    return isinstance(A, Hadamard) and split == "tail" and A.n >= LEARNED_MIN_N


def stack_weight(pred_a: torch.Tensor, pred_l: torch.Tensor, y: torch.Tensor,
                 held: torch.Tensor) -> torch.Tensor:
    """Stacking weight of a second estimator from held-out predictions, in ``[0, 1]``.

    The weight ``w`` of the convex combination ``(1 − w) p^a + w p^l`` of two estimators'
    predictions (Breiman 1996, Machine Learning 24, "Stacked regressions", with the weights
    constrained to a convex combination) that minimises a weighted held-out squared error is
    a convex quadratic's minimiser, clipped to ``[0, 1]``. With ``d_k = p^l_k − p^a_k`` and
    ``r_k = y − p^a_k`` on the held-out rows ``P_k`` of fold ``k``:

    .. math::
        w(ρ) = \\operatorname{clip}_{[0, 1]}
            \\frac{\\sum_k ρ_k ⟨P_k d_k,\\ P_k r_k⟩}{\\sum_k ρ_k \\|P_k d_k\\|^2}, \\qquad
        w = \\min\\big(w(e_0),\\ w(ρ^{\\mathrm{rel}})\\big),

    the smaller of the weight of fold 0 alone (the fold trained on the most rows, the most
    like the full problem: :func:`~torchtof.recon.tval3.holdout_split` puts it first) and the
    weight over every fold with each fold's rows divided by the first estimator's error
    there, ``ρ^rel_k ∝ 1 / ‖P_k r_k‖²`` (every fold counts alike, as in :func:`auto`'s
    score). ``0`` where the predictions agree on the held-out rows.

    Why these two (measured in ``docs/auto.md``, "Stacking with the learned network"): the
    plain pooled weight (``ρ = 1``) follows the fold trained on the fewest rows, whose
    held-out rows carry the most energy, and where the first estimator recovers the image
    almost exactly from all rows but not yet from the fewest (anisotropic TV with a box on a
    binary character) it cost 6 dB; fold 0 alone sees that regime, and the relative pooled
    weight keeps a single noisy fold from asking for too much.

    Args:
        pred_a, pred_l: predictions ``A x̂`` of the two estimators fitted on each fold,
            ``(R, F, M)``, fold 0 the one trained on the most rows.
        y: buckets ``(R, 1, M)``.
        held: ``(F, M)`` bool, the held-out rows ``P_k`` of each fold.

    Returns:
        ``(R,)`` weights of the second estimator.
    """
    h = held.to(y.dtype) * _unit(y)  # exact power of two: no over/underflow of d², r²
    d = (pred_l - pred_a) * h
    r = (y - pred_a) * h
    num, den = (d * r).sum(dim=-1), (d * d).sum(dim=-1)  # (R, F)
    tiny = torch.finfo(y.dtype).tiny

    def clipped(nu, de):
        w = nu / de.clamp_min(tiny)
        return torch.where(de > 0, w, torch.zeros_like(w)).clamp(0.0, 1.0)

    err = r.square().sum(dim=-1).clamp_min(tiny)  # (R, F): the first estimator's errors
    rho = err.amin(dim=-1, keepdim=True) / err  # relative weights in (0, 1]
    w_rel = clipped((rho * num).sum(-1), (rho * den).sum(-1))
    return torch.minimum(clipped(num[:, 0], den[:, 0]), w_rel)


def choice_predictions(ys: torch.Tensor, A: LinearOperator, choices: list,
                       train: torch.Tensor, cv_iter: int, tv_solver: str = "tval3",
                       fit_iter: int | None = None) -> torch.Tensor:
    """Held-out predictions ``A x̂`` ``(R, F, M)`` of each sample's chosen candidate
    (``choices``: ``R`` dicts of :func:`candidates`) fitted on each fold's training rows
    ``train (F, M)``: one batched solve per distinct TV/TGV choice (a constrained choice
    ``cv_iter`` iterations, a TV-L2/TGV-L2 choice ``fit_iter``, default ``cv_iter``), the
    closed form of a Gaussian-prior choice, zeros for the box-only solution
    (which is neither replaced nor stacked)."""
    nf, n = train.shape[0], A.n
    xa = ys.new_zeros(ys.shape[0], nf, n, n)
    by_key: dict = {}
    for i, ch in enumerate(choices):
        if ch["prior"] == "gauss":
            by_key.setdefault(("gauss", ch["ell"], ch["gamma"]), []).append(i)
        elif ch["prior"] != "box":
            by_key.setdefault(_key(ch), []).append(i)
    tm, masked = train.to(ys.dtype), MaskedRows(A, train)
    gauss_rows = []
    for key, rows in by_key.items():
        idx = torch.tensor(rows, device=ys.device)
        if key[0] == "gauss":
            gauss_rows.append((idx, key))
            continue
        mu = (_CONSTRAINED_MU if key[4] is None else ys.new_full((len(rows), nf), key[4]))
        xa[idx] = _fit(key[:4], ys[idx] * tm, masked, mu, key[4] is not None, cv_iter,
                       tv_solver, fit_iter)[0]
    pa = A(xa)
    for idx, (_, ell, gamma) in gauss_rows:
        pa[idx] = _gauss_fold_preds(ys[idx, 0], A, train, ell, (gamma,))[:, :, 0].to(ys.dtype)
    return pa


def stack_predictions(ys: torch.Tensor, A: Hadamard, choices: list, train: torch.Tensor,
                      cv_iter: int, tv_solver: str = "tval3", fit_iter: int | None = None,
                      weights: bool | str | os.PathLike = True
                      ) -> tuple[torch.Tensor, torch.Tensor]:
    """Held-out predictions of the stacking (module doc, "Stacking"): for ``ys (R, 1, M)`` and
    its chosen candidates ``choices``, those of :func:`choice_predictions` and those of the
    learned network (``weights``: ``pretrained`` of :class:`~torchtof.recon.learned.Learned`)
    fitted on each fold's first ``k`` rows (a tail split's training rows are a prefix: a plain
    ``Hadamard(n, m=k)``), each ``(R, F, M)``."""
    return (choice_predictions(ys, A, choices, train, cv_iter, tv_solver, fit_iter),
            _learned_predictions(ys, A, train, weights))


def _learned_predictions(ys: torch.Tensor, A: Hadamard, train: torch.Tensor,
                         weights: bool | str | os.PathLike = True) -> torch.Tensor:
    xl = [learned_recon(ys[..., :k], Hadamard(A.n, m=k, order=A.order).to(ys.device),
                        pretrained=weights)
          for k in train.sum(-1).tolist()]
    return A(torch.cat(xl, dim=1))


def _with_learned(res: AutoResult, y: torch.Tensor, A: Hadamard, bounds, opts: dict,
                  pa: torch.Tensor | None = None,
                  weights: bool | str | os.PathLike = True) -> AutoResult:
    """Stage 5 of :func:`auto` (module doc, "Stacking"): the chosen candidate and the learned
    network are fitted on the same tail folds, the weight of the network is the least-squares
    stacking weight of their held-out predictions (:func:`stack_weight`), and the result is
    that convex combination of the two full-row reconstructions (projected onto the caller's
    ``bounds``, if any). ``pa``: the choice's held-out predictions when already computed
    (:func:`_with_gauss`); ``weights``: the network's weights file (``True``: the shipped
    one)."""
    b, c, m = y.shape
    bc, n = b * c, A.n
    held, train = cv_folds(A, y, opts["folds"], opts["seed"], "tail")
    ys = y.reshape(bc, 1, m)
    choice = [ch for row in res.choice for ch in row]
    if pa is None:
        pa = choice_predictions(ys, A, choice, train, opts["cv_iter"], opts["tv_solver"],
                            opts["fit_iter"])
    pl = _learned_predictions(ys, A, train, weights)
    w = stack_weight(pa, pl, ys, held)
    w = torch.where(torch.tensor([ch["prior"] != "box" for ch in choice], device=y.device), w,
                    torch.zeros_like(w))
    x_full = learned_recon(ys, A, pretrained=weights).reshape(b, c, n, n)
    wi = w.reshape(b, c, 1, 1)
    x = res.x + wi * (x_full - res.x)
    if bounds is not None:  # the caller's box holds for the image: project the blend onto it
        x = project_box(x, bounds[0], bounds[1])
    residual = relative_residual(x, y, A)
    wl = w.tolist()
    nest = tuple(tuple(dict(choice[i * c + j], learned_weight=wl[i * c + j]) for j in range(c))
                 for i in range(b))
    return res._replace(x=x, residual=residual, choice=nest)


class Auto(nn.Module):
    """Module of :func:`auto`: ``forward(y) -> x``, ``solve(y) -> AutoResult``.

    Args:
        A: the operator (a submodule). bounds, folds, cv_iter, max_iter, split, slack, seed,
            priors, infer_box, gauss, learned, tv_solver, fit_iter: as :func:`auto`.

    Example:
        >>> from torchtof.operators import Hadamard
        >>> Auto(Hadamard(8, sr=0.5))(torch.zeros(2, 1, 32)).shape
        torch.Size([2, 1, 8, 8])
    """

    def __init__(self, A: LinearOperator, bounds: tuple | None = None, folds: int | None = None,
                 cv_iter: int = 100, max_iter: int = 1025, split: str | None = None,
                 slack: float = 0.0, seed: int = 0, priors: tuple = AUTO_PRIORS,
                 infer_box: bool = True, gauss: bool = True,
                 learned: bool | str | os.PathLike = True,
                 tv_solver: str = "tval3", fit_iter: int | None = None) -> None:
        super().__init__()
        if not isinstance(A, LinearOperator):
            raise TypeError(f"Auto: expected A to be a LinearOperator, got {type(A).__name__}")
        _check("Auto", folds, cv_iter, max_iter, bounds, split, slack, priors, infer_box,
               learned, gauss, tv_solver, fit_iter, seed)
        _check_folds("Auto", folds, A)
        self.A = A
        self.options = dict(bounds=bounds, folds=folds, cv_iter=cv_iter, max_iter=max_iter,
                            split=split, slack=slack, seed=seed, priors=tuple(priors),
                            infer_box=infer_box, gauss=gauss, learned=learned,
                            tv_solver=tv_solver, fit_iter=fit_iter)

    def solve(self, y: torch.Tensor) -> AutoResult:
        return auto(y, self.A, return_result=True, **self.options)

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        return self.solve(y).x

    def extra_repr(self) -> str:
        o = self.options
        return (f"bounds={o['bounds']}, folds={o['folds']}, cv_iter={o['cv_iter']}, "
                f"priors={o['priors']}, infer_box={o['infer_box']}, gauss={o['gauss']}, "
                f"learned={o['learned']}, tv_solver={o['tv_solver']!r}, "
                f"fit_iter={o['fit_iter']}")
