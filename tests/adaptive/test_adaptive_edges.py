"""Edges of torchtof.adaptive: inputs refused by name before any work, the repeated-block noise
estimate when the record ends inside the second block, the far-background test without a
noise level, and the caller's objects left alone."""

import functools
import math

import pytest
import torch

from torchtof.adaptive import (
    DarkReference,
    ProgressiveStop,
    block_statistics,
    choose_method,
    dark_reference,
    detect_far_background,
    detect_veil,
    run_adaptive,
    run_fixed,
    run_progressive,
    signed_buckets,
    solve_at_noise,
)
from torchtof.adaptive import pipeline as pipeline_mod
from torchtof.adaptive.detect import gate_changes_image
from torchtof.apps.bench.adaptive import _SceneExperiment, scene_type
from torchtof.operators import Hadamard

N = 16  # SR 0.375: M = 96 patterns


@functools.cache  # read-only in every test
def _data(scene="sky", seed=0, realisations=2):
    exp = _SceneExperiment(scene_type(scene, N), sr=0.375, srs=(0.375,), n=N, roi_px=2 * N)
    return exp.run(seed=seed, realisations=realisations)


def _raw(data):
    return {k: data.buckets[k][:1, :, :2] for k in ("depth", "depth_gated", "intensity")}


def _y(sigma=0.01, b=1, n=N, sr=0.375, seed=0):
    A = Hadamard(n, sr=sr)
    x = torch.zeros(b, 1, n, n)
    x[..., 4:10, 5:9] = 1.0
    y = A(x)
    return A, y + sigma * torch.randn(y.shape, generator=torch.Generator().manual_seed(seed))


# 1. noise="repeat" with a block past half the record --------------------------------------
def test_repeat_noise_counts_only_the_repeats_that_exist():
    data = _data()
    big_m = data.hadamard.m
    block = 64  # the second block is cut at the end of the record: 32 repeated patterns
    res = run_adaptive(data, 0, block=block, noise="repeat", compare_fixed=False)
    k = big_m - block
    assert res.repeat_patterns == k
    assert res.patterns_used == res.progressive.m + k
    assert res.acquisition_s == pytest.approx(2 * res.patterns_used / 30.0)
    a, b = (signed_buckets(data, r)[res.kind][..., block:] for r in (0, 1))
    want = float(((a - b).pow(2).sum() / (2 * k)).sqrt())  # ‖d‖²/(2K), K differences
    assert res.noise_sigma == pytest.approx(want, rel=1e-6)


@pytest.mark.parametrize("block", [93, 96, 200])
def test_repeat_noise_without_enough_repeats_is_refused_by_block(block):
    with pytest.raises(ValueError, match="block"):
        run_adaptive(_data(), 0, block=block, noise="repeat", compare_fixed=False)
    # without repeats (or with the pair sums) such a block is allowed
    res = run_adaptive(_data(), 0, block=block, noise="repeat", repeat=False,
                       compare_fixed=False)
    assert res.repeat_patterns == 0 and res.patterns_used == res.progressive.m


# 2. the caller's stop ----------------------------------------------------------------------
def test_run_adaptive_leaves_the_callers_stop_alone():
    stop = ProgressiveStop(N, block=8)
    res = run_adaptive(_data(), 0, block=8, noise="repeat", stop=stop, compare_fixed=False)
    assert stop.noise_sigma is None and stop.last == {}
    assert res.progressive.history[-1]["sigma"] == pytest.approx(
        run_adaptive(_data(), 0, block=8, noise="repeat", compare_fixed=False,
                     stop=ProgressiveStop(N, block=8)).progressive.history[-1]["sigma"])
    # a pair-sum stop also works with noise="repeat" (the sums are provided for it)
    pairs = ProgressiveStop(N, block=8, noise_sigma="pairs")
    res = run_adaptive(_data(), 0, block=8, noise="repeat", stop=pairs, compare_fixed=False)
    assert res.progressive.history[-1]["sigma"] > 0 and pairs.last == {}


# 3. the far-background test without a noise level -----------------------------------------
def test_far_background_is_not_tested_without_a_noise_level():
    # an empty field, one realisation, noise="repeat": no repeat, no noise level. The test
    # used to divide by 1e-12 and call this field "far background"
    data = _data("empty", seed=5, realisations=1)
    res = run_adaptive(data, 0, block=8, noise="repeat", compare_fixed=False)
    assert res.far is not None and not res.far.present and math.isnan(res.far.significance)
    assert any(s.startswith("far-background test (no noise level") for s in res.skipped)
    assert res.kind == "gated"  # the gate's documented default when it cannot be tested
    assert any("no repeat to test it" in s for s in res.stages)
    assert "nan sigma" in res.summary()


