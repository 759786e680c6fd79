"""The TV core: differences, adjoints, norms, shrinkage, Laplacian spectra, exact u-step."""

import pytest
import torch

from torchtof.operators import Hadamard, PatternOperator, random_binary_patterns
from torchtof.recon.dct import dct_matrix
from torchtof.recon.tv import (
    BOUNDARIES,
    admm_tv,
    exact_factors,
    exact_solve,
    grad2,
    grad2_adjoint,
    group_shrink,
    laplacian_eigs,
    laplacian_inverse,
    shrink,
    tv_norm,
)


def _dense_d(n, boundary):
    """``D`` as a ``(2n², n²)`` matrix, column by column from unit images."""
    eye = torch.eye(n * n, dtype=torch.float64).reshape(n * n, n, n)
    return grad2(eye, boundary).reshape(n * n, -1).T


@pytest.mark.parametrize("boundary", BOUNDARIES)
def test_adjointness(boundary):
    g = torch.Generator().manual_seed(0)
    u = torch.randn(2, 3, 7, 7, dtype=torch.float64, generator=g)
    w = torch.randn(2, 3, 2, 7, 7, dtype=torch.float64, generator=g)
    lhs = (grad2(u, boundary) * w).sum()
    rhs = (u * grad2_adjoint(w, boundary)).sum()
    assert abs(float(lhs - rhs)) < 1e-12 * float(lhs.abs() + 1)


def test_neumann_differences_by_hand():
    u = torch.tensor([[1.0, 4.0, 9.0], [2.0, 2.0, 0.0], [0.0, 5.0, 5.0]])
    g = grad2(u, "neumann")
    assert g[0].tolist() == [[3.0, 5.0, 0.0], [0.0, -2.0, 0.0], [5.0, 0.0, 0.0]]
    assert g[1].tolist() == [[1.0, -2.0, -9.0], [-2.0, 3.0, 5.0], [0.0, 0.0, 0.0]]
    gp = grad2(u, "periodic")  # wrap-around: last column is u[:, 0] - u[:, 2]
    assert gp[0, :, 2].tolist() == [-8.0, 2.0, -5.0]


def test_tv_of_a_step_image_by_hand():
    # 6×6 image, left half 0, right half 2: one vertical edge of 6 pixels, height 2.
    u = torch.zeros(1, 1, 6, 6)
    u[..., 3:] = 2.0
    # Neumann: only the edge counts, 6 · 2 = 12 (isotropic = anisotropic: one direction).
    assert tv_norm(u, True, boundary="neumann").item() == 12.0
    assert tv_norm(u, False, boundary="neumann").item() == 12.0
    # periodic: the wrap-around adds the second edge, 24.
    assert tv_norm(u, True).item() == 24.0
    # a single bright pixel (height 1) away from the border: isotropic 2 + 2·√1... by hand:
    # D at the pixel itself is (-1, -1) -> √2; left and upper neighbours (1, 0), (0, 1) -> 1, 1.
    p = torch.zeros(1, 1, 5, 5)
    p[..., 2, 2] = 1.0
    assert abs(tv_norm(p, True, boundary="neumann").item() - (2 + 2**0.5)) < 1e-6
    assert tv_norm(p, False, boundary="neumann").item() == 4.0


def test_shrink_known_values():
    v = torch.tensor([3.0, 4.0]).reshape(2, 1, 1)  # ‖v‖ = 5
    assert torch.allclose(shrink(v, 1.0, True).flatten(), torch.tensor([2.4, 3.2]))
    assert torch.allclose(shrink(v, 1.0, False).flatten(), torch.tensor([2.0, 3.0]))
    assert shrink(v, 6.0, True).abs().max() == 0
    # joint: the norm runs over channels too: two channels (3,4), (0,0) -> ‖·‖ = 5
    vj = torch.zeros(1, 2, 2, 1, 1)
    vj[0, 0, :, 0, 0] = torch.tensor([3.0, 4.0])
    out = group_shrink(vj, torch.full((1, 2), 1.0), "isotropic", joint=True)
    assert torch.allclose(out[0, 0].flatten(), torch.tensor([2.4, 3.2]))


