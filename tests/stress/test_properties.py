"""Property tests (hypothesis) of the numerical stress suite.

================================  ======================================  ===================
property                          inputs drawn                            tolerance
================================  ======================================  ===================
operators linear                  Hadamard n ∈ {4…64}, every order and    rel 1e-10 (float64)
                                  method, M ∈ [1, n²]; dense patterns of
                                  any shape; DMD split
operators adjoint-consistent      same                                    1e-12 (float64)
Hadamard rows orthonormal         same                                    A Aᵀ y = y, 1e-12
DMD split combines to A x         same                                    1e-12
sensor round trip (noise-free)    depth ∈ [0, c/2f), amplitude 1e-3…1e6   depth 1e-4 m (f32),
                                  e⁻, float32 and float64                 1e-9 m (f64);
                                                                          amplitude rel 1e-5
reconstructors and bucket scale   c = 10^k, k ∈ [−30, 30], float64;       rel 1e-6; BP, DIP
(g2: f(cy) = f(y); TGI, DGI, A⁺,  float32 at c = 1e±30                    1e-5; TVAL3 1e-2 (*);
TVAL3, BP, unrolled, DIP:                                                 float32 1e-4
f(cy) = c f(y))                                                           (iterative 1e-2)
================================  ======================================  ===================

(*) TVAL3 rescales the buckets to a spread of 1.5; ``c·y`` and ``y`` then differ in the last bit,
which can move its stopping decisions (233 vs 240 iterations at c = 10): the scale law holds to
the solver's tolerance (``tol_inner = 1e-3``), not bitwise as its docstring says.

Settings are derandomised (reproducible in CI) and small: the whole ``tests/stress`` run stays
well under the 3-minute CI budget on two busy cores.
"""

import functools
import math

import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from torchtof.operators import ORDERS, DMDSplit, Hadamard, PatternOperator
from torchtof.sensor import cw_tof_sensor, phasor_from_depth, unambiguous_range
from torchtof.testing.stability import BP_FAST, DIP_FAST, scene

F64 = torch.float64
FAST = settings(max_examples=30, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow])
SLOW = settings(max_examples=8, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow])


def _randn(*shape, seed):
    return torch.randn(shape, generator=torch.Generator().manual_seed(seed), dtype=F64)


def _check_linear_adjoint(A, seed, a, b):
    x1, x2 = _randn(2, 1, A.n, A.n, seed=seed), _randn(2, 1, A.n, A.n, seed=seed + 1)
    lhs, rhs = A(a * x1 + b * x2), a * A(x1) + b * A(x2)
    scale = (abs(a) + abs(b)) * (A(x1).norm() + A(x2).norm())
    assert float((lhs - rhs).norm()) <= 1e-10 * float(scale)
    y = _randn(2, 1, A.m, seed=seed + 2)
    ax, aty = A(x1), A.adjoint(y)
    gap = float(((ax * y).sum() - (x1 * aty).sum()).abs())
    assert gap <= 1e-12 * float(ax.norm() * y.norm() + x1.norm() * aty.norm())
    return y


coef = st.floats(-100, 100, allow_nan=False)


@FAST
@given(k=st.integers(2, 6), order=st.sampled_from(ORDERS),
       method=st.sampled_from(("matmul", "kron", "fwht")), frac=st.floats(0, 1),
       seed=st.integers(0, 10_000), a=coef, b=coef)
def test_hadamard_linear_adjoint_orthonormal(k, order, method, frac, seed, a, b):
    n = 2**k
    A = Hadamard(n, m=1 + round(frac * (n * n - 1)), order=order, method=method)
    y = _check_linear_adjoint(A, seed, a, b)
    torch.testing.assert_close(A(A.adjoint(y)), y, rtol=1e-12, atol=1e-12)  # A Aᵀ = I
    torch.testing.assert_close(A.pinv(y), A.adjoint(y))


@FAST
@given(k=st.integers(2, 4), order=st.sampled_from(ORDERS), frac=st.floats(0, 1),
       seed=st.integers(0, 10_000), a=coef, b=coef)
def test_dmd_split_linear_adjoint_and_combine(k, order, frac, seed, a, b):
    n = 2**k
    H = Hadamard(n, m=1 + round(frac * (n * n - 1)), order=order)
    S = DMDSplit(H)
    _check_linear_adjoint(S, seed, a, b)
    x = _randn(1, 2, n, n, seed=seed + 3)
    torch.testing.assert_close(S.combine(S(x)), H(x), rtol=1e-12, atol=1e-12)


@FAST
@given(n=st.integers(1, 9), m=st.integers(1, 40), binary=st.booleans(),
       seed=st.integers(0, 10_000), a=coef, b=coef)
def test_pattern_operator_linear_adjoint_and_pinv(n, m, binary, seed, a, b):
    p = _randn(m, n, n, seed=seed + 7)
    A = PatternOperator((p > 0).to(F64) if binary else p)
    y = _check_linear_adjoint(A, seed, a, b)
    x_ls = A.pinv(y)  # the normal equations of least squares hold at A⁺ y
    r = A.adjoint(A(x_ls) - y)
    assert float(r.norm()) <= 1e-6 * float(A.adjoint(y).norm()) + 1e-9


