"""Tests of torchtof.bucket: ROI, depth gate, depth/intensity/tap buckets (paper Eq. 10, §3.1)."""

import pytest
import torch

from torchtof.bucket import (
    PAPER_GATE_M,
    DepthBucket,
    DepthGate,
    IntensityBucket,
    TapBuckets,
    depth_bucket,
    depth_gate,
    intensity_bucket,
    roi_mask,
    tap_buckets,
)


def _rand(*shape, seed=0, dtype=torch.float32, lo=1.0, hi=5.0):
    g = torch.Generator().manual_seed(seed)
    return lo + (hi - lo) * torch.rand(*shape, generator=g, dtype=dtype)


# B=1, M=2 frames of 2x2 pixels
FRAMES = torch.tensor([[[[1.0, 2.0], [3.0, 4.0]], [[5.0, 5.0], [2.5, 5.0]]]])


# ---------------------------------------------------------------- known answers
def test_depth_bucket_known_sums():
    assert depth_bucket(FRAMES).tolist() == [[[10.0, 17.5]]]
    assert depth_bucket(FRAMES, gate_m=3.0).tolist() == [[[6.0, 2.5]]]  # 4 and 5 m nulled
    assert depth_bucket(FRAMES, roi=(0, 0, 1, 2)).tolist() == [[[3.0, 10.0]]]
    mask = torch.tensor([[False, True], [True, False]])
    assert depth_bucket(FRAMES, roi=mask).tolist() == [[[5.0, 7.5]]]
    assert depth_bucket(FRAMES, roi=mask, gate_m=3.0).tolist() == [[[5.0, 2.5]]]


def test_ungated_bucket_falls_with_light_gated_grows():
    """§3.1: no-photon pixels read 5 m, so D_i falls as more pixels see the object at 2 m."""
    lit = torch.zeros(1, 3, 4, 4)
    lit[0, 1, :2] = 1
    lit[0, 2] = 1  # frame 0: dark, frame 1: half lit, frame 2: fully lit
    depth = torch.where(lit > 0, torch.full_like(lit, 2.0), torch.full_like(lit, 5.0))
    raw = depth_bucket(depth)[0, 0]
    gated = depth_bucket(depth, gate_m=PAPER_GATE_M)[0, 0]
    assert raw[0] > raw[1] > raw[2]
    assert gated.tolist() == [0.0, 16.0, 32.0]


def test_intensity_bucket_known():
    amp = FRAMES / 10
    torch.testing.assert_close(intensity_bucket(amp), torch.tensor([[[1.0, 1.75]]]))
    torch.testing.assert_close(
        intensity_bucket(amp, roi=(1, 1, 1, 1)), torch.tensor([[[0.4, 0.5]]])
    )


def test_tap_buckets_known_and_order():
    taps = _rand(2, 3, 4, 5, 6)
    out = tap_buckets(taps)
    assert out.shape == (2, 4, 3)
    torch.testing.assert_close(out, taps.sum((-2, -1)).transpose(1, 2))
    assert float(out[1, 2, 0]) == pytest.approx(float(taps[1, 0, 2].sum()), rel=1e-6)


def test_tap_buckets_linear():
    a, b = _rand(2, 3, 4, 5, 5, seed=1), _rand(2, 3, 4, 5, 5, seed=2)
    for roi in (None, (1, 0, 3, 4), torch.rand(5, 5) > 0.5):
        torch.testing.assert_close(
            tap_buckets(a + b, roi), tap_buckets(a, roi) + tap_buckets(b, roi)
        )
        torch.testing.assert_close(tap_buckets(2.5 * a, roi), 2.5 * tap_buckets(a, roi))


# ---------------------------------------------------------------- depth gate
def test_depth_gate():
    d = _rand(2, 4, 6, 6, lo=0.5, hi=5.0)
    d[0, 0, 0, 0] = 3.0  # exactly at the gate: kept ("exceeding" the gate is nulled)
    out = depth_gate(d)
    assert (out <= 3.0).all()
    keep = d <= 3.0
    assert torch.equal(out[keep], d[keep]) and (out[~keep] == 0).all()
    assert float(out[0, 0, 0, 0]) == 3.0
    torch.testing.assert_close(DepthGate()(d), out)
    torch.testing.assert_close(DepthGate(2.0)(d), depth_gate(d, 2.0))