@pytest.mark.parametrize("boundary", BOUNDARIES)
def test_laplacian_eigs_match_dense(boundary):
    n = 6
    d = _dense_d(n, boundary)
    lap = d.T @ d
    eig = laplacian_eigs(n, n, boundary=boundary)
    if boundary == "periodic":
        f = torch.fft.fft(torch.eye(n, dtype=torch.complex128), norm="ortho")
        basis = torch.kron(f, f)  # 2-D DFT, rows: frequencies (k, l)
    else:
        c = dct_matrix(n)
        basis = torch.kron(c, c).to(torch.complex128)
    diag = basis @ lap.to(torch.complex128) @ basis.conj().T
    assert torch.allclose(diag.diagonal().real, eig.flatten(), atol=1e-10)
    assert torch.allclose(diag - torch.diag(diag.diagonal()), torch.zeros_like(diag), atol=1e-10)


@pytest.mark.parametrize("boundary", BOUNDARIES)
@pytest.mark.parametrize("orthonormal", [True, False])
def test_exact_solve_matches_dense(boundary, orthonormal):
    n = 8
    if orthonormal:
        A = Hadamard(n, sr=0.25)
    else:
        g = torch.Generator().manual_seed(1)
        A = PatternOperator(random_binary_patterns(24, n, generator=g, dtype=torch.float64))
    d = _dense_d(n, boundary)
    am = A.matrix().double()
    rho = torch.tensor([[0.5, 3.0]], dtype=torch.float64)
    r = torch.randn(1, 2, n, n, dtype=torch.float64, generator=torch.Generator().manual_seed(2))
    f = exact_factors(A, r, boundary)
    u, au = exact_solve(r, rho, A.forward, A.adjoint, f)
    for c in range(2):
        mat = d.T @ d + rho[0, c] * am.T @ am
        ref = torch.linalg.lstsq(mat, r[0, c].flatten()).solution
        assert torch.allclose(u[0, c].flatten(), ref, atol=1e-8)
        assert torch.allclose(au[0, c], am @ ref, atol=1e-8)


def test_laplacian_inverse_neumann_inverts_k():
    n = 8
    d = _dense_d(n, "neumann")
    k = d.T @ d + torch.full((n * n, n * n), 1.0 / (n * n), dtype=torch.float64)
    r = torch.randn(n, n, dtype=torch.float64)
    f = exact_factors(Hadamard(n, sr=0.25), r, "neumann")
    assert torch.allclose(k @ laplacian_inverse(r, f.kinv).flatten(), r.flatten(), atol=1e-10)


@pytest.mark.parametrize("boundary", BOUNDARIES)
def test_admm_tv_solves_constrained_problem(boundary):
    # A piecewise-constant square seen at SR 50 %: the TV minimiser with A u = b is the square.
    n = 16
    A = Hadamard(n, sr=0.5).double()
    x = torch.zeros(1, 1, n, n, dtype=torch.float64)
    x[..., 4:11, 5:12] = 1.0
    b = A(x)
    one = torch.ones(1, 1, dtype=torch.float64)
    out = admm_tv(b, A, 256 * one, 32 * one, one.bool(), boundary=boundary, max_iter=400)
    assert (out.u - x).abs().max() < 1e-3
    assert (A(out.u) - b).abs().max() < 1e-6


def test_box_bounds_one_validation_for_every_tv_solver():
    from torchtof.operators import Hadamard
    from torchtof.recon import auto, tgv, tval3
    from torchtof.recon.tv import box_bounds

    assert box_bounds(False, None, "f") == (None, None)
    assert box_bounds(True, None, "f") == (0.0, None)
    assert box_bounds(True, (-1, 2), "f") == (0.0, 2.0)
    assert box_bounds(False, (None, 5), "f") == (None, 5.0)
    A = Hadamard(8, sr=0.5)
    y = torch.zeros(1, 1, 32)
    for fn, f in (("tval3", tval3), ("tgv", tgv), ("auto", auto)):
        with pytest.raises(TypeError, match=f"{fn}: expected bounds lo a number or None"):
            f(y, A, bounds=("0", 1.0))
        with pytest.raises(TypeError, match=f"{fn}: expected bounds hi a number or None"):
            f(y, A, bounds=(0.0, True))
        with pytest.raises(ValueError, match=f"{fn}: expected bounds hi finite or None"):
            f(y, A, bounds=(0.0, float("inf")))
        with pytest.raises(ValueError, match=f"{fn}: expected bounds with lo < hi"):
            f(y, A, bounds=(1.0, 1.0))
        with pytest.raises(ValueError, match=f"{fn}: expected bounds to be a pair"):
            f(y, A, bounds=(0.0,))


