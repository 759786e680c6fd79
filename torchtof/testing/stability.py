"""The numerical stress matrix of every public module (``torchtof bench stability``, tests).

Rows are ``(module, edge case)``, columns the dtypes float16, bfloat16, float32, float64.
Every cell builds its inputs in float64, rounds them to the column's dtype and runs the
module; the outcome is one of

- ``ok``: every output is finite, has the input's dtype, passes the row's known-answer check
  (if any) and — float32, float16, bfloat16 — lies within the tolerance below of the float64
  result computed **on the same rounded inputs** (so the comparison measures the arithmetic,
  not the rounding of the inputs);
- ``error``: a clear error, i.e. a ``ValueError``/``TypeError`` whose message starts with the
  function or class name (``"tval3: expected y of dtype float32 or float64, got
  torch.float16"``). Intended for non-finite inputs (including inputs that overflow the
  dtype, e.g. 1e30 in float16), unsupported dtypes and degenerate data (zero buckets, one
  pattern, patterns an operator-specific solver does not accept). It counts as a failure for
  float32/float64 on an edge case that must compute, and when it reports "non-finite values"
  although every input was finite (a NaN made inside the module, blamed on the input);
- ``n/r``: not representable: the output is ±Inf only because the exact (float64) result
  exceeds the dtype's range (e.g. a 64×64-pixel tap bucket of 4095 DN in float16, 1.7e7 >
  65504) — the IEEE outcome, explained;
- ``n/a``: no such input exists (torch has no complex bfloat16, so phasor-domain modules
  have no bfloat16 column);
- ``FAIL``: a silent NaN/Inf, a result outside the tolerance, a changed dtype, a failed
  known-answer check, an error where a result was due, or an unclear exception
  (``RuntimeError``/``NotImplementedError`` from inside torch, a message without the name).

Tolerances (:data:`TOLERANCES`; metric against the float64 result on the same inputs; an
all-zero float64 result must be matched exactly). DIP, a non-convex fit whose float32 and
float64 trajectories drift apart over hundreds of Adam steps, is run for 20 steps and scored
by the gap between the two results' PSNR against the object after an affine fit. Rows whose
buckets carry a small contrast on a large offset (the depth buckets: ``offset / contrast`` =
5/3 at α = 1, 335 at α = 1e-3) multiply the tolerance by that condition factor. The float32
column is an accuracy specification; the half-precision columns only catch breakdowns
(blow-ups, zeroed or sign-flipped images, lost phase): with 8 (bfloat16) or 11 (float16)
significant bits a bucket with a 5 m × 64² px offset keeps only a few bits of its contrast,
so reconstructions that subtract the mean cannot be accurate.

==================  ==============================  ========  ========  ========
family              metric                          float32   float16   bfloat16
==================  ==============================  ========  ========  ========
operator            relative L2                     1e-5      4e-3      3e-2
sensor              relative L2 (taps, phasors)     1e-5      4e-3      3e-2
depth_m             max abs error (metres)          1e-4      2e-2      1e-1
phase_rad           max circular error (rad)        1e-5      1e-2      8e-2
bucket              relative L2                     1e-6      1e-3      1e-2
metric              max abs (dB, SSIM)              1e-3      5e-2      5e-1
recon_direct        relative L2 (CGI/TGI/DGI/A⁺)    1e-4      5e-2      3e-1
recon_illcond       relative L2 (A⁺y, κ ≈ 5e4)      1e-2      5e-2      3e-1
recon_iterative     relative L2 (TVAL3, BP, K-TV)   1e-2      1e-1      3e-1
recon_dip           PSNR gap to the object (dB)     1         3         3
none                no comparison (random draws)    —         —         —
==================  ==============================  ========  ========  ========

Rows cover the operators (Hadamard matmul/FWHT, DMD split, dense patterns: forward, adjoint,
pseudo-inverse), the sensor (phasor → taps → phase/amplitude/depth, camera rules, noise and
ADC, scattering in depth and phasor form with α ∈ {1e-3, 0.5, 1}, multipath, DMD → sensor
mixing), the buckets, the metrics and every reconstructor (CGI, TGI, DGI, pseudo-inverse,
TVAL3, basis pursuit, unrolled TVAL3, DIP) on these edge cases: zero and
constant buckets, buckets at 1e-30 and 1e30, all pixels "no photon" (depth 5 m), saturated
taps, phase exactly at the wrap-around, n = 4 and n = 256 (operators), SR = 1/n² and 100 %,
SNR < 0 dB, ill-conditioned random patterns, NaN inputs. ``tests/stress`` runs every row and
asserts that no cell fails.
"""

from __future__ import annotations

import math
import re
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial

import torch

from .._optional import progress_bar

__all__ = [
    "DTYPES",
    "TOLERANCES",
    "BP_FAST",
    "DIP_FAST",
    "Case",
    "Ctx",
    "scene",
    "illcond_patterns",
    "psnr_affine",
    "stability_cases",
    "evaluate_case",
    "bench_stability",
]

F16, BF16, F32, F64 = torch.float16, torch.bfloat16, torch.float32, torch.float64
DTYPES: tuple[torch.dtype, ...] = (F16, BF16, F32, F64)
NAMES = {F16: "float16", BF16: "bfloat16", F32: "float32", F64: "float64"}
_COMPLEX = {F16: torch.complex32, F32: torch.complex64, F64: torch.complex128}
_HALF = (F16, BF16)
STATUSES = ("ok", "error", "n/r", "n/a", "FAIL")

