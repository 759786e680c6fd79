import pytest
import scipy.linalg
import torch

from torchtof.operators import (
    DMDSplit,
    Hadamard,
    PatternOperator,
    combine_split,
    hadamard_patterns,
    sylvester,
)

from .registry import OPERATORS


@pytest.fixture(params=sorted(OPERATORS))
def op(request):
    return OPERATORS[request.param]()


def test_adjointness_float64(op):
    assert op.adjointness_test(dtype=torch.float64) < 1e-12


def test_matrix_consistent_with_forward(op):
    x = torch.randn(3, 2, op.n, op.n, dtype=torch.float64)
    y = op(x)
    yy = (x.reshape(3, 2, -1) @ op.matrix().T)
    torch.testing.assert_close(y, yy, rtol=1e-12, atol=1e-12)


def test_shapes_batch_and_dtype(op, dtype):
    for b in (1, 3):
        x = torch.randn(b, 2, op.n, op.n, dtype=dtype)
        y = op(x)
        assert y.shape == (b, 2, op.m) and y.dtype == dtype
        assert op.adjoint(y).shape == x.shape and op.adjoint(y).dtype == dtype


def test_batched_equals_stacked(op):
    x = torch.randn(3, 1, op.n, op.n, dtype=torch.float64)
    y = op(x)
    singles = torch.cat([op(x[i : i + 1]) for i in range(3)])
    torch.testing.assert_close(y, singles)


def test_input_not_modified(op):
    x = torch.randn(2, 1, op.n, op.n)
    x0 = x.clone()
    op.adjoint(op(x))
    assert torch.equal(x, x0)


def test_pinv_is_least_squares(op):
    x = torch.randn(2, 1, op.n, op.n, dtype=torch.float64)
    y = op(x)
    xp = op.pinv(y)
    torch.testing.assert_close(op(xp), y, rtol=1e-8, atol=1e-8)


