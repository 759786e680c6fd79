"""The demo's picture and its tap-bucket row."""

import functools

import torch

from torchtof.apps.demo import _merge_identical, demo_figure, evaluate_taps
from torchtof.experiment import PaperExperiment
from torchtof.methods import evaluate


@functools.cache  # one simulated experiment per worker, read-only in every test
def _data():
    return PaperExperiment(sr=0.25, n=16, roi_px=32, srs=(0.25,)).run(seed=0)


def test_identical_methods_are_merged_and_different_ones_are_not(tmp_path):
    data = _data()
    images, rows = {}, []
    for gate, kind in ((False, "depth"), (True, "depth_gated")):
        r, images[kind] = evaluate(data, 0.25, gate, ["CGI", "DGI", "PINV", "TVAL3"])
        rows += [{**x, "buckets": kind} for x in r]
    r, images["taps"] = evaluate_taps(data, 0.25, ["PINV"])
    rows += r + [{"method": "raw ToF", "buckets": "raw", "psnr": 0.0, "ssim": 0.0}]
    # CGI, DGI and PINV are affine in Aᵀ(y⁺ − y⁻) with complementary pairs: one panel
    assert _merge_identical(["CGI", "DGI", "PINV", "TVAL3"], images) == [
        ["CGI", "DGI", "PINV"], ["TVAL3"]]
    png = demo_figure(tmp_path / "demo.png", data, images, rows, ["CGI", "DGI", "PINV", "TVAL3"])
    assert png.stat().st_size > 10_000


def test_tap_buckets_beat_depth_buckets_under_stray_light():
    # the taps are linear in the light: the stray term cancels in y⁺ − y⁻ (paper Eqs. 5-6),
    # the depth buckets are not (Eq. 7), so the same exact inverse scores higher on taps
    data = _data()
    depth_rows, _ = evaluate(data, 0.25, False, ["PINV"])
    tap_rows, images = evaluate_taps(data, 0.25, ["PINV"])
    assert images["PINV"].shape == (1, 1, 16, 16)
    assert torch.isfinite(images["PINV"]).all()
    assert tap_rows[0]["psnr"] > depth_rows[0]["psnr"] + 1.0
