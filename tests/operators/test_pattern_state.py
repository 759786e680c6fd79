"""A PatternOperator's patterns travel in its state_dict, and what is derived from them
(orthonormality, the pseudo-inverse, the solvers' cached factors) follows a load."""

import pytest
import torch

from torchtof.operators import Hadamard, PatternOperator, sylvester
from torchtof.recon import TVAL3, BasisPursuit, pseudo_inverse, tval3


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


def test_in_place_edits_and_new_patterns_are_followed():
    # a calibration gain applied in place left A⁺ and orthonormal_rows of the old patterns:
    # the pseudo-inverse was 100 % off (2.5 dB against 11.7 dB on a fresh operator)
    g = torch.Generator().manual_seed(0)
    x = torch.rand(1, 1, 16, 16, generator=g)
    p = PatternOperator((torch.rand(128, 16, 16, generator=g) > 0.5).float())
    v0 = p.state_version
    with torch.no_grad():
        p.patterns.mul_(1000.0)
    fresh = PatternOperator(p.patterns)
    assert p.state_version > v0  # solvers' caches (exact u-step, ScaleA) drop the old entries
    assert torch.equal(pseudo_inverse(p(x), p), pseudo_inverse(fresh(x), fresh))
    assert torch.equal(tval3(p(x), p, mu=2**8), tval3(fresh(x), fresh, mu=2**8))
    # orthonormal rows appear when the patterns become Hadamard rows, and go again
    h = Hadamard(4).matrix(torch.float32).reshape(16, 4, 4)
    q = PatternOperator(torch.rand(16, 4, 4, generator=g))
    assert not q.orthonormal_rows
    q.patterns = h.clone()
    assert q.orthonormal_rows and q.pinv_matrix is None
    with torch.no_grad():
        q.patterns[0, 0, 0] = 7.0
    assert not q.orthonormal_rows
    with torch.no_grad():
        q.patterns[0, 0, 0] = float("nan")
    with pytest.raises(ValueError, match="PatternOperator: patterns contains non-finite values"):
        q.pinv(torch.ones(1, 1, 16))


def test_parameter_patterns_are_learned():
    g = torch.Generator().manual_seed(1)
    w = torch.nn.Parameter(torch.rand(24, 8, 8, generator=g, dtype=torch.float64))
    p = PatternOperator(w)
    assert p.patterns is w and [n for n, _ in p.named_parameters()] == ["patterns"]
    x = torch.rand(2, 1, 8, 8, generator=g, dtype=torch.float64)
    # the buckets' gradient in the patterns: d/dΦ Σ (Φ x)² = 2 (Φ x) xᵀ, summed over the batch
    p(x).pow(2).sum().backward()
    y = (w.detach().reshape(24, -1) @ x.reshape(2, -1).T)  # (24, 2)
    expect = 2 * (y @ x.reshape(2, -1)).reshape(24, 8, 8)
    torch.testing.assert_close(w.grad, expect, rtol=1e-12, atol=1e-12)
    torch.optim.SGD([w], lr=0.1).step()
    torch.testing.assert_close(p._cached_pinv(torch.float64, torch.device("cpu")),
                               torch.linalg.pinv(w.detach().reshape(24, -1)))
    # checkpoints are interchangeable with a buffer-held operator's
    q = PatternOperator(torch.zeros(24, 8, 8, dtype=torch.float64))
    q.load_state_dict(p.state_dict())
    assert torch.equal(q.patterns, w.detach())


def test_patterns_computed_from_a_parameter_keep_their_gradient():
    # P.patterns = base * gain (a buffer that requires grad): the solvers must not run it in
    # inference mode, the gradient reaches the gain
    g = torch.Generator().manual_seed(0)
    base = torch.rand(40, 8, 8, generator=g, dtype=torch.float64)
    p = PatternOperator(base)
    gain = torch.nn.Parameter(torch.tensor(1.05, dtype=torch.float64))
    p.patterns = base * gain
    y = torch.rand(1, 1, 40, generator=g, dtype=torch.float64)
    tval3(y, p, mu=256.0, max_iter=20, adaptive=False).sum().backward()
    assert gain.grad is not None and torch.isfinite(gain.grad) and gain.grad != 0


def test_rederived_inside_inference_mode_stays_ordinary():
    g = torch.Generator().manual_seed(0)
    p = PatternOperator(torch.rand(20, 8, 8, generator=g, dtype=torch.float64))
    with torch.no_grad():
        p.patterns.mul_(1.1)
    y = torch.rand(1, 1, 20, generator=g, dtype=torch.float64)
    with torch.inference_mode():
        p.pinv(y)  # the first use after the edit derives A⁺ here
    assert not p.pinv_matrix.is_inference()
    yg = y.clone().requires_grad_()
    p.pinv(yg).sum().backward()
    assert torch.isfinite(yg.grad).all()


def test_meta_then_to_empty_then_load():
    with torch.device("meta"):
        m = PatternOperator(torch.rand(20, 8, 8))
    src = _random(3, m=20)
    m.to_empty(device="cpu")  # uninitialised memory: not derived (nor refused) until used
    m.load_state_dict({"patterns": src.patterns.float()})
    ref = PatternOperator(src.patterns.float())
    assert torch.equal(m.pinv_matrix, ref.pinv_matrix)


def test_a_module_pickled_before_the_version_tracking_loads():
    import io

    p = _random(4, m=20)
    for k in ("_state_version", "_derived_from", "_orthonormal"):  # what older pickles lack
        p.__dict__.pop(k, None)
    buf = io.BytesIO()
    torch.save(p, buf)
    buf.seek(0)
    q = torch.load(buf, weights_only=False)
    assert q.state_version >= 0 and not q.orthonormal_rows
    y = q(_x())
    torch.testing.assert_close(q.pinv(y), PatternOperator(q.patterns).pinv(y))


def test_hadamard_subclass_pinv_uses_its_own_adjoint():
    class Signed(Hadamard):  # rows with a sign each: still A Aᵀ = I
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            self.register_buffer("s", torch.where(torch.arange(self.m) % 3 == 0, -1.0, 1.0))

        def forward(self, x):
            return super().forward(x) * self.s.to(x)

        def adjoint(self, y):
            return super().adjoint(y * self.s.to(y))

    a = Signed(8, sr=0.5)
    x = torch.rand(1, 1, 8, 8, dtype=torch.float64)
    dense = torch.linalg.pinv(a.matrix()) @ a(x).reshape(-1)
    torch.testing.assert_close(a.pinv(a(x)).reshape(-1), dense)
