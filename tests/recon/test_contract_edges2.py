"""More edges of the reconstructor contract: the relative residual at extreme float32 bucket
scales, BP's ``eps="auto"`` with too few buckets, flag and path arguments checked at the
entry, and the oracle sign of :func:`~torchtof.metrics.resolve_sign` at extreme scales."""

from __future__ import annotations

import warnings

import pytest
import torch

import torchtof.recon as recon
from torchtof.metrics import _pearson, resolve_sign
from torchtof.operators import Hadamard
from torchtof.recon.base import relative_residual
from torchtof.recon.learned import learned
from torchtof.recon.tgv import TGV, tgv
from torchtof.recon.unrolled import UnrolledTVAL3

N = 16
#: fast options per registered reconstructor (the DIP fits one sample for hundreds of steps)
FAST = {
    "bp": {"n_iter": 60},
    "tval3": {"max_iter": 40},
    "tgv": {"max_iter": 60},
    "joint_tv": {"n_iter": 40},
    "unrolled": {"pretrained": False},
    "learned": {"pretrained": False},
    "auto": {"cv_iter": 10, "max_iter": 40, "priors": ("tv",), "learned": False},
}
NAMES = [n for n in recon.names() if n != "dip"]


def _x0(dtype=torch.float64):
    x0 = torch.zeros(1, 1, N, N, dtype=dtype)
    x0[..., 4:11, 5:12] = 1.0
    return x0


@pytest.mark.parametrize("name", NAMES)
def test_float32_residual_at_extreme_scales(name):
    """``‖Ax − y‖/‖y‖`` is scale-free: float32 buckets of ``1e±30`` give a finite residual,
    the float64 one to float32 rounding (the sums of squares used to over/underflow)."""
    A = Hadamard(N, sr=0.5)
    y64 = A(_x0())

    def res(dtype, s):
        torch.manual_seed(0)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            net = recon.get(name).build(A, **FAST.get(name, {})).to(dtype)
            return net.solve(y64.to(dtype) * s).residual.detach()

    ref = res(torch.float64, 1.0)
    for s in (1e30, 1e-30):
        r = res(torch.float32, s)
        assert r.dtype == torch.float32 and bool(torch.isfinite(r).all()), (name, s, r)
        torch.testing.assert_close(r.double(), ref, rtol=1e-4, atol=1e-5, msg=f"{name} {s}")


def test_relative_residual_helper_zero_and_scale():
    A = Hadamard(8, sr=0.5)
    y = torch.zeros(2, 1, A.m)
    y[1] = A(torch.ones(1, 1, 8, 8))[0]
    x = torch.zeros(2, 1, 8, 8)
    r = relative_residual(x, y, A)  # y = 0 and x = 0: the exact fit, 0; else ‖y‖/‖y‖ = 1
    assert r.tolist() == [[0.0], [1.0]]
    for s in (1e-38, 1e36):
        assert relative_residual(x, y * s, A).tolist() == [[0.0], [1.0]]


@pytest.mark.parametrize("m", [1, 2, 4, 12])
def test_bp_auto_eps_with_few_buckets_fits_exactly(m):
    """Too few tail buckets for a noise estimate: the exact constraint, not ``x = 0``."""
    A = Hadamard(N, m=m)
    y = A(_x0(torch.float32))
    res = recon.get("bp").build(A, n_iter=200).solve(y)
    assert float(res.residual.max()) < 1e-5
    assert float(res.x.abs().max()) > 0


def test_bp_auto_eps_is_capped_below_the_bucket_norm():
    """Buckets of equal magnitude read as all noise (``ε = ‖y‖/0.6745``): the radius is capped
    below ``‖y‖`` (so ``x ≠ 0``) with a warning."""
    A = Hadamard(32, sr=0.25)
    y = torch.ones(1, 1, A.m)
    with pytest.warns(UserWarning, match="eps='auto'"):
        res = recon.get("bp").build(A, n_iter=100).solve(y)
    assert float(res.x.abs().max()) > 0
    assert float(res.residual.max()) <= 0.99 + 1e-5


@pytest.mark.parametrize("kw", [{"adaptive": 1}, {"return_result": "yes"}])
def test_tgv_flags_are_checked(kw):
    A = Hadamard(8, sr=0.5)
    y = torch.zeros(1, 1, A.m)
    name = next(iter(kw))
    with pytest.raises(TypeError, match=f"tgv: expected {name} to be a bool"):
        tgv(y, A, max_iter=2, **kw)


def test_tgv_module_checks_adaptive():
    with pytest.raises(TypeError, match="TGV: expected adaptive to be a bool"):
        TGV(Hadamard(8, sr=0.5), adaptive=0)


def test_learned_rejects_a_list_y():
    A = Hadamard(N, sr=0.5)
    with pytest.raises(TypeError, match="learned: expected y"):
        learned([0.0] * A.m, A, pretrained=False)


def test_unrolled_pretrained_type_checked():
    with pytest.raises(TypeError, match="UnrolledTVAL3: expected pretrained"):
        UnrolledTVAL3(Hadamard(N, sr=0.5), pretrained=1)