#: family -> (metric, {dtype: tolerance}); see the module docstring.
TOLERANCES: dict[str, tuple[str, dict[torch.dtype, float]]] = {
    "operator": ("rel", {F32: 1e-5, F16: 4e-3, BF16: 3e-2}),
    "sensor": ("rel", {F32: 1e-5, F16: 4e-3, BF16: 3e-2}),
    "depth_m": ("abs", {F32: 1e-4, F16: 2e-2, BF16: 1e-1}),
    "phase_rad": ("circ", {F32: 1e-5, F16: 1e-2, BF16: 8e-2}),
    "bucket": ("rel", {F32: 1e-6, F16: 1e-3, BF16: 1e-2}),
    "metric": ("abs", {F32: 1e-3, F16: 5e-2, BF16: 5e-1}),
    "recon_direct": ("rel", {F32: 1e-4, F16: 5e-2, BF16: 3e-1}),
    "recon_illcond": ("rel", {F32: 1e-2, F16: 5e-2, BF16: 3e-1}),
    "recon_iterative": ("rel", {F32: 1e-2, F16: 1e-1, BF16: 3e-1}),
    "recon_dip": ("psnr_gap", {F32: 1.0, F16: 3.0, BF16: 3.0}),
    "none": ("none", {}),
}

_CLEAR = re.compile(r"^[A-Za-z_][\w.\[\]]*: ")


class Ctx:
    """Inputs of one cell: tensors built in float64, rounded through ``dtype``, handed to the
    module in ``compute`` (``compute == dtype`` for the cell, float64 for its reference).
    ``nonfinite`` records whether rounding produced a NaN/Inf input (1e30 in float16);
    ``exact`` whether every input survived the rounding unchanged (then the float64
    reference of the cell is the float64 cell itself, and is not solved twice)."""

    def __init__(self, dtype: torch.dtype, compute: torch.dtype) -> None:
        self.dtype, self.compute = dtype, compute
        self.nonfinite = False
        self.exact = True

    def _seen(self, t: torch.Tensor) -> torch.Tensor:
        self.nonfinite |= not bool(torch.isfinite(t).all())
        return t

    def _rounded(self, x: torch.Tensor, to: torch.dtype) -> torch.Tensor:
        r = x.to(to)
        if self.exact and not torch.equal(r.to(x.dtype), x):
            self.exact = False
        return r

    def t(self, x: torch.Tensor) -> torch.Tensor:
        """A real float64 tensor rounded to ``dtype``, in ``compute``."""
        return self._seen(self._rounded(x, self.dtype).to(self.compute))

    def r(self, x: torch.Tensor) -> torch.Tensor:
        """Rounded to ``dtype`` but kept in float64 (operator patterns, stored as given)."""
        return self._seen(self._rounded(x, self.dtype).to(F64))

    def c(self, p: torch.Tensor) -> torch.Tensor:
        """A complex128 tensor rounded to ``dtype``, as the complex dtype of ``compute``."""
        return self._seen(self._rounded(p, _COMPLEX[self.dtype]).to(_COMPLEX[self.compute]))


@dataclass(frozen=True)
class Case:
    """One row of the matrix.

    Attributes:
        module: public module/function under test (row label).
        edge: the edge case (row label).
        run: ``run(ctx) -> tensor or tuple of tensors``; builds its inputs with ``ctx``.
        family: tolerance family (key of :data:`TOLERANCES`).
        expect: ``"ok"`` (float32/float64 must compute; half precision may raise a clear
            error), ``"error"`` (every dtype must raise a clear error) or ``"any"`` (a clear
            error is acceptable in every dtype).
        check: optional known-answer check ``check(outputs) -> message or None``.
        complex_in: the module takes complex phasors (no bfloat16 column).
        cond: condition factor of the data, multiplies the tolerance (buckets whose contrast
            is a small part of a large offset: ``offset / contrast``; 1 otherwise).
    """

    module: str
    edge: str
    run: Callable[[Ctx], torch.Tensor | tuple[torch.Tensor, ...]]
    family: str
    expect: str = "ok"
    check: Callable[[tuple[torch.Tensor, ...]], str | None] | None = None
    complex_in: bool = False
    cond: float = 1.0

    @property
    def id(self) -> str:
        return f"{self.module} | {self.edge}"


# -- evaluation --------------------------------------------------------------------------------


def _call(case: Case, ctx: Ctx) -> tuple[torch.Tensor, ...]:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = case.run(ctx)
    out = out if isinstance(out, tuple) else (out,)
    return tuple(o.detach() for o in out)


def _real64(t: torch.Tensor) -> torch.Tensor:
    if t.is_complex():
        t = torch.view_as_real(t.to(torch.complex128))
    return t.to(F64)


def psnr_affine(x_hat: torch.Tensor, truth: torch.Tensor) -> float:
    """PSNR (dB) of ``x_hat`` against a ``[0, 1]`` object after the least-squares affine map
    ``a·x_hat + b`` (scale-, offset- and sign-free: the DIP output is known up to an affine
    map, paper §3.1 negative images), computed in float64."""
    u, t = _real64(x_hat).flatten(), _real64(truth).flatten()
    du = u - u.mean()
    a = float((du * (t - t.mean())).sum() / du.pow(2).sum()) if float(du.abs().max()) > 0 else 0.0
    mse = float((a * du + t.mean() - t).pow(2).mean())
    return 10 * math.log10(1 / max(mse, 1e-10))


