import pytest
import torch

from torchtof.adaptive import solve_at_noise
from torchtof.operators import Hadamard
from torchtof.recon.tval3 import STOP_REASONS, tval3

N = 16


def _data(sigma, b=1, seed=0):
    A = Hadamard(N, sr=0.375)
    x = torch.zeros(b, 1, N, N, dtype=torch.float64)
    x[..., 4:12, 3:10] = 1.0
    y = A(x)
    g = torch.Generator().manual_seed(seed)
    return A, x, y + sigma * torch.randn(y.shape, generator=g, dtype=y.dtype)


def test_tval3_default_unchanged_and_reports_a_reason():
    A, _, y = _data(0.01, b=2)
    ref = tval3(y, A, return_result=True)
    off = tval3(y, A, discrepancy=None, return_result=True)
    assert torch.equal(ref.x, off.x) and torch.equal(ref.n_iter, off.n_iter)
    assert ref.stop_code.shape == (2, 1) and ref.stop_code.dtype == torch.int64
    assert all(r in STOP_REASONS for row in ref.reasons() for r in row)
    assert "discrepancy" not in sum(ref.reasons(), [])


def test_tval3_discrepancy_stops_at_the_noise_level():
    # the constrained model (mu = 2^8) fits the noise to ||Ax - y|| -> 0; Morozov stops it at
    # the first inner convergence whose residual is within tau M sigma^2
    sigma = 0.05
    A, x, y = _data(sigma)
    full = tval3(y, A, mu=2**8, return_result=True)
    early = tval3(y, A, mu=2**8, discrepancy=sigma, return_result=True)
    assert early.reasons() == [["discrepancy"]]
    assert int(early.n_iter) < int(full.n_iter)
    res = (A(early.x) - y).pow(2).sum()
    assert float(res) <= A.m * sigma**2 * (1 + 1e-9)
    assert float((A(full.x) - y).norm()) < float(res.sqrt())


def test_tval3_auto_discrepancy_and_max_iter_reason():
    A, _, y = _data(0.05)
    r = tval3(y, A, mu=2**8, discrepancy="auto", return_result=True)
    assert r.converged.all()
    short = tval3(y, A, max_iter=3, return_result=True)
    assert short.reasons() == [["max_iter"]]
    with pytest.raises(ValueError, match="discrepancy"):
        tval3(y, A, discrepancy="sometimes", return_result=True)
    with pytest.raises(ValueError, match="noise_sigma"):
        tval3(y, A, discrepancy=-1.0, return_result=True)


@pytest.mark.parametrize("method", ["PINV", "TVAL3", "BP"])
def test_solve_at_noise_reports_iterations_and_reasons(method):
    sigma = 0.05
    A, _, y = _data(sigma, b=2)
    r = solve_at_noise(method, y, A, sigma)
    assert r.x.shape == (2, 1, N, N)
    assert len(r.stop_reason) == 2 and r.n_iter.shape == (2, 1)
    expected = {"PINV": {"direct"}, "TVAL3": {"discrepancy", "tol", "max_outer", "max_iter"},
                "BP": {"tol", "max_iter"}}[method]
    assert {s for row in r.stop_reason for s in row} <= expected
    if method == "BP":  # the discrepancy radius is the constraint: every sample within it
        assert float((A(r.x) - y).norm(dim=-1).max()) <= (A.m**0.5) * sigma * (1 + 1e-3)


def test_dip_discrepancy_stops_before_max_iter():
    sigma = 0.05
    A, _, y = _data(sigma)
    r = solve_at_noise("DIP", y.float(), A, 3 * sigma, max_iter=60)  # generous bound: met early
    assert r.stop_reason == (("discrepancy",),)
    assert int(r.n_iter[0, 0]) < 60


def test_solve_at_noise_bad_inputs():
    A, _, y = _data(0.0)
    with pytest.raises(ValueError, match="method"):
        solve_at_noise("CGI", y, A)
    with pytest.raises(ValueError, match="shape"):
        solve_at_noise("PINV", y[0], A)


def test_tau_scales_the_discrepancy_bound_only():
    # tau: Morozov's factor on the bound, ‖Ax − y‖² ≤ τ M σ² = M (√τ σ)²; the μ model keeps σ
    A, _, y = _data(0.05)
    res = solve_at_noise("TVAL3", y, A, 0.05, tau=0.5)
    ref = tval3(y, A, noise_sigma=0.05, discrepancy=0.05 * 0.5**0.5, return_result=True)
    assert torch.equal(res.x, ref.x) and torch.equal(res.n_iter, ref.n_iter)


def test_model_sigma_false_leaves_the_model_to_tval3():
    # model_sigma=False: σ only bounds the residual; TVAL3 chooses its model as without σ
    A, _, y = _data(0.05)
    res = solve_at_noise("TVAL3", y, A, 0.05, model_sigma=False)
    ref = tval3(y, A, noise_sigma=None, discrepancy=0.05, return_result=True)
    assert torch.equal(res.x, ref.x) and list(map(list, res.stop_reason)) == ref.reasons()


def test_smaller_tau_never_stops_earlier():
    A, _, y = _data(0.05, b=3)
    loose = solve_at_noise("TVAL3", y, A, 0.05, tau=1.5)
    tight = solve_at_noise("TVAL3", y, A, 0.05, tau=0.5)
    assert bool((tight.n_iter >= loose.n_iter).all())


@pytest.mark.parametrize("tau", [0.0, -1.0, float("nan")])
def test_bad_tau(tau):
    A, _, y = _data(0.05)
    with pytest.raises(ValueError, match="tau"):
        solve_at_noise("TVAL3", y, A, 0.05, tau=tau)


def test_old_argument_order_and_n_iter_warn():
    A, _, y = _data(0.05)
    want = solve_at_noise("TVAL3", y, A, 0.05, max_iter=20)
    with pytest.warns(DeprecationWarning, match=r"\(method, y, A\)"):
        old = solve_at_noise("TVAL3", A, y, 0.05, max_iter=20)
    with pytest.warns(DeprecationWarning, match="n_iter= is renamed max_iter="):
        renamed = solve_at_noise("TVAL3", y, A, 0.05, n_iter=20)
    assert torch.equal(old.x, want.x) and torch.equal(renamed.x, want.x)
    assert int(want.n_iter.max()) <= 20