def test_unrolled_pretrained_missing_or_bad_file(tmp_path):
    A = Hadamard(N, sr=0.5)
    with pytest.raises(ValueError, match="UnrolledTVAL3: expected pretrained .*no such file"):
        UnrolledTVAL3(A, pretrained=tmp_path / "missing.pt")
    bad = tmp_path / "bad.pt"
    bad.write_text("not a weights file")
    with pytest.raises(ValueError, match="UnrolledTVAL3: expected pretrained"):
        UnrolledTVAL3(A, pretrained=str(bad))
    with pytest.raises(ValueError, match="UnrolledTVAL3.load_weights: expected path"):
        UnrolledTVAL3(A, pretrained=False).load_weights(tmp_path / "missing.pt")


def test_unrolled_weights_round_trip(tmp_path):
    A = Hadamard(N, sr=0.5)
    net = UnrolledTVAL3(A, n_layers=3, pretrained=False)
    path = tmp_path / "w.pt"
    net.save_weights(path)
    assert UnrolledTVAL3(A, n_layers=3, pretrained=path).weights_file == str(path)


@pytest.mark.parametrize("scale", [1e20, 1e-20, 1e30])
def test_pearson_and_oracle_sign_are_scale_free(scale):
    x = torch.tensor([[[[0.0, 1.0, 0.0, 1.0]]]])
    assert torch.equal(resolve_sign(5.0 - x, "auto", reference=scale * x),
                       resolve_sign(5.0 - x, "auto", reference=x))
    torch.testing.assert_close(_pearson(5.0 - x, scale * x), _pearson(5.0 - x, x))
    assert float(_pearson(5.0 - x, x)) == -1.0


def test_cgi_mean_bucket_at_rounding_level_is_zero_at_every_scale():
    """On a signed (±1) operator the mean bucket of this scene is zero up to rounding; g2 is
    scale-free, so the image must not depend on the buckets' scale (it was 1e18 at 1e-30:
    rounding noise of the mean divided into the correlation)."""
    import warnings

    from torchtof.operators import DMDSplit, Hadamard
    from torchtof.recon import cgi

    A = Hadamard(16, sr=0.5)
    x0 = torch.zeros(1, 1, 16, 16, dtype=torch.float64)
    x0[..., 4:11, 5:12] = 1
    y = A(x0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # g2 on signed patterns (warned)
        ref = cgi(y, A)
        for s in (1e-30, 1e-150, 1e30):
            assert torch.equal(cgi(y * s, A), ref)
    D = DMDSplit(A)  # light patterns: a mean bucket far from zero keeps its exact quotient
    yd = D(x0)
    ref = cgi(yd, D)
    assert float(ref.abs().max()) > 0.5
    for s in (1e-30, 1e30):
        torch.testing.assert_close(cgi(yd * s, D), ref, rtol=1e-12, atol=0)


@pytest.mark.parametrize("name", ["tval3", "tgv", "learned", "auto"])
def test_buckets_near_the_ends_of_float32_give_the_scaled_image(name):
    """f(c·y) = c·f(y) up to the dtype's ends: buckets of ~3e38 and ~1e-40 (subnormal) in
    float32 used to give NaN (the spread or the norm over- or underflowed); the stacking of
    ``auto`` with the network overflowed at 1e38."""
    A = Hadamard(32, sr=0.25)
    x = torch.zeros(1, 1, 32, 32)
    x[..., 3:10, 4:12] = 1.0
    y = A(x)
    y = y / y.abs().max()
    opts = {"tval3": {"max_iter": 60}, "tgv": {"max_iter": 30}, "learned": {},
            "auto": {"cv_iter": 5, "max_iter": 10, "priors": ("tv",)}}[name]
    f = getattr(recon, name)
    ref = f(y, A, **opts)
    for c in (2.0**127, 2.0**-130):  # exact powers of two: the same image, scaled
        got = f(c * y, A, **opts)
        assert torch.isfinite(got).all(), (name, c)
        tol = 1e-6 if c > 1 else 1e-3  # subnormal buckets keep fewer bits
        torch.testing.assert_close(got / c, ref, rtol=tol, atol=tol * float(ref.abs().max()))


def test_tval3_auto_on_noisy_buckets_near_the_ends_of_float32():
    # noisy buckets run mu='auto''s hold-out check, whose squared errors overflowed (2^64) or
    # underflowed (2^-100): the check then always kept the constrained model
    A = Hadamard(16, sr=0.3)
    g = torch.Generator().manual_seed(0)
    y = A(torch.rand(1, 1, 16, 16, generator=g))
    y = y + 0.01 * torch.randn(1, 1, A.m, generator=g)
    ref = recon.tval3(y, A, max_iter=50)
    for c in (2.0**64, 2.0**100, 2.0**-100):
        torch.testing.assert_close(recon.tval3(c * y, A, max_iter=50) / c, ref, rtol=0, atol=0)


@pytest.mark.parametrize("name", ["tval3", "tgv"])
def test_all_zero_buckets_keep_the_callers_box(name):
    A = Hadamard(8, sr=0.5)
    x = getattr(recon, name)(torch.zeros(1, 1, A.m), A, bounds=(0.5, 1.0), max_iter=20)
    assert torch.equal(x, torch.full_like(x, 0.5))  # 0 projected onto the box, both solvers