def _distance(out: tuple, ref: tuple, metric: str) -> tuple[float, int]:
    """Worst error over the outputs and the index of the worst output."""
    if metric == "psnr_gap":  # outputs (x_hat, object)
        return abs(psnr_affine(out[0], ref[1]) - psnr_affine(ref[0], ref[1])), 0
    worst, where = 0.0, 0
    for k, (o, r) in enumerate(zip(out, ref, strict=True)):
        o, r = _real64(o), _real64(r)
        if o.shape != r.shape:
            return math.inf, k
        if metric == "rel":
            rn = float(r.norm())
            on = float(o.norm())
            e = float((o - r).norm()) / rn if rn > 0 else (0.0 if on == 0 else math.inf)
        elif o.numel() == 0:
            e = 0.0
        elif metric == "abs":
            e = float((o - r).abs().max())
        else:  # circular distance of phases in radians
            d = torch.remainder(o - r, 2 * math.pi)
            e = float(torch.minimum(d, 2 * math.pi - d).max())
        if e > worst or math.isnan(e):
            worst, where = e, k
    return worst, where


def _first_line(e: BaseException) -> str:
    msg = str(e).strip()
    return msg.splitlines()[0][:200] if msg else type(e).__name__


def _reference(case: Case, dtype: torch.dtype) -> tuple[torch.Tensor, ...] | str:
    try:
        return _call(case, Ctx(dtype, F64))
    except Exception as e:  # noqa: BLE001 - reported in the cell
        return f"float64 reference failed: {type(e).__name__}: {_first_line(e)}"


def _cell(case: Case, dtype: torch.dtype, f64: tuple | None = None,
          keep: list | None = None) -> dict:
    """One cell. ``f64``: the float64 cell's outputs, the reference of a cell whose inputs all
    round to ``dtype`` exactly (the same inputs, the same float64 computation); ``keep``: a
    list the outputs are appended to."""
    name = NAMES[dtype]
    if case.complex_in and dtype not in _COMPLEX:
        return {"status": "n/a", "detail": f"torch has no complex {name} dtype"}
    ctx = Ctx(dtype, dtype)
    try:
        out = _call(case, ctx)
        if keep is not None:
            keep.append(out)
    except (ValueError, TypeError) as e:
        msg = _first_line(e)
        if not _CLEAR.match(msg):
            return {"status": "FAIL", "detail": f"unclear {type(e).__name__}: {msg}"}
        if "non-finite" in msg and not ctx.nonfinite:
            return {"status": "FAIL", "detail": f"NaN/Inf made inside, blamed on a finite "
                    f"input: {msg}"}
        if case.expect == "ok" and dtype not in _HALF and not ctx.nonfinite:
            return {"status": "FAIL", "detail": f"error on valid {name} input: {msg}"}
        return {"status": "error", "detail": msg}
    except Exception as e:  # noqa: BLE001 - any other exception is a finding
        return {"status": "FAIL", "detail": f"unclear {type(e).__name__}: {_first_line(e)}"}
    if case.expect == "error":
        return {"status": "FAIL", "detail": "expected a clear error, got a result"}
    for k, o in enumerate(out):
        if not (o.is_floating_point() or o.is_complex()):
            continue
        bad = ~torch.isfinite(o)
        if bool(bad.any()):
            n_nan = int(torch.isnan(o).sum())
            what = f"{n_nan} NaN, {int(bad.sum()) - n_nan} Inf of {o.numel()}"
            if ctx.nonfinite:
                return {"status": "FAIL", "detail": f"non-finite input passed silently to "
                        f"output {k} ({what})"}
            ref = _reference(case, dtype)
            if not isinstance(ref, str) and n_nan == 0:
                big = float(_real64(ref[k]).abs().max())
                if math.isfinite(big) and big > torch.finfo(dtype).max:
                    return {"status": "n/r", "detail": f"exact result up to {big:.3g} exceeds "
                            f"the {name} range: output {k} is ±Inf"}
            return {"status": "FAIL", "detail": f"silent NaN/Inf in output {k} ({what})"}
        want = _COMPLEX[dtype] if o.is_complex() else dtype
        if o.dtype != want:
            return {"status": "FAIL", "detail": f"output {k} has dtype {o.dtype}, not {want}"}
    if case.check is not None:
        msg = case.check(out)
        if msg:
            return {"status": "FAIL", "detail": f"check: {msg}"}
    metric, tols = TOLERANCES[case.family]
    if dtype == F64 or metric == "none":
        return {"status": "ok", "detail": ""}
    ref = f64 if f64 is not None and ctx.exact else _reference(case, dtype)
    if isinstance(ref, str):
        return {"status": "FAIL", "detail": ref}
    err, k = _distance(out, ref, metric)
    tol = tols[dtype] * case.cond
    if not err <= tol:
        return {"status": "FAIL", "detail": f"{metric} error {err:.3g} of output {k} vs float64 "
                f"> tol {tol:g}", "err": err, "tol": tol}
    return {"status": "ok", "detail": "", "err": err, "tol": tol}


def evaluate_case(case: Case) -> dict:
    """Run one row in every dtype: ``{"id", "module", "edge", "family", "cells": {dtype: …}}``;
    a cell is ``{"status", "detail"}`` plus ``"err"``/``"tol"`` where compared. The float64
    cell runs first: its outputs are the reference of every cell whose inputs round exactly."""
    kept: list = []
    cells = {F64: _cell(case, F64, keep=kept)}
    for dt in DTYPES:
        if dt != F64:
            cells[dt] = _cell(case, dt, f64=kept[0] if kept else None)
    return {
        "id": case.id,
        "module": case.module,
        "edge": case.edge,
        "family": case.family,
        "cells": {NAMES[dt]: cells[dt] for dt in DTYPES},
    }