@pytest.mark.parametrize("sigma", [0.0, -1.0, float("nan"), float("inf")])
def test_detect_far_background_refuses_a_bad_noise_level(sigma):
    with pytest.raises(ValueError, match="intensity_sigma"):
        detect_far_background(_raw(_data()), sigma)


def test_detect_far_background_refuses_bad_thresholds():
    raw = _raw(_data())
    with pytest.raises(ValueError, match="k_sigma"):
        detect_far_background(raw, 50.0, k_sigma=float("nan"))
    with pytest.raises(ValueError, match="r_min"):
        detect_far_background(raw, 50.0, r_min=float("nan"))
    with pytest.raises(ValueError, match="intensity_sigma"):
        detect_far_background(raw, torch.tensor([50.0, 60.0]))
    assert detect_far_background(raw, torch.tensor(50.0)) == detect_far_background(raw, 50.0)
    unknown = detect_far_background(raw, None)  # no noise level: no test, R only
    assert not unknown.present and math.isnan(unknown.significance)
    assert unknown.ratio == detect_far_background(raw, 50.0).ratio


# 4. gate_changes_image ----------------------------------------------------------------------
def test_gate_test_is_one_sample_with_a_level_and_differences():
    g = torch.Generator().manual_seed(0)
    yd, yg = torch.randn(1, 1, 64, generator=g), torch.randn(1, 1, 64, generator=g)
    dd, dg = torch.randn(1, 1, 32, generator=g), torch.randn(1, 1, 32, generator=g)
    gate_changes_image(yd, yg, dd, dg)  # one sample: fine
    with pytest.raises(ValueError, match="one sample"):
        gate_changes_image(yd.expand(2, 1, 64), yg.expand(2, 1, 64), dd, dg)
    with pytest.raises(ValueError, match="one sample"):
        gate_changes_image(yd, yg, dd.expand(2, 1, 32), dg.expand(2, 1, 32))
    for level in (1.5, 0.0, 1.0, float("nan")):
        with pytest.raises(ValueError, match="level"):
            gate_changes_image(yd, yg, dd, dg, level=level)
    with pytest.raises(ValueError, match=">= 1 difference"):
        gate_changes_image(yd, yg, dd[..., :0], dg[..., :0])


# 5. detect_veil, dark_reference ------------------------------------------------------------
def test_detect_veil_refuses_bad_options_by_name():
    data = _data()
    raw, ref, p = _raw(data), dark_reference(data.config), (2 * N) ** 2
    assert not detect_veil(raw, ref, p).present
    for roi, err in ((0, ValueError), (-p, ValueError), (1.5, TypeError)):
        with pytest.raises(err, match="roi_pixels"):
            detect_veil(raw, ref, roi)
    with pytest.raises(ValueError, match="shift_m"):
        detect_veil(raw, ref, p, shift_m=float("nan"))
    for a in (float("nan"), 1.5, -0.1):
        with pytest.raises(ValueError, match="alpha_max"):
            detect_veil(raw, ref, p, alpha_max=a)
    with pytest.raises(TypeError, match="reference"):
        detect_veil(raw, "ref", p)
    with pytest.raises(ValueError, match="depth_m"):
        DarkReference(float("nan"), 1.0, 1.0)


def test_dark_reference_refuses_bad_frames_and_config():
    cfg = _data().config
    for frames in (0, -1):
        with pytest.raises(ValueError, match="frames"):
            dark_reference(cfg, frames=frames)
    with pytest.raises(TypeError, match="frames"):
        dark_reference(cfg, frames=2.5)
    with pytest.raises(TypeError, match="config"):
        dark_reference("cfg")


# 6. solve_at_noise ---------------------------------------------------------------------------
@pytest.mark.parametrize("method", ["PINV", "Unrolled", "TVAL3", "BP"])
@pytest.mark.parametrize("sigma", [float("nan"), -0.01, float("inf")])
def test_solve_at_noise_refuses_a_bad_noise_level(method, sigma):
    A, y = _y()
    with pytest.raises(ValueError, match="solve_at_noise: expected noise_sigma"):
        solve_at_noise(method, y, A, sigma)
    with pytest.raises(ValueError, match="solve_at_noise: .*noise_sigma"):
        solve_at_noise(method, y, A, torch.tensor([[sigma]]))