@FAST
@given(frac=st.floats(0, 0.999), log_amp=st.floats(-3, 6), dtype=st.sampled_from((torch.float32,
                                                                                   F64)))
def test_sensor_round_trip(frac, log_amp, dtype):
    """Noise-free phasor → taps → Eq. 7/8/1 recovers the depth (mod c/2f) and |P|/2."""
    r = unambiguous_range(30e6)
    depth = torch.full((1, 1, 2, 2), frac * r, dtype=F64)
    amp = 10.0**log_amp
    p = phasor_from_depth(amp, depth.to(dtype), 30e6)
    f = cw_tof_sensor(p, shot=None, adc_bits=None, min_m=0.0, max_m=2 * r)
    d = torch.remainder(f.depth.double() - depth, r)
    err = float(torch.minimum(d, r - d).max())  # circular: the wrap may read 0 or R
    assert err <= (1e-4 if dtype == torch.float32 else 1e-9)
    rel = float((f.amplitude.double() - amp / 2).abs().max()) / (amp / 2)
    assert rel <= (1e-5 if dtype == torch.float32 else 1e-12)
    assert f.depth.dtype == dtype and bool(torch.isfinite(f.phase).all())


# -- reconstructors: scale laws -----------------------------------------------------------------


def _make(name, A):
    from torchtof.recon.bp import BasisPursuit
    from torchtof.recon.correlation import CGI, DGI, TGI
    from torchtof.recon.dip import DIP
    from torchtof.recon.pinv import PseudoInverse
    from torchtof.recon.tval3 import TVAL3
    from torchtof.recon.unrolled import UnrolledTVAL3

    return {
        "CGI": lambda: CGI(A), "TGI": lambda: TGI(A), "DGI": lambda: DGI(A),
        "PseudoInverse": lambda: PseudoInverse(A), "TVAL3": lambda: TVAL3(A),
        "BasisPursuit": lambda: BasisPursuit(A, **BP_FAST),
        "UnrolledTVAL3": lambda: UnrolledTVAL3(A, pretrained=False),
        "DIP": lambda: DIP(A, **{**DIP_FAST, "max_iter": 5}),
    }[name]()


#: name -> (degree of homogeneity f(c y) = c^deg f(y), uses the 0/1 DMD split, rel. tolerance)
SCALE_LAW = {
    "CGI": (0, True, 1e-6), "TGI": (1, True, 1e-6), "DGI": (1, True, 1e-6),
    "PseudoInverse": (1, False, 1e-6), "TVAL3": (1, False, 1e-2),
    "BasisPursuit": (1, False, 1e-5), "UnrolledTVAL3": (1, False, 1e-6), "DIP": (1, False, 1e-5),
}


@functools.cache
def _setup(name, dtype):
    deg, split, _ = SCALE_LAW[name]
    H = Hadamard(8, sr=0.5)
    A = DMDSplit(H) if split else H
    y = A(scene(8) + 0.05 * _randn(1, 1, 8, 8, seed=3)).to(dtype)
    rec = _make(name, A)
    with torch.no_grad() if name != "DIP" else torch.enable_grad():
        return rec, y, rec(y).detach()


def _scaled(name, dtype, c):
    rec, y, base = _setup(name, dtype)
    deg = SCALE_LAW[name][0]
    out = rec(y * c).detach()
    return out / c**deg if deg else out, base


def _rel(a, b):
    return float((a.double() - b.double()).norm() / b.double().norm())


@SLOW
@given(k=st.floats(-30, 30))
@pytest.mark.parametrize("name", [
    # TVAL3's 16 solves take 6 s; its scale law at 1e±30: the float32 test below (default run)
    pytest.param(n, marks=pytest.mark.slow) if n == "TVAL3" else n for n in sorted(SCALE_LAW)
])
def test_reconstructor_scale_law_float64(name, k):
    out, base = _scaled(name, F64, 10.0**k)
    assert bool(torch.isfinite(out).all())
    assert _rel(out, base) <= SCALE_LAW[name][2]


_F32_SCALE_BUGS: dict[str, str] = {}  # fixed: correlation._safe_div, bp's norm


@pytest.mark.parametrize("c", [1e-30, 1e30], ids=["1e-30", "1e30"])
@pytest.mark.parametrize("name", [
    pytest.param(n, marks=[pytest.mark.xfail(strict=True, reason="BUG: " + _F32_SCALE_BUGS[n])]
                 if n in _F32_SCALE_BUGS else [])
    for n in sorted(SCALE_LAW)
])
def test_reconstructor_scale_law_float32_extremes(name, c):
    out, base = _scaled(name, torch.float32, c)
    assert out.dtype == torch.float32 and bool(torch.isfinite(out).all())
    tol = 1e-2 if name in ("TVAL3", "BasisPursuit", "UnrolledTVAL3", "DIP") else 1e-4
    assert _rel(out, base) <= tol
    assert not math.isnan(_rel(out, base))