def test_depth_gate_errors():
    with pytest.raises(ValueError, match="depth_gate: expected gate_m > 0"):
        depth_gate(FRAMES, gate_m=0.0)
    with pytest.raises(ValueError, match="DepthGate: expected gate_m > 0"):
        DepthGate(-1.0)
    with pytest.raises(ValueError, match="depth_gate: depth contains non-finite"):
        depth_gate(FRAMES * float("nan"))


# ---------------------------------------------------------------- ROI
def test_roi_variants_agree():
    d = _rand(2, 3, 6, 7)
    box = (1, 2, 3, 4)
    mask = torch.zeros(6, 7, dtype=torch.bool)
    mask[1:4, 2:6] = True
    by_slice = d[..., 1:4, 2:6].sum((-2, -1)).unsqueeze(1)
    torch.testing.assert_close(depth_bucket(d, roi=box), by_slice)
    torch.testing.assert_close(depth_bucket(d, roi=mask), by_slice)
    assert torch.equal(roi_mask((6, 7), box), mask)
    assert torch.equal(roi_mask((6, 7)), torch.ones(6, 7, dtype=torch.bool))
    torch.testing.assert_close(depth_bucket(d, roi=(0, 0, 6, 7)), depth_bucket(d))


@pytest.mark.parametrize(
    "roi, exc, msg",
    [
        ((0, 0, 0, 2), ValueError, "positive height and width"),
        ((0, 0, 2, -1), ValueError, "positive height and width"),
        ((5, 5, 1, 1), ValueError, "inside the 4x4 frame"),
        ((2, 2, 3, 1), ValueError, "inside the 4x4 frame"),
        ((-1, 0, 2, 2), ValueError, "top >= 0"),
        (torch.zeros(4, 4, dtype=torch.bool), ValueError, "selects no pixel"),
        (torch.ones(3, 4, dtype=torch.bool), ValueError, r"shape \(H, W\) = \(4, 4\)"),
        (torch.ones(4, 4), TypeError, "dtype torch.bool"),
        ((0, 0, 2.0, 2), TypeError, "ints"),
        ("all", TypeError, "expected roi to be None"),
    ],
)
def test_bad_roi_raises(roi, exc, msg):
    with pytest.raises(exc, match=f"depth_bucket: .*{msg}") as info:
        depth_bucket(torch.ones(1, 2, 4, 4), roi=roi)
    assert "roi" in str(info.value), "the message must name the argument"
    with pytest.raises(exc, match="roi_mask: "):
        roi_mask((4, 4), roi)


def test_module_roi_errors_and_buffer():
    with pytest.raises(ValueError, match="DepthBucket: expected roi of positive height"):
        DepthBucket(roi=(0, 0, 0, 3))
    with pytest.raises(ValueError, match="TapBuckets: roi mask selects no pixel"):
        TapBuckets(roi=torch.zeros(3, 3, dtype=torch.bool))
    with pytest.raises(TypeError, match="IntensityBucket: expected roi mask of dtype torch.bool"):
        IntensityBucket(roi=torch.ones(3, 3))
    mask = torch.rand(5, 5, generator=torch.Generator().manual_seed(0)) > 0.5
    mod = DepthBucket(roi=mask)
    assert mod.roi_mask.dtype == torch.bool and torch.equal(mod.roi_mask, mask)
    assert dict(mod.named_buffers()).keys() == {"roi_mask"}
    assert mod.state_dict() == {}, "the ROI buffer is non-persistent"
    mod.to(torch.float64)
    assert mod.roi_mask.dtype == torch.bool
    with pytest.raises(ValueError, match="depth_bucket: expected roi .* inside the 4x4 frame"):
        DepthBucket(roi=(3, 3, 2, 2))(torch.ones(1, 1, 4, 4))


