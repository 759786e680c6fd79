"""Tests of basis pursuit / BPDN (torchtof/recon/bp.py)."""

from __future__ import annotations

import warnings

import numpy as np
import onnxruntime as ort
import pytest
import scipy.optimize
import torch

from torchtof.operators import Hadamard, PatternOperator
from torchtof.recon.bp import BasisPursuit, BPResult, _projector, basis_pursuit, gram_factor
from torchtof.recon.dct import dct2, haar2, idct2, ihaar2

N_SIDE = 8
M = 26  # ≈ 40 % of 64
FWD = {"dct": dct2, "haar": haar2}
INV = {"dct": idct2, "haar": ihaar2}


def _gen(seed):
    return torch.Generator().manual_seed(seed)


def _hadamard(m=M):
    return Hadamard(N_SIDE, m=m)


def _gaussian(m=M, seed=1):
    return PatternOperator(
        torch.randn(m, N_SIDE, N_SIDE, generator=_gen(seed), dtype=torch.float64)
    )


def _sparse_image(basis, b=3, k=3, seed=2):
    """Images with ``k`` non-zero coefficients in ``basis``."""
    g = _gen(seed)
    z = torch.zeros(b, 1, N_SIDE * N_SIDE, dtype=torch.float64)
    for i in range(b):
        z[i, 0, torch.randperm(N_SIDE * N_SIDE, generator=g)[:k]] = torch.randn(
            k, generator=g, dtype=torch.float64
        )
    return INV[basis](z.reshape(b, 1, N_SIDE, N_SIDE))


def _l1(x, basis):
    return FWD[basis](x).abs().sum(dim=(-2, -1))


def _lp_optimum(a, basis, y):
    """``min Σt s.t. −t ≤ z ≤ t, AΨz = y`` with HiGHS; returns the optimal ``Σ|z|``."""
    n2 = N_SIDE * N_SIDE
    eye = torch.eye(n2, dtype=torch.float64).reshape(n2, 1, N_SIDE, N_SIDE)
    psi = INV[basis](eye).reshape(n2, n2).T.numpy()  # column j = Ψ e_j
    ap = a @ psi
    i = np.eye(n2)
    res = scipy.optimize.linprog(
        np.r_[np.zeros(n2), np.ones(n2)],
        A_ub=np.block([[i, -i], [-i, -i]]),
        b_ub=np.zeros(2 * n2),
        A_eq=np.c_[ap, np.zeros_like(ap)],
        b_eq=y,
        bounds=[(None, None)] * n2 + [(0, None)] * n2,
        method="highs",
    )
    assert res.status == 0, res.message
    return res.fun


# -- known answers --------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("op", "basis", "scene"),
    [
        ("hadamard", "dct", "dense"),
        ("hadamard", "haar", "dense"),
        ("gaussian", "dct", "sparse"),
        ("gaussian", "haar", "sparse"),
    ],
)
def test_matches_lp_optimum(op, basis, scene):
    A = _hadamard() if op == "hadamard" else _gaussian()
    if scene == "dense":
        x = torch.rand(2, 1, N_SIDE, N_SIDE, generator=_gen(3), dtype=torch.float64)
    else:
        x = _sparse_image(basis, b=2, k=4)
    y = A(x)
    res = basis_pursuit(y, A, basis=basis, tol=1e-7, return_result=True)
    assert bool(res.converged.all())
    a = A.matrix().numpy()
    for i in range(y.shape[0]):
        f_lp = _lp_optimum(a, basis, y[i, 0].numpy())
        f_bp = float(_l1(res.x[i], basis))
        assert abs(f_bp - f_lp) <= 1e-4 * f_lp, (f_bp, f_lp)
    assert float(res.residual.max()) < 1e-10  # feasible
    torch.testing.assert_close(res.residual,
                               torch.linalg.vector_norm(A(res.x) - y, dim=-1) / y.norm(dim=-1))