# -- inputs and checks ---------------------------------------------------------------------------


def _gen(seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def _rand(*shape: int, seed: int = 0) -> torch.Tensor:
    return torch.rand(shape, generator=_gen(seed), dtype=F64)


def _randn(*shape: int, seed: int = 0) -> torch.Tensor:
    return torch.randn(shape, generator=_gen(seed), dtype=F64)


def scene(n: int) -> torch.Tensor:
    """The binary test object ``(1, 1, n, n)``: a T (bar and stem), a stand-in for 天."""
    x = torch.zeros(1, 1, n, n, dtype=F64)
    q = max(n // 4, 1)
    x[..., q, q : n - q] = 1.0
    x[..., q : n - q, n // 2 - max(n // 8, 1) + 1 : n // 2 + 1] = 1.0
    return x


def illcond_patterns(m: int = 24, n: int = 8, gap: float = 1e-4) -> torch.Tensor:
    """Random 0/1 patterns, the last a copy of the first plus ``gap`` times Gaussian noise:
    ``κ(A) ≈ 5/gap`` (5e4 at the default, 24 × 64)."""
    from ..operators import random_binary_patterns

    p = random_binary_patterns(m, n, generator=_gen(7), dtype=F64)
    p[-1] = p[0] + gap * torch.randn(n, n, generator=_gen(8), dtype=F64)
    return p


def _in_range(lo: float, hi: float, idx: int = 0) -> Callable:
    def check(out):
        o = out[idx].double()
        if bool((o < lo).any() | (o > hi).any()):
            got = f"[{float(o.min()):.6g}, {float(o.max()):.6g}]"
            return f"output {idx} outside [{lo}, {hi}]: {got}"
        return None

    return check


def _all_equal(value: float, idx: int = 0, rel: float = 0.0) -> Callable:
    def check(out):
        o = out[idx].double()
        if not bool(((o - value).abs() <= rel * abs(value)).all()):
            return (f"output {idx} expected {value} everywhere, got "
                    f"[{float(o.min()):.6g}, {float(o.max()):.6g}]")
        return None

    return check


def _phase_range(out) -> str | None:
    o = out[0].double()
    if bool((o < 0).any() | (o >= 2 * math.pi).any()):
        return f"phase outside [0, 2π): [{float(o.min())!r}, {float(o.max())!r}]"
    return None


def _wrap_check(r: float) -> Callable:
    def check(out):
        """Depth at the wrap reads ~0 (wrapped) or ~R (just below), nothing in between."""
        d = out[0].double()
        if bool((torch.minimum(d.abs(), (d - r).abs()) > 1e-2).any()):
            got = f"[{float(d.min())}, {float(d.max())}]"
            return f"depth at the wrap neither 0 nor {r:.4f} m: {got}"
        return None

    return check


# -- operators ---------------------------------------------------------------------------------


def _forward(make: Callable, x64: Callable[[int], torch.Tensor]) -> Callable:
    def run(ctx: Ctx):
        A = make(ctx)
        return A(ctx.t(x64(A.n)))

    return run


def _adjoint_pinv(make: Callable, x64: Callable[[int], torch.Tensor]) -> Callable:
    """``(Aᵀy, A⁺y)`` with ``y = A x`` formed in float64 (``A⁺`` only where it is cheap:
    orthonormal rows or a dense Gram of at most 2²⁰ entries)."""

    def run(ctx: Ctx):
        A = make(ctx)
        y = ctx.t(A(x64(A.n)))
        if A.orthonormal_rows or A.m * A.n**2 <= 2**20:
            return A.adjoint(y), A.pinv(y)
        return A.adjoint(y)

    return run


def _operator_cases() -> list[Case]:
    from ..operators import (
        DMDSplit,
        Hadamard,
        PatternOperator,
        gaussian_speckle_patterns,
        random_binary_patterns,
    )

    def had(method, n, **kw):
        return lambda ctx: Hadamard(n, method=method, **kw)

    def split(n, **kw):
        return lambda ctx: DMDSplit(Hadamard(n, **kw))

    def dense(n, m=20):
        return lambda ctx: PatternOperator(
            ctx.r(random_binary_patterns(m, n, generator=_gen(1), dtype=F64))
        )

    def rand_x(n):
        return _rand(2, 1, n, n, seed=n)

    q = {"sr": 0.25}
    edges = {  # edge -> (n, size keywords, x builder)
        "random x, n=4, SR=100%": (4, {}, rand_x),
        "random x, n=256, SR=25%": (256, q, rand_x),
        "constant x = 1, n=256": (256, q, lambda n: torch.ones(1, 1, n, n, dtype=F64)),
        "SR = 1/n² (one pattern), n=8": (8, {"m": 1}, rand_x),
        "SR = 100%, n=8": (8, {}, rand_x),
        "x = 0": (8, q, lambda n: torch.zeros(1, 1, n, n, dtype=F64)),
        "x at 1e-30": (8, q, lambda n: 1e-30 * rand_x(n)),
        "x at 1e30": (8, q, lambda n: 1e30 * rand_x(n)),
    }
    cases = []
    for label, maker in (("Hadamard[matmul]", partial(had, "matmul")),
                         ("Hadamard[kron]", partial(had, "kron")),
                         ("Hadamard[fwht]", partial(had, "fwht")), ("DMDSplit", split)):
        for edge, (n, kw, x64) in edges.items():
            cases.append(Case(f"{label}.forward", edge, _forward(maker(n, **kw), x64), "operator"))
            cases.append(Case(f"{label}.adjoint/pinv", edge, _adjoint_pinv(maker(n, **kw), x64),
                              "operator"))
    for edge in ("random x, n=4, SR=100%", "x = 0", "x at 1e-30", "x at 1e30"):
        n, x64 = edges[edge][0], edges[edge][2]
        cases.append(Case("PatternOperator.forward", edge, _forward(dense(n), x64), "operator"))
        cases.append(Case("PatternOperator.adjoint", edge, lambda ctx, n=n, x64=x64: dense(n)(
            ctx).adjoint(ctx.t(dense(n)(ctx)(x64(n)))), "operator"))
    cases.append(Case("PatternOperator.forward", "SR = 1/n² (one pattern)",
                      _forward(dense(8, m=1), rand_x), "operator"))

    def speckle(ctx):
        return PatternOperator(ctx.r(gaussian_speckle_patterns(
            24, 8, grain=1.0, generator=_gen(2), dtype=F64)))

    cases.append(Case("PatternOperator.forward", "Gaussian speckle patterns (grain 1 px)",
                      _forward(speckle, rand_x), "operator"))
    cases.append(Case("PatternOperator.adjoint", "Gaussian speckle patterns (grain 1 px)",
                      lambda ctx: speckle(ctx).adjoint(ctx.t(speckle(ctx)(rand_x(8)))),
                      "operator"))

    def nan_x(n):
        x = _rand(1, 1, n, n)
        x[..., 0, 0] = math.nan
        return x

    for label, make in (("Hadamard", had("auto", 8, **q)), ("DMDSplit", split(8, **q)),
                        ("PatternOperator", dense(8))):
        cases.append(Case(f"{label}.forward", "NaN in x", _forward(make, nan_x), "operator",
                          expect="error"))
        cases.append(Case(f"{label}.adjoint", "NaN in y", lambda ctx, make=make: make(ctx).adjoint(
            ctx.t(torch.full((1, 1, make(ctx).m), math.nan, dtype=F64))), "operator",
            expect="error"))

    def pinv(ctx, n):
        A = PatternOperator(ctx.r(random_binary_patterns(20, n, generator=_gen(1), dtype=F64)))
        return A.pinv(ctx.t(A(_rand(1, 1, n, n, seed=5))))

    def illcond(ctx):
        A = PatternOperator(ctx.r(illcond_patterns()))
        return A.pinv(ctx.t(A(_rand(1, 1, 8, 8, seed=5))))

    cases.append(Case("PatternOperator.pinv", "random 0/1 patterns, n=4, M=20",
                      partial(pinv, n=4), "recon_illcond"))
    cases.append(Case("PatternOperator.pinv", "ill-conditioned random patterns (κ≈5e4)",
                      illcond, "recon_illcond"))
    return cases


# -- sensor ------------------------------------------------------------------------------------

_F_HZ = 30e6


def _sensor_cases() -> list[Case]:
    from ..sensor import (
        CWToFSensor,
        DMDToSensor,
        Multipath,
        ScatteringMedium,
        camera_rules,
        correlation_taps,
        cw_tof_sensor,
        phasor_from_depth,
        tap_amplitude,
        tap_phase,
        tof_noise,
        unambiguous_range,
    )

    shape = (2, 1, 8, 8)

    def depth_map(seed=11):
        return 1.0 + 3.9 * _rand(*shape, seed=seed)

    def const(v):
        return lambda: torch.full(shape, float(v), dtype=F64)

    def chain(amp64, depth64, **cfg):
        """phasor_from_depth → cw_tof_sensor, real inputs in the column dtype."""
        cfg = {"shot": None, "adc_bits": None, **cfg}

        def run(ctx):
            p = phasor_from_depth(ctx.t(amp64()), ctx.t(depth64()), _F_HZ)
            return cw_tof_sensor(p, freq_hz=_F_HZ, generator=_gen(3), **cfg).depth

        return run

    r = unambiguous_range(_F_HZ)
    mod = "phasor_from_depth→cw_tof_sensor"
    cases = [
        Case(mod, "random depth [1, 4.9] m, a = 100", chain(const(100), depth_map), "depth_m",
             check=_in_range(1.0, 5.0)),
        Case(mod, "all pixels no photon (a = 0 → 5 m)", chain(const(0), depth_map), "depth_m",
             check=_all_equal(5.0)),
        Case(mod, "phase exactly at the wrap (d = c/2f)", chain(const(100), const(r), min_m=0.0),
             "none", check=_wrap_check(r)),
        Case(mod, "amplitude 1e-30", chain(const(1e-30), depth_map), "depth_m"),
        Case(mod, "amplitude 1e30", chain(const(1e30), depth_map), "depth_m"),
        Case(mod, "partly saturated taps (12-bit ADC, a = 1e4)",
             chain(const(1e4), depth_map, adc_bits=12), "depth_m", check=_in_range(1.0, 5.0)),
        Case(mod, "all taps saturated (ambient 1e7 e⁻ → 5 m)",
             chain(const(100), depth_map, adc_bits=12, ambient_e=1e7), "depth_m",
             check=_all_equal(5.0)),
        Case(mod, "extreme noise (SNR < 0 dB)",
             chain(const(4), depth_map, shot="poisson", read_noise_e=20.0, ambient_e=50.0),
             "none", check=_in_range(1.0, 5.0)),
    ]

    def phasor64():
        return phasor_from_depth(100.0 * _rand(*shape, seed=12), depth_map(13), _F_HZ)

    def zero_phasor():
        return torch.zeros(shape, dtype=torch.complex128)

    def on_phasor(make, p64):
        return lambda ctx: make()(ctx.c(p64()))

    sensor = partial(CWToFSensor, shot=None, adc_bits=None)
    cases += [
        Case("CWToFSensor", "random phasors (complex in)",
             lambda ctx: sensor()(ctx.c(phasor64())).depth, "depth_m", complex_in=True),
        Case("CWToFSensor", "all pixels no photon (P = 0)",
             lambda ctx: sensor()(ctx.c(zero_phasor())).depth, "depth_m", complex_in=True,
             check=_all_equal(5.0)),
    ]

    def taps64(scale):
        return lambda: scale * correlation_taps(phasor64(), offset=60.0)

    def fixed(values):
        return lambda: torch.tensor(values, dtype=F64).view(1, 4, 1, 1)

    tap_edges = {
        "random taps": taps64(1.0),
        "zero taps": lambda: torch.zeros(1, 4, 4, 4, dtype=F64),
        "constant taps (c1=c2=c3=c4)": lambda: torch.full((1, 4, 4, 4), 7.0, dtype=F64),
        "taps at 1e-30": taps64(1e-30),
        "taps at 1e30": taps64(1e30),
        "saturated taps (all 4095 DN)": lambda: torch.full((1, 4, 4, 4), 4095.0, dtype=F64),
        "phase exactly at the wrap (c4 − c3 = −0)": fixed([5.0, 1.0, 3.0, 3.0]),
        "phase just below the wrap (c4 − c3 = −1e-6)": fixed([5.0, 1.0, 3.0, 3.0 - 1e-6]),
    }
    for edge, t64 in tap_edges.items():
        cases.append(Case("tap_phase", edge, lambda ctx, t64=t64: tap_phase(ctx.t(t64())),
                          "phase_rad", check=_phase_range))
        cases.append(Case("tap_amplitude", edge,
                          lambda ctx, t64=t64: tap_amplitude(ctx.t(t64())), "sensor"))

    def rules(ctx):
        d = torch.tensor([0.3, 1.0, 2.124, 2.125, 4.99, 5.0, 7.0, 3.0], dtype=F64)
        a = torch.tensor([1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 0.0], dtype=F64)
        return camera_rules(ctx.t(d.view(1, 1, 2, 4)), ctx.t(a.view(1, 1, 2, 4)), step_m=0.25)

    cases.append(Case("camera_rules", "clip to [1, 5] m, 0.25 m step, dark pixel", rules,
                      "depth_m"))

    def noise(scale, offset=0.0, **cfg):
        return lambda ctx: tof_noise(ctx.t(offset + scale * _rand(1, 4, 8, 8, seed=13)),
                                     generator=_gen(4), **cfg)

    cases += [
        Case("tof_noise", "saturated taps (full well 2e4 e⁻, 12-bit ADC)",
             noise(1e4, 3e4, shot=None, full_well_e=2e4, adc_bits=12), "sensor",
             check=_all_equal(4095.0, rel=1e-3)),
        Case("tof_noise", "extreme noise (Poisson + 50 e⁻ read noise on 2 e⁻)",
             noise(2.0, shot="poisson", read_noise_e=50.0, adc_bits=12), "none",
             check=_in_range(0.0, 4096.0)),
    ]
    for alpha in (1e-3, 0.5, 1.0):
        cases.append(Case("ScatteringMedium[depth]", f"α = {alpha:g}, all pixels 5 m",
                          lambda ctx, a=alpha: ScatteringMedium(a, size=(8, 8))(
                              ctx.t(torch.full(shape, 5.0, dtype=F64))), "sensor"))
        cases.append(Case("ScatteringMedium[phasor]", f"α = {alpha:g}, random phasors",
                          on_phasor(partial(ScatteringMedium, alpha, "phasor", size=(8, 8),
                                            backscatter_e=20.0), phasor64),
                          "sensor", complex_in=True))
    multipath = partial(Multipath, 0.3, 0.7, _F_HZ, blur_sigma=1.0)
    cases += [
        Case("Multipath", "random phasors", on_phasor(multipath, phasor64), "sensor",
             complex_in=True),
        Case("Multipath", "all pixels no photon (P = 0)", on_phasor(multipath, zero_phasor),
             "sensor", complex_in=True),
        Case("DMDToSensor", "8×8 → 12×12 (mixed pixels)",
             on_phasor(partial(DMDToSensor, 8, 12), phasor64), "sensor", complex_in=True),
    ]
    return cases


# -- buckets and metrics -----------------------------------------------------------------------


def _bucket_cases() -> list[Case]:
    from ..bucket import depth_bucket, intensity_bucket, tap_buckets

    def five():
        return torch.full((1, 4, 64, 64), 5.0, dtype=F64)

    return [
        Case("depth_bucket", "all pixels no photon, 64×64 ROI",
             lambda ctx: depth_bucket(ctx.t(five())), "bucket", check=_all_equal(5.0 * 4096)),
        Case("depth_bucket", "all pixels no photon, 3 m gate",
             lambda ctx: depth_bucket(ctx.t(five()), gate_m=3.0), "bucket",
             check=_all_equal(0.0)),
        Case("intensity_bucket", "amplitude at 1e-30",
             lambda ctx: intensity_bucket(ctx.t(1e-30 * _rand(1, 4, 16, 16))), "bucket"),
        Case("intensity_bucket", "amplitude at 1e30",
             lambda ctx: intensity_bucket(ctx.t(1e30 * _rand(1, 4, 16, 16))), "bucket"),
        Case("tap_buckets", "saturated taps (4095 DN), 64×64 ROI",
             lambda ctx: tap_buckets(ctx.t(torch.full((1, 2, 4, 64, 64), 4095.0, dtype=F64))),
             "bucket"),
        Case("depth_bucket", "NaN depth", lambda ctx: depth_bucket(
            ctx.t(torch.full((1, 2, 4, 4), math.nan, dtype=F64))), "bucket", expect="error"),
    ]


def _metric_cases() -> list[Case]:
    from ..metrics import compare, depth_rmse

    def cmp(x_hat64, polarity="positive"):
        def run(ctx):
            s = compare(ctx.t(x_hat64()), ctx.t(scene(16)), polarity=polarity, bits=None)
            return s["psnr"], s["ssim"]

        return run

    def noisy():
        return scene(16) + 0.2 * _randn(1, 1, 16, 16, seed=21)

    cap = _all_equal(100.0, rel=1e-6)
    return [
        Case("compare (PSNR/SSIM)", "noisy image", cmp(noisy), "metric"),
        Case("compare (PSNR/SSIM)", "image at 1e-30", cmp(lambda: 1e-30 * noisy()), "metric"),
        Case("compare (PSNR/SSIM)", "image at 1e30", cmp(lambda: 1e30 * noisy()), "metric"),
        Case("compare (PSNR/SSIM)", "constant image",
             cmp(lambda: torch.full((1, 1, 16, 16), 3.0, dtype=F64)), "metric"),
        Case("compare (PSNR/SSIM)", "identical images (100 dB cap)", cmp(lambda: scene(16)),
             "metric", check=cap),
        Case("compare (PSNR/SSIM)", "negative depth image 5 − 3x (100 dB cap)",
             cmp(lambda: 5.0 - 3.0 * scene(16), "negative"), "metric", check=cap),
        Case("depth_rmse", "no-photon map (5 m) vs 2 m object",
             lambda ctx: depth_rmse(ctx.t(torch.full((1, 1, 8, 8), 5.0, dtype=F64)),
                                    ctx.t(2.0 + scene(8))), "depth_m"),
    ]


# -- reconstructors ----------------------------------------------------------------------------

#: Fast DIP settings for the matrix (the fit is the cost; the numerics are those of 300 steps).
# zeta=0: with the TV term, 20-step float32 and float64 fits on tiny fully sampled scenes
# diverge chaotically (0.02–6 dB apart); the matrix tests arithmetic, not the prior
DIP_FAST = {"max_iter": 20, "zeta": 0.0}
#: Iteration cap of basis pursuit in the matrix (the ill-conditioned rows never converge).
BP_FAST = {"n_iter": 300}


def _recon_makers() -> dict[str, tuple[bool, str, Callable]]:
    """name -> (uses the 0/1 DMD split operator, tolerance family, factory(A) -> module).

    Imports are lazy, so a reconstructor that fails to import fails its own rows only.
    """

    def make(name, **options):
        def build(A):
            from ..recon import registry

            return registry.get(name).module(A, **options)

        return build

    return {
        "CGI": (True, "recon_direct", make("CGI")),
        "TGI": (True, "recon_direct", make("TGI")),
        "DGI": (True, "recon_direct", make("DGI")),
        "PseudoInverse": (False, "recon_direct", make("pinv")),
        "TVAL3": (False, "recon_iterative", make("tval3")),
        "BasisPursuit": (False, "recon_iterative", make("bp", **BP_FAST)),
        "UnrolledTVAL3": (False, "recon_iterative", make("unrolled", pretrained=False)),
        "DIP": (False, "recon_dip", make("dip", **DIP_FAST)),
    }


def _recon_edges() -> dict[str, dict]:
    """edge -> spec: ``n``, ``sr``/``m``, ``x`` (scene builder), ``y`` (transform of ``A x``),
    ``op`` (``"illcond"`` for dense ill-conditioned patterns), ``expect``."""

    def k(n):  # ToF pixels per DMD pixel of the paper's 64×64 ROI
        return (64 / n) ** 2

    def depth(alpha):
        """Per-DMD-pixel depth sums (Eq. 15, Dˢ = 1 m for α < 1): 5 m where the object is
        not, 2 m on it; condition factor offset / contrast = (5α + Dˢ) / 3α."""
        ds = 1.0 if alpha < 1 else 0.0
        return {"x": lambda n: k(n) * (alpha * (5.0 - 3.0 * scene(n)) + ds),
                "cond": (5 * alpha + ds) / (3 * alpha)}

    def snr_minus6(y):
        sig = y.norm() / y.numel() ** 0.5
        return y + sig * 10 ** (6 / 20) * _randn(*y.shape, seed=17)

    def nan(y):
        y = y.clone()
        y[..., 0] = math.nan
        return y

    return {
        "binary object, n=8, SR=50%": {},
        "zero buckets": {"y": torch.zeros_like, "expect": "any"},
        "constant buckets": {"y": lambda y: torch.full_like(y, 3.0), "expect": "any"},
        "buckets at 1e-30": {"y": lambda y: 1e-30 * y},
        "buckets at 1e30": {"y": lambda y: 1e30 * y},
        "ungated depth buckets (5 m offset, α = 1)": depth(1.0),
        "scattered depth, α = 0.5": depth(0.5),
        "scattered depth, α = 1e-3": depth(1e-3),
        "n=4, SR=100%": {"n": 4, "sr": 1.0},
        "SR = 1/n² (one pattern)": {"m": 1, "expect": "any"},
        "SR = 100%": {"sr": 1.0},
        "extreme noise (SNR = −6 dB)": {"y": snr_minus6},
        "ill-conditioned random patterns (κ≈5e4)": {"op": "illcond", "expect": "any"},
        "NaN in buckets": {"y": nan, "expect": "error"},
    }


def _recon_run(make: Callable, split: bool, spec: dict, with_truth: bool = False) -> Callable:
    """Row runner: build ``A`` and the buckets in float64, reconstruct in the cell's dtype
    (``with_truth``: also return the object, for the PSNR-gap metric)."""
    from ..operators import DMDSplit, Hadamard, PatternOperator

    n = spec.get("n", 8)

    def run(ctx: Ctx) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        if spec.get("op") == "illcond":
            A = PatternOperator(ctx.r(illcond_patterns(n=n)))
        else:
            A = Hadamard(n, **({"m": spec["m"]} if "m" in spec else {"sr": spec.get("sr", 0.5)}))
            A = DMDSplit(A) if split else A
        y = spec.get("y", lambda v: v)(A(spec.get("x", scene)(n)))
        x_hat = make(A)(ctx.t(y))
        return (x_hat, ctx.t(scene(n))) if with_truth else x_hat

    return run


def _unrolled_shipped(ctx: Ctx) -> torch.Tensor:
    from ..operators import Hadamard
    from ..recon.unrolled import UnrolledTVAL3

    A = Hadamard(32, sr=0.25)
    return UnrolledTVAL3(A, pretrained=True)(ctx.t(A(scene(32))))


def _recon_cases() -> list[Case]:
    cases = []
    for name, (split, family, make) in _recon_makers().items():
        for edge, spec in _recon_edges().items():
            fam = "recon_illcond" if spec.get("op") == "illcond" and name == "PseudoInverse" \
                else family
            run = _recon_run(make, split, spec, with_truth=fam == "recon_dip")
            cases.append(Case(name, edge, run, fam,
                              expect=spec.get("expect", "ok"), cond=spec.get("cond", 1.0)))
    cases.append(Case("UnrolledTVAL3", "shipped weights (n=32, SR=25%)", _unrolled_shipped,
                      "recon_iterative"))
    return cases


# -- the whole chain ----------------------------------------------------------------------------


def _experiment_cases() -> list[Case]:
    """The paper's experiment (scene → DMD → sensor → buckets) at a tiny size, in air and
    through the sheet with α ∈ {1e-3, 0.5, 1}: finite buckets, raw ToF depth in [1, 5] m
    (noise draws differ between dtypes: no float64 comparison)."""

    def run(ctx: Ctx, **cfg) -> tuple[torch.Tensor, ...]:
        from ..experiment import PaperExperiment

        exp = PaperExperiment(sr=0.25, n=8, roi_px=16, srs=(0.25,), **cfg)
        data = exp.run(seed=0, realisations=1, dtype=ctx.compute)
        return (data.raw_tof_image, *data.buckets.values())

    cases = [Case("PaperExperiment", "air, n=8, 16×16 ROI", run, "none",
                  check=_in_range(1.0, 5.0))]
    for alpha in (1e-3, 0.5, 1.0):
        cases.append(Case("PaperExperiment", f"scattering sheet α = {alpha:g}",
                          partial(run, scattering=True, alpha=alpha), "none",
                          check=_in_range(1.0, 5.0)))
    return cases


# -- the matrix --------------------------------------------------------------------------------


def stability_cases() -> list[Case]:
    """Every row of the matrix, in print order (operators, sensor, buckets, metrics, recon,
    the whole experiment)."""
    return (_operator_cases() + _sensor_cases() + _bucket_cases() + _metric_cases()
            + _recon_cases() + _experiment_cases())


def bench_stability(cases: list[Case] | None = None, progress: bool = False) -> dict:
    """Build the stress matrix (module docstring): one row per case, one cell per dtype.

    Args:
        cases: rows to run (default: :func:`stability_cases`).
        progress: show a progress bar over the rows (stderr).

    Returns:
        JSON-able dict: ``rows`` (see :func:`evaluate_case`), ``counts`` per dtype and status,
        ``tolerances`` (family -> metric and per-dtype tolerance), ``time_s``, ``torch``.

    Example:
        >>> res = bench_stability([c for c in stability_cases() if c.module == "camera_rules"])
        >>> res["counts"]["float32"]["ok"], res["counts"]["float16"]["FAIL"]
        (1, 0)
    """
    t0 = time.perf_counter()
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # tiny problems: two contending threads are ~10x slower
    try:
        todo = stability_cases() if cases is None else cases
        bar = progress_bar(todo, desc="stability rows", disable=not progress, leave=False)
        rows = [evaluate_case(c) for c in bar]
    finally:
        torch.set_num_threads(threads)
    counts = {
        NAMES[dt]: {s: sum(r["cells"][NAMES[dt]]["status"] == s for r in rows) for s in STATUSES}
        for dt in DTYPES
    }
    tolerances = {
        fam: {"metric": metric, **{NAMES[dt]: tol for dt, tol in tols.items()}}
        for fam, (metric, tols) in TOLERANCES.items()
    }
    return {
        "benchmark": "stability",
        "dtypes": [NAMES[dt] for dt in DTYPES],
        "rows": rows,
        "counts": counts,
        "tolerances": tolerances,
        "time_s": time.perf_counter() - t0,
        "torch": torch.__version__,
    }