# ---------------------------------------------------------------- module == function, batch, dtype
CASES = [
    (DepthBucket, depth_bucket, (3, 5, 5), {"roi": (1, 1, 3, 3), "gate_m": 3.0}),
    (DepthBucket, depth_bucket, (3, 5, 5), {}),
    (IntensityBucket, intensity_bucket, (3, 5, 5), {"roi": torch.eye(5, dtype=torch.bool)}),
    (TapBuckets, tap_buckets, (3, 4, 5, 5), {"roi": (0, 1, 5, 3)}),
]


@pytest.mark.parametrize("module, func, frame_shape, kw", CASES)
@pytest.mark.parametrize("b", [1, 3])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_module_function_batch_dtype(module, func, frame_shape, kw, b, dtype):
    x = _rand(b, *frame_shape, dtype=dtype)
    x0 = x.clone()
    out = func(x, **kw)
    c = 4 if func is tap_buckets else 1
    assert out.shape == (b, c, frame_shape[0]) and out.dtype == dtype
    torch.testing.assert_close(module(**kw)(x), out)
    singles = torch.cat([func(x[i : i + 1], **kw) for i in range(b)])
    torch.testing.assert_close(out, singles)
    assert torch.equal(x, x0), "input modified in place"


@pytest.mark.parametrize("module, func, frame_shape, kw", CASES)
def test_gradcheck(module, func, frame_shape, kw):
    x = _rand(2, *frame_shape, dtype=torch.float64, seed=3)
    if "gate_m" in kw:  # keep every value away from the gate discontinuity
        x = torch.where((x - kw["gate_m"]).abs() < 0.1, x + 0.5, x)
    x.requires_grad_(True)
    assert torch.autograd.gradcheck(lambda t: func(t, **kw), (x,))


# ---------------------------------------------------------------- input checks
def test_rank_and_finite_errors():
    with pytest.raises(ValueError, match=r"depth_bucket: expected depth of rank 4 \(B, M, H, W\)"):
        depth_bucket(torch.ones(2, 4, 4))
    with pytest.raises(ValueError, match="intensity_bucket: expected amplitude of rank 4"):
        intensity_bucket(torch.ones(1, 1, 2, 4, 4))
    with pytest.raises(ValueError, match=r"tap_buckets: expected taps of rank 5 \(B, M, 4, H, W\)"):
        tap_buckets(torch.ones(1, 4, 4, 4))
    with pytest.raises(ValueError, match=r"tap_buckets: expected taps of shape \(B, M, 4, H, W\)"):
        tap_buckets(torch.ones(1, 2, 3, 4, 4))
    bad = FRAMES.clone()
    bad[0, 1, 0, 0] = float("nan")
    with pytest.raises(ValueError, match=r"depth_bucket: depth contains non-finite values \(1 NaN"):
        depth_bucket(bad)
    bad[0, 1, 0, 0] = float("inf")
    with pytest.raises(ValueError, match="depth_bucket: depth contains non-finite.*1 Inf"):
        depth_bucket(bad, gate_m=3.0)
    with pytest.raises(ValueError, match="tap_buckets: taps contains non-finite"):
        tap_buckets(torch.full((1, 1, 4, 2, 2), float("inf")))
    with pytest.raises(TypeError, match="depth_bucket: expected depth to be a floating-point"):
        depth_bucket(torch.ones(1, 1, 2, 2, dtype=torch.int64))


def test_roi_box_takes_numpy_integers():
    import numpy as np

    from torchtof.bucket import roi_mask
    got = roi_mask((np.int64(4), np.int32(4)), (np.int64(1), 1, np.int32(2), 2))
    assert torch.equal(got, roi_mask((4, 4), (1, 1, 2, 2)))


def test_empty_frames_are_named_by_their_argument():
    from torchtof.bucket import depth_bucket, intensity_bucket, tap_buckets

    with pytest.raises(ValueError, match=r"depth_bucket: expected depth frames of positive"):
        depth_bucket(torch.zeros(1, 3, 0, 4))
    with pytest.raises(ValueError, match=r"intensity_bucket: expected amplitude frames of "):
        intensity_bucket(torch.zeros(1, 3, 4, 0))
    with pytest.raises(ValueError, match=r"tap_buckets: expected taps frames of positive"):
        tap_buckets(torch.zeros(1, 3, 4, 0, 4))