def test_exact_recovery_of_dct_sparse_image():
    A = _gaussian()
    x = _sparse_image("dct", k=3)
    res = basis_pursuit(A(x), A, tol=1e-8, return_result=True)
    err = (res.x - x).flatten(1).norm(dim=1) / x.flatten(1).norm(dim=1)
    assert float(err.max()) < 1e-6


def test_full_hadamard_is_exact_inverse():
    A = Hadamard(N_SIDE)  # M = N: {Ax = y} is a single point
    x = torch.rand(2, 1, N_SIDE, N_SIDE, generator=_gen(4), dtype=torch.float64)
    torch.testing.assert_close(basis_pursuit(A(x), A, n_iter=3), x, rtol=0, atol=1e-12)


def _soft(c, t):
    return torch.sign(c) * (c.abs() - t).clamp(min=0)


@pytest.mark.parametrize("scale", [1.0, 2.0])
def test_lagrangian_form_closed_form(scale):
    """With a square orthogonal ``A``, ``½‖Ax − y‖² + λ‖Ψᵀx‖₁`` is solved by soft thresholding;
    ``scale = 2`` sends the same rows through the general (Gram) path with ``L = 4``."""
    H = Hadamard(N_SIDE)
    x = torch.rand(2, 1, N_SIDE, N_SIDE, generator=_gen(5), dtype=torch.float64)
    A = PatternOperator(scale * H.matrix().reshape(-1, N_SIDE, N_SIDE)) if scale != 1 else H
    lam = 0.3
    res = basis_pursuit(A(x), A, lam=lam, tol=1e-12, return_result=True)
    want = idct2(_soft(dct2(x), lam / scale**2))
    torch.testing.assert_close(res.x, want, rtol=0, atol=1e-10)
    assert bool(res.converged.all())


def test_constraint_form_closed_form():
    """Square orthogonal ``A``: ``min ‖z‖₁ s.t. ‖z − c‖ ≤ ε`` is ``S_τ(c)`` with
    ``‖S_τ(c) − c‖ = ε`` (τ by bisection)."""
    A = Hadamard(N_SIDE)
    x = torch.rand(1, 1, N_SIDE, N_SIDE, generator=_gen(6), dtype=torch.float64)
    eps = 0.5
    c = dct2(x)
    lo, hi = 0.0, float(c.abs().max())
    for _ in range(200):
        t = (lo + hi) / 2
        lo, hi = (t, hi) if float((_soft(c, t) - c).norm()) < eps else (lo, t)
    res = basis_pursuit(A(x), A, eps=eps, tol=1e-10, return_result=True)
    torch.testing.assert_close(res.x, idct2(_soft(c, t)), rtol=0, atol=1e-9)
    # the constraint is active: ‖Ax − y‖ = ε, reported relative to ‖y‖
    torch.testing.assert_close(res.residual, eps / A(x).norm(dim=-1))


def test_constraint_form_general_path_matches_orthonormal():
    """``‖2Ax − 2y‖ ≤ 2ε`` is ``‖Ax − y‖ ≤ ε``: Gram path (s² = 4) == closed-form path."""
    H = _hadamard()
    A2 = PatternOperator(2 * H.matrix().reshape(-1, N_SIDE, N_SIDE))
    assert not A2.orthonormal_rows
    x = torch.rand(2, 1, N_SIDE, N_SIDE, generator=_gen(7), dtype=torch.float64)
    r1 = basis_pursuit(H(x), H, eps=0.2, tol=1e-10, return_result=True)
    r2 = basis_pursuit(A2(x), A2, eps=0.4, tol=1e-10, return_result=True)
    torch.testing.assert_close(r2.x, r1.x, rtol=0, atol=1e-7)
    torch.testing.assert_close(r1.residual, 0.2 / H(x).norm(dim=-1))


