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
