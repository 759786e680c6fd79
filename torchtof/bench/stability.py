"""``torchtof bench stability``: the numerical stress matrix of every public module.

Rows are ``(module, edge case)``, columns the dtypes float16, bfloat16, float32, float64.
Every cell runs the module on inputs built in float64 and rounded to the column's dtype,
then classifies the outcome:

- ``ok``: every output is finite, keeps the input's dtype, passes the row's known-answer
  check (if any) and — for float32/float16/bfloat16 — lies within the documented tolerance
  of the float64 result computed **on the same rounded inputs** (so the comparison measures
  the arithmetic, not the rounding of the inputs);
- ``error``: a clear error — ``ValueError``/``TypeError`` whose message starts with the
  function or class name (``"tval3: expected y of dtype float32 or float64, got
  torch.float16"``). It is the intended outcome for non-finite inputs and for dtypes a module
  does not support; it is a failure for a supported dtype (float32/float64) on valid input;
- ``n/a``: no such input exists (torch has no complex bfloat16, so phasor-domain modules
  have no bfloat16 column);
- ``FAIL``: a silent NaN/Inf, a result outside the tolerance, a changed dtype, a failed
  known-answer check, an error where a result was due, or an unclear exception
  (``RuntimeError``/``NotImplementedError`` from inside torch, a message without the name).

Tolerances (``TOLERANCES``; metric against the float64 result on the same inputs):

==================  ============================  ========  ========  ========
family              metric                        float32   float16   bfloat16
==================  ============================  ========  ========  ========
operator            relative L2                   1e-5      4e-3      3e-2
sensor              relative L2 (taps, phasors)   1e-5      4e-3      3e-2
depth_m             max abs error, metres         1e-4      2e-2      1e-1
phase_rad           max circular error, rad       1e-5      4e-3      3e-2
bucket              relative L2                   1e-6      1e-3      1e-2
metric              max abs (dB, SSIM units)      1e-3      5e-2      5e-1
recon_direct        relative L2 (CGI/TGI/DGI/A⁺)  1e-4      2e-2      1e-1
recon_illcond       relative L2 (A⁺ y, κ ≈ 1e3)   1e-2      —         —
recon_iterative     relative L2 (TVAL3, BP, K-TV) 1e-3      5e-2      2e-1
recon_dip           relative L2 (fitted DIP)      5e-2      —         —
none                no comparison (random draws)  —         —         —
==================  ============================  ========  ========  ========

A ``—`` means the family has no tolerance for that dtype: its modules must raise a clear
error there (``recon_illcond`` and ``recon_dip`` are not posed in half precision). An
all-zero float64 result must be matched exactly (no tolerance).

Rows cover the operators (Hadamard matmul/fwht, DMD split, dense patterns), the sensor
(phasor→taps→phase/amplitude/depth, camera rules, noise/ADC, scattering in depth and phasor
form with α ∈ {1e-3, 0.5, 1}, multipath, DMD→sensor mixing), the buckets, the metrics and
every reconstructor that is importable (CGI, TGI, DGI, pseudo-inverse, TVAL3, basis pursuit,
unrolled TVAL3, DIP) on the edge cases of the stress issue: zero and constant buckets,
buckets at 1e-30 and 1e30, all pixels "no photon" (depth 5 m), saturated taps, phase exactly
at the wrap-around, n = 4 and n = 256 (operators), SR = 1/n² and 100 %, SNR < 0 dB,
ill-conditioned random patterns, NaN inputs. ``tests/stress`` asserts that no cell fails.
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

__all__ = [
    "DTYPES",
    "TOLERANCES",
    "Case",
    "Ctx",
    "stability_cases",
    "evaluate_case",
    "bench_stability",
    "print_stability",
]

F16, BF16, F32, F64 = torch.float16, torch.bfloat16, torch.float32, torch.float64
DTYPES: tuple[torch.dtype, ...] = (F16, BF16, F32, F64)
_NAME = {F16: "float16", BF16: "bfloat16", F32: "float32", F64: "float64"}
_COMPLEX = {F16: torch.complex32, F32: torch.complex64, F64: torch.complex128}
_HALF = (F16, BF16)

#: family -> (metric, {dtype: tolerance}); see the module docstring.
TOLERANCES: dict[str, tuple[str, dict[torch.dtype, float]]] = {
    "operator": ("rel", {F32: 1e-5, F16: 4e-3, BF16: 3e-2}),
    "sensor": ("rel", {F32: 1e-5, F16: 4e-3, BF16: 3e-2}),
    "depth_m": ("abs", {F32: 1e-4, F16: 2e-2, BF16: 1e-1}),
    "phase_rad": ("circ", {F32: 1e-5, F16: 4e-3, BF16: 3e-2}),
    "bucket": ("rel", {F32: 1e-6, F16: 1e-3, BF16: 1e-2}),
    "metric": ("abs", {F32: 1e-3, F16: 5e-2, BF16: 5e-1}),
    "recon_direct": ("rel", {F32: 1e-4, F16: 2e-2, BF16: 1e-1}),
    "recon_illcond": ("rel", {F32: 1e-2}),
    "recon_iterative": ("rel", {F32: 1e-3, F16: 5e-2, BF16: 2e-1}),
    "recon_dip": ("rel", {F32: 5e-2}),
    "none": ("none", {}),
}

_CLEAR = re.compile(r"^[A-Za-z_][\w.\[\]]*: ")


class Ctx:
    """Inputs of one cell: tensors built in float64, rounded through ``dtype`` and handed to
    the module in ``compute`` (``compute == dtype`` for the cell itself, float64 for its
    reference)."""

    def __init__(self, dtype: torch.dtype, compute: torch.dtype) -> None:
        self.dtype, self.compute = dtype, compute

    def t(self, x: torch.Tensor) -> torch.Tensor:
        """A real float64 tensor rounded to ``dtype``, in ``compute``."""
        return x.to(self.dtype).to(self.compute)

    def r(self, x: torch.Tensor) -> torch.Tensor:
        """Rounded to ``dtype`` but kept in float64 (operator patterns, stored as given)."""
        return x.to(self.dtype).to(F64)

    def c(self, p: torch.Tensor) -> torch.Tensor:
        """A complex128 tensor rounded to ``dtype``, as the complex dtype of ``compute``."""
        return p.to(_COMPLEX[self.dtype]).to(_COMPLEX[self.compute])


@dataclass(frozen=True)
class Case:
    """One row of the matrix.

    Attributes:
        module: public module/function under test (row label).
        edge: the edge case (row label).
        run: ``run(ctx) -> tensor or tuple of tensors``; builds its inputs with ``ctx``.
        family: tolerance family (key of :data:`TOLERANCES`).
        expect: ``"ok"`` (float32/float64 must compute; half precision may raise a clear
            error), ``"error"`` (every dtype must raise a clear error) or ``"any"``.
        check: optional known-answer check ``check(outputs, ctx) -> message or None``.
        complex_in: the module takes complex phasors (no bfloat16 column).
    """

    module: str
    edge: str
    run: Callable[[Ctx], torch.Tensor | tuple[torch.Tensor, ...]]
    family: str
    expect: str = "ok"
    check: Callable[[tuple[torch.Tensor, ...], Ctx], str | None] | None = None
    complex_in: bool = False

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


def _distance(out: tuple, ref: tuple, metric: str) -> float:
    worst = 0.0
    for o, r in zip(out, ref):
        o, r = _real64(o), _real64(r)
        if o.shape != r.shape:
            return math.inf
        if metric == "rel":
            rn = float(r.norm())
            e = float((o - r).norm()) / rn if rn > 0 else (0.0 if float(o.norm()) == 0 else math.inf)
        elif metric == "abs":
            e = float((o - r).abs().max()) if o.numel() else 0.0
        else:  # circular distance of phases in radians
            d = torch.remainder(o - r, 2 * math.pi)
            e = float(torch.minimum(d, 2 * math.pi - d).max()) if o.numel() else 0.0
        worst = max(worst, e)
    return worst


def _cell(case: Case, dtype: torch.dtype) -> dict:
    name = _NAME[dtype]
    if case.complex_in and dtype not in _COMPLEX:
        return {"status": "n/a", "detail": f"torch has no complex {name} dtype"}
    ctx = Ctx(dtype, dtype)
    try:
        out = _call(case, ctx)
    except (ValueError, TypeError) as e:
        msg = str(e).splitlines()[0] if str(e) else type(e).__name__
        if not _CLEAR.match(msg):
            return {"status": "FAIL", "detail": f"unclear {type(e).__name__}: {msg[:160]}"}
        if case.expect == "ok" and dtype not in _HALF:
            return {"status": "FAIL", "detail": f"error on valid {name} input: {msg[:160]}"}
        return {"status": "error", "detail": msg[:160]}
    except Exception as e:  # noqa: BLE001 - any other exception is a finding
        msg = str(e).splitlines()[0] if str(e) else ""
        return {"status": "FAIL", "detail": f"unclear {type(e).__name__}: {msg[:160]}"}
    if case.expect == "error":
        return {"status": "FAIL", "detail": "expected a clear error, got a result"}
    for k, o in enumerate(out):
        if o.is_floating_point() or o.is_complex():
            bad = ~torch.isfinite(o)
            if bool(bad.any()):
                n_nan = int(torch.isnan(o).sum())
                return {
                    "status": "FAIL",
                    "detail": f"silent NaN/Inf in output {k} ({n_nan} NaN, "
                    f"{int(bad.sum()) - n_nan} Inf of {o.numel()})",
                }
            want = _COMPLEX[dtype] if o.is_complex() else dtype
            if o.dtype != want:
                return {"status": "FAIL", "detail": f"output {k} has dtype {o.dtype}, not {want}"}
    if case.check is not None:
        msg = case.check(out, ctx)
        if msg:
            return {"status": "FAIL", "detail": f"check: {msg}"}
    metric, tols = TOLERANCES[case.family]
    if dtype == F64 or metric == "none":
        return {"status": "ok", "detail": ""}
    if dtype not in tols:
        return {"status": "FAIL", "detail": f"no {name} tolerance for {case.family}: expected a "
                "clear error"}
    try:
        ref = _call(case, Ctx(dtype, F64))
    except Exception as e:  # noqa: BLE001
        return {"status": "FAIL", "detail": f"float64 reference failed: {type(e).__name__}: {e}"}
    err = _distance(out, ref, metric)
    tol = tols[dtype]
    if not err <= tol:
        return {"status": "FAIL", "detail": f"{metric} error {err:.3g} vs float64 > tol {tol:g}",
                "err": err, "tol": tol}
    return {"status": "ok", "detail": "", "err": err, "tol": tol}


def evaluate_case(case: Case) -> dict:
    """Run one row in every dtype: ``{"id", "module", "edge", "family", "cells": {dtype: …}}``."""
    return {
        "id": case.id,
        "module": case.module,
        "edge": case.edge,
        "family": case.family,
        "cells": {_NAME[dt]: _cell(case, dt) for dt in DTYPES},
    }


# -- inputs --------------------------------------------------------------------------------------


def _gen(seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def _rand(*shape: int, seed: int = 0) -> torch.Tensor:
    return torch.rand(shape, generator=_gen(seed), dtype=F64)


def _randn(*shape: int, seed: int = 0) -> torch.Tensor:
    return torch.randn(shape, generator=_gen(seed), dtype=F64)


def _object(n: int) -> torch.Tensor:
    """A binary T-shaped object ``(1, 1, n, n)`` (a stand-in for the paper's 天)."""
    x = torch.zeros(1, 1, n, n, dtype=F64)
    q = max(n // 4, 1)
    x[..., q, q : n - q] = 1.0
    x[..., q : n - q, n // 2 - max(n // 8, 1) + 1 : n // 2 + 1] = 1.0
    return x


def _illcond_patterns(m: int = 24, n: int = 8, gap: float = 1e-3) -> torch.Tensor:
    """Random 0/1 patterns with one row a near copy of another: ``κ(A) ≈ 1/gap``."""
    from ..operators import random_binary_patterns

    p = random_binary_patterns(m, n, generator=_gen(7), dtype=F64)
    p[-1] = p[0] + gap * (p[1] - p[2])
    return p


def _finite_range(lo: float, hi: float, idx: int = 0) -> Callable:
    def check(out, ctx):
        o = out[idx].double()
        if bool((o < lo).any() | (o > hi).any()):
            return f"output {idx} outside [{lo}, {hi}]: [{float(o.min()):.4g}, {float(o.max()):.4g}]"
        return None

    return check


def _all_equal(value: float, idx: int = 0, rel: float = 0.0) -> Callable:
    def check(out, ctx):
        o = out[idx].double()
        if not bool(((o - value).abs() <= rel * abs(value)).all()):
            return f"output {idx} expected {value} everywhere, got [{float(o.min()):.6g}, " \
                   f"{float(o.max()):.6g}]"
        return None

    return check


def _phase_range(idx: int = 0) -> Callable:
    def check(out, ctx):
        o = out[idx].double()
        if bool((o < 0).any() | (o >= 2 * math.pi).any()):
            return f"phase outside [0, 2π): [{float(o.min())!r}, {float(o.max())!r}]"
        return None

    return check


# -- operators ---------------------------------------------------------------------------------


def _op_row(make: Callable[[Ctx], object], x64: Callable[[int], torch.Tensor]):
    """``(A x, Aᵀ y, A⁺ y)`` of the operator ``make(ctx)``, ``y = A x`` formed in float64."""

    def run(ctx: Ctx):
        A = make(ctx)
        x = x64(A.n)
        y = A(x)
        return A(ctx.t(x)), A.adjoint(ctx.t(y)), A.pinv(ctx.t(y))

    return run


def _operator_cases() -> list[Case]:
    from ..operators import DMDSplit, Hadamard, PatternOperator, random_binary_patterns

    def had(method, n, **kw):
        return lambda ctx: Hadamard(n, method=method, **kw)

    def split(n, **kw):
        return lambda ctx: DMDSplit(Hadamard(n, **kw))

    def dense(n=8, m=20):
        return lambda ctx: PatternOperator(
            ctx.r(random_binary_patterns(m, n, generator=_gen(1), dtype=F64))
        )

    def rand_x(n):
        return _rand(2, 1, n, n, seed=n)

    def nan_x(n):
        x = _rand(1, 1, n, n)
        x[..., 0, 0] = math.nan
        return x

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
                         ("Hadamard[fwht]", partial(had, "fwht")), ("DMDSplit", split)):
        for edge, (n, kw, x64) in edges.items():
            cases.append(Case(label, edge, _op_row(maker(n, **kw), x64), "operator"))
    for edge in ("random x, n=4, SR=100%", "x = 0", "x at 1e-30", "x at 1e30"):
        cases.append(Case("PatternOperator", edge, _op_row(dense(n=8 if "n=4" not in edge else 4),
                                                           edges[edge][2]), "operator"))
    cases.append(Case("PatternOperator", "SR = 1/n² (one pattern)", _op_row(dense(m=1), rand_x),
                      "operator"))
    for label, make in (("Hadamard", had("auto", 8, **q)), ("DMDSplit", split(8, **q)),
                        ("PatternOperator", dense())):
        cases.append(Case(label, "NaN in x (forward)",
                          lambda ctx, make=make: make(ctx)(ctx.t(nan_x(8))), "operator",
                          expect="error"))
        cases.append(Case(label, "NaN in y (adjoint)", lambda ctx, make=make: make(ctx).adjoint(
            ctx.t(torch.full((1, 1, make(ctx).m), math.nan, dtype=F64))), "operator",
            expect="error"))

    def illcond(ctx):
        A = PatternOperator(ctx.r(_illcond_patterns()))
        return A.pinv(ctx.t(A(_rand(1, 1, 8, 8, seed=5))))

    cases.append(Case("PatternOperator.pinv", "ill-conditioned random patterns (κ≈1e3)",
                      illcond, "recon_illcond"))
    return cases


# -- sensor ------------------------------------------------------------------------------------

_F_HZ = 30e6


def _range_m() -> float:
    from ..sensor import unambiguous_range

    return unambiguous_range(_F_HZ)


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
    )

    def depth_map(seed=11, shape=(2, 1, 8, 8)):
        return 1.0 + 3.9 * _rand(*shape, seed=seed)

    def chain(amp64, depth64, **cfg):
        """phasor_from_depth → cw_tof_sensor, inputs real in the column dtype."""
        cfg = {"shot": None, "adc_bits": None, **cfg}

        def run(ctx):
            p = phasor_from_depth(ctx.t(amp64()), ctx.t(depth64()), _F_HZ)
            f = cw_tof_sensor(p, freq_hz=_F_HZ, generator=_gen(3), **cfg)
            return f.depth, f.amplitude

        return run

    amp = lambda v: (lambda: torch.full((2, 1, 8, 8), float(v), dtype=F64))  # noqa: E731
    r = _range_m()
    cases = [
        Case("phasor_from_depth→cw_tof_sensor", "random depth [1, 4.9] m, a = 100",
             chain(amp(100), depth_map), "depth_m", check=_finite_range(1.0, 5.0)),
        Case("phasor_from_depth→cw_tof_sensor", "all pixels no photon (a = 0 → 5 m)",
             chain(amp(0), depth_map), "depth_m", check=_all_equal(5.0)),
        Case("phasor_from_depth→cw_tof_sensor", "phase exactly at the wrap (d = c/2f)",
             chain(amp(100), lambda: torch.full((1, 1, 4, 4), r, dtype=F64), min_m=0.0),
             "none", check=lambda out, ctx: _wrap_check(out[0], r)),
        Case("phasor_from_depth→cw_tof_sensor", "amplitude 1e-30",
             chain(amp(1e-30), depth_map), "depth_m"),
        Case("phasor_from_depth→cw_tof_sensor", "amplitude 1e30",
             chain(amp(1e30), depth_map), "depth_m"),
        Case("phasor_from_depth→cw_tof_sensor", "saturated taps (12-bit ADC, a = 1e6)",
             chain(amp(1e6), depth_map, adc_bits=12), "depth_m", check=_all_equal(5.0)),
        Case("phasor_from_depth→cw_tof_sensor", "extreme noise (SNR < 0 dB)",
             chain(amp(4), depth_map, shot="poisson", read_noise_e=20.0, ambient_e=50.0),
             "none", check=_finite_range(1.0, 5.0)),
    ]

    def phasor64(shape=(2, 1, 8, 8), seed=12, scale=100.0):
        d = depth_map(seed, shape)
        return phasor_from_depth(scale * _rand(*shape, seed=seed + 1), d, _F_HZ)

    def module_run(make, p64):
        return lambda ctx: make()(ctx.c(p64()))

    cases.append(Case("CWToFSensor", "random phasors (complex in)",
                      lambda ctx: CWToFSensor(shot=None, adc_bits=None)(ctx.c(phasor64())).depth,
                      "depth_m", complex_in=True))
    cases.append(Case("CWToFSensor", "all pixels no photon (P = 0)",
                      lambda ctx: CWToFSensor(shot=None, adc_bits=None)(
                          ctx.c(torch.zeros(1, 1, 4, 4, dtype=torch.complex128))).depth,
                      "depth_m", complex_in=True, check=_all_equal(5.0)))

    # taps -> phase / amplitude (Eqs. 7-8) on real taps
    def taps64(scale=1.0, offset=0.0):
        return lambda: scale * correlation_taps(phasor64(), offset=offset)

    tap_edges = {
        "random taps": taps64(),
        "zero taps": lambda: torch.zeros(1, 4, 4, 4, dtype=F64),
        "constant taps (c1=c2=c3=c4)": lambda: torch.full((1, 4, 4, 4), 7.0, dtype=F64),
        "taps at 1e-30": taps64(1e-30),
        "taps at 1e30": taps64(1e30),
        "saturated taps (all 4095 DN)": lambda: torch.full((1, 4, 4, 4), 4095.0, dtype=F64),
        "phase exactly at the wrap (c4−c3 = −0)": lambda: torch.tensor(
            [5.0, 1.0, 3.0, 3.0 - 1e-300], dtype=F64).view(1, 4, 1, 1),
        "phase just below the wrap (c4−c3 = −1e-6)": lambda: torch.tensor(
            [5.0, 1.0, 3.0, 3.0 - 1e-6], dtype=F64).view(1, 4, 1, 1),
    }
    for edge, t64 in tap_edges.items():
        cases.append(Case("tap_phase", edge, lambda ctx, t64=t64: tap_phase(ctx.t(t64())),
                          "phase_rad", check=_phase_range()))
        cases.append(Case("tap_amplitude", edge,
                          lambda ctx, t64=t64: tap_amplitude(ctx.t(t64())), "sensor"))

    def rules(ctx):
        d = ctx.t(torch.tensor([0.3, 1.0, 2.124, 2.125, 4.99, 5.0, 7.0, 3.0]).view(1, 1, 2, 4))
        a = ctx.t(torch.tensor([1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 0.0]).view(1, 1, 2, 4))
        return camera_rules(d, a, step_m=0.25)

    cases.append(Case("camera_rules", "clip [1, 5] m, 0.25 m step, dark pixel",
                      rules, "depth_m"))

    def noise(cfg, scale):
        return lambda ctx: tof_noise(ctx.t(scale * _rand(1, 4, 8, 8, seed=13)),
                                     generator=_gen(4), **cfg)

    cases.append(Case("tof_noise", "saturated taps (full well + 12-bit ADC)",
                      noise({"shot": None, "full_well_e": 2e4, "adc_bits": 12}, 1e6), "sensor",
                      check=_all_equal(4095.0, rel=1e-3)))
    cases.append(Case("tof_noise", "extreme noise (Poisson + read 50 e⁻ on 2 e⁻)",
                      noise({"shot": "poisson", "read_noise_e": 50.0, "adc_bits": 12}, 2.0),
                      "none", check=_finite_range(0.0, 4095.0)))

    for alpha in (1e-3, 0.5, 1.0):
        cases.append(Case("ScatteringMedium[depth]", f"α = {alpha:g}, all pixels 5 m",
                          lambda ctx, a=alpha: ScatteringMedium(a, size=(8, 8))(
                              ctx.t(torch.full((2, 1, 8, 8), 5.0, dtype=F64))), "sensor"))
        cases.append(Case("ScatteringMedium[phasor]", f"α = {alpha:g}, random phasors",
                          module_run(lambda a=alpha: ScatteringMedium(
                              a, "phasor", size=(8, 8), backscatter_e=20.0), phasor64),
                          "sensor", complex_in=True))
    cases.append(Case("Multipath", "random phasors", module_run(
        lambda: Multipath(0.3, 0.7, _F_HZ, blur_sigma=1.0), phasor64), "sensor",
        complex_in=True))
    cases.append(Case("Multipath", "all pixels no photon (P = 0)", module_run(
        lambda: Multipath(0.3, 0.7, _F_HZ, blur_sigma=1.0),
        lambda: torch.zeros(1, 1, 8, 8, dtype=torch.complex128)), "sensor", complex_in=True))
    cases.append(Case("DMDToSensor", "8×8 → 12×12 (mixed pixels)", module_run(
        lambda: DMDToSensor(8, 12), phasor64), "sensor", complex_in=True))
    return cases


def _wrap_check(depth: torch.Tensor, r: float) -> str | None:
    """Depth at the wrap must read ~0 (wrapped) or ~R, nothing in between, never NaN."""
    d = depth.double()
    dist = torch.minimum(d.abs(), (d - r).abs())
    if bool((dist > 1e-2).any()):
        return f"depth at the wrap is neither 0 nor {r:.4f} m: [{float(d.min())}, {float(d.max())}]"
    return None


# -- buckets and metrics -----------------------------------------------------------------------


def _bucket_cases() -> list[Case]:
    from ..bucket import depth_bucket, intensity_bucket, tap_buckets

    five = lambda: torch.full((1, 4, 64, 64), 5.0, dtype=F64)  # noqa: E731
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

    truth = lambda: _object(16)  # noqa: E731

    def cmp(x_hat64, polarity="positive"):
        def run(ctx):
            s = compare(ctx.t(x_hat64()), ctx.t(truth()), polarity=polarity, bits=None)
            return s["psnr"], s["ssim"]

        return run

    noisy = lambda: truth() + 0.2 * _randn(1, 1, 16, 16, seed=21)  # noqa: E731
    return [
        Case("compare (PSNR/SSIM)", "noisy image", cmp(noisy), "metric"),
        Case("compare (PSNR/SSIM)", "image at 1e-30", cmp(lambda: 1e-30 * noisy()), "metric"),
        Case("compare (PSNR/SSIM)", "image at 1e30", cmp(lambda: 1e30 * noisy()), "metric"),
        Case("compare (PSNR/SSIM)", "constant image", cmp(lambda: torch.full(
            (1, 1, 16, 16), 3.0, dtype=F64)), "metric"),
        Case("compare (PSNR/SSIM)", "identical images (100 dB cap)", cmp(truth), "metric",
             check=_all_equal(100.0, rel=1e-6)),
        Case("compare (PSNR/SSIM)", "negative depth image 5 − 3x", cmp(
            lambda: 5.0 - 3.0 * truth(), "negative"), "metric"),
        Case("depth_rmse", "no-photon map (5 m) vs 2 m object",
             lambda ctx: depth_rmse(ctx.t(torch.full((1, 1, 8, 8), 5.0, dtype=F64)),
                                    ctx.t(2.0 + _object(8))), "depth_m"),
    ]


# -- reconstructors ----------------------------------------------------------------------------


def _recon_makers() -> dict[str, tuple[bool, str, Callable]]:
    """name -> (uses the 0/1 DMD split operator, tolerance family, factory(A) -> module).

    Imports are lazy so a missing reconstructor fails its own rows, not the whole matrix.
    """

    def corr(cls):
        def make(A):
            from ..recon import correlation

            return getattr(correlation, cls)(A)

        return make

    def pinv(A):
        from ..recon.pinv import PseudoInverse

        return PseudoInverse(A)

    def tval3(A):
        from ..recon.tval3 import TVAL3

        return TVAL3(A)

    def bp(A):
        from ..recon.bp import BasisPursuit

        return BasisPursuit(A)

    def unrolled(A):
        from ..recon.unrolled import UnrolledTVAL3

        return UnrolledTVAL3(A, pretrained=False)

    def dip(A):
        from ..recon.dip import DIP

        return DIP(A, **_DIP_FAST)

    return {
        "CGI": (True, "recon_direct", corr("CGI")),
        "TGI": (True, "recon_direct", corr("TGI")),
        "DGI": (True, "recon_direct", corr("DGI")),
        "PseudoInverse": (False, "recon_direct", pinv),
        "TVAL3": (False, "recon_iterative", tval3),
        "BasisPursuit": (False, "recon_iterative", bp),
        "UnrolledTVAL3": (False, "recon_iterative", unrolled),
        "DIP": (False, "recon_dip", dip),
    }


#: Small, fast DIP settings for the stress matrix (tiny U-Net, few steps).
_DIP_FAST: dict = {}


def _recon_edges() -> dict[str, dict]:
    """edge -> spec: ``n``, ``sr``/``m``, ``x`` (scene builder), ``y`` (transform of ``A x``),
    ``op`` (``"hadamard"`` or ``"illcond"``), ``expect``, ``family`` override."""
    obj = _object
    k = lambda n: (64 / n) ** 2  # noqa: E731 - ToF pixels per DMD pixel (64×64 ROI)

    def snr_minus6(y, seed=17):
        sig = y.norm() / y.numel() ** 0.5
        return y + sig * 10 ** (6 / 20) * _randn(*y.shape, seed=seed)

    def nan(y):
        y = y.clone()
        y[..., 0] = math.nan
        return y

    return {
        "binary object, n=8, SR=50%": {},
        "zero buckets": {"y": torch.zeros_like},
        "constant buckets": {"y": lambda y: torch.full_like(y, 3.0)},
        "buckets at 1e-30": {"y": lambda y: 1e-30 * y},
        "buckets at 1e30": {"y": lambda y: 1e30 * y},
        "ungated depth buckets (5 m offset, α = 1)": {"x": lambda n: k(n) * (5.0 - 3.0 * obj(n))},
        "scattered depth, α = 0.5": {"x": lambda n: k(n) * (0.5 * (5.0 - 3.0 * obj(n)) + 1.0)},
        "scattered depth, α = 1e-3": {"x": lambda n: k(n) * (1e-3 * (5.0 - 3.0 * obj(n)) + 1.0)},
        "n=4, SR=100%": {"n": 4, "sr": 1.0},
        "SR = 1/n² (one pattern)": {"m": 1},
        "SR = 100%": {"sr": 1.0},
        "extreme noise (SNR = −6 dB)": {"y": snr_minus6},
        "ill-conditioned random patterns (κ≈1e3)": {"op": "illcond"},
        "NaN in buckets": {"y": nan, "expect": "error"},
    }


def _recon_run(make: Callable, split: bool, spec: dict) -> Callable[[Ctx], torch.Tensor]:
    from ..operators import DMDSplit, Hadamard, PatternOperator

    n = spec.get("n", 8)

    def run(ctx: Ctx) -> torch.Tensor:
        if spec.get("op") == "illcond":
            A = PatternOperator(ctx.r(_illcond_patterns(n=n)))
        else:
            size = {"m": spec["m"]} if "m" in spec else {"sr": spec.get("sr", 0.5)}
            A = Hadamard(n, **size)
            A = DMDSplit(A) if split else A
        x = spec.get("x", _object)(n)
        y = spec.get("y", lambda v: v)(A(x))
        return make(A)(ctx.t(y))

    return run


def _recon_cases() -> list[Case]:
    cases = []
    for name, (split, family, make) in _recon_makers().items():
        for edge, spec in _recon_edges().items():
            fam = "recon_illcond" if spec.get("op") == "illcond" and name == "PseudoInverse" \
                else family
            cases.append(Case(name, edge, _recon_run(make, split, spec), fam,
                              expect=spec.get("expect", "ok")))
    cases.append(Case("UnrolledTVAL3", "shipped weights (n=32, SR=25%)", _unrolled_shipped,
                      "recon_iterative"))
    return cases


def _unrolled_shipped(ctx: Ctx) -> torch.Tensor:
    from ..operators import Hadamard
    from ..recon.unrolled import UnrolledTVAL3

    A = Hadamard(32, sr=0.25)
    net = UnrolledTVAL3(A, pretrained=True)
    return net(ctx.t(A(_object(32))))


# -- the matrix --------------------------------------------------------------------------------


def stability_cases() -> list[Case]:
    """Every row of the matrix, in print order (operators, sensor, buckets, metrics, recon)."""
    return (_operator_cases() + _sensor_cases() + _bucket_cases() + _metric_cases()
            + _recon_cases())


def bench_stability(cases: list[Case] | None = None) -> dict:
    """Build the stress matrix (module docstring): one row per case, one cell per dtype.

    Args:
        cases: rows to run (default: :func:`stability_cases`).

    Returns:
        JSON-able dict: ``rows`` (see :func:`evaluate_case`), ``counts`` per dtype and status,
        ``tolerances`` (family -> metric and per-dtype tolerance), ``time_s``, ``torch``.
    """
    t0 = time.perf_counter()
    rows = [evaluate_case(c) for c in (stability_cases() if cases is None else cases)]
    counts = {
        _NAME[dt]: {s: sum(r["cells"][_NAME[dt]]["status"] == s for r in rows)
                    for s in ("ok", "error", "n/a", "FAIL")}
        for dt in DTYPES
    }
    tolerances = {
        fam: {"metric": metric, **{_NAME[dt]: tol for dt, tol in tols.items()}}
        for fam, (metric, tols) in TOLERANCES.items()
    }
    return {
        "benchmark": "stability",
        "dtypes": [_NAME[dt] for dt in DTYPES],
        "rows": rows,
        "counts": counts,
        "tolerances": tolerances,
        "time_s": time.perf_counter() - t0,
        "torch": torch.__version__,
    }


def print_stability(result: dict) -> None:
    """Print the matrix: short codes per cell, numbered notes for every error and failure."""
    dts = result["dtypes"]
    notes: dict[str, int] = {}
    table = []
    for r in result["rows"]:
        line = [r["module"], r["edge"]]
        for d in dts:
            cell = r["cells"][d]
            code = cell["status"]
            if code in ("error", "FAIL", "n/a"):
                key = f"{code}: {cell['detail']}"
                num = notes.setdefault(key, len(notes) + 1)
                code = f"{code}[{num}]"
            line.append(code)
        table.append(line)
    head = ["module", "edge case", *dts]
    widths = [max(len(row[i]) for row in [head, *table]) for i in range(len(head))]
    print(f"numerical stress matrix, torch {result['torch']}, {len(table)} rows, "
          f"{result['time_s']:.1f} s")
    print("  ".join(h.ljust(w) for h, w in zip(head, widths)))
    print("  ".join("-" * w for w in widths))
    for row in table:
        print("  ".join(v.ljust(w) for v, w in zip(row, widths)))
    print("\ncounts:", "; ".join(
        f"{d}: " + ", ".join(f"{v} {k}" for k, v in result["counts"][d].items())
        for d in dts))
    if notes:
        print("\nnotes:")
        for key, num in notes.items():
            print(f"  [{num}] {key}")
    print("\ntolerances (vs float64 on the same rounded inputs):")
    for fam, t in result["tolerances"].items():
        vals = ", ".join(f"{d} {t[d]:g}" for d in dts if d in t)
        print(f"  {fam:16s} {t['metric']:5s} {vals or '-'}")