def test_general_projection_onto_ball_matches_scipy():
    A = PatternOperator(torch.rand(12, 4, 4, generator=_gen(8), dtype=torch.float64))
    u, s2, s2inv = gram_factor(A)
    assert float(s2.max() / s2.min()) > 100  # spread spectrum: Newton needs several steps
    y = A(torch.rand(2, 1, 4, 4, generator=_gen(9), dtype=torch.float64))
    v = 3 * torch.randn(2, 1, 4, 4, generator=_gen(10), dtype=torch.float64)
    eps = torch.tensor([0.5, 1e-4], dtype=torch.float64).reshape(2, 1, 1)
    p = _projector(A, y, (u, s2, s2inv), eps)(v)
    torch.testing.assert_close(
        torch.linalg.vector_norm(A(p) - y, dim=-1), eps[..., 0], rtol=1e-7, atol=0
    )
    a = A.matrix().numpy()
    for i in range(2):
        vv, yy, ee = v[i, 0].flatten().numpy(), y[i, 0].numpy(), float(eps[i])
        sol = scipy.optimize.minimize(
            lambda q, vv=vv: 0.5 * ((q - vv) ** 2).sum(),
            vv,
            jac=lambda q, vv=vv: q - vv,
            constraints=[
                {
                    "type": "ineq",
                    "fun": lambda q, yy=yy, ee=ee: ee**2 - ((a @ q - yy) ** 2).sum(),
                    "jac": lambda q, yy=yy: -2 * a.T @ (a @ q - yy),
                }
            ],
            method="SLSQP",
            options={"ftol": 1e-15, "maxiter": 1000},
        )
        np.testing.assert_allclose(p[i, 0].flatten().numpy(), sol.x, rtol=0, atol=1e-6)


def test_equality_general_path_invariant_to_row_mixing():
    """``{RAx = Ry} = {Ax = y}`` for invertible ``R``: same solution via the Gram path."""
    H = _hadamard()
    r = torch.randn(M, M, generator=_gen(11), dtype=torch.float64) + 4 * torch.eye(M)
    A = PatternOperator((r @ H.matrix()).reshape(-1, N_SIDE, N_SIDE))
    x = torch.rand(2, 1, N_SIDE, N_SIDE, generator=_gen(12), dtype=torch.float64)
    r1 = basis_pursuit(H(x), H, tol=1e-9, return_result=True)
    r2 = basis_pursuit(A(x), A, tol=1e-9, return_result=True)
    torch.testing.assert_close(_l1(r2.x, "dct"), _l1(r1.x, "dct"), rtol=1e-6, atol=0)
    torch.testing.assert_close(H(r2.x), H(x), rtol=0, atol=1e-9)


def test_rank_deficient_patterns_project_onto_least_squares_set():
    H = _hadamard()
    p = H.matrix().reshape(-1, N_SIDE, N_SIDE)
    A = PatternOperator(torch.cat([p, p[:3]]))  # repeated rows: A Aᵀ singular
    x = torch.rand(1, 1, N_SIDE, N_SIDE, generator=_gen(13), dtype=torch.float64)
    res = basis_pursuit(A(x), A, tol=1e-9, return_result=True)
    ref = basis_pursuit(H(x), H, tol=1e-9, return_result=True)
    assert bool(torch.isfinite(res.x).all())
    torch.testing.assert_close(_l1(res.x, "dct"), _l1(ref.x, "dct"), rtol=1e-6, atol=0)


def test_auto_eps_from_the_tail():
    """``ε = √M · median|y_tail| / 0.6745`` over the last M/4 measurements; the constraint
    is active at the solution, so ``‖Ax − y‖ = ε``."""
    A = Hadamard(4)  # M = 16, tail = last 4
    y = torch.zeros(1, 1, 16, dtype=torch.float64)
    y[..., 0] = 100.0
    y[..., -4:] = torch.tensor([1.0, -2.0, 3.0, -4.0], dtype=torch.float64)
    res = basis_pursuit(y, A, eps="auto", tol=1e-10, return_result=True)
    eps = 4 * 2.0 / 0.6744897501960817  # lower median of (1, 2, 3, 4) is 2
    torch.testing.assert_close(float(res.residual), eps / float(y.norm()), rtol=1e-8, atol=0)


