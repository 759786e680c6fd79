"""Sizes that cannot fit are refused before allocating: the dual-frequency hypotheses
(common range from a tolerant frequency ratio) and the exact u-step's M×M factorisation."""

import math

import pytest
import torch

import torchtof
from torchtof.hardware import opt8241
from torchtof.operators import Hadamard, PatternOperator, random_binary_patterns
from torchtof.recon import (
    TVAL3,
    DualFrequencyDepth,
    JointTV,
    PseudoInverse,
    common_range,
    dual_frequency_depth,
    hypothesis_spacing,
    joint_tv,
    tv,
    tval3,
)
from torchtof.sensor import SPEED_OF_LIGHT

C = SPEED_OF_LIGHT


@pytest.fixture
def memory_limit():
    yield torchtof.set_memory_limit
    torchtof.set_memory_limit(None)


def _wrapped(d, f):
    return torch.remainder(4 * math.pi * f * d / C, 2 * math.pi)


def _pll_hz(freq_hz):
    """What the OPT8241's PLL 1 makes when asked for ``freq_hz`` (quad_cnt_max 4)."""
    s = opt8241.pll_settings(freq_hz, 4)
    return opt8241.pll_frequency_hz(s["mod_m1"], s["mod_m_frac1"], s["mod_n1"], s["mod_ps1"], 4)


# -- common range ----------------------------------------------------------------------------


def test_common_range_known_answers():
    # 30 = 3·10 MHz, 20 = 2·10 MHz: range c/(2·10 MHz) = 14.99 m, spacing c/(2·10 MHz·6)
    r = common_range(30e6, 20e6)
    assert (r.p, r.q) == (3, 2)
    assert r.freq_hz == 10e6
    assert abs(r.range_m - C / 2e7) < 1e-12
    assert abs(r.spacing_m - C / 1.2e8) < 1e-12  # 2.498 m
    assert abs(hypothesis_spacing(30e6, 20e6) - 2.4982704833) < 1e-9
    assert (common_range(20e6, 30e6).p, common_range(20e6, 30e6).q) == (2, 3)
    # 48 = 4·12, 36 = 3·12 MHz: 12.49 m; 30 and 20.1 MHz: 100·0.3 and 67·0.3 MHz, 499.65 m
    assert abs(common_range(48e6, 36e6).range_m - C / 2.4e7) < 1e-12
    r = common_range(30e6, 20.1e6)
    assert (r.p, r.q) == (100, 67)
    assert abs(r.range_m - C / 6e5) < 1e-9


def test_pll_frequency_gives_the_range_of_the_round_one():
    """The PLL makes 19 999 992.37 Hz for 20 MHz (gcd with 30 MHz: 8 Hz, 18 750 km and
    10^13 hypotheses before): the ratio is still 3/2 and the depth unwraps to 15 m."""
    f1, f2 = _pll_hz(30e6), _pll_hz(20e6)
    assert f1 == 30e6 and abs(f2 - 19_999_992.37) < 0.01
    r = common_range(f1, f2)
    assert (r.p, r.q) == (3, 2)
    assert abs(r.range_m - C / 2e7) < 1e-5
    assert abs(hypothesis_spacing(f1, f2) - C / 1.2e8) < 1e-6
    d = torch.linspace(0.0, 14.98, 3001, dtype=torch.float64)
    out = dual_frequency_depth(_wrapped(d, f1), _wrapped(d, f2), f1, f2)
    assert float((out - d).abs().max()) < 1e-4  # the 3/2 mismatch: 5.7 µm at 15 m
    DualFrequencyDepth(PseudoInverse(Hadamard(8, sr=0.5)), f1, f2)  # constructs at once


def test_ratio_tolerance_boundary():
    # f2 = 20 MHz·(1 + ε): the phases drift apart by (c/2)|3/f1 − 2/f2| ≈ 6ε of the spacing
    # at the common range; 3/2 is kept while 6ε <= 1e-3
    assert (common_range(30e6, 20e6 * (1 + 1e-4)).p, common_range(30e6, 20e6 * (1 + 1e-4)).q) \
        == (3, 2)
    with pytest.raises(ValueError, match="no common range"):  # next convergent: 1666/1111
        common_range(30e6, 20e6 * (1 + 3e-4))


