"""TGV²: the symmetrised gradient, the prior's known values and the primal-dual solver."""

from __future__ import annotations

import pytest
import torch

import torchtof.recon as recon
from torchtof.data import planar_depth
from torchtof.metrics import psnr
from torchtof.operators import Hadamard, PatternOperator
from torchtof.recon.tgv import TGV, TGVResult, tgv, tgv_prior
from torchtof.recon.tv import sym_grad2, sym_grad2_adjoint
from torchtof.recon.tval3 import MaskedRows

B_RULES = ("periodic", "neumann")


def _grid(n, dtype=torch.float64):
    return torch.meshgrid(torch.arange(n, dtype=dtype), torch.arange(n, dtype=dtype),
                          indexing="ij")


def _psnr(a, b):
    return float(psnr(a, b, bits=None).reshape(-1)[0])


# -- the symmetrised gradient E --------------------------------------------------------------


@pytest.mark.parametrize("boundary", B_RULES)
def test_sym_grad2_adjoint(boundary):
    g = torch.Generator().manual_seed(0)
    w = torch.randn(3, 2, 2, 7, 5, generator=g, dtype=torch.float64)
    q = torch.randn(3, 2, 4, 7, 5, generator=g, dtype=torch.float64)
    lhs = (sym_grad2(w, boundary) * q).sum()
    rhs = (w * sym_grad2_adjoint(q, boundary)).sum()
    assert abs(float(lhs - rhs)) <= 1e-12 * float(lhs.abs() + rhs.abs())


@pytest.mark.parametrize("boundary", B_RULES)
def test_sym_grad2_gradcheck(boundary):
    w = torch.randn(1, 2, 4, 5, dtype=torch.float64, requires_grad=True)
    q = torch.randn(1, 4, 4, 5, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda t: sym_grad2(t, boundary), (w,))
    assert torch.autograd.gradcheck(lambda t: sym_grad2_adjoint(t, boundary), (q,))


def test_sym_grad2_known_values():
    # w_x = a·j, w_y = c·j (j the column): ∂x w_x = a, ∂y w_x = 0, ∂x w_y = c, ∂y w_y = 0, so
    # E w = [[a, c/2], [c/2, 0]] away from the last column (Neumann: 0 there)
    a, c = 0.3, -0.8
    _, j = _grid(5)
    w = torch.stack((a * j, c * j))
    e = sym_grad2(w, "neumann")
    want = torch.tensor([a, c / 2, c / 2, 0.0], dtype=torch.float64)[:, None, None]
    torch.testing.assert_close(e[..., :-1], want.expand(4, 5, 4), rtol=0, atol=1e-15)
    assert float(e[..., -1].abs().max()) == 0.0
    # a constant field has E w = 0 under both rules
    const = torch.tensor([1.5, -2.0], dtype=torch.float64)[:, None, None].expand(2, 5, 5)
    for b in B_RULES:
        assert float(sym_grad2(const, b).abs().max()) == 0.0


# -- the prior ---------------------------------------------------------------------------------


@pytest.mark.parametrize("tv", ["isotropic", "anisotropic"])
def test_prior_of_affine_image_is_zero(tv):
    # x = c0 + c1·j + c2·i, w = (c1, c2) everywhere: ∇x − P w = 0 and E w = 0 (Neumann)
    i, j = _grid(6)
    x = (0.4 + 0.1 * j - 0.05 * i)[None, None]
    w = torch.tensor([0.1, -0.05], dtype=torch.float64)[None, None, :, None, None]
    w = w.expand(1, 1, 2, 6, 6)
    assert float(tgv_prior(x, w, (1.0, 2.0), tv).abs().max()) < 1e-14
    # with w = 0 the prior is α₁·TV: anisotropic TV of the ramp = (|0.1| + |0.05|)·6·5
    tv0 = tgv_prior(x, torch.zeros_like(w), (3.0, 2.0), "anisotropic")
    assert float(tv0) == pytest.approx(3.0 * 0.15 * 30, rel=1e-12)


