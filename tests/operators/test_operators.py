import warnings

import pytest
import scipy.linalg
import torch

from torchtof.operators import (
    DMDSplit,
    Hadamard,
    PatternOperator,
    combine_split,
    hadamard_patterns,
    split_patterns,
    sylvester,
)

from .registry import OPERATORS


@pytest.fixture(params=sorted(OPERATORS))
def op(request):
    return OPERATORS[request.param]()


def test_adjointness_float64(op):
    assert op.adjointness_test(dtype=torch.float64) < 1e-12


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_loop_pair_is_forward_and_adjoint_bit_for_bit(op, dtype):
    # the solvers' loops call these in place of forward/adjoint: same arithmetic, any batch
    x = torch.randn(3, 2, op.n, op.n, dtype=dtype)
    y = torch.randn(3, 2, op.m, dtype=dtype)
    fwd, adj = op.loop_pair(y)
    assert torch.equal(fwd(x), op(x)) and torch.equal(adj(y), op.adjoint(y))
    assert torch.equal(fwd(x[:1]), op(x[:1])) and torch.equal(adj(y[:1]), op.adjoint(y[:1]))


def test_a_subclass_overriding_forward_is_called_by_the_solvers():
    # the fast path must not bypass a user's forward/adjoint (a sensor model, a call counter)
    from torchtof.recon import basis_pursuit, tval3

    class Counted(Hadamard):
        calls = 0

        def forward(self, x):
            Counted.calls += 1
            return super().forward(x)

    A = Counted(8, sr=0.5)
    fwd, _ = A.loop_pair(torch.zeros(1, 1, A.m))
    assert fwd.__func__ is Counted.forward
    y = A(torch.rand(1, 1, 8, 8, dtype=torch.float64))
    for solve, budget in ((tval3, {"max_iter": 5}), (basis_pursuit, {"n_iter": 5})):
        before = Counted.calls
        with warnings.catch_warnings():  # 5 iterations: BP warns that it did not converge
            warnings.simplefilter("ignore")
            solve(y, A, **budget)
        assert Counted.calls - before >= 5, solve.__name__


def test_masked_rows_loop_pair_is_its_forward_and_adjoint():
    from torchtof.recon.tval3 import MaskedRows

    A = Hadamard(8, sr=0.5)
    mask = torch.rand(2, A.m, generator=torch.Generator().manual_seed(0)) > 0.3
    op = MaskedRows(A, mask)
    x, y = torch.randn(3, 2, 8, 8, dtype=torch.float64), torch.randn(3, 2, A.m, dtype=torch.float64)
    fwd, adj = op.loop_pair(y)
    assert torch.equal(fwd(x), op(x)) and torch.equal(adj(y), op.adjoint(y))
    assert (fwd(x)[:, 0, ~mask[0]] == 0).all() and (fwd(x)[:, 1, mask[1]] != 0).all()


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
    # the minimum-norm solution, not any solution: A⁺ y of the dense matrix's own SVD (a
    # null-space component would still fit the buckets)
    ref = (y.reshape(2, -1) @ torch.linalg.pinv(op.matrix(torch.float64)).T)
    torch.testing.assert_close(xp.reshape(2, -1), ref, rtol=1e-8, atol=1e-8)


def test_gradcheck(op):
    x = torch.randn(1, 1, op.n, op.n, dtype=torch.float64, requires_grad=True)
    y = torch.randn(1, 1, op.m, dtype=torch.float64, requires_grad=True)
    # fast mode (random projections vᵀ J u of the Jacobian) where the full Jacobian is large
    fast = op.n >= 32
    assert torch.autograd.gradcheck(op, (x,), fast_mode=fast)
    assert torch.autograd.gradcheck(op.adjoint, (y,), fast_mode=fast)


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


