"""Tests of torchtof.metrics: PSNR (Eqs. 13-14), SSIM, depth RMSE, sign resolution, protocol."""

import math

import pytest
import torch

from torchtof.metrics import (
    PSNR,
    SSIM,
    DepthRMSE,
    NormalizeImage,
    ResolveSign,
    affine_fit,
    compare,
    depth_rmse,
    normalize_image,
    psnr,
    resolve_sign,
    ssim,
)
from torchtof.scenes import sky_character


def _rand(*shape, seed=0, dtype=torch.float32):
    return torch.rand(*shape, generator=torch.Generator().manual_seed(seed), dtype=dtype)


# ---------------------------------------------------------------- psnr
@pytest.mark.parametrize("bits", [None, 8, 12])
def test_psnr_closed_form(bits):
    x = torch.zeros(1, 1, 4, 4)
    # MSE on [0, 1] = 0.01 -> 20 dB whatever k (MAX cancels without quantisation)
    assert float(psnr(x + 0.1, x, bits=bits)) == pytest.approx(20.0, abs=1e-4)
    y = x.clone()
    y[..., :2, :] = 1.0  # half the pixels off by 1 -> MSE 0.5 -> 10 log10 2
    assert float(psnr(y, x, bits=bits)) == pytest.approx(10 * math.log10(2), abs=1e-5)


def test_psnr_quantized_k_bit():
    x = torch.zeros(1, 1, 4, 4)
    # 0.1 * 255 = 25.5 rounds to 26 on the 8-bit scale: PSNR = 20 log10(255 / 26)
    got = float(psnr(x + 0.1, x, bits=8, quantize=True))
    assert got == pytest.approx(20 * math.log10(255 / 26), abs=1e-4)
    # 4 bits: 0.1 * 15 = 1.5 -> 2: PSNR = 20 log10(15 / 2)
    got = float(psnr(x + 0.1, x, bits=4, quantize=True))
    assert got == pytest.approx(20 * math.log10(15 / 2), abs=1e-4)
    # quantisation clamps to [0, MAX]
    assert float(psnr(x + 2.0, x + 1.0, bits=8, quantize=True)) == 100.0


def test_psnr_identical_capped():
    x = _rand(3, 1, 8, 8)
    out = psnr(x, x)
    assert torch.equal(out, torch.full((3,), 100.0))
    assert float(psnr(x[:1], x[:1], max_db=60.0)) == pytest.approx(60.0)
    xh = x.clone().requires_grad_(True)
    psnr(xh, x).sum().backward()
    assert torch.isfinite(xh.grad).all()


@pytest.mark.parametrize("b", [1, 3])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_psnr_shapes_dtype_batch(b, dtype):
    x, xh = _rand(b, 2, 6, 6, dtype=dtype), _rand(b, 2, 6, 6, seed=1, dtype=dtype)
    x0, xh0 = x.clone(), xh.clone()
    out = psnr(xh, x)
    assert out.shape == (b,) and out.dtype == dtype
    singles = torch.cat([psnr(xh[i : i + 1], x[i : i + 1]) for i in range(b)])
    torch.testing.assert_close(out, singles)
    torch.testing.assert_close(psnr(xh, x, reduction="mean"), out.mean())
    torch.testing.assert_close(PSNR(bits=8)(xh, x), out)
    assert torch.equal(x, x0) and torch.equal(xh, xh0)


def test_psnr_gradcheck():
    x = _rand(2, 1, 3, 3, dtype=torch.float64)
    xh = _rand(2, 1, 3, 3, seed=1, dtype=torch.float64).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda a: psnr(a, x, bits=8), (xh,))


