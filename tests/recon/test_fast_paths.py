"""The solvers' fast paths give the bits of the plain ones: the in-place twins of the Neumann
differences, TVAL3's deferred fallback branch and the TGV fold fits in column chunks."""

from __future__ import annotations

import functools
import importlib
import warnings

import pytest
import torch

from torchtof.operators import Hadamard
from torchtof.recon.tv import (
    IN_PLACE_MIN_PIXELS,
    grad2,
    grad2_adjoint,
    grad2_adjoint_nb,
    grad2_nb,
    loop_differences,
    sym_grad2,
    sym_grad2_adjoint,
    sym_grad2_adjoint_nb,
    sym_grad2_nb,
)
from torchtof.recon.tval3 import MaskedRows

tval3_mod = importlib.import_module("torchtof.recon.tval3")
tgv_mod = importlib.import_module("torchtof.recon.tgv")
auto_mod = importlib.import_module("torchtof.recon.auto")


def _bits_equal(a: torch.Tensor, b: torch.Tensor) -> bool:
    """Equal values and equal signs of zero (``torch.equal`` alone has ``-0 == +0``)."""
    return (a.dtype == b.dtype and a.shape == b.shape and torch.equal(a, b)
            and torch.equal(torch.signbit(a), torch.signbit(b)))


def _results_equal(a, b) -> bool:
    return all(_bits_equal(u, v) if isinstance(u, torch.Tensor) else u == v
               for u, v in zip(a, b))


# -- the in-place twins of the Neumann differences -------------------------------------------

#: (plain function, in-place twin, channels of the input: None for an image)
PAIRS = [
    (grad2, grad2_nb, None),
    (grad2_adjoint, grad2_adjoint_nb, 2),
    (sym_grad2, sym_grad2_nb, 2),
    (sym_grad2_adjoint, sym_grad2_adjoint_nb, 4),
]
#: batch shapes × image sizes: below and above IN_PLACE_MIN_PIXELS, tiny and odd images
SHAPES = [((), (5, 7)), ((3,), (1, 4)), ((2,), (6, 1)), ((2, 3), (17, 19)), ((1, 1), (1, 1)),
          ((1, 3), (64, 64)), ((1, 5), (64, 64)), ((4, 2), (48, 50))]


def _input(batch, hw, channels, dtype, kind, gen):
    shape = (*batch, *(() if channels is None else (channels,)), *hw)
    if kind == "random":
        return torch.randn(shape, generator=gen, dtype=dtype)
    # adversarial: small integers and signed zeros, so that differences and sums hit ±0
    choice = torch.randint(0, 5, shape, generator=gen)
    vals = torch.tensor([0.0, -0.0, 1.0, -1.0, 0.5], dtype=dtype)
    return vals[choice]


@pytest.mark.parametrize("plain, twin, channels", PAIRS, ids=lambda v: getattr(v, "__name__",
                                                                                str(v)))
@pytest.mark.parametrize("batch, hw", SHAPES)
@pytest.mark.parametrize("kind", ["random", "signed_zeros"])
def test_in_place_twins_equal_the_plain_functions_bit_for_bit(plain, twin, channels, batch, hw,
                                                              kind, dtype, gen):
    x = _input(batch, hw, channels, dtype, kind, gen)
    assert _bits_equal(twin(x), plain(x, "neumann"))


def test_signed_zero_inputs_reach_signed_zero_outputs():
    # the sign of zero is exercised: the last column is p − (+0), which keeps a −0, and the
    # corner sums two of them (an implementation writing 0 − p or p + 0 there would differ)
    w = torch.full((1, 2, 3, 3), -0.0)
    out = grad2_adjoint_nb(w)
    assert bool(torch.signbit(out[..., -1, -1]).all()) and not bool(torch.signbit(out[..., 0, 0]))
    assert _bits_equal(out, grad2_adjoint(w, "neumann"))


@pytest.mark.parametrize("plain, twin, channels", PAIRS, ids=lambda v: getattr(v, "__name__",
                                                                                str(v)))
def test_in_place_twins_fall_back_under_autograd(plain, twin, channels, gen):
    shape = (2, 3, *(() if channels is None else (channels,)), 8, 9)
    x = torch.randn(shape, generator=gen, dtype=torch.float64, requires_grad=True)
    out = twin(x)
    assert out.grad_fn is not None
    ref = plain(x, "neumann")
    assert _bits_equal(out, ref)
    g = torch.randn(out.shape, generator=gen, dtype=torch.float64)
    (g1,) = torch.autograd.grad(out, x, g)
    (g2,) = torch.autograd.grad(ref, x, g)
    assert _bits_equal(g1, g2)