def test_split_patterns_stream_in_chunks():
    # rows start:stop of the 2M DMD patterns equal the slice of the full stack, for ranges
    # that start or stop inside a (φ⁺, φ⁻) pair and across the internal chunk boundary
    from torchtof.operators import split as split_mod

    s = DMDSplit(Hadamard(8, sr=0.75))  # 48 ±1 rows, 96 DMD rows
    full = split_patterns(s.hadamard.patterns())
    old = split_mod.PATTERN_CHUNK
    split_mod.PATTERN_CHUNK = 5  # force several chunks
    try:
        assert torch.equal(s.patterns(), full)
        for a, b in [(0, 1), (1, 2), (3, 50), (17, 96), (95, 96), (40, 40)]:
            assert torch.equal(s.patterns(start=a, stop=b), full[a:b])
        got = torch.cat([p for _, p in s.iter_patterns(7)])
        assert torch.equal(got, full)
    finally:
        split_mod.PATTERN_CHUNK = old
    assert torch.equal(s.hadamard.patterns(start=5, stop=9), s.hadamard.patterns()[5:9])
    with pytest.raises(ValueError, match=r"DMDSplit.patterns: expected 0 <= start <= stop <= 96"):
        s.patterns(start=10, stop=97)
    with pytest.raises(TypeError, match="Hadamard.patterns: expected start to be an int"):
        s.hadamard.patterns(start=1.0)
    with pytest.raises(ValueError, match="iter_patterns: expected chunk"):
        next(s.iter_patterns(0))


def test_patterns_refuse_what_exceeds_the_memory_limit():
    import torchtof

    torchtof.set_memory_limit("1M")
    try:
        # 2·1024 DMD patterns of 32x32 float32 = 8 MiB, plus one chunk of 2·256 rows (2 MiB)
        # = 10 MiB > 1 MiB: refused with the estimate
        with pytest.raises(ValueError, match=r"DMDSplit.patterns: 2048 DMD patterns of 32x32 "
                                             r"needs about 10 MiB, more than the memory limit "
                                             r"of 1 MiB"):
            DMDSplit(Hadamard(32)).patterns()
        with pytest.raises(ValueError, match="Hadamard.patterns: 1024 patterns"):
            Hadamard(32).patterns()
        # a chunk that fits still streams
        assert next(DMDSplit(Hadamard(32)).iter_patterns(64))[1].shape == (64, 32, 32)
        with pytest.raises(ValueError, match="PatternOperator: an \\(1024, 32, 32\\)"):
            PatternOperator(torch.ones(1024, 32, 32))
    finally:
        torchtof.set_memory_limit(None)
    assert torchtof.memory_limit() > 0


def test_memory_limit_settings(monkeypatch):
    import torchtof
    from torchtof._memory import memory_limit

    monkeypatch.setenv("TORCHTOF_MEMORY_LIMIT", "2G")
    assert memory_limit() == 2 << 30
    monkeypatch.setenv("TORCHTOF_MEMORY_LIMIT", "none")
    assert memory_limit() == 0
    monkeypatch.setenv("TORCHTOF_MEMORY_LIMIT", "lots")
    with pytest.raises(ValueError, match="TORCHTOF_MEMORY_LIMIT: expected bytes"):
        memory_limit()
    with pytest.raises(ValueError, match="set_memory_limit: expected limit >= 0"):
        torchtof.set_memory_limit(-1)
    with pytest.raises(TypeError, match="set_memory_limit: expected limit to be an int"):
        torchtof.set_memory_limit(1.5)


def test_dense_views_refuse_what_cannot_fit():
    import torchtof

    # Hadamard(256) as a dense matrix: 65536² float64 = 32 GiB (plus the m×m unit vectors)
    torchtof.set_memory_limit("16G")
    try:
        with pytest.raises(ValueError, match=r"Hadamard.matrix: the dense 65536x65536 matrix "
                                             r"needs about"):
            Hadamard(256).matrix()
        with pytest.raises(ValueError, match=r"DMDSplit.pinv: the dense 32x16 pseudo-inverse"):
            torchtof.set_memory_limit(1000)
            DMDSplit(Hadamard(4)).pinv(torch.zeros(1, 1, 32))
    finally:
        torchtof.set_memory_limit(None)