def test_psnr_errors():
    x = torch.zeros(1, 1, 4, 4)
    with pytest.raises(ValueError, match="psnr: expected x_hat and x of the same shape"):
        psnr(x, torch.zeros(1, 1, 4, 3))
    with pytest.raises(ValueError, match="psnr: expected x_hat of rank 4"):
        psnr(x[0], x[0])
    with pytest.raises(ValueError, match=r"psnr: expected bits in \[1, 64\]"):
        psnr(x, x, bits=0)
    with pytest.raises(TypeError, match="psnr: expected bits to be an int or None"):
        psnr(x, x, bits=8.0)
    with pytest.raises(ValueError, match="psnr: quantize=True needs bits"):
        psnr(x, x, bits=None, quantize=True)
    with pytest.raises(ValueError, match="psnr: x_hat contains non-finite values"):
        psnr(x / 0, x)
    with pytest.raises(ValueError, match="psnr: expected reduction in"):
        psnr(x, x, reduction="sum")


# ---------------------------------------------------------------- ssim
@pytest.mark.parametrize("b", [1, 3])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_ssim_identical_and_batch(b, dtype):
    x = _rand(b, 1, 16, 16, dtype=dtype)
    out = ssim(x, x)
    assert out.shape == (b,) and out.dtype == dtype
    torch.testing.assert_close(out, torch.ones(b, dtype=dtype))
    y = _rand(b, 1, 16, 16, seed=3, dtype=dtype)
    s = ssim(y, x)
    assert (s < 0.5).all()
    singles = torch.cat([ssim(y[i : i + 1], x[i : i + 1]) for i in range(b)])
    torch.testing.assert_close(s, singles)
    torch.testing.assert_close(SSIM()(y, x), s)
    assert ssim(1 - x, x).mean() < 0  # anti-correlated content


def test_ssim_constant_images_no_nan():
    z = torch.zeros(1, 1, 8, 8)
    assert float(ssim(z, z)) == pytest.approx(1.0)
    assert torch.isfinite(ssim(z, torch.ones_like(z))).all()


def test_ssim_gradcheck():
    x = _rand(1, 1, 5, 5, dtype=torch.float64)
    xh = _rand(1, 1, 5, 5, seed=1, dtype=torch.float64).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda a: ssim(a, x, window_size=3), (xh,))


def test_ssim_errors():
    x = torch.zeros(1, 1, 4, 4)
    with pytest.raises(ValueError, match="ssim: expected an odd window_size"):
        ssim(x, x, window_size=9)  # 9 // 2 = 4 is not < min(H, W) = 4
    with pytest.raises(ValueError, match="ssim: expected an odd window_size"):
        ssim(torch.zeros(1, 1, 8, 8), torch.zeros(1, 1, 8, 8), window_size=4)
    with pytest.raises(ValueError, match="ssim: expected data_range > 0"):
        ssim(x, x, data_range=0.0)


# ---------------------------------------------------------------- depth_rmse
def test_depth_rmse_known_answer():
    z = torch.full((2, 1, 4, 4), 2.0)
    zh = z.clone()
    zh[0] += 0.5
    zh[1, 0, 0, 0] = 6.0  # one pixel off by 4 m out of 16 -> sqrt(16 / 16) = 1
    torch.testing.assert_close(depth_rmse(zh, z), torch.tensor([0.5, 1.0]))
    mask = torch.zeros(4, 4, dtype=torch.bool)
    mask[0, :2] = True  # (H, W) mask broadcasts: image 1 -> sqrt(16 / 2)
    torch.testing.assert_close(depth_rmse(zh, z, mask), torch.tensor([0.5, math.sqrt(8.0)]))
    torch.testing.assert_close(DepthRMSE()(zh, z, mask), depth_rmse(zh, z, mask))
    torch.testing.assert_close(depth_rmse(zh, z, reduction="mean"), torch.tensor(0.75))


def test_depth_rmse_dtype_and_errors():
    z = torch.full((1, 1, 3, 3), 2.0, dtype=torch.float64)
    assert depth_rmse(z + 1, z).dtype == torch.float64
    with pytest.raises(ValueError, match="depth_rmse: mask selects no pixel"):
        depth_rmse(z, z, torch.zeros(3, 3, dtype=torch.bool))
    with pytest.raises(TypeError, match="depth_rmse: expected mask to be a bool tensor"):
        depth_rmse(z, z, torch.ones(3, 3))
    with pytest.raises(ValueError, match="depth_rmse: expected mask broadcastable"):
        depth_rmse(z, z, torch.ones(2, 2, dtype=torch.bool))
    with pytest.raises(ValueError, match="depth_rmse: depth contains non-finite"):
        depth_rmse(z, z * float("nan"))