def test_support_twin_equals_the_plain_support(gen):
    w = _input((2, 3), (6, 5), 2, torch.float64, "signed_zeros", gen)
    assert _bits_equal(tgv_mod._support_nb(w), tgv_mod._support(w, "neumann"))
    w.requires_grad_(True)
    assert tgv_mod._support_nb(w).grad_fn is not None


def test_loop_differences_choose_the_twins_only_where_they_gain():
    n = 32
    big = torch.zeros(IN_PLACE_MIN_PIXELS // (n * n), 1, 10)
    small = torch.zeros(IN_PLACE_MIN_PIXELS // (n * n) - 1, 1, 10)
    assert loop_differences("neumann", big, n).in_place
    assert loop_differences("neumann", big, n).grad is grad2_nb
    assert not loop_differences("neumann", small, n).in_place
    assert not loop_differences("periodic", big, n).in_place
    ops = loop_differences("periodic", big, n)
    u = torch.randn(2, 5, 5)
    assert _bits_equal(ops.grad(u), grad2(u, "periodic"))


def test_loop_differences_use_the_plain_ops_while_tracing():
    seen = []

    def f(b):
        seen.append(loop_differences("neumann", b, 64).in_place)
        return b * 2

    b = torch.zeros(4, 1, 10)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # torch.jit.trace's notice
        torch.jit.trace(f, (b,), check_trace=False)
    assert seen == [False]
    assert loop_differences("neumann", b, 64).in_place


# -- TVAL3: the deferred fallback branch ------------------------------------------------------


def _count_adjoints(A):
    """Patch ``A.loop_pair`` to count the solver loop's ``Aᵀ`` calls: one per step, one per
    redone step, two at the set-up (a step with its fallback branch would make two)."""
    calls = [0]
    pair = A.loop_pair

    def loop_pair(like):
        fwd, adj = pair(like)

        def counted(r):
            calls[0] += 1
            return adj(r)

        return fwd, counted

    A.loop_pair = loop_pair
    return calls


def _scene(n, seed):
    g = torch.Generator().manual_seed(seed)
    x = (torch.rand(1, 1, n, n, generator=g, dtype=torch.float64) > 0.5).double() * 0.8
    return x + 0.1 * torch.rand(1, 1, n, n, generator=g, dtype=torch.float64)


def _buckets(A, x, seed, noise=0.01):
    g = torch.Generator().manual_seed(seed + 100)
    y = A(x)
    return y + noise * (y.max() - y.min()) * torch.randn(y.shape, generator=g, dtype=y.dtype)


@pytest.fixture
def eager(monkeypatch):
    """Run ``fn()`` with every TVAL3 step computing both step lengths and taking its fallback
    branch in place: the plain iteration, the reference of the fast one."""
    def run(fn):
        with monkeypatch.context() as m:
            m.setattr(tval3_mod, "_solve", functools.partial(tval3_mod._solve, _eager=True))
            return fn()
    return run


@pytest.mark.parametrize("kw", [dict(mu=2.0**8), dict(mu=2.0**8, nonneg=True),
                                dict(mu=2.0**8, boundary="neumann", tv="anisotropic"),
                                dict(mu=2.0**6, tvl2=True)])
def test_deferred_fallback_equals_the_eager_step(kw, eager):
    A = Hadamard(16, sr=0.25).double()
    calls = _count_adjoints(A)
    redone = 0
    for seed in range(4):
        x = _scene(16, seed)
        y = _buckets(A, x, seed)
        calls[0] = 0
        got = tval3_mod.tval3(y, A, return_result=True, **kw)
        redone += calls[0] - 2 - int(got.n_iter.max())
        ref = eager(lambda y=y: tval3_mod.tval3(y, A, return_result=True, **kw))
        assert _results_equal(got, ref)
    if "tvl2" not in kw:  # the constrained model's outer steps do need the branch
        assert redone > 0


def test_deferred_fallback_at_the_last_iteration_equals_the_eager_step(eager):
    # caps on the iterations: where the capped step left its branch out, only the redo after
    # the loop completes it (this scene's 15th step needs the branch)
    A = Hadamard(16, sr=0.25).double()
    calls = _count_adjoints(A)
    y = _buckets(A, _scene(16, 6), 6)
    redone = []
    for k in range(1, 25):
        calls[0] = 0
        got = tval3_mod.tval3(y, A, mu=2.0**8, nonneg=True, max_iter=k, return_result=True)
        redone.append(calls[0] - 2 - int(got.n_iter.max()))
        ref = eager(lambda k=k: tval3_mod.tval3(y, A, mu=2.0**8, nonneg=True, max_iter=k,
                                                return_result=True))
        assert _results_equal(got, ref), k
    # a redo first appears at a cap: that step's branch was completed after the loop
    assert 0 in redone and max(redone) > 0


@pytest.mark.parametrize("boundary", ["periodic", "neumann"])
def test_deferred_fallback_in_a_batch_stopping_at_different_iterations(boundary, eager):
    A = Hadamard(32, sr=0.25).double()
    x = torch.cat([_scene(32, s) for s in range(3)], 1)  # (1, 3)
    x = torch.cat([x, x.flip(-1), x.flip(-2), x.flip(-1, -2), x.mT, x.mT.flip(-1)], 0)
    y = _buckets(A, x, 1)  # (6, 3): Neumann solves take the in-place differences
    assert loop_differences(boundary, y, 32).in_place == (boundary == "neumann")
    got = tval3_mod.tval3(y, A, mu=2.0**8, boundary=boundary, return_result=True)
    assert len(set(got.n_iter.reshape(-1).tolist())) > 1
    ref = eager(lambda: tval3_mod.tval3(y, A, mu=2.0**8, boundary=boundary,
                                        return_result=True))
    assert _results_equal(got, ref)


def test_adaptive_mode_keeps_one_host_read_per_iteration_with_deferred_fallbacks():
    from tests.test_syncs import count_syncs

    A = Hadamard(16, sr=0.25).double()
    y = _buckets(A, _scene(16, 6), 6)

    def syncs(k):
        with count_syncs() as n:
            tval3_mod.tval3(y, A, mu=2.0**8, max_iter=k, tol=1e-300, tol_inner=1e-300)
        return n[0]

    syncs(5)
    assert syncs(60) - syncs(30) == 30


# -- TGV: frozen samples and the fold fits in column chunks -----------------------------------


@pytest.mark.parametrize("adaptive", [True, False])
def test_tgv_frozen_samples_keep_their_solo_result(adaptive):
    # a sample that converges early (or a constant one, frozen from the start) ends as it
    # would alone: its x and w stay where they stopped
    A = Hadamard(16, sr=0.5).double()
    x = torch.cat([_scene(16, 0), torch.zeros(1, 1, 16, 16, dtype=torch.float64) + 0.3,
                   _scene(16, 2) * 0.5], 1)
    y = _buckets(A, x, 0)
    y[:, 1] = 0.7
    kw = dict(max_iter=300 if adaptive else 40, adaptive=adaptive, check_every=1, tol=1e-4,
              return_result=True)
    batch = tgv_mod.tgv(y, A, **kw)
    if adaptive:
        assert len(set(batch.n_iter.reshape(-1).tolist())) > 1
    for c in range(3):
        solo = tgv_mod.tgv(y[:, c:c + 1], A, **kw)
        assert _bits_equal(batch.x[:, c:c + 1], solo.x)
        assert _bits_equal(batch.w[:, c:c + 1], solo.w)
        assert torch.equal(batch.n_iter[:, c:c + 1], solo.n_iter)


@pytest.mark.parametrize("tvl2", [False, True])
def test_tgv_fold_fits_in_chunks_equal_one_batch(tvl2, monkeypatch):
    n, k = 16, 7
    A = Hadamard(n, sr=0.25).double()
    g = torch.Generator().manual_seed(0)
    mask = torch.rand(k, A.m, generator=g) > 0.3
    x = torch.cat([_scene(n, s) for s in range(2)], 0)  # (2, 1, n, n): two rows
    y = A(x).expand(-1, k, -1) * mask.double()
    mu = torch.logspace(-1, 3, k, dtype=torch.float64).expand(2, k)
    tl = torch.tensor([tvl2, True, False, tvl2, False, True, tvl2]).expand(2, k)
    group = ("tgv", "isotropic", "neumann", (0.0, None))
    masked = MaskedRows(A, mask)
    whole = auto_mod._tgv_fit(group, y, masked, mu, tl, 200)
    # 2 rows × n² = 512 pixels per column: chunks of 1, 2 and 3 columns
    for cols in (1, 2, 3):
        monkeypatch.setattr(auto_mod, "_TGV_CHUNK_PIXELS", cols * 2 * n * n)
        chunked = auto_mod._tgv_fit(group, y, masked, mu, tl, 200)
        assert _results_equal(chunked, whole), cols
    assert whole[0].shape == (2, k, n, n)