# -- invariances, batching, modes -------------------------------------------------------------


def test_scale_invariance():
    A = _hadamard()
    y = A(torch.rand(2, 1, N_SIDE, N_SIDE, generator=_gen(14), dtype=torch.float64))
    r = basis_pursuit(y, A, return_result=True)
    assert torch.equal(basis_pursuit(8 * y, A), 8 * r.x)  # power of two: bit-exact
    fixed = basis_pursuit(y, A, n_iter=50, adaptive=False)
    torch.testing.assert_close(
        basis_pursuit(3.7e3 * y, A, n_iter=50, adaptive=False), 3.7e3 * fixed, rtol=1e-9, atol=0
    )


@pytest.mark.parametrize("op", ["hadamard", "gaussian"])
@pytest.mark.parametrize("kw", [{}, {"eps": 0.05}, {"lam": 0.01}, {"basis": "haar"}])
def test_batched_equals_stacked_singles(op, kw):
    A = _hadamard() if op == "hadamard" else _gaussian()
    y = A(torch.rand(3, 2, N_SIDE, N_SIDE, generator=_gen(15), dtype=torch.float64))
    res = basis_pursuit(y, A, n_iter=100, **kw, return_result=True)
    singles = [basis_pursuit(y[i : i + 1, c : c + 1], A, n_iter=100, **kw,
                             return_result=True) for i in range(3)
               for c in range(2)]  # fmt: skip
    x = torch.stack([s.x[0, 0] for s in singles]).reshape(3, 2, N_SIDE, N_SIDE)
    torch.testing.assert_close(res.x, x, rtol=1e-6, atol=1e-8)
    iters = torch.stack([s.n_iter[0, 0] for s in singles]).reshape(3, 2)
    assert int((res.n_iter - iters).abs().max()) <= 1
    assert res.n_iter.shape == res.residual.shape == res.converged.shape == (3, 2)


def test_zero_measurements_give_zero_image():
    for A, x in ((_hadamard(), torch.rand(3, 1, 8, 8, generator=_gen(16)).double()),
                 (_gaussian(), _sparse_image("dct", k=3))):  # fmt: skip
        y = A(x)
        y[1] = 0
        for kw in ({}, {"eps": 0.1}, {"lam": 0.1}):
            res = basis_pursuit(y, A, n_iter=300, **kw, return_result=True)
            assert torch.equal(res.x[1], torch.zeros_like(res.x[1]))
            assert bool(res.converged[1].all()) and bool(torch.isfinite(res.x).all())
            other = basis_pursuit(y[[0, 2]], A, n_iter=300, **kw)
            torch.testing.assert_close(res.x[[0, 2]], other, rtol=1e-6, atol=1e-9)
        assert torch.equal(basis_pursuit(torch.zeros_like(y), A), torch.zeros_like(x))
        for kw in ({}, {"eps": 0.1}, {"lam": 0.1}):  # finite gradients at y = 0
            yg = y.clone().requires_grad_()
            basis_pursuit(yg, A, n_iter=20, **kw).square().sum().backward()
            assert bool(torch.isfinite(yg.grad).all())


def test_eps_larger_than_signal_gives_zero():
    A = _hadamard()
    y = A(torch.rand(1, 1, N_SIDE, N_SIDE, generator=_gen(17), dtype=torch.float64))
    res = basis_pursuit(y, A, eps=1.01 * float(y.norm()), return_result=True)
    assert float(res.x.abs().max()) < 1e-12