def test_prior_of_a_step_with_w_zero():
    # a vertical step of height h over n rows: anisotropic α₁·h·n (E 0 = 0)
    x = torch.zeros(1, 1, 4, 4, dtype=torch.float64)
    x[..., 2:] = 0.7
    w = torch.zeros(1, 1, 2, 4, 4, dtype=torch.float64)
    assert float(tgv_prior(x, w, (2.0, 5.0), "anisotropic")) == pytest.approx(2.0 * 0.7 * 4)


# -- the solver: known answers -----------------------------------------------------------------


def test_planes_beat_tv_staircase():
    # a piecewise-planar depth map from an eighth of the Hadamard rows (noise-free): TGV²
    # recovers the planes, first-order TV (TVAL3, both boundary rules) staircases them
    n = 32
    x = planar_depth(n).reshape(1, 1, n, n)
    A = Hadamard(n, sr=0.125)
    y = A(x)
    p_tgv = _psnr(tgv(y, A), x)
    p_tv = max(_psnr(recon.tval3(y, A, mu=2.0**8, boundary=b), x) for b in B_RULES)
    assert p_tgv > p_tv + 10.0, (p_tgv, p_tv)


def test_affine_image_from_random_patterns():
    # an affine image (zero TGV²) from a quarter as many random ±0.5 patterns as pixels, the
    # dualised-data path (no orthonormal rows): recovered to a small fraction of its range
    n = 16
    i, j = _grid(n)
    x = (0.2 + 0.03 * j + 0.01 * i)[None, None]
    g = torch.Generator().manual_seed(0)
    A = PatternOperator(torch.rand(64, n, n, generator=g, dtype=torch.float64) - 0.5)
    r = tgv(A(x), A, tol=1e-6, max_iter=5000, return_result=True)
    assert r.stop_reason == (("tol",),)
    assert float((r.x - x).abs().max()) < 1e-3 * float(x.max() - x.min())


@pytest.mark.parametrize("bounds", [None, (0.0, None)])
def test_constrained_model_fits_the_buckets(bounds):
    # the constrained model satisfies A x = y: exactly by the closed-form projection (Hadamard,
    # no box) or to the stopping tolerance by the dualised data term (with a box)
    n = 16
    A = Hadamard(n, sr=0.25)
    g = torch.Generator().manual_seed(1)
    y = A(planar_depth(n).reshape(1, 1, n, n))
    y = y + 0.01 * float(y.abs().max()) * torch.randn(y.shape, generator=g, dtype=y.dtype)
    r = tgv(y, A, bounds=bounds, tol=1e-6, max_iter=5000, return_result=True)
    assert r.stop_reason == (("tol",),)
    assert float(r.residual) < (1e-12 if bounds is None else 5e-5)


def test_tvl2_weight_moves_between_fit_and_smoothing():
    # TV-L2: a larger μ fits the buckets closer (the data term's weight does what it says)
    n = 16
    A = Hadamard(n, sr=0.5)
    g = torch.Generator().manual_seed(2)
    y = A(planar_depth(n).reshape(1, 1, n, n))
    y = y + 0.02 * float(y.abs().max()) * torch.randn(y.shape, generator=g, dtype=y.dtype)
    res = [float(tgv(y, A, mu=m, tvl2=True, max_iter=300, return_result=True).residual)
           for m in (2.0**2, 2.0**6, 2.0**10)]
    assert res[0] > res[1] > res[2] > 0


def test_bounds_respected():
    n = 16
    A = Hadamard(n, sr=0.25)
    y = A(planar_depth(n).reshape(1, 1, n, n))
    r = tgv(y, A, bounds=(0.3, 0.6), max_iter=300, return_result=True)
    assert float(r.x.min()) >= 0.3 and float(r.x.max()) <= 0.6
    # a negative image projected onto x ≥ 0
    r = tgv(-y, A, nonneg=True, max_iter=300, return_result=True)
    assert float(r.x.min()) >= 0.0


