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


def test_without_matplotlib_every_figure_falls_back_or_says_so(tmp_path, monkeypatch, capsys):
    """The plot extra is optional: without matplotlib the demo's picture, a depth-map strip and
    a single reconstruction become plain montages (what README's extras table promises: the
    object's pixels appear in the montage), and a curve plot is skipped with a note naming
    the extra instead of failing after the work."""
    import sys
    from pathlib import Path

    import numpy as np
    from skimage.io import imread

    from torchtof.apps.bench.recon import plot_sweep
    from torchtof.apps.depth_demo import plot_depth_maps
    from torchtof.report import save_image

    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib -> ImportError
    monkeypatch.setitem(sys.modules, "matplotlib.pyplot", None)
    data = _data()
    images, rows = {}, []
    for gate, kind in ((False, "depth"), (True, "depth_gated")):
        r, images[kind] = evaluate(data, 0.25, gate, ["CGI", "TVAL3"])
        rows += [{**x, "buckets": kind} for x in r]
    png = demo_figure(tmp_path / "demo.png", data, images, rows, ["CGI", "TVAL3"])
    grid = imread(png)
    assert grid.shape == (2 * 16, 4 * 16)  # 2 bucket kinds × (object, raw, CGI, TVAL3)
    obj = (data.x[0, 0].numpy() - data.x.min().item()) / np.ptp(data.x.numpy())
    np.testing.assert_allclose(grid[:16, :16] / 255, obj, atol=1 / 255 + 1e-6)
    one = save_image(tmp_path / "one.png", images["depth"]["TVAL3"], "t", polarity="negative")
    assert imread(one).shape == (16, 16)
    depth = torch.rand(1, 1, 8, 8, generator=torch.Generator().manual_seed(0)) + 1.0
    strip = plot_depth_maps(tmp_path / "d.png", depth, {"A": depth}, [{"rmse_m": 0.0}], "t")
    np.testing.assert_array_equal(imread(strip)[:, :8], imread(strip)[:, 8:])
    assert plot_sweep([], Path(tmp_path / "s.png")) is None
    assert "pip install 'torchtof[plot]'" in capsys.readouterr().err
    assert not (tmp_path / "s.png").exists()
