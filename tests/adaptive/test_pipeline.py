import functools
import math

import pytest
import torch

from torchtof import cli
from torchtof.adaptive import AdaptiveResult, ProgressiveStop, run_adaptive, signed_buckets
from torchtof.apps.bench.adaptive import _SceneExperiment, flatness_psnr, scene_type

N = 16


@functools.cache  # read-only in every test: one simulation per worker
def _data(scene="sky", scattering=False, realisations=2):
    exp = _SceneExperiment(scene_type(scene, N), sr=0.375, srs=(0.375,), n=N, roi_px=2 * N,
                           scattering=scattering)
    return exp.run(seed=0, realisations=realisations)


def test_air_skips_the_gate_and_the_veil_stage():
    # repeats: 8 repeated differences leave the F test too little power to see the sensor's
    # own departure from an affine gate (mixed pixels, ~2σ² per coefficient at N = 16), so
    # the gate is skipped; the pair-sum estimate (default) sees it and keeps the gate there
    data = _data()
    res = run_adaptive(data, 0, block=8, noise="repeat")
    assert isinstance(res, AdaptiveResult)
    assert res.kind == "depth" and res.polarity == "negative"
    assert any("depth gate" in s for s in res.skipped)
    assert any("veil compensation" in s for s in res.skipped)
    assert res.repeat_patterns == 8
    assert 8 < res.patterns_used <= res.patterns_max + 8
    assert res.image.shape == (1, 1, N, N)
    assert res.fixed is not None and res.fixed.patterns_used == data.hadamard.m
    assert res.fixed.kind == "gated"
    assert res.time_saved_s == pytest.approx(res.fixed.total_s - res.total_s)
    # acquisition time is two frames per +-1 pattern at 30 fps
    assert res.acquisition_s == pytest.approx(2 * res.patterns_used / 30.0)
    assert "patterns" in res.summary()


def test_veil_keeps_the_gate_and_compensates():
    data = _data(scattering=True)
    res = run_adaptive(data, 1, block=8, compare_fixed=False)
    assert res.veil.present and res.kind == "gated"
    assert res.stop_kind == "gated"  # the gate kept: the stop reads the gated buckets
    assert any("depth gate" in s for s in res.stages)
    assert res.fixed is None and res.time_saved_s is None


def test_single_realisation_estimates_the_noise_and_custom_stop():
    data = _data(realisations=1)
    res = run_adaptive(data, 0, block=8, compare_fixed=False,
                       stop=ProgressiveStop(N, block=8, rule="change", tol=0.5))
    assert res.repeat_patterns == 0
    assert res.progressive.history[-1]["sigma"] > 0
    with pytest.raises(ValueError, match="r in"):
        run_adaptive(data, 3)


def test_budget_choice_is_recorded():
    data = _data()
    res = run_adaptive(data, 0, block=8, time_budget_s=1e-3, compare_fixed=False)
    assert res.choice is not None and res.method == res.choice.method == "PINV"
    assert res.solver_stop == "direct"


def test_signed_buckets_are_prefix_consistent():
    data = _data()
    sb = signed_buckets(data, 0)
    assert set(sb) == {"depth", "gated", "intensity"}
    small = signed_buckets(data, 0, 0.125)
    assert torch.equal(small["gated"], sb["gated"][..., : small["gated"].shape[-1]])


def test_flatness_psnr_known_values():
    img = torch.zeros(1, 1, 4, 4)
    img[..., ::2, :] = 0.1
    img[..., 1::2, :] = -0.1  # zero mean, rms 0.1 in gain units of 1 -> 20 dB
    assert flatness_psnr(img, 1.0) == pytest.approx(20.0, abs=1e-4)
    assert flatness_psnr(img, -2.0) == pytest.approx(20.0 + 20 * math.log10(2.0), abs=1e-4)


def test_cli_demo_auto(tmp_path, capsys):
    rc = cli.main(["demo", "--auto", "--n", "16", "--scene", "sky", "--out", str(tmp_path)])
    assert rc == 0
    out = capsys.readouterr().out
    assert "adaptive" in out and "fixed" in out and "skipped" in out
    assert (tmp_path / "auto.png").is_file() and (tmp_path / "auto.json").is_file()


def test_cli_bench_lists_adaptive():
    args = cli.build_parser().parse_args(["bench", "adaptive", "--quick"])
    assert args.which == "adaptive"


@pytest.mark.slow  # two pipeline runs (9 s); the gate's F test: tests/adaptive/test_detect.py
def test_gate_choice_costs_no_frames():
    # a stop on the ungated buckets: forcing the gate on (every F test rejects) or
    # off (none does) changes the buckets reconstructed but not the patterns acquired
    data = _data()
    kw = dict(block=8, compare_fixed=False, stop_kind="depth")
    on = run_adaptive(data, 0, gate_level=1e-9, **kw)
    off = run_adaptive(data, 0, gate_level=1 - 1e-12, **kw)
    assert on.kind == "gated" and off.kind == "depth"
    assert on.stop_kind == off.stop_kind == "depth"
    assert on.patterns_used == off.patterns_used