@pytest.mark.parametrize("order", ["natural", "sequency", "cake_cutting", "russian_doll"])
def test_dmd_all_off_frame_reads_exactly_zero(order):
    # φ⁻ of the all-on row is the all-off frame: its bucket is 0 for any scene, exactly, so
    # shot noise can be drawn from non-negative scenes' DMD buckets (it read −ε·Σx before)
    x = torch.rand(4, 1, 64, 64, generator=torch.Generator().manual_seed(0))
    y = DMDSplit(Hadamard(64, sr=0.25, order=order))(x)
    assert torch.equal(y[..., 1], torch.zeros_like(y[..., 1]))
    assert torch.allclose(y[..., 0], x.sum(dim=(-2, -1)), rtol=1e-6)  # all on: ⟨1, x⟩
    assert bool((y >= 0).all())
    torch.poisson(100 * y, generator=torch.Generator().manual_seed(1))  # valid rates


@pytest.mark.parametrize("dtype", [torch.uint8, torch.bool, torch.int8, torch.int64,
                                   torch.float16])
def test_dmd_patterns_in_mask_dtypes(dtype):
    S = DMDSplit(Hadamard(8, sr=0.5))
    ref = S.patterns(torch.float64)
    for start, stop in ((0, None), (3, 9)):
        p = S.patterns(dtype, start, stop)
        assert p.dtype == dtype
        assert torch.equal(p.to(torch.float64), ref[start:stop])
    with pytest.raises(TypeError, match=r"DMDSplit\.patterns: expected dtype a real"):
        S.patterns(torch.complex64)


@pytest.mark.parametrize("dtype", [torch.uint8, torch.bool])
def test_hadamard_patterns_refuse_dtypes_without_minus_one(dtype):
    # uint8 wrapped −1 to 255 and bool made every entry True
    with pytest.raises(TypeError, match=r"Hadamard\.patterns: expected dtype a floating or "):
        Hadamard(8, sr=0.5).patterns(dtype)


def test_operators_take_numpy_sizes_and_rates():
    import numpy as np

    from torchtof.operators import hadamard_order, random_binary_patterns
    from torchtof.operators.fwht import kron_factors

    a, b = Hadamard(np.int64(8), sr=np.float32(0.25)), Hadamard(8, sr=0.25)
    assert type(a.n) is int and a.m == b.m == 16
    x = torch.rand(1, 1, 8, 8)
    assert torch.equal(a(x), b(x))
    doll = hadamard_order(8, "russian_doll")
    assert torch.equal(hadamard_order(np.int64(8), "russian_doll"), doll)
    assert kron_factors(np.int64(4096), np.int32(16)) == (16, 16, 16)
    g = torch.Generator().manual_seed(0)
    assert random_binary_patterns(np.int64(4), np.int32(8), generator=g).shape == (4, 8, 8)
    with pytest.raises(TypeError, match="Hadamard: expected sr to be a number, got bool"):
        Hadamard(8, sr=True)


def test_pinv_errors_name_pinv():
    with pytest.raises(ValueError, match=r"^Hadamard\.pinv: expected y"):
        Hadamard(8).pinv(torch.ones(1, 1, 3))


def test_pattern_operator_pinv_follows_a_dtype_round_trip():
    # Module.half() cast the float64 A⁺ buffer to float16; .float() afterwards kept that
    # rounding (1e-3 error where a fresh operator has 4e-7): A⁺ is derived again after a cast
    g = torch.Generator().manual_seed(0)
    p, x = torch.rand(20, 8, 8, generator=g), torch.rand(1, 1, 8, 8, generator=g)
    a = PatternOperator(p)
    v0 = a.state_version
    a.half().float()
    fresh = PatternOperator(a.patterns)  # the same float16-rounded patterns, derived once
    assert a.pinv_matrix.dtype == torch.float64 and a.state_version > v0
    assert torch.equal(a.pinv_matrix, fresh.pinv_matrix)
    assert torch.equal(a.pinv(a(x)), fresh.pinv(fresh(x)))
    a.double()
    assert torch.equal(a.pinv_matrix, PatternOperator(a.patterns).pinv_matrix)