def test_scale_invariant_for_orthonormal_rows():
    n = 16
    A = Hadamard(n, sr=0.25)
    y = A(planar_depth(n).reshape(1, 1, n, n))
    a = tgv(y, A, mu=2.0**8, tvl2=True, max_iter=200, adaptive=False)
    b = tgv(7.5 * y, A, mu=2.0**8, tvl2=True, max_iter=200, adaptive=False)
    torch.testing.assert_close(b, 7.5 * a, rtol=1e-9, atol=1e-12)


def test_zero_buckets_and_empty_batch():
    A = Hadamard(8, sr=0.5)
    r = tgv(torch.zeros(2, 1, 32, dtype=torch.float64), A, return_result=True)
    assert float(r.x.abs().max()) == 0.0 and r.n_iter.tolist() == [[0], [0]]
    assert bool(r.converged.all()) and float(r.residual.abs().max()) == 0.0
    e = tgv(torch.zeros(0, 1, 32), A, return_result=True)
    assert e.x.shape == (0, 1, 8, 8) and e.x.dtype == torch.float32


def test_dtype_and_result_type():
    A = Hadamard(8, sr=0.5)
    x = planar_depth(8, dtype=torch.float32).reshape(1, 1, 8, 8)
    r = TGV(A, max_iter=50).solve(A(x))
    assert isinstance(r, TGVResult) and r.x.dtype == torch.float32
    assert r.w.shape == (1, 1, 2, 8, 8) and r.stop_code.shape == (1, 1)
    assert recon.get("tgv").module is TGV and recon.get("TGV").function is tgv


def test_alpha_auto_is_n_over_sqrt_m():
    # "auto": α0/α1 = n/√M (64 rows of a 16×16 image: 2); equals passing that ratio and the
    # pair (1, 2); another ratio gives another solution
    from torchtof.recon.tgv import auto_ratio

    A = Hadamard(16, sr=0.25)
    assert auto_ratio(A) == 2.0 and auto_ratio(Hadamard(32, sr=0.0625)) == 4.0
    y = A(planar_depth(16).reshape(1, 1, 16, 16))
    kw = dict(mu=2.0**8, tvl2=True, max_iter=60, adaptive=False)
    a = tgv(y, A, **kw)
    torch.testing.assert_close(tgv(y, A, alpha=2.0, **kw), a, rtol=0, atol=0)
    torch.testing.assert_close(tgv(y, A, alpha=(1.0, 2.0), **kw), a, rtol=0, atol=0)
    assert float((tgv(y, A, alpha=8.0, **kw) - a).abs().max()) > 1e-6


# -- batching per-sample weights (what cross-validation needs) ----------------------------------


@pytest.mark.parametrize("nonneg", [False, True])  # closed-form / dualised data term
def test_per_sample_weights_equal_separate_calls(nonneg):
    n = 16
    A = Hadamard(n, sr=0.25)
    g = torch.Generator().manual_seed(3)
    y = A(planar_depth(n).reshape(1, 1, n, n))
    y = y + 0.01 * float(y.abs().max()) * torch.randn(y.shape, generator=g, dtype=y.dtype)
    mus = [2.0**4, 2.0**8, 2.0**12]
    tvl2 = [True, True, False]
    # folds × weights as channels, each with its own row mask (as auto batches TVAL3)
    mask = torch.ones(3, A.m, dtype=torch.bool)
    mask[0, -8:] = False
    mask[2, -16:] = False
    Am = MaskedRows(A, mask)
    yb = (y * mask.to(y.dtype)).reshape(1, 3, A.m)
    r = tgv(yb, Am, mu=torch.tensor([mus]), tvl2=torch.tensor([tvl2]), max_iter=400,
            nonneg=nonneg, return_result=True)
    for c in range(3):
        Ac = MaskedRows(A, mask[c : c + 1])
        s = tgv(yb[:, c : c + 1], Ac, mu=mus[c], tvl2=tvl2[c], max_iter=400, nonneg=nonneg,
                return_result=True)
        torch.testing.assert_close(r.x[:, c : c + 1], s.x, rtol=1e-10, atol=1e-12)
        assert int(r.n_iter[0, c]) == int(s.n_iter)