# ---------------------------------------------------------------- normalize_image
def test_normalize_image():
    x = torch.tensor([[[[2.0, 4.0], [3.0, 4.0]]], [[[5.0, 5.0], [5.0, 5.0]]]])
    out = normalize_image(x)
    torch.testing.assert_close(out[0, 0], torch.tensor([[0.0, 1.0], [0.5, 1.0]]))
    assert torch.equal(out[1], torch.zeros(1, 2, 2)), "constant image -> zeros, no NaN"
    torch.testing.assert_close(NormalizeImage()(x), out)
    torch.testing.assert_close(
        normalize_image(x - 3.5, "clip")[0, 0], torch.tensor([[0, 0.5], [0, 0.5]])
    )
    with pytest.raises(ValueError, match="normalize_image: expected mode in"):
        normalize_image(x, "zscore")
    xh = _rand(2, 1, 3, 3, dtype=torch.float64).requires_grad_(True)
    assert torch.autograd.gradcheck(normalize_image, (xh,))


# ---------------------------------------------------------------- sign resolution
def test_resolve_sign_recovers_negated():
    x = sky_character(16).repeat(2, 1, 1, 1)
    x[1] = _rand(1, 1, 16, 16)
    x[1] = normalize_image(x[1:2])[0]
    neg = 5.0 - 3.0 * x  # a negative depth image (object nearer = darker)
    torch.testing.assert_close(resolve_sign(neg, "negative"), x)
    torch.testing.assert_close(resolve_sign(neg, "auto", reference=x), x)
    mixed = torch.cat([neg[:1], 2.0 * x[1:] + 1.0])  # one negative, one positive image
    torch.testing.assert_close(resolve_sign(mixed, "auto", reference=x), x)
    torch.testing.assert_close(ResolveSign("auto")(mixed, x), x)
    torch.testing.assert_close(resolve_sign(2.0 * x + 1.0), x)


def test_resolve_sign_constant_and_errors():
    c = torch.full((1, 1, 4, 4), 3.0)
    assert torch.isfinite(resolve_sign(c, "auto", reference=c)).all()
    assert torch.equal(resolve_sign(c, "negative"), torch.ones_like(c))
    with pytest.raises(ValueError, match="resolve_sign: expected polarity in"):
        resolve_sign(c, "flip")
    with pytest.raises(ValueError, match="resolve_sign: polarity='auto' needs a reference"):
        resolve_sign(c, "auto")
    with pytest.raises(ValueError, match="resolve_sign: expected x_hat of rank 4"):
        resolve_sign(c[0], "negative")


def test_affine_fit():
    x = _rand(3, 1, 5, 5, dtype=torch.float64)
    xh = -2.0 * x + 7.0
    torch.testing.assert_close(affine_fit(xh, x), x)
    c = torch.ones_like(x)
    fit = affine_fit(c, x)  # constant x_hat -> the mean of x
    torch.testing.assert_close(fit, x.mean((1, 2, 3), keepdim=True).expand_as(x))


# ---------------------------------------------------------------- protocol
def test_compare_protocol():
    x = sky_character(16).repeat(3, 1, 1, 1)
    neg = 5.0 - 3.0 * x
    for pol in ("negative", "auto", "affine"):
        out = compare(neg, x, polarity=pol)
        assert set(out) == {"psnr", "ssim"} and out["psnr"].shape == (3,)
        torch.testing.assert_close(out["psnr"], torch.full((3,), 100.0))
        torch.testing.assert_close(out["ssim"], torch.ones(3))
    wrong = compare(neg, x, polarity="positive")
    assert (wrong["psnr"] < 5.0).all() and (wrong["ssim"] < 0).all()
    # reconstruction with the right sign but noise scores in between, and k-bit quantised
    noisy = neg + 0.3 * torch.randn(x.shape, generator=torch.Generator().manual_seed(0))
    out = compare(noisy, x, polarity="negative")
    assert (out["psnr"] > 5).all() and (out["psnr"] < 40).all()
    ref = psnr(resolve_sign(noisy, "negative"), x, bits=8, quantize=True)
    torch.testing.assert_close(out["psnr"], ref)
    with pytest.raises(ValueError, match="compare: expected polarity in"):
        compare(neg, x, polarity="abs")