def test_frequencies_without_a_small_ratio_are_refused():
    with pytest.raises(ValueError, match=r"common_range: 30000000 and 7 Hz have no common "
                                         r"range within 65536 wrap-count pairs"):
        common_range(30e6, 7.0)
    # 30 MHz and 30 MHz + 7 Hz: ratio 1/1 to within the tolerance (was 2.4 PB of hypotheses)
    with pytest.raises(ValueError, match="dual_frequency_depth: expected two different"):
        dual_frequency_depth(torch.zeros(3), torch.zeros(3), 30e6, 30e6 + 7)
    with pytest.raises(ValueError, match="no common range"):
        DualFrequencyDepth(PseudoInverse(Hadamard(8, sr=0.5)), 30e6, 7.0)
    with pytest.raises(ValueError, match="hypothesis_spacing: expected freq_2_hz > 0"):
        hypothesis_spacing(30e6, 0.0)


def test_hypotheses_over_the_memory_limit_are_refused(memory_limit):
    p = torch.zeros(100_000, dtype=torch.float64)
    memory_limit("1M")
    # 30 + 20 MHz: wrap counts -1..3 and -1..2 (5 x 4), two float64 copies: 32e6 bytes
    with pytest.raises(ValueError, match=r"dual_frequency_depth: 5x4 wrap-count hypotheses "
                                         r"for 100000 phases needs about 30.5 MiB"):
        dual_frequency_depth(p, p, 30e6, 20e6)
    memory_limit(None)
    assert dual_frequency_depth(p, p, 30e6, 20e6).shape == p.shape


# -- the exact u-step's factorisation ----------------------------------------------------------


def test_exact_u_step_over_the_memory_limit_is_refused_at_the_entry(memory_limit):
    """n = 256 at SR 25 %: m = 16384 rows, the m x m eigendecomposition in float64 with its
    LAPACK syevd workspace (4 m² doubles, 8 GiB) and the float32 eigenvectors (1 GiB): refused
    when built, before anything is allocated."""
    A = Hadamard(256, sr=0.25)
    assert A.m == 16384
    memory_limit("8G")
    with pytest.raises(ValueError, match=r"TVAL3: the exact u-step's 16384x16384 "
                                         r"eigendecomposition \(n=256\) needs about 9\.05 GiB.*"
                                         r"u_step='bb'"):
        TVAL3(A, u_step="exact")
    with pytest.raises(ValueError, match=r"JointTV: the exact u-step's 16384x16384 .*"
                                         r"JointTV always factors it"):
        JointTV(A)
    y = torch.zeros(1, 2, A.m)
    with pytest.raises(ValueError, match="tval3: the exact u-step's 16384x16384"):
        tval3(y, A, u_step="exact", return_result=True)
    with pytest.raises(ValueError, match="joint_tv: the exact u-step's 16384x16384"):
        joint_tv(y, A)
    TVAL3(A)  # the default BB u-step needs no factorisation


def test_exact_u_step_within_the_limit_still_solves(memory_limit):
    A = Hadamard(16, sr=0.5)
    x = torch.zeros(1, 1, 16, 16, dtype=torch.float64)
    x[..., 4:12, 4:12] = 1.0
    memory_limit("1M")  # m = 128: 4·128² doubles alone are 0.5 MiB, the images 1.5 MiB more
    with pytest.raises(ValueError, match="TVAL3: the exact u-step's 128x128"):
        TVAL3(A, u_step="exact", mu=2**8)
    memory_limit("64M")
    res = TVAL3(A, u_step="exact", mu=2**8).solve(A(x))
    assert float((res.x - x).abs().max()) < 1e-2


@pytest.mark.parametrize("boundary", ["periodic", "neumann"])
def test_factors_built_in_blocks_solve_the_dense_system(boundary, monkeypatch):
    """S = A K⁻¹ Aᵀ built 5 rows at a time (the last block 1 row): the exact u-step still
    solves (DᵀD + ρAᵀA) u = r, checked against the dense matrices."""
    n = 8
    monkeypatch.setattr(tv, "_BLOCK_VALUES", 5 * n * n)
    g = torch.Generator().manual_seed(1)
    A = PatternOperator(random_binary_patterns(26, n, generator=g, dtype=torch.float64))
    eye = torch.eye(n * n, dtype=torch.float64).reshape(n * n, n, n)
    d = tv.grad2(eye, boundary).reshape(n * n, -1).T  # D column by column
    am = A.matrix().double()
    rho = torch.tensor([[0.5, 3.0]], dtype=torch.float64)
    r = torch.randn(1, 2, n, n, dtype=torch.float64, generator=torch.Generator().manual_seed(2))
    u, au = tv.exact_solve(r, rho, A.forward, A.adjoint, tv.exact_factors(A, r, boundary))
    for c in range(2):
        ref = torch.linalg.lstsq(d.T @ d + rho[0, c] * am.T @ am, r[0, c].flatten()).solution
        assert torch.allclose(u[0, c].flatten(), ref, atol=1e-8)
        assert torch.allclose(au[0, c], am @ ref, atol=1e-8)
