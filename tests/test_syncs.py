"""Host syncs of the solvers: none per iteration on fixed-iteration paths.

A host sync is any read of tensor data by Python: ``bool(t)`` (``if t:``), ``t.item()``,
``float(t)``, ``int(t)``, ``t.tolist()``. On a GPU each one waits for the device, so a solver
loop must not do them. The counter patches those methods of ``torch.Tensor``; the count of a
run with ``2K`` iterations minus that of a run with ``K`` iterations is the number of syncs
that ``K`` extra iterations make (the entry checks cancel).
"""

from __future__ import annotations

import contextlib

import pytest
import torch

from torchtof.operators import Hadamard

_SYNC_METHODS = ("__bool__", "item", "__float__", "__int__", "tolist")


@contextlib.contextmanager
def count_syncs():
    """Count the host syncs made in the block: ``with count_syncs() as n: ...; n[0]``."""
    n = [0]
    saved = {name: getattr(torch.Tensor, name) for name in _SYNC_METHODS}

    def wrap(orig):
        def counted(self, *args, **kwargs):
            n[0] += 1
            return orig(self, *args, **kwargs)

        return counted

    for name, orig in saved.items():
        setattr(torch.Tensor, name, wrap(orig))
    try:
        yield n
    finally:
        for name, orig in saved.items():
            setattr(torch.Tensor, name, orig)


def _syncs(run) -> int:
    with count_syncs() as n:
        run()
    return n[0]


def test_counter_counts():
    t = torch.ones(3)
    with count_syncs() as n:
        bool(t.sum() > 0)
        t.sum().item()
        float(t[0])
        if t[1]:
            pass
    assert n[0] == 4


def _data():
    g = torch.Generator().manual_seed(0)
    A = Hadamard(16, sr=0.5)
    return A, A(torch.rand(2, 1, 16, 16, generator=g, dtype=torch.float64))


def _per_extra_iterations(make_run, k: int) -> int:
    make_run(k)()  # warm caches (operator factors, lazy buffers) outside the count
    return _syncs(make_run(2 * k)) - _syncs(make_run(k))


def test_unrolled_no_sync_per_layer():
    from torchtof.recon import UnrolledTVAL3

    A, y = _data()

    def make(k):
        net = UnrolledTVAL3(A, n_layers=k, pretrained=False)
        return lambda: net(y)

    assert _per_extra_iterations(make, 3) == 0


def test_unrolled_no_sync_per_layer_through_operator_calls(monkeypatch):
    # without the Hadamard fast path (the base class's loop_pair) every layer calls
    # A.forward/A.adjoint, whose input checks are skipped inside the loop (the input was
    # validated once at entry)
    import torchtof.recon.unrolled as mod
    from torchtof.operators import Hadamard, LinearOperator

    monkeypatch.setattr(Hadamard, "loop_pair", LinearOperator.loop_pair)
    A, y = _data()

    def make(k):
        s = torch.ones(k, dtype=torch.float64)
        return lambda: mod.unrolled_tval3(y, A, 256 * s, 32 * s, s, s / 32, 4 * s)

    assert _per_extra_iterations(make, 3) == 0
    with count_syncs() as n:  # the same calls outside the solver do check (and sync)
        A.adjoint(A.forward(A.adjoint(y)))
    assert n[0] > 0


def test_dip_no_sync_per_step_without_early_stop():
    from torchtof.recon import fit_dip

    A, y = _data()

    def make(k):
        return lambda: fit_dip(y[:1].float(), A, max_iter=k, early_stop=None, zeta=0.1)

    assert _per_extra_iterations(make, 3) == 0


def test_dip_early_stop_one_sync_per_check():
    # ES-WMV reads the window variance once per step (the stopping test itself); nothing else
    from torchtof.recon import fit_dip

    A, y = _data()

    def make(k):
        return lambda: fit_dip(y[:1].float(), A, max_iter=k, early_stop="wmv", window=2,
                               patience=1000)

    assert _per_extra_iterations(make, 4) <= 4


@pytest.mark.parametrize("name", ["cgi", "tgi", "dgi", "pinv"])
def test_direct_methods_sync_only_at_entry(name):
    # no loop: a handful of input checks at most, independent of the batch size
    import torchtof.recon as recon
    from torchtof.operators import DMDSplit

    spec = recon.get(name)
    A = Hadamard(16, sr=0.5)
    A = DMDSplit(A) if spec.operator == "split" else A
    x = torch.rand(8, 1, 16, 16, dtype=torch.float64)
    rec = spec.build(A)
    rec(A(x[:1]))
    assert _syncs(lambda: rec(A(x[:1]))) == _syncs(lambda: rec(A(x)))


# -- solvers owned by the TV core: fixed-iteration paths (adaptive=False) ---------------------


def test_tval3_fixed_iterations_no_sync_per_iteration():
    from torchtof.recon import tval3

    A, y = _data()

    def make(k):
        return lambda: tval3(y, A, max_iter=k, adaptive=False, return_result=True)

    assert _per_extra_iterations(make, 5) == 0


def test_bp_fixed_iterations_no_sync_per_iteration():
    from torchtof.recon import basis_pursuit

    A, y = _data()

    def make(k):
        return lambda: basis_pursuit(y, A, n_iter=k, adaptive=False, return_result=True)

    assert _per_extra_iterations(make, 5) == 0


def test_joint_tv_fixed_iterations_no_sync_per_iteration():
    from torchtof.recon import joint_tv

    A, y = _data()

    def make(k):
        return lambda: joint_tv(y, A, n_iter=k, adaptive=False)

    assert _per_extra_iterations(make, 5) == 0


# -- check_finite: skipped where it cannot or must not read the data --------------------------


def test_check_finite_skips_meta_tensors_and_unchecked_blocks():
    from torchtof._checks import check_finite, unchecked

    check_finite(torch.empty(3, device="meta"), "x", "f")  # no data: nothing to read
    bad = torch.tensor([1.0, float("nan")])
    with pytest.raises(ValueError, match=r"f: x contains non-finite values \(1 NaN, 0 Inf\)"):
        check_finite(bad, "x", "f")
    with count_syncs() as n, unchecked(), unchecked():
        check_finite(bad, "x", "f")
    assert n[0] == 0
    with pytest.raises(ValueError):  # the state is restored after (nested) blocks
        check_finite(bad, "x", "f")


@pytest.mark.slow  # dynamo's start-up; test_compile's fast case covers the operators' checks
def test_check_finite_skipped_under_compile():
    import torch._dynamo

    from torchtof._checks import check_finite

    def f(x):
        check_finite(x, "x", "f")
        return x * 2

    torch._dynamo.reset()
    g = torch.compile(f, fullgraph=True, backend="eager")  # a host sync would break the graph
    assert torch.equal(g(torch.ones(3)), torch.full((3,), 2.0))