def test_metrics_do_not_overflow_on_finite_input():
    # SSIM of x̂ = 0 against a constant c with c = 0.01·L: μ terms (c1)/(c² + c1) = 1/2,
    # σ terms c2/c2 = 1, so SSIM = 0.5 at every pixel, for L = 1 as for L = 1e30.
    z = torch.zeros(1, 1, 8, 8)
    for big in (1.0, 1e30):
        torch.testing.assert_close(ssim(z, z + 0.01 * big, data_range=big), torch.tensor([0.5]))
    torch.testing.assert_close(ssim(z + 5e29, z + 5e29, data_range=1e30), torch.tensor([1.0]))
    # min-max of [−3e38, 0, 3e38]: (x − min)/(max − min) = 0, 1/2, 1
    out = normalize_image(torch.tensor([-3e38, 0.0, 3e38]).view(1, 1, 1, 3))
    torch.testing.assert_close(out, torch.tensor([0.0, 0.5, 1.0]).view(1, 1, 1, 3))
    # PSNR at 64 bits: MSE on [0, 1] = 0.1² = 0.01 -> 20 dB (MAX² cancels), quantised too
    # (0.1·(2^64 − 1) rounds to an integer within 1 ulp)
    for q in (False, True):
        torch.testing.assert_close(psnr(z, z + 0.1, bits=64, quantize=q), torch.tensor([20.0]))
    # far outside [0, 1]: MSE = (6e38)² = 3.6e77 -> −10·log10(3.6e77) = −775.563 dB
    got = psnr(z + 3e38, z - 3e38, bits=None)
    torch.testing.assert_close(got, torch.tensor([-10 * (math.log10(3.6) + 77)]))


def test_depth_rmse_and_affine_fit_do_not_overflow():
    # an error of 1e30 m on every pixel: RMSE = sqrt(mean(1e60)) = 1e30, finite in float32
    z = torch.zeros(2, 1, 4, 4)
    torch.testing.assert_close(depth_rmse(z + 1e30, z), torch.tensor([1e30, 1e30]))
    mask = torch.zeros(4, 4, dtype=torch.bool)
    mask[0, 0] = True
    torch.testing.assert_close(depth_rmse(z + 1e30, z, mask), torch.tensor([1e30, 1e30]))
    # x̂ = 3e37·x is an exact affine image of x: the fit returns x (a = 1/3e37, b = 0)
    x = torch.rand(1, 1, 8, 8, generator=torch.Generator().manual_seed(0))
    torch.testing.assert_close(affine_fit(3e37 * x, x), x, rtol=0, atol=1e-6)


def test_ssim_and_psnr_edge_inputs_raise_by_name():
    from torchtof.metrics import psnr, ssim
    a = torch.rand(1, 1, 8, 8) * 1e3
    with pytest.raises(ValueError, match="ssim: data_range 1e-38 is too small for x_hat"):
        ssim(a, a.clone(), data_range=1e-38)
    with pytest.raises(ValueError, match="ssim: expected x with at least one pixel"):
        ssim(torch.zeros(1, 0, 8, 8), torch.zeros(1, 0, 8, 8))
    e = torch.zeros(0, 1, 8, 8)
    for f in (psnr, ssim):
        assert f(e, e).shape == (0,)  # 'none': an empty batch gives an empty result
        with pytest.raises(ValueError, match=rf"{f.__name__}: reduction='mean' of an empty"):
            f(e, e, reduction="mean")