def test_fixed_mode_runs_exactly_n_iter():
    A = _hadamard()
    y = A(torch.rand(2, 1, N_SIDE, N_SIDE, generator=_gen(18), dtype=torch.float64))
    res = basis_pursuit(y, A, n_iter=7, adaptive=False, return_result=True)
    assert res.n_iter.tolist() == [[7], [7]] and not bool(res.converged.any())
    short = basis_pursuit(y, A, n_iter=7, tol=1e-12, return_result=True)
    assert short.n_iter.tolist() == [[7], [7]] and not bool(short.converged.any())
    one = basis_pursuit(y, A, n_iter=1, adaptive=False, return_result=True)
    assert one.x.shape == (2, 1, N_SIDE, N_SIDE)
    easy = basis_pursuit(y, A, tol=1e-4, return_result=True)
    assert bool(easy.converged.all()) and int(easy.n_iter.max()) < 5000


@pytest.mark.parametrize("B", [1, 3])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_shapes_dtype_and_input_untouched(B, dtype):
    A = _hadamard()
    y = A(torch.rand(B, 1, N_SIDE, N_SIDE, generator=_gen(19), dtype=dtype))
    y0 = y.clone()
    res = basis_pursuit(y, A, n_iter=200, return_result=True)
    assert isinstance(res, BPResult)
    assert res.x.shape == (B, 1, N_SIDE, N_SIDE) and res.x.dtype == dtype
    assert res.x.device == y.device and res.residual.dtype == dtype
    assert res.n_iter.dtype == torch.int64 and res.converged.dtype == torch.bool
    assert torch.equal(y, y0)


def test_float32_close_to_float64():
    A = _gaussian()
    y = A(_sparse_image("dct", k=3))
    x64 = basis_pursuit(y, A)
    x32 = basis_pursuit(y.float(), A)
    assert x32.dtype == torch.float32
    torch.testing.assert_close(x32.double(), x64, rtol=0, atol=1e-4)


def test_module_equals_function_and_holds_gram():
    A = _gaussian()
    y = A(torch.rand(2, 1, N_SIDE, N_SIDE, generator=_gen(20), dtype=torch.float64))
    bp = BasisPursuit(A, basis="haar", n_iter=100, eps=0.01)
    assert hasattr(bp, "gram_u") and "gram_u" not in bp.state_dict()
    ref = basis_pursuit(y, A, basis="haar", n_iter=100, eps=0.01, return_result=True)
    torch.testing.assert_close(bp(y), ref.x, rtol=0, atol=1e-12)
    res = bp.solve(y)
    assert torch.equal(res.n_iter, ref.n_iter)
    H = _hadamard()
    assert not hasattr(BasisPursuit(H), "gram_u")
    torch.testing.assert_close(BasisPursuit(H, n_iter=50)(H(y.new_ones(1, 1, 8, 8))).sum(),
                               torch.tensor(64.0, dtype=torch.float64))  # fmt: skip


@pytest.mark.parametrize(
    ("adaptive", "kw"),
    [
        (True, {}),
        (False, {}),
        (False, {"eps": 0.05}),
        (False, {"lam": 0.01}),
        (False, {"basis": "haar"}),
    ],  # fmt: skip
)
@pytest.mark.parametrize("op", ["hadamard", "gaussian"])
def test_gradcheck(adaptive, kw, op):
    A = Hadamard(4, m=6) if op == "hadamard" else PatternOperator(torch.randn(6, 4, 4).double())
    y = A(torch.rand(1, 1, 4, 4, generator=_gen(22), dtype=torch.float64)).requires_grad_()
    assert torch.autograd.gradcheck(
        lambda y: basis_pursuit(y, A, n_iter=5, adaptive=adaptive, **kw), (y,)
    )


