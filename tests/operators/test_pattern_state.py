"""A PatternOperator's patterns travel in its state_dict, and what is derived from them
(orthonormality, the pseudo-inverse, the solvers' cached factors) follows a load."""

import pytest
import torch

from torchtof.operators import PatternOperator, sylvester
from torchtof.recon import TVAL3, BasisPursuit


def _random(seed, m=24, n=8):
    g = torch.Generator().manual_seed(seed)
    return PatternOperator(torch.rand(m, n, n, generator=g, dtype=torch.float64))


def _x(n=8):
    x = torch.zeros(2, 1, n, n, dtype=torch.float64)
    x[:, :, 2:6, 3:7] = 1.0
    return x + 0.1 * torch.rand(x.shape, generator=torch.Generator().manual_seed(5),
                                dtype=torch.float64)


def test_state_dict_round_trip_through_a_file(tmp_path):
    a, b = _random(0), _random(1)
    assert "patterns" in a.state_dict()
    torch.save(a.state_dict(), tmp_path / "op.pt")
    y = b(_x())
    b.load_state_dict(torch.load(tmp_path / "op.pt"))
    assert b.state_version == 1
    torch.testing.assert_close(b(_x()), a(_x()), rtol=0, atol=0)
    torch.testing.assert_close(b.pinv(y), a.pinv(y), rtol=0, atol=0)


def test_loaded_orthonormal_rows_are_recognised():
    h = sylvester(64)[:24].reshape(24, 8, 8) / 8.0  # rows of H₆₄/8: A Aᵀ = I
    op = _random(0)
    assert not op.orthonormal_rows
    op.load_state_dict({"patterns": h.double()})
    assert op.orthonormal_rows
    y = op(_x())
    torch.testing.assert_close(op.pinv(y), op.adjoint(y))


@pytest.mark.parametrize("make", [
    lambda A: TVAL3(A, mu=2**8, u_step="exact", max_iter=20, adaptive=False),
    lambda A: TVAL3(A, mu=2**8, max_iter=20, adaptive=False),
    lambda A: BasisPursuit(A, n_iter=50, adaptive=False),
])
def test_solvers_follow_loaded_patterns(make):
    """Each model runs once before the load, so its per-operator caches (the exact u-step's
    factors, ScaleA's s₂, basis pursuit's Gram factor) hold the old patterns' values."""
    a, b = make(_random(0)), make(_random(1))
    y = a.A(_x())
    b(y)
    b.load_state_dict(a.state_dict())
    torch.testing.assert_close(b(y), a(y), rtol=1e-10, atol=1e-10)


def test_non_finite_loaded_patterns_are_refused():
    op = _random(0)
    bad = op.patterns.clone()
    bad[0, 0, 0] = float("nan")
    with pytest.raises(ValueError, match="PatternOperator.load_state_dict: .*patterns"):
        op.load_state_dict({"patterns": bad})