def test_solve_at_noise_refuses_bad_options_at_entry():
    A, y = _y(b=2)
    with pytest.raises(ValueError, match="noise_sigma broadcastable"):
        solve_at_noise("TVAL3", y, A, torch.tensor([0.01, 0.02, 0.03]))
    with pytest.raises(TypeError, match="max_iter"):
        solve_at_noise("TVAL3", y, A, 0.01, max_iter=2.7)
    with pytest.raises(ValueError, match="max_iter"):
        solve_at_noise("PINV", y, A, 0.01, max_iter=0)
    with pytest.raises(TypeError, match="solve_at_noise: expected y"):
        solve_at_noise("BP", y.long(), A, 0.01)
    with pytest.raises(ValueError, match="tau"):
        solve_at_noise("PINV", y, A, 0.01, tau=float("inf"))
    with pytest.raises(ValueError, match="sign"):
        solve_at_noise("PINV", y, A, 0.01, sign=0)
    with pytest.raises(TypeError, match="solve_at_noise: expected A"):
        solve_at_noise("TVAL3", y, "A", 0.01)
    with pytest.raises(TypeError, match="model_sigma"):
        solve_at_noise("TVAL3", y, A, 0.01, model_sigma="no")


def test_zero_noise_means_the_noise_free_model_for_every_method():
    A, y = _y(0.0)
    y = y.double()
    bp = solve_at_noise("BP", y, A, 0.0)  # was refused (eps = 0); now the exact constraint
    ref = solve_at_noise("BP", y, A, None)
    assert float(bp.residual.max()) < 1e-4 and bp.noise_sigma == 0.0
    assert bp.x.shape == ref.x.shape
    dip = solve_at_noise("DIP", y.float(), A, 0.0, max_iter=5)  # no early stop at σ = 0
    assert dip.stop_reason == (("max_iter",),) and int(dip.n_iter[0, 0]) == 5
    tv = solve_at_noise("TVAL3", y, A, 0.0)
    assert tv.stop_reason[0][0] != "discrepancy" or float(tv.residual.max()) == 0.0


# 7. ProgressiveStop --------------------------------------------------------------------------
@pytest.mark.parametrize("sigma", [torch.tensor(-0.01), torch.tensor(float("nan")),
                                   torch.ones(2, 1, 3)])
def test_progressive_stop_checks_a_tensor_noise_level_at_construction(sigma):
    with pytest.raises(ValueError, match="noise_sigma"):
        ProgressiveStop(N, noise_sigma=sigma)
    stop = ProgressiveStop(N)
    with pytest.raises(ValueError, match="noise_sigma"):  # and whenever it is set
        stop.noise_sigma = sigma


def test_progressive_stop_checks_order_n_and_the_record():
    with pytest.raises(ValueError, match="order"):
        ProgressiveStop(N, order="foo")
    with pytest.raises(ValueError, match="power of two"):
        ProgressiveStop(12)
    A, y = _y(sr=1.0)  # 256 patterns of n = 16
    with pytest.raises(ValueError, match="n² = 64"):
        run_progressive({"gated": y}, ProgressiveStop(8, noise_sigma=0.01))
    with pytest.raises(ValueError, match="n² = 64"):
        ProgressiveStop(8, noise_sigma=0.01)({"gated": y[..., :96]})
    stop = ProgressiveStop(N, noise_sigma=torch.tensor([0.01, 0.02]))  # (2,): C = 2
    with pytest.raises(ValueError, match="noise_sigma broadcastable"):
        stop({"gated": y[..., :96]})  # (1, 1, m): C = 1
    with pytest.raises(ValueError, match="n = 16"):  # run_adaptive: the record's n
        run_adaptive(_data(), 0, block=8, stop=ProgressiveStop(32), compare_fixed=False)
    with pytest.raises(ValueError, match="order"):
        run_adaptive(_data(), 0, block=8, stop=ProgressiveStop(N, order="natural"),
                     compare_fixed=False)


# 8. block_statistics -------------------------------------------------------------------------
def test_block_statistics_refuses_bad_inputs():
    A, y = _y(sr=1.0)
    nan = y.clone()
    nan[..., 5] = float("nan")
    cases = [((y, 0, 0.01), ValueError, "block"), ((y, -3, 0.01), ValueError, "block"),
             ((y, 2.5, 0.01), TypeError, "block"), ((nan, 32, 0.01), ValueError, "y"),
             ((y, 32, float("nan")), ValueError, "noise_sigma"),
             ((y, 32, -0.5), ValueError, "noise_sigma"),
             ((y, 32, torch.tensor([[-0.5]])), ValueError, "noise_sigma"),
             ((y.long(), 32, 0.01), TypeError, "y"), ((y[0], 32, 0.01), ValueError, "shape")]
    for args, err, match in cases:
        with pytest.raises(err, match=f"block_statistics: .*{match}"):
            block_statistics(*args)
    with pytest.raises(ValueError, match="n² = 64"):
        block_statistics(y, 32, 0.01, n=8)
    with pytest.raises(ValueError, match="order"):
        block_statistics(y, 32, 0.01, n=N, order="foo")