@pytest.mark.parametrize(
    ("op", "kw"), [("hadamard", {}), ("hadamard", {"eps": 0.05}), ("gaussian", {})]
)
def test_onnx_export_matches_eager(tmp_path, op, kw):
    A = _hadamard() if op == "hadamard" else PatternOperator(_gaussian().patterns.float())
    bp = BasisPursuit(A, n_iter=10, adaptive=False, **kw).eval()
    y2 = A(torch.rand(2, 1, N_SIDE, N_SIDE, generator=_gen(23)))
    y3 = A(torch.rand(3, 1, N_SIDE, N_SIDE, generator=_gen(24)))
    path = tmp_path / "bp.onnx"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            bp, (y2,), str(path), opset_version=17, dynamo=False, input_names=["y"],
            output_names=["x"], dynamic_axes={"y": {0: "B"}, "x": {0: "B"}},
        )  # fmt: skip
    out = ort.InferenceSession(str(path)).run(None, {"y": y3.numpy()})[0]
    np.testing.assert_allclose(out, bp(y3).numpy(), rtol=1e-4, atol=1e-5)


# -- errors -------------------------------------------------------------------------------------


def test_errors():
    A = _hadamard()
    y = A(torch.rand(1, 1, N_SIDE, N_SIDE))
    cases = [
        (ValueError, r"basis_pursuit: expected y of shape \(\*, \*, 26\), got \(1, 1, 25\)",
         dict(y=y[..., :25])),
        (ValueError, r"basis_pursuit: expected y of rank 3 \(B, C, M\), got shape \(1, 26\)",
         dict(y=y[0])),
        (ValueError, r"basis_pursuit: y contains non-finite values \(1 NaN",
         dict(y=torch.where(torch.arange(26) == 3, float("nan"), y))),
        (TypeError, r"basis_pursuit: expected y of dtype float32 or float64, got torch.float16",
         dict(y=y.half())),
        (TypeError, r"basis_pursuit: expected y to be a floating-point tensor",
         dict(y=y.long())),
        (TypeError, r"basis_pursuit: expected A to be a LinearOperator, got Linear",
         dict(A=torch.nn.Linear(2, 2))),
        (ValueError, r"basis_pursuit: expected basis in \('dct', 'haar', 'identity'\), got 'fft'",
         dict(basis="fft")),
        (ValueError, r"basis_pursuit: expected n_iter >= 1, got 0", dict(n_iter=0)),
        (TypeError, r"basis_pursuit: expected n_iter to be an int, got float", dict(n_iter=5.0)),
        (ValueError, r"basis_pursuit: expected rho > 0 and finite, got 0", dict(rho=0)),
        (ValueError, r"basis_pursuit: expected rho > 0 and finite, got -1", dict(rho=-1.0)),
        (ValueError, r"basis_pursuit: expected alpha in \(0.0, 2.0\), got 2", dict(alpha=2)),
        (ValueError, r"basis_pursuit: expected tol >= 0 and finite, got -1", dict(tol=-1.0)),
        (ValueError, r"basis_pursuit: expected eps > 0 and finite, got 0", dict(eps=0.0)),
        (ValueError, r"basis_pursuit: expected eps to be None, a number or 'auto', got 'x'",
         dict(eps="x")),
        (ValueError, r"basis_pursuit: expected lam > 0 and finite, got -0.1", dict(lam=-0.1)),
        (ValueError, r"basis_pursuit: give eps \(constraint form\) or lam", dict(eps=1, lam=1)),
    ]  # fmt: skip
    for exc, msg, kw in cases:
        args = dict(y=y, A=A) | kw
        with pytest.raises(exc, match=msg):
            basis_pursuit(**args, return_result=True)
    g = _gaussian()
    with pytest.raises(ValueError, match=r"basis_pursuit: eps='auto' .* orthonormal rows"):
        basis_pursuit(g(torch.rand(1, 1, 8, 8).double()), g, eps="auto", return_result=True)
    p6 = PatternOperator(torch.rand(10, 6, 6))
    with pytest.raises(ValueError, match=r"basis_pursuit: expected A.n \(image side\) for "):
        basis_pursuit(p6(torch.rand(1, 1, 6, 6)), p6, basis="haar", return_result=True)
    with pytest.raises(ValueError, match=r"BasisPursuit: expected rho > 0"):
        BasisPursuit(A, rho=0.0)
    with pytest.raises(ValueError, match=r"BasisPursuit: expected n_iter >= 1"):
        BasisPursuit(A, n_iter=0)
    with pytest.raises(TypeError, match=r"BasisPursuit: expected A to be a LinearOperator"):
        BasisPursuit("A")
    with pytest.raises(ValueError, match=r"basis_pursuit: expected y of shape"):
        BasisPursuit(A)(y[..., :3])


