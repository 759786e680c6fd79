"""Command-line mistakes of ``torchtof acquire`` / ``torchtof reconstruct``: each is one line
``torchtof CMD: error: argument --X: …`` with exit status 2, found before any store is
written; ``--simulated`` runs without pyusb; the depth gate only with depth buckets."""

import sys

import pytest

from torchtof.cli import main
from torchtof.experiment import PaperExperiment
from torchtof.hardware.simulated import Faults

# the recorder needs zarr >= 3 (Python >= 3.11; torchtof.hardware.require_zarr3)
zarr = pytest.importorskip("zarr", minversion="3")

ARGS = ["acquire", "--simulated", "--scene", "sky", "--sr", "0.25", "--n", "8", "--roi-px", "16",
        "--noise-free", "--no-progress"]


def _usage_error(argv: list[str], capsys) -> str:
    """Run ``torchtof ARGV``, expect a usage error: exit 2 and one line on stderr."""
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    path = tmp_path_factory.mktemp("mistakes") / "run.zarr"
    assert main([*ARGS, "-o", str(path)]) == 0
    return path


# -- 1: --sim-faults ---------------------------------------------------------------------------
@pytest.mark.parametrize("plan,names", [
    ('{"nack": 1}', "'nack'"),
    ('{"nack": {"PAT_CONFIG": 0}}', "'PAT_CONFIG'"),
    ('{"nack": {"NO_SUCH_COMMAND": [0]}}', "NO_SUCH_COMMAND"),
    ('{"late_reply": {"PAT_CONFIG": [-1]}}', "'late_reply'"),
    ('{"drop": 5}', "'drop'"),
    ('{"drop": ["3"]}', "'drop'"),
    ('{"drop": "a"}', "'drop'"),
    ('{"stall": [1.5]}', "'stall'"),
    ('{"ctrl_fail": [true]}', "'ctrl_fail'"),
    ('{"set_failed": ["no_such_flag"]}', "'set_failed'"),
    ('{"vanish_after_frames": "x"}', "'vanish_after_frames'"),
    ('{"hang_at_frame": -1}', "'hang_at_frame'"),
    ('{"hang_s": "long"}', "'hang_s'"),
    ('{"hang_file": 3}', "'hang_file'"),
    ('{"no_seq_echo": 1}', "'no_seq_echo'"),
    ('{"nope": 1}', "'nope'"),
])
def test_malformed_sim_faults_are_usage_errors_before_any_store(plan, names, tmp_path, capsys):
    out = tmp_path / "x.zarr"
    err = _usage_error([*ARGS, "--sim-faults", plan, "-o", str(out)], capsys)
    assert err.startswith("torchtof acquire: error: argument --sim-faults: ") and names in err
    assert not out.exists()


def test_sim_faults_without_simulated_is_a_usage_error(tmp_path, capsys):
    err = _usage_error(["acquire", "--sim-faults", '{"drop": [3]}', "-o",
                        str(tmp_path / "x.zarr")], capsys)
    assert "argument --sim-faults:" in err and "--simulated" in err


def test_faults_from_dict_checks_every_field():
    f = Faults.from_dict({"drop": [1, 2], "late_reply": {"PAT_CONFIG": [0]}, "hang_s": 2,
                          "set_failed": ["pix_cnt_max_set_failed"], "vanish_after_frames": 0,
                          "hang_file": "h.txt", "no_seq_echo": True, "hang_at_read": None})
    assert f.drop == {1, 2} and f.late_reply == {"PAT_CONFIG": {0}} and f.hang_s == 2.0
    assert f.set_failed == {"pix_cnt_max_set_failed"} and f.vanish_after_frames == 0
    for bad in ({"drop": 5}, {"nack": 1}, {"drop": ["3"]}, {"vanish_after_frames": "x"}):
        with pytest.raises(ValueError, match=f"'{next(iter(bad))}'"):
            Faults.from_dict(bad)


def test_a_valid_fault_plan_still_runs(tmp_path, capsys):
    out = tmp_path / "f.zarr"
    assert main([*ARGS, "--sim-faults", '{"drop": [3]}', "-o", str(out)]) == 0
    assert "(1 retries" in capsys.readouterr().out  # the sequence with the lost frame