def test_gradcheck(op):
    x = torch.randn(1, 1, op.n, op.n, dtype=torch.float64, requires_grad=True)
    y = torch.randn(1, 1, op.m, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(op, (x,))
    assert torch.autograd.gradcheck(op.adjoint, (y,))


@pytest.mark.parametrize("n", [2, 4, 8, 16, 32])
@pytest.mark.parametrize("order", ["natural", "cake_cutting", "sequency", "russian_doll"])
def test_rows_are_scipy_hadamard_rows(n, order):
    if n == 2:
        with pytest.raises(ValueError, match="n"):
            Hadamard(n, order=order)
        return
    big = n * n
    A = Hadamard(n, order=order)
    rows = (A.matrix() * n).round().to(torch.int64)
    H = torch.from_numpy(scipy.linalg.hadamard(big)).to(torch.int64)
    torch.testing.assert_close(rows, H[A.index])
    # every order is a permutation of the full basis
    assert torch.equal(torch.sort(A.index).values, torch.arange(big))


@pytest.mark.parametrize("method", ["matmul", "kron", "fwht"])
def test_orthonormal_rows(method):
    A = Hadamard(16, sr=0.3, method=method)
    a = A.matrix()
    torch.testing.assert_close(a @ a.T, torch.eye(A.m, dtype=a.dtype), rtol=0, atol=1e-12)
    assert A.orthonormal_rows


def test_fwht_equals_matmul_float32():
    x = torch.randn(4, 1, 32, 32)
    a, b = Hadamard(32, sr=0.4, method="fwht"), Hadamard(32, sr=0.4, method="matmul")
    torch.testing.assert_close(a(x), b(x), rtol=1e-5, atol=1e-4)
    y = a(x)
    torch.testing.assert_close(a.adjoint(y), b.adjoint(y), rtol=1e-5, atol=1e-5)


def test_full_set_pinv_exact():
    A = Hadamard(16)
    x = torch.rand(2, 1, 16, 16, dtype=torch.float64)
    torch.testing.assert_close(A.pinv(A(x)), x, rtol=0, atol=1e-12)


def test_sr_prefix_property():
    big, small = Hadamard(16, sr=0.5), Hadamard(16, sr=0.125)
    x = torch.randn(1, 1, 16, 16)
    torch.testing.assert_close(big(x)[..., : small.m], small(x))


def test_dmd_split_patterns_binary_and_combine():
    A = Hadamard(8, sr=0.5)
    S = DMDSplit(A)
    p = S.patterns()
    assert set(p.unique().tolist()) <= {0.0, 1.0}
    torch.testing.assert_close(p[0::2] + p[1::2], torch.ones_like(p[0::2]))
    x = torch.rand(2, 1, 8, 8, dtype=torch.float64)
    torch.testing.assert_close(combine_split(S(x), 8), A(x))
    # offset common to both frames cancels: y⁺ − y⁻ is unchanged by a constant added to all
    torch.testing.assert_close(S.combine(S(x) + 7.0), A(x))


def test_pattern_operator_matches_hadamard():
    A = Hadamard(8, sr=0.5)
    P = PatternOperator(hadamard_patterns(8, A.m, dtype=torch.float64) / 8)
    assert P.orthonormal_rows
    x = torch.randn(2, 3, 8, 8, dtype=torch.float64)
    torch.testing.assert_close(P(x), A(x))


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(n=12), "power of two"),
        (dict(n=512), "power of two"),
        (dict(n=8, sr=0.0), "sr"),
        (dict(n=8, sr=1.5), "sr"),
        (dict(n=8, m=0), "m"),
        (dict(n=8, m=65), "m"),
        (dict(n=8, sr=0.5, m=4), "exactly one"),
        (dict(n=8, order="zigzag"), "order"),
        (dict(n=8, method="dense"), "method"),
    ],
)
def test_bad_config(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Hadamard(**kwargs)


def test_bad_inputs():
    A = Hadamard(8, sr=0.25)
    with pytest.raises(ValueError, match=r"Hadamard.forward: expected x of shape \(\*, \*, 8, 8\)"):
        A(torch.zeros(1, 1, 4, 4))
    with pytest.raises(ValueError, match="rank 4"):
        A(torch.zeros(8, 8))
    with pytest.raises(ValueError, match=r"expected y of shape \(\*, \*, 16\)"):
        A.adjoint(torch.zeros(1, 1, 15))
    with pytest.raises(ValueError, match="NaN"):
        A.adjoint(torch.full((1, 1, 16), float("nan")))
    with pytest.raises(TypeError, match="floating-point"):
        A(torch.zeros(1, 1, 8, 8, dtype=torch.int64))
    with pytest.raises(TypeError, match="torch.Tensor"):
        A([[1.0]])
    with pytest.raises(ValueError, match="patterns"):
        PatternOperator(torch.zeros(3, 4, 5))
    with pytest.raises(TypeError, match="Hadamard"):
        DMDSplit(PatternOperator(torch.ones(2, 4, 4)))
    with pytest.raises(ValueError, match=r"PatternOperator: .*n >= 1, got \(3, 0, 0\)"):
        PatternOperator(torch.zeros(3, 0, 0))
    with pytest.raises(TypeError, match="PatternOperator: expected patterns to be a real tensor"):
        PatternOperator(torch.ones(3, 4, 4, dtype=torch.complex64))
    with pytest.raises(ValueError, match="even"):
        combine_split(torch.zeros(1, 1, 3), 4)


@pytest.mark.parametrize("n", [4, 8, 32, 64, 128])
def test_kron_equals_matmul_every_size(n):
    """The radix-16 Kronecker stages equal H_n X H_n (Sylvester: H_N = ⊗ H_r), float64."""
    x = torch.randn(3, 2, n, n, dtype=torch.float64)
    a, b = Hadamard(n, sr=0.3, method="kron"), Hadamard(n, sr=0.3, method="matmul")
    torch.testing.assert_close(a(x), b(x), rtol=1e-12, atol=1e-10)
    y = a(x)
    torch.testing.assert_close(a.adjoint(y), b.adjoint(y), rtol=1e-12, atol=1e-10)


def test_kron_factors_and_bad_factors():
    from torchtof.operators.fwht import fwht_kron, kron_factors, sylvester

    assert kron_factors(4096) == (16, 16, 16)
    assert kron_factors(2048) == (8, 16, 16)
    assert kron_factors(16) == (16,)
    assert kron_factors(2, radix=16) == (2,)
    x = torch.randn(5, 64, dtype=torch.float64)
    ref = x @ sylvester(64, torch.float64)
    for fac in ((64,), (4, 16), (16, 4), (2, 2, 2, 8)):
        hs = tuple(sylvester(r, torch.float64) for r in fac)
        torch.testing.assert_close(fwht_kron(x, hs), ref, rtol=1e-12, atol=1e-12)
    with pytest.raises(ValueError, match="factors multiply to 32"):
        fwht_kron(x, (sylvester(2), sylvester(16)))
    with pytest.raises(ValueError, match="big"):
        kron_factors(48)


def test_auto_method_by_size():
    assert Hadamard(32, sr=0.25).method == "matmul"
    assert Hadamard(64, sr=0.25).method == "kron"
    assert Hadamard(256, m=10).method == "kron"


def test_sylvester_result_is_not_shared_with_operators():
    # H_8 written into must not reach the cache behind Hadamard buffers: an operator built
    # before and one built after must both still have ±1 rows with A Aᵀ = I.
    before = Hadamard(8, m=64, method="matmul")
    h = sylvester(8)
    h[h < 0] = 0
    h2 = sylvester(8)
    assert torch.equal(h2.abs(), torch.ones(8, 8))  # a fresh ±1 matrix again
    after = Hadamard(8, m=64, method="matmul")
    eye = torch.eye(64, dtype=torch.float64)
    for op in (before, after):
        assert torch.equal(op.h.abs(), torch.ones(8, 8))
        a = op.matrix()
        torch.testing.assert_close(a @ a.T, eye, rtol=0, atol=1e-12)
    # the kron path's factors come from the same cache
    hk = sylvester(16)
    hk.zero_()
    a = Hadamard(64, m=16, method="kron").matrix()
    torch.testing.assert_close(a @ a.T, torch.eye(16, dtype=torch.float64), rtol=0, atol=1e-12)


def test_hadamard_finite_when_the_result_fits():
    # a constant 1e36 on 32x32: the all-ones row (first in cake-cutting order) gives
    # Σx / n = 1024·1e36 / 32 = 3.2e37 < 3.4e38 = float32 max, every other row 0.
    a = Hadamard(32, sr=0.25)
    y = a(torch.full((1, 1, 32, 32), 1e36))
    assert torch.isfinite(y).all()
    torch.testing.assert_close(y[0, 0, 0], torch.tensor(3.2e37), rtol=1e-6, atol=0)
    assert y[0, 0, 1:].abs().max() <= 1e-6 * 3.2e37
    # back: Aᵀ(3.2e37·e₀) = 3.2e37 / 32 on every pixel = 1e36
    x = a.adjoint(torch.nn.functional.one_hot(torch.tensor([[0]]), a.m).float() * 3.2e37)
    torch.testing.assert_close(x, torch.full((1, 1, 32, 32), 1e36), rtol=1e-6, atol=0)
    # the DMD split: φ⁺ of the all-ones row is all ones, Σx = 1024·1e34 = 1.024e37; φ⁻ = 0
    ys = DMDSplit(a)(torch.full((1, 1, 32, 32), 1e34))
    assert torch.isfinite(ys).all()
    torch.testing.assert_close(ys[0, 0, :2], torch.tensor([1.024e37, 0.0]), rtol=1e-6, atol=1e31)
