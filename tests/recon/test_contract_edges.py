"""Edges of the reconstructor contract: scale-free results at extreme bucket scales, and bad
inputs rejected at the entry by a ``ValueError``/``TypeError`` that names the function and the
argument (no NaN output, no cryptic error from inside torch, no failure deferred to a fit)."""

from __future__ import annotations

import importlib

import pytest
import torch

import torchtof.recon as recon
from torchtof.operators import Hadamard
from torchtof.recon.base import pow2_scale
from torchtof.recon.bp import BasisPursuit, basis_pursuit
from torchtof.recon.depth import JointTV, joint_tv
from torchtof.recon.dip import DIP, dip, fit_dip
from torchtof.recon.learned import Learned, learned
from torchtof.recon.pinv import PseudoInverse, pseudo_inverse
from torchtof.recon.tgv import tgv
from torchtof.recon.tval3 import tval3
from torchtof.recon.unrolled import UnrolledTVAL3, unrolled_tval3

auto = importlib.import_module("torchtof.recon.auto").auto

N = 16
#: the fast options of tests/test_contract.py
AUTO_FAST = {"cv_iter": 10, "max_iter": 60, "priors": ("tv",), "learned": False}


@pytest.fixture
def A():
    return Hadamard(N, sr=0.5)


def _y(A, b=1, dtype=torch.float64):
    g = torch.Generator().manual_seed(1)
    x = torch.zeros(b, 1, N, N, dtype=torch.float64)
    x[..., 4:11, 5:12] = 1.0
    x = x + 0.3 * torch.rand(b, 1, N, N, generator=g, dtype=torch.float64)
    return A(x).to(dtype)


def _per_layer(k=3):
    v = torch.ones(k, dtype=torch.float64)
    return dict(mu=256 * v, beta=32 * v, step=v, thresh=v / 32, precond=4 * v)


# -- scale: squared errors must neither overflow nor underflow -----------------------------------


def test_pow2_scale_is_exact_and_one_at_ordinary_scales():
    v = torch.tensor([[2.0**40, -3.0], [2.0, 0.5], [0.0, 0.0], [1e-30, 0.0]])
    s = pow2_scale(v)
    assert s.shape == (4, 1) and s[1:3].eq(1.0).all()  # ordinary and zero rows: untouched
    m, _ = torch.frexp(s)
    assert bool((m == 0.5).all())  # powers of two: multiplying by them is exact
    assert 0.5 <= float((v[:1] * s[:1]).abs().max()) < 1.0
    assert 0.5 <= float((v[3:] * s[3:]).abs().max()) < 1.0


@pytest.mark.parametrize("dtype, scale", [(torch.float32, 1e20), (torch.float32, 1e-30),
                                          (torch.float64, 1e155), (torch.float64, 1e-170)])
def test_auto_is_scale_equivariant_at_extreme_scales(A, dtype, scale):
    # the squared CV errors and the discrepancy bound overflowed (1e20 in float32) or
    # underflowed; the score became NaN and the first candidate was picked blindly (9 % off)
    y = _y(A, b=2, dtype=dtype)
    rec = recon.get("auto").build(A, **AUTO_FAST)
    ref = rec(y)
    res = rec.solve(y * scale)
    assert bool(torch.isfinite(res.score[torch.isfinite(res.score)]).all())
    tol = 1e-5 if dtype == torch.float32 else 1e-12
    err = float((res.x / scale - ref).norm() / ref.norm())
    assert err < tol, err


def test_auto_scale_by_a_power_of_two_changes_nothing_but_the_scale(A):
    y = _y(A, b=2, dtype=torch.float32)
    rec = recon.get("auto").build(A, **AUTO_FAST)
    for s in (2.0**70, 2.0**-100):
        torch.testing.assert_close(rec(y * s) / s, rec(y), rtol=1e-6, atol=0)


@pytest.mark.parametrize("scale", [2.0**512, 1e154, 1e-160])
def test_dip_is_scale_free_at_extreme_scales(A, scale):
    # the z-score's std overflowed (1e154 in float64: 71 % off) or underflowed
    y = _y(A)
    ref = dip(y, A, max_iter=5, seed=1)
    out = dip(y * scale, A, max_iter=5, seed=1) / scale
    err = float((out - ref).norm() / ref.norm())
    assert err < 1e-9, err


# -- unrolled_tval3: the per-layer scalars -------------------------------------------------------


@pytest.mark.parametrize("name", ["mu", "beta", "step", "thresh", "precond"])
@pytest.mark.parametrize("bad", [float("nan"), 0.0, -1.0, float("inf")])
def test_unrolled_rejects_nonpositive_or_nonfinite_scalars(A, name, bad):
    p = _per_layer()
    p[name] = p[name].clone()
    p[name][1] = bad
    with pytest.raises(ValueError, match=rf"^unrolled_tval3: expected every entry of {name} > 0"):
        unrolled_tval3(_y(A), A, **p)