@pytest.mark.slow  # the veil case, realisation 1: test_veil_keeps_the_gate_and_compensates
def test_auto_stop_reads_the_chosen_buckets():
    data = _data(scattering=True)  # veil: gate kept, the stop reads the gated buckets
    assert run_adaptive(data, 0, block=8, compare_fixed=False).stop_kind == "gated"
    # air (repeats), the empty field and a far background: the slow tests below


@pytest.mark.slow  # three pipeline runs (12 s)
def test_auto_stop_reads_the_ungated_buckets_where_the_gate_changes_nothing():
    air = dict(block=8, compare_fixed=False, noise="repeat")
    assert run_adaptive(_data(), 0, **air).stop_kind == "depth"
    # default (pair sums): the empty field, where the gate changes nothing, reads the
    # ungated buckets; a far background keeps the gate
    _empty_and_far_background((0,))


def _empty_and_far_background(realisations):
    empty, far = _data("empty"), _data("farbg")
    for r in realisations:
        assert run_adaptive(empty, r, block=8, compare_fixed=False).stop_kind == "depth"
        assert run_adaptive(far, r, block=8, compare_fixed=False).stop_kind == "gated"


@pytest.mark.slow
def test_auto_stop_reads_the_chosen_buckets_second_realisation():
    _empty_and_far_background((1,))


@pytest.mark.slow  # two pipeline runs (6 s)
def test_lower_discrepancy_bound_never_stops_earlier():
    # q σ̂² shrinks with disc_level: a tighter Morozov bound can only stop TVAL3 later
    data = _data()
    loose = run_adaptive(data, 0, block=8, compare_fixed=False, disc_level=0.9)
    tight = run_adaptive(data, 0, block=8, compare_fixed=False, disc_level=0.001)
    assert loose.patterns_used == tight.patterns_used and loose.kind == tight.kind
    assert tight.n_iter >= loose.n_iter


@pytest.mark.parametrize(("kw", "match"), [({"stop_kind": "x"}, "stop_kind"),
                                           ({"gate_level": 1.0}, "gate_level"),
                                           ({"disc_level": 0.0}, "disc_level")])
def test_bad_pipeline_options(kw, match):
    with pytest.raises(ValueError, match=match):
        run_adaptive(_data(), 0, block=8, compare_fixed=False, **kw)


def test_cli_bench_adaptive_seed_and_light_options():
    from torchtof.apps.bench.adaptive import parse_seeds

    args = cli.build_parser().parse_args(["bench", "adaptive", "--seeds", "0-5", "--signal-e",
                                          "4000", "--realisations", "3"])
    assert parse_seeds(args.seeds) == [0, 1, 2, 3, 4, 5]
    assert args.signal_e == 4000.0 and args.realisations == 3
    assert cli.build_parser().parse_args(["bench", "adaptive", "--seed", "7"]).seed == 7
    assert cli.build_parser().parse_args(["bench", "adaptive", "--noise", "pairs"]).noise == "pairs"
    assert cli.build_parser().parse_args(["bench", "adaptive"]).noise is None
    with pytest.raises(SystemExit):
        cli.build_parser().parse_args(["bench", "adaptive", "--noise", "frames"])
    assert parse_seeds("0,3,7") == [0, 3, 7] and parse_seeds("2") == [2]
    for bad in ("5-2", "a", "", "-1"):
        with pytest.raises(ValueError, match="parse_seeds"):
            parse_seeds(bad)


@pytest.mark.slow  # two small benches (~5 s); the CLI parsing test above is the fast one
def test_bench_adaptive_seeds_runs_each_seed():
    from torchtof.apps.bench.adaptive import bench_adaptive_seeds

    res = bench_adaptive_seeds([0, 1], realisations=2, n=N, block=8, scenes=["empty"],
                               progress=False, signal_e=800.0)
    assert [r["seed"] for r in res["per_seed"]] == [0, 1]
    assert all(r["overrides"] == {"signal_e": 800.0} for r in res["per_seed"])
    assert res["acceptance_dense"] is True  # no dense row: vacuous
    # the flat-truth row takes 4x the realisations (heavy-tailed per-run MSE)
    assert all(r["empty_realisations"] == 8 and len(r["runs"][0]["runs"]) == 8
               for r in res["per_seed"])


def test_pairs_noise_costs_no_patterns_and_matches_the_repeats():
    data = _data()
    res = run_adaptive(data, 0, block=8, compare_fixed=False)  # noise="pairs": the default
    assert res.repeat_patterns == 0
    assert res.patterns_used == res.progressive.m  # no repeated block counted
    assert res.acquisition_s == pytest.approx(2 * res.patterns_used / 30.0)
    # sigma of the chosen buckets, against the two realisations' difference over all patterns
    from torchtof.adaptive import noise_from_repeats

    both = torch.cat([signed_buckets(data, r)[res.kind] for r in (0, 1)])
    assert 0.8 < res.noise_sigma / float(noise_from_repeats(both)) < 1.5  # pairs: biased up
    assert res.progressive.history[-1]["sigma"] > 0
    with pytest.raises(ValueError, match="noise"):
        run_adaptive(data, 0, noise="frames")