# -- split_tv: the TV-L2 solve of auto on orthonormal rows -------------------------------------


def _pdhg_tv_l2(b, A, mu, tv, boundary, lo=None, hi=None, iters=5000):
    """Independent oracle for min TV(u) + mu/2||Au - b||^2 + box: the primal-dual algorithm of
    Chambolle & Pock 2011 (J. Math. Imaging Vis. 40, Alg. 1, theta = 1) with dense matrices,
    K = [D; A], f = TV-norm + mu/2||. - b||^2 (dual proxes: projection on the unit balls and
    (s - sigma b)/(1 + sigma/mu)), g = the box indicator (prox: clamp)."""
    n = A.n
    eye = torch.eye(n * n, dtype=torch.float64).reshape(n * n, 1, n, n)
    dm = grad2(eye, boundary).reshape(n * n, -1).T  # (2n^2, n^2), rows: x-diffs then y-diffs
    am = A(eye).reshape(n * n, -1).T  # (M, n^2)
    k = torch.cat([dm, am])
    lip = float(torch.linalg.matrix_norm(k, ord=2))
    tau = sigma = 0.99 / lip
    x = torch.zeros(n * n, dtype=torch.float64)
    xb, yd, ya = x.clone(), torch.zeros(2 * n * n, dtype=torch.float64), torch.zeros(am.shape[0],
                                                                                        dtype=torch.float64)
    bv = b.reshape(-1)
    for _ in range(iters):
        s = yd + sigma * (dm @ xb)
        if tv == "isotropic":
            v = s.reshape(2, n * n)
            yd = (v / v.norm(dim=0).clamp_min(1.0)).reshape(-1)
        else:
            yd = s.clamp(-1.0, 1.0)
        ya = (ya + sigma * (am @ xb) - sigma * bv) / (1.0 + sigma / mu)
        x_new = x - tau * (dm.T @ yd + am.T @ ya)
        if lo is not None:
            x_new = x_new.clamp(min=lo, max=hi)
        xb, x = 2 * x_new - x, x_new
    return x.reshape(1, 1, n, n)


def _tv_l2_objective(u, b, A, mu, tv, boundary):
    return float(tv_norm(u, tv == "isotropic", boundary=boundary).sum()
                 + 0.5 * mu * (A(u) - b).square().sum())


_SPLIT_CASES = [(bd, tv, box) for bd in BOUNDARIES for tv in ("isotropic", "anisotropic")
                for box in ((None, None), (0.15, 0.5))]
_SPLIT_DEFAULT = {("neumann", "isotropic", (0.15, 0.5)), ("periodic", "anisotropic", (None, None))}


@pytest.mark.parametrize("boundary,tv,box", [
    pytest.param(*c, marks=() if c in _SPLIT_DEFAULT else pytest.mark.slow) for c in _SPLIT_CASES])