# -- noise_sigma tensors -------------------------------------------------------------------------


def test_learned_rejects_a_nonfinite_noise_tensor(A):
    y = _y(A, b=2)
    for bad in (float("nan"), float("inf")):
        with pytest.raises(ValueError, match="noise_sigma finite"):
            learned(y, A, noise_sigma=torch.tensor([[bad], [1.0]]), pretrained=False,
                    n_layers=2)


@pytest.mark.parametrize("sigma, match", [
    ([float("nan"), 1.0], "noise_sigma >= 0 and finite"),
    ([-1.0, 1.0], "noise_sigma >= 0 and finite"),
    ([1.0, 1.0, 1.0], "noise_sigma a float or a tensor of one or B = 2"),
])
def test_joint_tv_validates_a_noise_tensor(A, sigma, match):
    y = _y(A, b=2).expand(-1, 2, -1)
    with pytest.raises(ValueError, match=rf"^joint_tv: expected {match}"):
        joint_tv(y, A, noise_sigma=torch.tensor(sigma), n_iter=5)
    with pytest.raises(ValueError, match=rf"^joint_tv: expected {match}"):
        JointTV(A, n_iter=5)(y, torch.tensor(sigma))


def test_tval3_noise_tensor_of_the_wrong_shape_and_negative_discrepancy(A):
    y = _y(A, b=2)
    with pytest.raises(ValueError, match=r"^tval3: expected noise_sigma broadcastable to \(B, C\)"):
        tval3(y, A, noise_sigma=torch.ones(3))
    with pytest.raises(ValueError, match="^tval3: expected discrepancy >= 0"):
        tval3(y, A, discrepancy=-1)
    with pytest.raises(ValueError, match="^tval3: expected discrepancy >= 0 and finite"):
        tval3(y, A, discrepancy=torch.tensor([[float("nan")], [1.0]]))
    with pytest.raises(ValueError, match=r"^tval3: expected discrepancy broadcastable"):
        tval3(y, A, discrepancy=torch.ones(2, 3))


# -- dip: constant samples, options checked at construction -------------------------------------


def test_dip_zero_or_constant_sample_does_not_kill_the_batch(A):
    y = _y(A, b=3)
    y[1] = 0.0
    y[2] = 2.5
    res = DIP(A, max_iter=4, seed=0).solve(y)
    assert torch.equal(res.x[1], torch.zeros_like(res.x[1]))  # zero buckets: x = 0
    assert bool((res.x[2] == res.x[2].flatten()[0]).all())  # constant buckets: constant image
    torch.testing.assert_close(res.x[0:1], dip(y[0:1], A, max_iter=4, seed=0), rtol=0, atol=0)
    assert res.stop_reason[1] == ("direct",) and res.stop_reason[2] == ("direct",)
    assert res.n_iter[1:].eq(0).all() and res.converged[1:].all()
    assert not dip(y[1:2], A, max_iter=4, output="unit").any()
    with pytest.raises(ValueError, match="fit_dip: y is constant"):  # its documented error
        fit_dip(y[1:2], A, max_iter=4)


def test_dip_one_measurement_gives_the_determined_image():
    A1 = Hadamard(N, m=1)  # the all-ones row alone: a constant image, as every reconstructor
    y = torch.full((1, 1, 1), 3.0, dtype=torch.float64)
    torch.testing.assert_close(dip(y, A1, max_iter=4), pseudo_inverse(y, A1))


@pytest.mark.parametrize("kw, exc, match", [
    ({"max_iter": -1}, ValueError, "DIP: expected max_iter >= 1"),
    ({"lr": float("nan")}, ValueError, "DIP: expected lr > 0"),
    ({"seed": "a"}, TypeError, "DIP: expected seed to be an int"),
    ({"betas": (0.5, 1.0)}, ValueError, "DIP: expected betas"),
    ({"early_stop": "discrepancy"}, ValueError, "DIP: early_stop='discrepancy' needs"),
    ({"unet": 3}, TypeError, "DIP: expected unet to be a UNet"),
    ({"maxiter": 3}, TypeError, r"DIP: unexpected options \['maxiter'\]"),
])
def test_dip_options_are_checked_at_construction(A, kw, exc, match):
    with pytest.raises(exc, match=f"^{match}"):
        DIP(A, **kw)


def test_dip_function_checks_options_before_any_fit(A):
    with pytest.raises(TypeError, match=r"^dip: unexpected options \['maxiter'\]"):
        dip(_y(A), A, maxiter=3)
    with pytest.raises(ValueError, match="^dip: expected max_iter >= 1"):
        dip(_y(A, b=2), A, max_iter=0)


