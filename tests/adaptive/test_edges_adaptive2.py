"""Edges of the adaptive pipeline: a clear set-up whose dark frame holds no light (no α from
the intensities, paper Eq. 15), records too short for the gate's F test or the repeats, the
first call's timed region, and integer/number arguments of the stop and the gate test."""

import builtins
import time
import types
import warnings

import numpy as np
import pytest
import torch

from torchtof.adaptive import (
    DarkReference,
    ProgressiveStop,
    dark_reference,
    detect_veil,
    run_adaptive,
    run_fixed,
)
from torchtof.adaptive.detect import gate_changes_image
from torchtof.experiment import PaperExperiment


def _raw(d_dark: float, s_dark: float, p: int = 4) -> dict:
    """Raw buckets ``(1, 1, 2)`` of the all-on and dark frames, per-pixel means × P."""
    mk = lambda on, off: torch.tensor([[[on * p, off * p]]], dtype=torch.float64)  # noqa: E731
    return {"depth": mk(2.0, d_dark), "depth_gated": mk(2.0, 0.0), "intensity": mk(10.0, s_dark)}


@pytest.fixture(scope="module")
def dark_free():
    """A noise-free record without stray light: the clear dark frame holds no light."""
    exp = PaperExperiment(sr=0.375, n=8, roi_px=16, srs=(0.375,), stray_e=0.0, shot=None,
                          read_noise_e=0.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return exp.run(seed=0, realisations=2)


@pytest.fixture(scope="module")
def short():
    """A record of M = 6 patterns (n = 8, SR 0.09375): too short for the F test (8)."""
    exp = PaperExperiment(sr=0.09375, n=8, roi_px=16, srs=(0.09375,))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        data = exp.run(seed=0, realisations=2)
    assert data.hadamard.m == 6
    return data


# 1. veil without an intensity reference -------------------------------------------------------
def test_dark_reference_takes_zero_intensity_and_refuses_a_negative_one():
    assert DarkReference(5.0, 0.0, 0.0).intensity == 0.0  # a real, noise-free reading
    with pytest.raises(ValueError, match="DarkReference: expected intensity >= 0"):
        DarkReference(5.0, 0.0, -1.0)
    for bad in (float("inf"), float("nan")):
        with pytest.raises(ValueError, match="intensity"):
            DarkReference(5.0, 0.0, bad)


def test_zero_reference_intensity_gives_alpha_one_and_the_shift_decides():
    ref = DarkReference(depth_m=5.0, gated_m=0.0, intensity=0.0)
    still = detect_veil(_raw(d_dark=5.0, s_dark=0.0), ref, roi_pixels=4)
    assert still.alpha == 1.0 and not still.present  # was alpha 0 and a veil
    assert still.ds_m == pytest.approx(0.0)
    moved = detect_veil(_raw(d_dark=4.5, s_dark=3.0), ref, roi_pixels=4)
    assert moved.alpha == 1.0 and moved.present and moved.shift_m == pytest.approx(0.5)
    assert moved.ds_m == pytest.approx(4.5 - 5.0)  # Eq. 15 with α̂ = 1: D̂ˢ = d' − d


def test_pipelines_on_a_dark_free_record_are_finite(dark_free):
    assert dark_reference(dark_free.config).intensity == 0.0
    fixed = run_fixed(dark_free, 0)
    assert fixed.veil.alpha == 1.0 and not fixed.veil.present
    assert torch.isfinite(fixed.image).all()  # was inf: divided by alpha^ = 0
    res = run_adaptive(dark_free, 0, block=8, compare_fixed=False)
    assert not res.veil.present and torch.isfinite(res.image).all()
    assert not any(s.startswith("veil compensation") for s in res.stages)


def test_alpha_zero_against_a_lit_reference_is_refused(dark_free):
    lit = DarkReference(depth_m=5.0, gated_m=0.0, intensity=100.0)  # the record's dark is 0
    with pytest.raises(ValueError, match=r"run_fixed: expected data .*alpha\^ = 0"):
        run_fixed(dark_free, 0, reference=lit)
    with pytest.raises(ValueError, match=r"run_adaptive: expected data .*reference.intensity"):
        run_adaptive(dark_free, 0, block=8, reference=lit, compare_fixed=False)


# 3./4. records shorter than the F test and the repeats ----------------------------------------
@pytest.mark.parametrize("stop_kind", ["auto", "depth"])
def test_pairs_on_a_short_record_skip_the_gate_test_and_keep_the_gate(short, stop_kind):
    res = run_adaptive(short, 0, block=4, compare_fixed=False, stop_kind=stop_kind)
    assert res.kind == "gated" and res.patterns_used == 6
    assert any(s.startswith("gate test (only 6 patterns") for s in res.skipped)
    assert any("too few patterns to test it" in s for s in res.stages)
    assert torch.isfinite(res.image).all()


def test_repeat_on_a_short_record_says_it_is_too_short(short):
    with pytest.raises(ValueError, match=r"run_adaptive: expected a record of at least 8 "
                                         r"patterns .*got 6; use noise='pairs' or repeat=False"):
        run_adaptive(short, 0, block=4, noise="repeat", compare_fixed=False)
    res = run_adaptive(short, 0, block=4, noise="repeat", repeat=False, compare_fixed=False)
    assert res.repeat_patterns == 0


# 6. the first call's compute time -------------------------------------------------------------
def test_scipy_stats_is_imported_before_the_clock_starts(monkeypatch, dark_free):
    """The gate's F test and the discrepancy bound import scipy.stats lazily (~0.5 s the
    first time): the import statement must run before compute_s starts counting."""
    from torchtof.adaptive import pipeline

    events = []
    real_import, real_clock = builtins.__import__, time.perf_counter

    def spy_import(name, globals=None, locals=None, fromlist=(), level=0):
        if name.startswith("scipy.stats"):
            events.append("import scipy.stats")
        return real_import(name, globals, locals, fromlist, level)

    def spy_clock():
        events.append("clock")
        return real_clock()

    monkeypatch.setattr(builtins, "__import__", spy_import)
    monkeypatch.setattr(pipeline, "time", types.SimpleNamespace(perf_counter=spy_clock))
    run_adaptive(dark_free, 0, block=8, compare_fixed=False)
    assert "import scipy.stats" in events
    assert events.index("import scipy.stats") < events.index("clock")


# 7. integer and number arguments --------------------------------------------------------------
def test_progressive_stop_takes_numpy_ints_and_refuses_wrong_types_with_type_error():
    stop = ProgressiveStop(16, block=np.int64(8), patience=np.int32(2),
                           min_patterns=np.int64(0))
    assert (stop.block, stop.patience, stop.min_patterns) == (8, 2, 16)
    assert type(stop.block) is int and type(stop.patience) is int
    for kw, name in ((dict(block=8.0), "block"), (dict(patience=1.0), "patience"),
                     (dict(min_patterns="0"), "min_patterns"), (dict(target="x"), "target"),
                     (dict(block=True), "block")):
        with pytest.raises(TypeError, match=f"ProgressiveStop: expected {name}"):
            ProgressiveStop(16, **kw)
    for kw, name in ((dict(block=2), "block"), (dict(patience=0), "patience"),
                     (dict(min_patterns=-1), "min_patterns"), (dict(target=0.0), "target"),
                     (dict(target=float("nan")), "target")):
        with pytest.raises(ValueError, match=f"ProgressiveStop: expected {name}"):
            ProgressiveStop(16, **kw)


def test_gate_test_dof_takes_numpy_ints():
    g = torch.Generator().manual_seed(0)
    yd, yg = (torch.randn(1, 1, 16, generator=g, dtype=torch.float64) for _ in range(2))
    dd, dg = (torch.randn(1, 1, 8, generator=g, dtype=torch.float64) for _ in range(2))
    a = gate_changes_image(yd, yg, dd, dg, dof=np.int64(5))
    assert a == gate_changes_image(yd, yg, dd, dg, dof=5)
    with pytest.raises(TypeError, match="gate_changes_image: expected dof to be an int"):
        gate_changes_image(yd, yg, dd, dg, dof=5.0)
    with pytest.raises(ValueError, match="gate_changes_image: expected dof >= 1"):
        gate_changes_image(yd, yg, dd, dg, dof=0)