# 9. run_progressive ------------------------------------------------------------------------
def test_run_progressive_refuses_bad_blocks_and_stops():
    A, y = _y(sr=1.0)
    stop = ProgressiveStop(N, noise_sigma=0.01)
    for block, err in ((0, ValueError), (-5, ValueError), (2.5, TypeError), (True, TypeError)):
        with pytest.raises(err, match="run_progressive: expected block"):
            run_progressive({"gated": y}, stop, block=block)
    with pytest.raises(TypeError, match="run_progressive: expected buckets"):
        run_progressive({"gated": [1.0, 2.0]}, stop)
    with pytest.raises(TypeError, match="stop"):
        run_progressive({"gated": y}, None)
    with pytest.raises(ValueError, match="'gated'"):
        run_progressive({"depth": y}, stop)
    assert run_progressive({"gated": y}, stop).m == run_progressive({"gated": y}, stop, 32).m


# 10. run_adaptive options ------------------------------------------------------------------
@pytest.mark.parametrize(("kw", "err", "match"), [
    ({"fps": 0}, ValueError, "fps"), ({"fps": -30.0}, ValueError, "fps"),
    ({"fps": float("nan")}, ValueError, "fps"), ({"block": 0}, ValueError, "block"),
    ({"block": 8.0}, TypeError, "block"), ({"r": True}, TypeError, "r to be an int"),
    ({"r": 0.5}, TypeError, "r to be an int"), ({"method": "foo"}, ValueError, "method"),
    ({"method": "PINV", "time_budget_s": -1.0}, ValueError, "time_budget_s"),
    ({"time_budget_s": float("nan")}, ValueError, "time_budget_s"),
    ({"target_psnr": float("nan")}, ValueError, "target_psnr"),
    ({"reference": "x"}, TypeError, "reference"), ({"stop": "x"}, TypeError, "stop"),
    ({"repeat": "no"}, TypeError, "repeat"), ({"compare_fixed": 1}, TypeError, "compare_fixed"),
])
def test_run_adaptive_refuses_bad_options_before_any_work(kw, err, match, monkeypatch):
    def no_work(*a, **k):
        raise AssertionError("work started before the options were checked")

    monkeypatch.setattr(pipeline_mod, "detect_veil", no_work)
    kw = {"r": 0, "block": 8, "compare_fixed": False, **kw}
    with pytest.raises(err, match=f"run_adaptive: .*{match}"):
        run_adaptive(_data(), **kw)


def test_run_adaptive_and_run_fixed_refuse_other_data():
    with pytest.raises(TypeError, match="run_adaptive: expected data"):
        run_adaptive("foo", 0)
    with pytest.raises(TypeError, match="run_fixed: expected data"):
        run_fixed("foo", 0)
    with pytest.raises(ValueError, match="run_fixed: expected method"):
        run_fixed(_data(), 0, method="foo")


# 11. choose_method -------------------------------------------------------------------------
def test_choose_method_refuses_bad_values_and_reads_one_name():
    for n, err in ((0, ValueError), (-32, ValueError), (32.0, TypeError)):
        with pytest.raises(err, match="choose_method: expected n"):
            choose_method(n, 0.25, time_budget_s=1.0)
    with pytest.raises(ValueError, match="target_psnr"):
        choose_method(32, 0.25, target_psnr=float("nan"))
    with pytest.raises(ValueError, match="target_depth_rmse_m"):
        choose_method(32, 0.25, target_depth_rmse_m=-1.0)
    with pytest.raises(ValueError, match="methods"):  # "BPX" is no "BP" (was a substring match)
        choose_method(32, 0.25, time_budget_s=1.0, methods="BPX")
    with pytest.raises(TypeError, match="methods"):
        choose_method(32, 0.25, time_budget_s=1.0, methods=5)
    with pytest.raises(TypeError, match="sr"):
        choose_method(32, "0.25", time_budget_s=1.0)
    assert choose_method(32, 0.25, time_budget_s=1.0, methods="TVAL3").method == "TVAL3"


# 12. signed_buckets --------------------------------------------------------------------------
@pytest.mark.parametrize("r", [5, 2, -1])
def test_signed_buckets_refuses_r_out_of_range(r):
    with pytest.raises(ValueError, match="signed_buckets: expected r in"):
        signed_buckets(_data(), r)


def test_signed_buckets_refuses_sr_out_of_range():
    with pytest.raises(ValueError, match="sr"):
        signed_buckets(_data(), 0, 0.5)
    assert signed_buckets(_data(), 0, 0.125)["gated"].shape == (1, 1, 32)


# 13. the docstring says what the code does --------------------------------------------------
def test_run_adaptive_docstring_names_the_repeated_block():
    doc = run_adaptive.__doc__
    assert "repeat of the first block" not in doc and "repeat of the second block" in doc