def test_split_tv_reaches_the_minimiser_of_an_independent_solver(boundary, tv, box):
    from torchtof.recon.tv import split_tv

    n = 8
    A = Hadamard(n, sr=0.375).double()
    x = torch.zeros(1, 1, n, n, dtype=torch.float64)
    x[..., 2:6, 1:5] = 1.0
    x[..., 5:7, 5:8] = 0.5
    g = torch.Generator().manual_seed(0)
    b = A(x) + 0.05 * torch.randn(1, 1, A.m, generator=g, dtype=torch.float64)
    mu = 4.0
    ref = _pdhg_tv_l2(b, A, mu, tv, boundary, *box)
    got = split_tv(b, A, torch.full((1, 1), mu, dtype=torch.float64), tv=tv, boundary=boundary,
                   bounds=box, max_iter=2000)
    f_ref = _tv_l2_objective(ref, b, A, mu, tv, boundary)
    f_got = _tv_l2_objective(got, b, A, mu, tv, boundary)
    assert f_got <= f_ref + 1e-6 * f_ref
    assert (got - ref).abs().max() < 2e-3
    if box[0] is not None:
        assert got.min() >= box[0] and got.max() <= box[1]
        # both bounds are active: the test means something
        assert float(ref.min()) == box[0] and float(ref.max()) == box[1]


def test_split_tv_recovers_a_constant_and_is_scale_equivariant():
    from torchtof.recon.tv import split_tv

    A = Hadamard(16, sr=0.25).double()
    c = torch.full((1, 1, 16, 16), 0.7, dtype=torch.float64)
    mu = torch.full((1, 1), 64.0, dtype=torch.float64)
    # TV(c) = 0 and A c = b: the constant is the minimiser
    torch.testing.assert_close(split_tv(A(c), A, mu, max_iter=300), c, rtol=0, atol=1e-8)
    g = torch.Generator().manual_seed(1)
    b = torch.randn(2, 3, A.m, generator=g, dtype=torch.float64)
    mus = torch.tensor([[4.0, 64.0, 1024.0]], dtype=torch.float64).expand(2, 3)
    u = split_tv(b, A, mus, max_iter=50)
    torch.testing.assert_close(split_tv(5.0 * b, A, mus / 5.0, max_iter=50), 5.0 * u)
    # zero buckets: zeros, no NaN
    z = split_tv(torch.zeros(1, 1, A.m, dtype=torch.float64), A, mu, max_iter=20)
    assert torch.equal(z, torch.zeros_like(z))


def test_split_tv_on_masked_rows_solves_the_subset_problem():
    """A row-masked orthonormal operator (auto's folds): A^T M A is a projection, so the split
    p-step stays exact and the solve is that of the unmasked subset of rows."""
    from torchtof.recon.tv import split_tv
    from torchtof.recon.tval3 import MaskedRows

    n, k = 16, 48
    A = Hadamard(n, sr=0.375).double()
    sub = Hadamard(n, m=k).double()  # the first k rows of the same order
    x = torch.zeros(1, 1, n, n, dtype=torch.float64)
    x[..., 3:12, 4:9] = 1.0
    y = A(x)
    mask = torch.zeros(1, A.m, dtype=torch.bool)
    mask[0, :k] = True
    mu = torch.full((1, 1), 100.0, dtype=torch.float64)
    got = split_tv(y * mask, MaskedRows(A, mask), mu, max_iter=300)
    want = split_tv(y[..., :k], sub, mu, max_iter=300)
    torch.testing.assert_close(got, want, rtol=0, atol=1e-5)


def test_split_tv_refuses_an_operator_without_orthonormal_rows():
    from torchtof.recon.tv import split_tv

    g = torch.Generator().manual_seed(0)
    P = PatternOperator(random_binary_patterns(16, 8, generator=g))
    with pytest.raises(ValueError, match="split_tv: expected A with orthonormal rows"):
        split_tv(torch.zeros(1, 1, 16), P, torch.ones(1, 1))
    H = Hadamard(4, sr=1.0)
    with pytest.raises(ValueError, match="split_tv: expected tv in"):
        split_tv(torch.zeros(1, 1, 16), H, torch.ones(1, 1), tv="iso")
    with pytest.raises(ValueError, match="split_tv: expected bounds with lo < hi"):
        split_tv(torch.zeros(1, 1, 16), H, torch.ones(1, 1), bounds=(1.0, 0.0))
    # a float64 weight does not change a float32 solve's dtype
    assert split_tv(torch.ones(1, 1, 16), H, torch.ones(1, 1, dtype=torch.float64),
                    max_iter=2).dtype == torch.float32