# -- 2: --simulated without pyusb --------------------------------------------------------------
@pytest.fixture
def no_pyusb(monkeypatch):
    for name in ("usb", "usb.core", "usb.util"):
        monkeypatch.setitem(sys.modules, name, None)  # import usb… -> ImportError


def test_simulated_acquire_runs_without_pyusb(no_pyusb, store, tmp_path, capsys):
    out = tmp_path / "nousb.zarr"
    # a stalled bulk read and a failed control transfer: USB errors without pyusb
    assert main([*ARGS, "--sim-faults", '{"stall": [3], "ctrl_fail": [1]}', "-o",
                 str(out)]) == 0
    assert "recorded 16/16 pattern pairs" in capsys.readouterr().out
    a, b = zarr.open_group(str(out), mode="r"), zarr.open_group(str(store), mode="r")
    assert (a["buckets_depth"][:] == b["buckets_depth"][:]).all()
    # a vanished device is still a DeviceLostError (exit 1, the --resume hint)
    assert main([*ARGS, "--sim-faults", '{"vanish_after_frames": 5}', "-o",
                 str(tmp_path / "gone.zarr")]) == 1
    assert "disappeared during the run" in capsys.readouterr().err


def test_real_bench_without_pyusb_names_the_extra(no_pyusb, tmp_path, capsys):
    from torchtof.hardware import dlpc350, opt8241

    for cls in (dlpc350.LightCrafter4500, opt8241.OPT8241):
        with pytest.raises(ImportError, match=r"pip install 'torchtof\[hardware\]'"):
            cls.open()
    assert main(["acquire", "-o", str(tmp_path / "x.zarr")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "pip install 'torchtof[hardware]'" in err[0], err


# -- 3: the output store, the timing options, one prefix -----------------------------------------
def test_existing_store_is_a_usage_error_and_resume_still_works(store, capsys):
    err = _usage_error([*ARGS, "-o", str(store)], capsys)
    assert err.startswith("torchtof acquire: error: argument -o/--output: ")
    assert "exists; pass --resume" in err
    assert main([*ARGS, "--resume", "-o", str(store)]) == 0
    assert "recorded 16/16 pattern pairs" in capsys.readouterr().out


def test_resume_mismatch_has_one_prefix(store, capsys):
    assert main([*ARGS[:-1], "--sr", "0.5", "--no-progress", "--resume", "-o", str(store)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"torchtof acquire: cannot resume {store}: it was recorded with m=16, this "
                   "run has m=32"], err


@pytest.mark.parametrize("kind", ["file", "folder"])
def test_output_that_is_not_a_store_is_refused_and_kept(kind, tmp_path, capsys):
    out = tmp_path / "out"
    if kind == "file":
        out.write_text("keep")
    else:
        out.mkdir()
        (out / "keep.txt").write_text("keep")
    for extra in ([], ["--resume"]):
        err = _usage_error([*ARGS, *extra, "-o", str(out)], capsys)
        assert "argument -o/--output:" in err and "choose a new path" in err
    assert (out if kind == "file" else out / "keep.txt").read_text() == "keep"
    # an empty folder is a new store
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main([*ARGS, "-o", str(empty)]) == 0


def test_library_acquire_never_overwrites_other_files(tmp_path):
    from torchtof.experiment import ExperimentConfig
    from torchtof.hardware import acquire
    from torchtof.hardware.simulated import SimulatedBench

    out = tmp_path / "notes"
    out.mkdir()
    (out / "keep.txt").write_text("keep")
    bench = SimulatedBench(ExperimentConfig(n=8, roi_px=16, srs=(0.25,)))
    with pytest.raises(FileExistsError, match="not a torchtof acquisition"):
        acquire(out, bench.lightcrafter(), bench.camera(), n=8, sr=0.25, progress=False)
    assert (out / "keep.txt").read_text() == "keep"


@pytest.mark.parametrize("extra,flag", [
    (["--period-us", "100"], "--period-us"),  # PAT_EXPO_PRD: exposure <= period - 230 us
    (["--exposure-us", "5000", "--period-us", "5229"], "--period-us"),
    (["--exposure-us", "20000"], "--exposure-us"),  # longer than a 60 Hz video frame
    (["--exposure-us", "5000", "--period-us", "25000"], "--period-us"),
    (["--exposure-us", str(2**32)], "--exposure-us"),
])
def test_exposure_and_period_mistakes_name_the_options(extra, flag, tmp_path, capsys):
    out = tmp_path / "x.zarr"
    err = _usage_error([*ARGS, *extra, "-o", str(out)], capsys)
    assert err.startswith(f"torchtof acquire: error: argument {flag}: ")
    assert "dlpc350:" not in err and not out.exists()
    if "5229" in extra or "100" in extra:
        assert "--exposure-us" in err and "230 us" in err


def test_a_period_230_us_longer_than_the_exposure_is_accepted(tmp_path):
    assert main([*ARGS, "--exposure-us", "5000", "--period-us", "5230", "-o",
                 str(tmp_path / "x.zarr")]) == 0


# -- 4: reconstruct --method lists the registry ------------------------------------------------
def test_reconstruct_help_and_error_list_every_registry_method(capsys):
    from torchtof.recon import registry

    labels = ", ".join(s.label for s in registry.specs())
    assert "TGV" in labels
    with pytest.raises(SystemExit) as exc:
        main(["reconstruct", "--help"])
    assert exc.value.code == 0
    assert labels in " ".join(capsys.readouterr().out.split())
    err = _usage_error(["reconstruct", "run.zarr", "--method", "nope"], capsys)
    assert labels in err


# -- 5: the depth gate applies to depth buckets only ------------------------------------------
def test_reconstruct_gate_with_intensity_is_a_usage_error(store, tmp_path, capsys):
    out = tmp_path / "rec"
    err = _usage_error(["reconstruct", str(store), "--kind", "intensity", "--gate", "--out",
                        str(out)], capsys)
    assert err.startswith("torchtof reconstruct: error: argument --gate: ")
    assert "--kind intensity" in err and not out.exists()


def test_experiment_data_refuses_the_gate_without_depth_buckets():
    data = PaperExperiment(sr=0.25, n=8, roi_px=16, srs=(0.25,)).run(seed=0)
    for kind in ("intensity", "taps"):
        with pytest.raises(ValueError, match=rf"gate=True .*kind='{kind}'"):
            data.measurements(0.25, kind=kind, gate=True)
        with pytest.raises(ValueError, match="gate"):
            data.split_buckets(0.25, kind=kind, gate=True)
        assert data.measurements(0.25, kind=kind)[1].shape[-1] == 16
    gated = data.split_buckets(0.25, "depth", gate=True)
    assert gated.equal(data.buckets["depth_gated"][..., :32])


@pytest.mark.parametrize(("argv", "flag"), [
    (["--scene", "steps"], "--scene"), (["--roi-px", "64"], "--roi-px"),
    (["--scattering"], "--scattering"), (["--noise-free"], "--noise-free"),
    (["--seed", "3"], "--seed"),
    (["--seed", "0"], "--seed"), (["--scene", "sky"], "--scene"),  # at their default values
])
def test_simulated_only_options_on_the_real_bench_are_usage_errors(argv, flag, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["acquire", *argv, "-o", str(tmp_path / "r.zarr")])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"argument {flag}: used with --simulated only" in err[0], err
    assert not (tmp_path / "r.zarr").exists()


@pytest.mark.parametrize("value", ["7", "1"])  # 1: at its default value
def test_real_bench_only_options_with_simulated_are_usage_errors(value, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["acquire", "--simulated", "--n", "8", "--sr", "0.5", "--display", value,
              "-o", str(tmp_path / "s.zarr")])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "argument --display: used on the real bench only" in err[0], err
    assert not (tmp_path / "s.zarr").exists()


def test_auto_block_below_the_rules_minimum_names_block(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["acquire", "--simulated", "--n", "8", "--sr", "0.5", "--auto", "--block", "2",
              "-o", str(tmp_path / "s.zarr")])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "argument --block: expected >= 4 with --auto" in err[0], err
