"""TVAL3's ``ScaleA`` in both directions: the TV solvers give the same image for ``c·A`` with
buckets ``c·y`` at every ``c > 0``, and a zero operator is refused by name.

The published ``ScaleA`` divides ``A`` and ``b`` by ``√s₂`` only when ``s₂ > 1``. With
patterns in small physical units (``s₂ ≪ 1``) the fixed ``μ``, ``β`` then weigh the data too
little: before this rule TVAL3 returned ``x ≈ 0`` with a relative residual of 1 and
``converged=True`` for patterns scaled by 10⁻⁶.
"""

from __future__ import annotations

import pytest
import torch

import torchtof.recon as recon
from torchtof.operators import PatternOperator
from torchtof.recon.depth import joint_tv
from torchtof.recon.tv import largest_eig_normal, scale_a


def _problem(c: float):
    g = torch.Generator().manual_seed(0)
    p = torch.rand(40, 8, 8, generator=g, dtype=torch.float64)
    x = torch.rand(2, 1, 8, 8, generator=g, dtype=torch.float64)
    P = PatternOperator(p)
    Pc = PatternOperator(p * c)
    return x, P, P(x), Pc, Pc(x)


SOLVERS = {
    "tval3": lambda y, A: recon.tval3(y, A, mu=256.0, max_iter=200, return_result=True),
    "tgv": lambda y, A: recon.tgv(y, A, max_iter=300, return_result=True),
    "joint_tv": lambda y, A: joint_tv(y.reshape(1, 2, -1), A, mu=256.0, n_iter=200,
                                      return_result=True),
}


@pytest.mark.parametrize("name", sorted(SOLVERS))
@pytest.mark.parametrize("c", [2.0**-20, 2.0**-10])
def test_small_operator_gives_the_same_image(name, c):
    x, P, y, Pc, yc = _problem(c)
    assert largest_eig_normal(Pc, yc) < 1.0 < largest_eig_normal(P, y)  # the case at issue
    r, rc = SOLVERS[name](y, P), SOLVERS[name](yc, Pc)
    # c·A x = c·y has the solutions of A x = y; with c a power of two every scaled quantity
    # is exact, so the iterates are the same (another c moves the stopping step by rounding)
    torch.testing.assert_close(rc.x, r.x, rtol=1e-12, atol=1e-12)
    assert float(rc.residual.max()) < 0.05  # the data are fitted, not x ≈ 0


def test_scale_a_factor_both_ways():
    _, P, y, Pc, yc = _problem(2.0**-20)
    s2 = largest_eig_normal(P, y)
    assert scale_a(P, y, "f") == pytest.approx(1.0 / s2)
    assert scale_a(Pc, yc, "f") == pytest.approx(2.0**40 / s2)  # s₂(c·A) = c²·s₂(A)


@pytest.mark.parametrize("name", sorted(SOLVERS))
def test_zero_operator_is_refused_by_name(name):
    Z = PatternOperator(torch.zeros(40, 8, 8, dtype=torch.float64))
    fn = {"tval3": "tval3", "tgv": "tgv", "joint_tv": "joint_tv"}[name]
    with pytest.raises(ValueError, match=rf"{fn}: A is zero"):
        SOLVERS[name](torch.ones(2, 1, 40, dtype=torch.float64), Z)


def test_power_iteration_of_a_zero_operator_is_zero_not_nan():
    Z = PatternOperator(torch.zeros(6, 4, 4))
    assert largest_eig_normal(Z, torch.zeros(1)) == 0.0