# -- clear errors instead of cryptic ones --------------------------------------------------------


def test_joint_tv_bounds_are_checked_by_name(A):
    with pytest.raises(ValueError, match=r"^JointTV: expected bounds to be a pair"):
        JointTV(A, bounds=-1)
    with pytest.raises(TypeError, match="^JointTV: expected bounds lo a number or None"):
        JointTV(A, bounds=("a", 1))
    y = _y(A).expand(-1, 2, -1)
    with pytest.raises(ValueError, match="^joint_tv: expected bounds to be a pair"):
        joint_tv(y, A, bounds=-1, n_iter=5)
    with pytest.raises(ValueError, match="^joint_tv: expected bounds with lo < hi"):
        joint_tv(y, A, bounds=(1.0, 0.0), n_iter=5)


@pytest.mark.parametrize("seed, exc", [("x", TypeError), (2.5, TypeError), (True, TypeError),
                                       (-1, ValueError)])
def test_auto_seed_is_checked(A, seed, exc):
    with pytest.raises(exc, match="^Auto: expected seed"):
        recon.get("auto").build(A, split="random", seed=seed)
    with pytest.raises(exc, match="^auto: expected seed"):
        auto(_y(A), A, split="random", seed=seed, **AUTO_FAST)


def test_basis_pursuit_without_an_operator():
    with pytest.raises(TypeError, match="^BasisPursuit: expected A to be a LinearOperator"):
        BasisPursuit(None)
    with pytest.raises(TypeError, match="^basis_pursuit: expected A to be a LinearOperator"):
        basis_pursuit(torch.zeros(1, 1, 4), None)


def test_learned_rejects_complex_y_and_a_bad_pretrained(A):
    y = _y(A)
    with pytest.raises(TypeError, match="^Learned.forward: expected y to be a real"):
        Learned(A, pretrained=False, n_layers=2)(y.to(torch.complex128))
    with pytest.raises(TypeError, match="^Learned: expected pretrained to be a bool or a"):
        learned(y, A, pretrained=3)


@pytest.mark.parametrize("call, flag", [
    (lambda A, y: basis_pursuit(y, A, adaptive="no", n_iter=5), "adaptive"),
    (lambda A, y: BasisPursuit(A, adaptive=1), "adaptive"),
    (lambda A, y: basis_pursuit(y, A, n_iter=5, return_result=1), "return_result"),
    (lambda A, y: unrolled_tval3(y, A, **_per_layer(), isotropic="no"), "isotropic"),
    (lambda A, y: UnrolledTVAL3(A, pretrained=False, isotropic="no"), "isotropic"),
    (lambda A, y: joint_tv(y.expand(-1, 2, -1), A, joint="no", n_iter=5), "joint"),
    (lambda A, y: JointTV(A, joint=0), "joint"),
    (lambda A, y: JointTV(A, adaptive="yes"), "adaptive"),
    (lambda A, y: tval3(y, A, mu=10.0, tvl2="no"), "tvl2"),
    (lambda A, y: tval3(y, A, return_result="no"), "return_result"),
    (lambda A, y: tval3(y, A, adaptive=None), "adaptive"),
    (lambda A, y: auto(y, A, return_result="no", **AUTO_FAST), "return_result"),
])
def test_flags_must_be_bools(A, call, flag):
    with pytest.raises(TypeError, match=f"expected {flag} to be a bool"):
        call(A, _y(A))


def test_tgv_mu_inf_is_rejected_as_a_number_and_in_a_tensor(A):
    y = _y(A, b=2)
    with pytest.raises(ValueError, match="^tgv: expected mu > 0 and finite"):
        tgv(y, A, mu=float("inf"), tvl2=True, max_iter=5)
    mu = torch.tensor([[float("inf")], [1.0]], dtype=torch.float64)
    with pytest.raises(ValueError, match="^tgv: expected every entry of mu > 0 and finite"):
        tgv(y, A, mu=mu, tvl2=True, max_iter=5)
    with pytest.raises(ValueError, match="^tgv: expected every entry of mu > 0 and finite"):
        tgv(y, A, mu=mu, tvl2=False, max_iter=5)


def test_pseudo_inverse_checks_y_by_its_own_name(A):
    y = _y(A)
    for fn in (lambda t: pseudo_inverse(t, A), PseudoInverse(A)):
        with pytest.raises(ValueError, match="^pseudo_inverse: y contains non-finite values"):
            fn(y * float("nan"))
        with pytest.raises(TypeError, match="^pseudo_inverse: expected y to be a real"):
            fn(y.to(torch.complex128))
        with pytest.raises(ValueError, match=r"^pseudo_inverse: expected y of shape"):
            fn(y[..., :-1])
    torch.testing.assert_close(pseudo_inverse(y, A), A.adjoint(y), rtol=0, atol=0)