def test_fixed_iterations_make_no_host_reads():
    from tests.test_syncs import count_syncs

    A = Hadamard(16, sr=0.5)
    y = A(planar_depth(16).reshape(1, 1, 16, 16))

    def syncs(k):
        with count_syncs() as n:
            tgv(y, A, max_iter=k, adaptive=False, return_result=True)
        return n[0]

    syncs(5)
    assert syncs(10) == syncs(5)


# -- bad inputs --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "kw, exc, name",
    [
        (dict(mu=-1.0), ValueError, "mu"),
        (dict(mu="auto"), TypeError, "mu"),
        (dict(mu=torch.tensor([[1.0, -2.0]])), ValueError, "mu"),
        (dict(mu=torch.ones(3, 3)), ValueError, "mu"),
        (dict(alpha=0.0), ValueError, "alpha"),
        (dict(alpha="big"), ValueError, "alpha"),
        (dict(alpha=(1.0, "a")), TypeError, "alpha"),
        (dict(alpha=(1.0, 2.0, 3.0)), TypeError, "alpha"),
        (dict(tv="tv1"), ValueError, "tv"),
        (dict(boundary="mirror"), ValueError, "boundary"),
        (dict(max_iter=0), ValueError, "max_iter"),
        (dict(max_iter=2.5), TypeError, "max_iter"),
        (dict(tol=-1e-3), ValueError, "tol"),
        (dict(tvl2="yes"), TypeError, "tvl2"),
        (dict(tvl2=torch.ones(1, 2)), TypeError, "tvl2"),
        (dict(bounds=(1.0, 0.0)), ValueError, "bounds"),
        (dict(nonneg=1), TypeError, "nonneg"),
        (dict(check_every=0), ValueError, "check_every"),
    ],
)
def test_bad_options_raise_naming_the_argument(kw, exc, name):
    A = Hadamard(8, sr=0.5)
    y = torch.zeros(1, 2, 32)
    with pytest.raises(exc, match=name):
        tgv(y, A, **kw, return_result=True)


def test_bad_y_and_operator_raise():
    A = Hadamard(8, sr=0.5)
    with pytest.raises(ValueError, match="y"):
        tgv(torch.zeros(1, 1, 31), A, return_result=True)
    with pytest.raises(TypeError, match="y"):
        tgv(torch.zeros(1, 1, 32, dtype=torch.int64), A, return_result=True)
    with pytest.raises(ValueError, match="y"):
        tgv(torch.full((1, 1, 32), float("nan")), A, return_result=True)
    with pytest.raises(TypeError, match="A"):
        tgv(torch.zeros(1, 1, 32), "A", return_result=True)
    with pytest.raises(TypeError, match="A"):
        TGV(None)
    with pytest.raises(ValueError, match="alpha"):
        TGV(A, alpha=-1.0)


@pytest.mark.parametrize("tv", ["isotropic", "anisotropic"])
def test_tgv_prior_gradient_on_flat_regions(tv):
    # as a training loss: a flat image (∇x − w = 0, Ew = 0 everywhere) has the subgradient 0,
    # not NaN (√ of a zero sum), and the gradient elsewhere is the norm's
    x = torch.zeros(1, 1, 6, 6, dtype=torch.float64, requires_grad=True)
    w = torch.zeros(1, 1, 2, 6, 6, dtype=torch.float64, requires_grad=True)
    tgv_prior(x, w, (1.0, 2.0), tv).sum().backward()
    assert torch.equal(x.grad, torch.zeros_like(x)) and torch.equal(w.grad, torch.zeros_like(w))
    g = torch.Generator().manual_seed(0)
    x2 = torch.rand(1, 1, 5, 5, generator=g, dtype=torch.float64, requires_grad=True)
    w2 = torch.rand(1, 1, 2, 5, 5, generator=g, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda a, b: tgv_prior(a, b, (1.0, 2.0), tv), (x2, w2))