def test_equality_constrained_bp_on_noisy_buckets_warns_with_the_fix():
    import warnings

    from torchtof.operators import Hadamard
    from torchtof.recon import BasisPursuit

    A = Hadamard(16, sr=0.25)
    g = torch.Generator().manual_seed(0)
    x = torch.rand(1, 1, 16, 16, generator=g)
    y = A(x) + 0.05 * torch.randn(1, 1, A.m, generator=g)
    with pytest.warns(UserWarning, match="eps='auto'"):
        BasisPursuit(A, n_iter=20)(y)  # the budget runs out before the noise is fitted
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        BasisPursuit(A, n_iter=20, eps="auto")(y)


@pytest.mark.slow
def test_default_exact_model_against_the_auto_radius():
    # Why eps=None stays the default: the tail MAD reads signal as noise, so on noise-free
    # buckets eps="auto" gives a radius that is far too large (binary horse, n = 32, SR 25 %:
    # 15.3 vs 10.5 dB); on 5 %-noise buckets the exact fit fits the noise and eps="auto" wins
    # (moon: 10.0 vs 17.9 dB).
    from torchtof.metrics import psnr
    from torchtof.operators import Hadamard
    from torchtof.recon import basis_pursuit
    from torchtof.scenes import binary_scene, skimage_scene

    A = Hadamard(32, sr=0.25).double()

    def gap(x, noise):
        y = A(x)
        g = torch.Generator().manual_seed(0)
        y = y + noise * (y.max() - y.min()) * torch.randn(y.shape, dtype=y.dtype, generator=g)
        p = [float(psnr(basis_pursuit(y, A, eps=e).clamp(0, 1), x, bits=8))
             for e in (None, "auto")]
        return p[1] - p[0]

    assert gap(binary_scene("horse", 32, dtype=torch.float64), 0.0) < -2.0
    assert gap(skimage_scene("moon", 32, dtype=torch.float64), 0.05) > 3.0


def test_operator_too_small_for_float32_is_named_not_nan():
    from torchtof.operators import PatternOperator
    P = PatternOperator(torch.rand(6, 4, 4, generator=torch.Generator().manual_seed(0)) * 1e-20)
    x = torch.rand(1, 1, 4, 4, generator=torch.Generator().manual_seed(1))
    with pytest.raises(ValueError, match="basis_pursuit: A's rows are too small for torch.float32"):
        basis_pursuit(P(x), P)
    assert torch.isfinite(basis_pursuit(P(x.double()), P)).all()  # float64 holds them


def test_a_gram_requiring_grad_keeps_the_graph():
    # patterns being learned give a Gram factor that requires grad: the loop must not run in
    # inference mode then (the gradient reaches the patterns through it)
    from torchtof.recon.bp import gram_factor

    g = torch.Generator().manual_seed(4)
    w = torch.nn.Parameter(torch.randn(10, 4, 4, generator=g, dtype=torch.float64))
    P = PatternOperator(w.detach())  # the solve's operator holds no gradient itself...
    y = P(torch.rand(1, 1, 4, 4, generator=g, dtype=torch.float64)).detach()
    gram = gram_factor(PatternOperator(w))  # ...the Gram factor passed in does
    assert any(t.requires_grad for t in gram)
    x = basis_pursuit(y, P, n_iter=5, adaptive=False, gram=gram)
    assert x.requires_grad
    x.sum().backward()
    assert w.grad is not None and torch.isfinite(w.grad).all()
