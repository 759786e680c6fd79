"""The command line: demo, bench, reproduce (small, real runs — they write real files)."""

import inspect
import json

import pytest
import torch

from torchtof.cli import main


def test_demo_writes_png_and_table(tmp_path, capsys):
    rc = main(["demo", "--methods", "CGI,DGI,PINV,TVAL3", "--out", str(tmp_path)])
    assert rc == 0
    out = capsys.readouterr().out
    assert "raw ToF" in out and "TVAL3" in out and "PSNR dB" in out
    assert (tmp_path / "demo.png").stat().st_size > 10_000
    rows = json.loads((tmp_path / "demo.json").read_text())
    names = {r["method"] for r in rows}
    assert {"raw ToF", "CGI", "DGI", "PINV", "TVAL3"} <= names
    assert all(torch.isfinite(torch.tensor(r["psnr"])) for r in rows)


def test_bench_operators_json(tmp_path, capsys):
    path = tmp_path / "ops.json"
    assert main(["bench", "operators", "--n", "16", "32", "--batch", "2", "--json", str(path)]) == 0
    res = json.loads(path.read_text())
    assert [r["n"] for r in res["rows"]] == [16, 32]
    for r in res["rows"]:
        assert r["hadamard_matmul_s"] > 0 and r["dense_s"] > 0 and r["speedup_vs_dense"] > 0
    assert "speedup_vs_dense" in capsys.readouterr().out


def test_recon_sweep_and_pareto():
    from torchtof.apps.bench.recon import pareto, sweep

    rows = sweep(ns=(16,), srs=(0.25,), scenes=("sky", "steps"),
                 knobs={"PINV": [None], "TVAL3": [5, None]}, progress=False)
    assert len(rows) == 3 * 2
    pts = pareto(rows)
    assert {p["label"] for p in pts} == {"PINV", "TVAL3@5", "TVAL3"}
    assert any(p["pareto"] for p in pts)
    fastest = min(pts, key=lambda p: p["time_s"])
    best = max(pts, key=lambda p: p["psnr"])
    assert fastest["pareto"] and best["pareto"]


def test_reproduce_writes_everything(tmp_path):
    from torchtof.apps.reproduce import reproduce

    # n = 16, direct methods, no depth curves (tests/test_depth_demo.py runs those): plumbing
    res = reproduce(tmp_path, quick=True, realisations=1, methods=("CGI", "PINV"), n=16,
                    depth=False)
    for case in ("air", "air+gate", "scatter", "scatter+gate"):
        assert (tmp_path / f"images_{case}.png").exists()
        assert (tmp_path / f"psnr_{case}.png").exists()
    text = (tmp_path / "table.md").read_text()
    assert "[9.44]" in text  # the paper's value beside ours
    claims = (tmp_path / "claims.md").read_text()
    assert "not evaluated" in claims  # DIP absent in this run
    assert "psnr_mean" in (tmp_path / "psnr.csv").read_text()
    assert {c["claim"] for c in res["claims"]} >= {"PSNR rises with SR (6.25 % → 37.5 %)"}


def test_reproduce_says_only_what_it_ran(tmp_path, capsys):
    from torchtof.apps.reproduce import reproduce

    res = reproduce(tmp_path, quick=True, realisations=1, methods=("CGI", "TVAL3"), n=16,
                    depth=False)
    claim = next(c for c in res["claims"] if c["claim"].startswith("TVAL3 ≥ CGI and BP"))
    assert claim["evidence"].endswith("(only CGI evaluated)")  # BP was not run
    heads = [ln for ln in (tmp_path / "table.md").read_text().splitlines()
             if ln.startswith("### ")]
    assert len(heads) == 4
    for h in heads:  # the paper gives a raw ToF PSNR in air only
        assert ("(paper 5.70)" in h) == h.startswith("### air"), h
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert "depth_" not in last and "reproduce.json" in last


@pytest.mark.parametrize("argv, msg", [
    (["demo", "--n", "8", "--methods", "CGI", "--out", "/proc/nope"],
     "argument --out: cannot make the folder '/proc/nope'"),
    (["bench", "operators", "--n"], "argument --n: expected at least one argument"),
])
def test_usage_errors_come_before_the_work(argv, msg, capsys):
    # an unwritable --out was found after the whole run; '--n' with no values ran the
    # default grid
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr()
    assert msg in err.err and "PSNR" not in err.out


def test_bad_command():
    with pytest.raises(SystemExit):
        main(["bench", "nothing"])


# -- one error path ------------------------------------------------------------------------
BAD = [
    (["demo", "--sr", "2"], "--sr"),
    (["demo", "--sr", "abc"], "--sr"),
    (["demo", "--n", "0"], "--n"),
    (["demo", "--n", "48"], "argument --n: expected a power of two in [8, 256], got '48'"),
    (["demo", "--n", "4"], "argument --n: expected a power of two in [8, 256]"),
    (["demo", "--depth", "nosuch"], "--depth"),
    (["demo", "--scene", "nonexistent"], "--scene"),
    (["demo", "--methods", "FOO"], "--methods"),
    (["demo", "--realisations", "0"], "--realisations"),
    (["--threads", "0", "demo"], "--threads"),
    (["reproduce", "--realisations", "0"], "--realisations"),
    (["bench", "nothing"], "which"),
    (["bench", "adaptive", "--seeds", "x-y"], "--seeds"),
    (["export", "nope"], "MODEL"),
    (["export", "hadamard", "--opset", "13"], "--opset"),
    (["acquire", "--simulated", "--sim-faults", "{bad", "-o", "x.zarr"], "--sim-faults"),
    (["acquire", "--simulated", "--sim-faults", "[1]", "-o", "x.zarr"], "--sim-faults"),
    (["export", "tval3", "--n", "48"], "argument --n: expected a power of two"),
    (["bench", "operators", "--n", "48"], "argument --n: expected a power of two"),
    (["acquire", "--simulated", "--sr", "0", "-o", "x.zarr"], "argument --sr:"),
    (["acquire", "--simulated", "--n", "48", "-o", "x.zarr"], "argument --n:"),
    (["acquire", "--simulated", "--n", "4", "-o", "x.zarr"], "argument --n:"),
    (["acquire", "--simulated", "--scene", "nosuch", "-o", "x.zarr"], "argument --scene:"),
    (["acquire", "--simulated", "--roi-px", "8", "-o", "x.zarr"], "argument --roi-px:"),
    (["acquire", "--simulated", "--block", "0", "-o", "x.zarr"], "argument --block:"),
    (["acquire", "--simulated", "--order", "nosuch", "-o", "x.zarr"], "argument --order:"),
    (["acquire", "--simulated"], "-o/--output"),
    (["acquire", "--camera-roi", "0", "8", "9", "32", "-o", "x.zarr"],
     "argument --camera-roi: expected COL and WIDTH multiples of 16"),
    (["acquire", "--camera-roi", "200", "0", "65", "64", "-o", "x.zarr"],
     "a region inside the 320x240 sensor, got 200 0 65 64"),
    (["acquire", "--simulated", "--n", "8", "--camera-roi", "0", "0", "9", "32", "-o", "x.zarr"],
     "argument --camera-roi: rows 0..8, columns 0..31 lie beyond the simulated sensor"),
    (["reconstruct", "no_such_run.zarr", "--method", "FOO"], "argument --method:"),
    (["reconstruct", "no_such_run.zarr"], "no such store: no_such_run.zarr"),
    (["train", "--n", "48"], "unrecognized arguments: --n 48"),
    (["train", "--sr", "0"], "did you mean --sr-range?"),
    (["train", "--sr-range", "0", "1"], "argument --sr-range:"),
    (["train", "--sr-range", "0.5", "0.25"], "argument --sr-range: expected LO <= HI"),
    (["train", "--sizes", "48"], "argument --sizes:"),
    (["train", "--steps", "0"], "argument --steps:"),
    (["train", "--orders", "nosuch"], "argument --orders:"),
    (["train", "--init", "no_such.pt"], "argument --init: no such weights file: 'no_such.pt'"),
    (["train", "--families", "cats=1"], "argument --families: expected NAME=P"),
    (["train", "--families", "planar=0.3", "natural=0.7", "planar=0.3"],
     "argument --families: a family named twice"),
    (["train", "--families", "leaves=0.5", "planar=0.6"],
     "argument --families: train: expected families' probabilities >= 0 summing to 1"),
    (["demo", "--sr", "0.5", "--nosuch"], "unrecognized arguments: --nosuch"),
    (["nosuch"], "argument COMMAND"),
    (["--thr", "2", "demo"], "unrecognized arguments: --thr"),  # not "invalid choice: '2'"
    (["--threads", "2", "--nosuch", "demo"], "unrecognized arguments: --nosuch"),
]


@pytest.mark.parametrize(("argv", "names"), BAD, ids=[" ".join(a) for a, _ in BAD])
def test_mistakes_exit_2_with_one_line_before_any_work(argv, names, capsys, monkeypatch):
    import torchtof.experiment

    def no_work(*a, **k):
        raise AssertionError("the experiment ran before the options were checked")

    monkeypatch.setattr(torchtof.experiment.PaperExperiment, "run", no_work)
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    # exactly one line, no usage block, from the subcommand that was given
    cmd = "torchtof" if argv[0].startswith("-") or argv[0] == "nosuch" else f"torchtof {argv[0]}"
    assert len(lines) == 1 and lines[0].startswith(f"{cmd}: error: "), err
    assert names in lines[0], err
    assert "usage:" not in err and "Traceback" not in err and "Config" not in err
    assert out == ""  # nothing started (no progress bar, no banner)


def test_scene_error_lists_the_valid_names(capsys):
    with pytest.raises(SystemExit):
        main(["demo", "--scene", "nosuch"])
    err = capsys.readouterr().err
    assert "SKIMAGE_NAMES" not in err
    for name in ("sky", "steps", "motorcycle", "slanted", "steps_far", "skimage:<image>",
                 "camera", "horse"):
        assert name in err, name
    with pytest.raises(SystemExit):
        main(["demo", "--scene", "binary:nosuch"])
    err = capsys.readouterr().err
    assert "unknown image 'nosuch'" in err and "astronaut" in err and "SKIMAGE" not in err


def test_debug_and_help_still_give_the_full_usage(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--debug", "demo", "--n", "48"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("usage: torchtof demo") and "argument --n:" in err
    with pytest.raises(SystemExit) as exc:
        main(["train", "-h"])
    assert exc.value.code == 0
    text = capsys.readouterr().out
    assert "--sr-range LO HI" in text and "--n-layers" in text


@pytest.mark.parametrize(("rank", "printed"), [(None, True), ("0", True), ("1", False)])
def test_train_prints_its_summary_once_per_run(rank, printed, tmp_path, capsys, monkeypatch):
    # under torchrun every process runs the command; only rank 0 reports what was written
    import torchtof.apps.train as app
    from torchtof.recon.learned_train import train_learned

    seen = {}

    def fake(**kw):
        seen.update(kw)
        return type("R", (), {"losses": [1.0, 0.5], "wall_s": 3.0})()

    assert set(inspect.signature(train_learned).parameters) >= {"steps", "out", "device"}
    monkeypatch.setattr(app, "train_learned", fake)
    if rank is None:
        monkeypatch.delenv("RANK", raising=False)
    else:
        monkeypatch.setenv("RANK", rank)
    assert main(["train", "--steps", "2", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert seen["steps"] == 2 and seen["out"] == str(tmp_path) and seen["init"] is None
    assert ("wrote " in out) == printed, out


def test_train_init_shipped_names_the_package_weights(tmp_path, capsys, monkeypatch):
    import torchtof.apps.train as app
    from torchtof.recon.learned import WEIGHTS_FILE

    seen = {}
    monkeypatch.setattr(app, "train_learned", lambda **kw: seen.update(kw) or type(
        "R", (), {"losses": [1.0], "wall_s": 1.0})())
    assert main(["train", "--init", "shipped", "--out", str(tmp_path)]) == 0
    assert seen["init"] == str(WEIGHTS_FILE) and WEIGHTS_FILE.is_file()
    capsys.readouterr()


def test_calibrate_only_uses_the_runs_scene_mixture(tmp_path, capsys, monkeypatch):
    import json

    import torchtof.apps.train as app
    from torchtof.recon.learned_train import train_learned

    mix = {"silhouette": 0.5, "leaves": 0.5}
    train_learned(steps=1, batch_size=2, sizes=(16,), n_layers=2, width=4, progress=False,
                  calibrate=False, families=mix, out=tmp_path)
    seen = {}

    def fake(model, seed, **kw):
        seen.update(kw)
        return {"tau": 0.1, "losses": {}, "loss_off": 0.0}

    monkeypatch.setattr(app, "calibrate_tau", fake)
    net = ["--sizes", "16", "--n-layers", "2", "--width", "4", "--out", str(tmp_path)]
    assert main(["train", "--calibrate-only", *net]) == 0
    assert seen["families"] == mix
    assert json.loads((tmp_path / "recipe.json").read_text())["calibration_families"] == mix
    assert main(["train", "--calibrate-only", "--families", "planar=1", *net]) == 0
    assert seen["families"] == {"planar": 1.0}
    capsys.readouterr()


def test_train_families_reach_the_run(tmp_path, capsys, monkeypatch):
    import torchtof.apps.train as app

    seen = {}
    monkeypatch.setattr(app, "train_learned", lambda **kw: seen.update(kw) or type(
        "R", (), {"losses": [1.0], "wall_s": 1.0})())
    assert main(["train", "--families", "planar=0.25", "leaves=0.75", "--out",
                 str(tmp_path)]) == 0
    assert seen["families"] == {"planar": 0.25, "leaves": 0.75}
    assert main(["train", "--out", str(tmp_path)]) == 0
    assert seen["families"] is None
    capsys.readouterr()


def test_train_scales_reach_the_run_and_the_weights(tmp_path, capsys):
    """``--scales 3`` trains a three-scale prior, records it in recipe.json and the weights
    file, and the file rebuilds the same network; ``--scales 1`` is refused by argparse."""
    from torchtof.operators import Hadamard
    from torchtof.recon.learned import Learned

    out = tmp_path / "s3"
    assert main(["train", "--steps", "1", "--batch-size", "2", "--sizes", "16", "--n-layers",
                 "2", "--width", "4", "--scales", "3", "--no-calibrate", "--no-progress",
                 "--out", str(out)]) == 0
    assert json.loads((out / "recipe.json").read_text())["scales"] == 3
    net = Learned(Hadamard(16, sr=0.25), pretrained=out / "learned.pt")
    assert (net.prior.scales, len(net.prior.deeper)) == (3, 1)
    with pytest.raises(SystemExit) as exc:
        main(["train", "--scales", "1", "--out", str(out)])
    assert exc.value.code == 2
    assert "--scales: expected an int >= 2, got '1'" in capsys.readouterr().err


def test_calibrate_only_builds_the_runs_network(tmp_path, capsys, monkeypatch):
    """--calibrate-only on a --scales 3 --width 4 run rebuilds that network from recipe.json
    when the options are left at their defaults (its weights load, the file records them);
    a different explicit value is a usage error naming the option."""
    import torchtof.apps.train as app
    from torchtof.operators import Hadamard
    from torchtof.recon.learned import Learned
    from torchtof.recon.learned_train import train_learned

    train_learned(steps=1, batch_size=2, sizes=(16,), n_layers=2, width=4, scales=3,
                  progress=False, calibrate=False, out=tmp_path)
    seen = {}

    def fake(model, seed, **kw):
        seen.update(scales=model.prior.scales, width=model.prior.width, n=model.n_layers)
        return {"tau": 0.1, "losses": {}, "loss_off": 0.0}

    monkeypatch.setattr(app, "calibrate_tau", fake)
    out = ["--sizes", "16", "--out", str(tmp_path)]
    assert main(["train", "--calibrate-only", *out]) == 0
    assert seen == {"scales": 3, "width": 4, "n": 2}
    net = Learned(Hadamard(16, sr=0.25), pretrained=tmp_path / "learned.pt")
    assert (net.prior.scales, net.prior.width, net.n_layers) == (3, 4, 2)
    state = torch.load(tmp_path / "checkpoint.pt", weights_only=False)["model"]
    torch.testing.assert_close(net.prior.deeper[0]["mid1"].weight,
                               state["prior.deeper.0.mid1.weight"])
    capsys.readouterr()
    assert main(["train", "--calibrate-only", "--scales", "4", *out]) == 2
    assert "argument --scales: the run in" in capsys.readouterr().err


def test_reconstruct_refuses_a_folder_that_is_not_a_store(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["reconstruct", str(tmp_path)])
    assert exc.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1, lines
    assert "is not a torchtof store (no zarr group): " in lines[0] and str(tmp_path) in lines[0]


def test_bench_summary_names_every_file_it_wrote(tmp_path, capsys, monkeypatch):
    import torchtof.cli

    png = tmp_path / "tradeoff.png"
    res = {"rows": [{}], "plot": str(png), "json": str(tmp_path / "tradeoff.json")}
    monkeypatch.setattr(torchtof.cli, "_bench_result", lambda args: (res, lambda r: None))
    assert main(["bench", "tradeoff", "--quick", "--out", str(tmp_path)]) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert last.startswith("torchtof bench tradeoff: 1 rows in ")
    for name in ("tradeoff.png", "tradeoff.json"):
        assert str(tmp_path / name) in last, last
    # one JSON, the bench's own, with the load the run had (no second bench_tradeoff.json)
    assert not (tmp_path / "bench_tradeoff.json").exists()
    saved = json.loads((tmp_path / "tradeoff.json").read_text())
    assert set(saved["machine"]) == {"start", "end"}
    assert {"load_1min", "cpus", "threads"} <= set(saved["machine"]["start"])


def test_bench_onnx_progress_line_has_three_significant_digits():
    from torchtof.apps.bench.onnx import progress_line

    row = {"model": "pinv", "batch": 4, "eager_s": 0.0009510731546395187, "ort_s": 1.23456,
           "compile_s": 0.000123456}
    assert progress_line(row) == ("pinv batch 4: eager 0.000951 s, onnxruntime 1.23 s, "
                                  "compile 0.000123 s")


@pytest.mark.parametrize(("script", "argv", "expect"), [
    ("benchmarks/time_dip.py", ["--help"], "usage: time_dip.py"),
    pytest.param("benchmarks/time_dip.py", ["--iters", "0"],
                 "time_dip.py: error: argument --iters:", marks=pytest.mark.slow),
    ("examples/train_unrolled.py", ["--n", "48"],
     "train_unrolled.py: error: argument --n/--size: expected a power of two"),
    pytest.param("benchmarks/auto_bands.py", ["--cells", "sky:32"],
                 "auto_bands.py: error: argument --cells: invalid parse_cell value: 'sky:32'",
                 marks=pytest.mark.slow),
    pytest.param("benchmarks/versus_rev.py", ["--rounds", "0"],
                 "versus_rev.py: error: --rounds and --repeats must be >= 1",
                 marks=pytest.mark.slow),
    pytest.param("benchmarks/tvl2_convergence.py", ["--max-iter", "0"],
                 "tvl2_convergence.py: error: expected --max-iter", marks=pytest.mark.slow),
    pytest.param("benchmarks/tvl2_convergence.py", ["--beta", "0"],
                 "tvl2_convergence.py: error: expected --admm-iter >= 1 and --admm-tol, --beta",
                 marks=pytest.mark.slow),
    pytest.param("benchmarks/auto_tv_solver.py", ["--cells", "sky:32"],
                 "auto_tv_solver.py: error: expected --cells items scene:n:sr:order",
                 marks=pytest.mark.slow),
    pytest.param("benchmarks/auto_tv_solver.py", ["--variants", "tval3", "tval3:0"],
                 "auto_tv_solver.py: error: expected --variants items", marks=pytest.mark.slow),
])
def test_scripts_parse_their_options_first(script, argv, expect):
    import subprocess
    import sys
    from pathlib import Path

    repo = Path(__file__).resolve().parents[1]
    proc = subprocess.run([sys.executable, str(repo / script), *argv], capture_output=True,
                          text=True, timeout=120, env={**__import__("os").environ,
                                                       "PYTHONPATH": str(repo)})
    text = proc.stdout + proc.stderr
    assert expect in text, text
    if argv != ["--help"]:
        assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1, text
    else:
        assert proc.returncode == 0 and "--iters" in proc.stdout


def test_error_inside_a_command_is_one_line_and_debug_shows_it(tmp_path, capsys, monkeypatch):
    pytest.importorskip("onnx")
    import torchtof.apps.onnx_models

    def fails(*a, **k):
        raise ValueError("export_model: expected something else")

    monkeypatch.setattr(torchtof.apps.onnx_models, "export_checked", fails)
    argv = ["export", "hadamard", "--out", str(tmp_path)]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("torchtof export: error: export_model:"), err
    assert "--debug" in err[0]
    with pytest.raises(ValueError, match="export_model"):
        main(["--debug", *argv])


def test_reproduce_refuses_zero_realisations(tmp_path):
    from torchtof.apps.reproduce import reproduce

    with pytest.raises(ValueError, match="realisations"):
        reproduce(tmp_path, realisations=0)


def _all_parsers():
    from torchtof.cli import build_parser

    p = build_parser()
    sub = next(a for a in p._actions if a.__class__.__name__ == "_SubParsersAction")
    return [("torchtof", p), *sub.choices.items()]


@pytest.mark.parametrize(("name", "parser"), _all_parsers(), ids=lambda v: v
                         if isinstance(v, str) else "")
def test_every_option_has_help_and_shows_its_default(name, parser):
    assert not parser.allow_abbrev, name  # --n must not silently mean --n-layers
    missing = [a.dest for a in parser._actions if not a.help and a.dest != "help"]
    assert not missing, f"{name}: options without help: {missing}"
    text = " ".join(parser.format_help().split())
    for a in parser._actions:
        if a.option_strings and a.default not in (None, False, "==SUPPRESS==") and a.help:
            assert "(default:" in a.help or f"default: {a.default}" in text, (name, a.dest)


def test_bench_writes_json_under_out_and_a_summary(tmp_path, capsys):
    assert main(["bench", "operators", "--n", "8", "--batch", "2", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    path = tmp_path / "bench_operators.json"
    assert json.loads(path.read_text())["rows"][0]["n"] == 8
    assert out[-1].startswith("torchtof bench operators: 1 rows in ") and str(path) in out[-1]
    assert any(", 1 thread, torch" in line for line in out), out  # not "1 threads"


def test_calibrate_only_uses_the_runs_starting_estimate(tmp_path, capsys, monkeypatch):
    """A run trained with --x0 markov is calibrated and saved with that start; asking for
    another one is a usage error naming --x0."""
    import torchtof.apps.train as app
    from torchtof.operators import Hadamard
    from torchtof.recon.learned import Learned
    from torchtof.recon.learned_train import train_learned

    train_learned(steps=1, batch_size=2, sizes=(16,), n_layers=2, width=4, progress=False,
                  calibrate=False, out=tmp_path, x0="markov")
    seen = {}

    def fake(model, seed, **kw):
        seen["x0"] = model.x0
        return {"tau": 0.1, "losses": {}, "loss_off": 0.0}

    monkeypatch.setattr(app, "calibrate_tau", fake)
    net = ["--sizes", "16", "--n-layers", "2", "--width", "4", "--out", str(tmp_path)]
    assert main(["train", "--calibrate-only", *net]) == 0
    assert seen["x0"] == "markov"
    assert Learned(Hadamard(16, sr=0.25), pretrained=tmp_path / "learned.pt").x0 == "markov"
    assert main(["train", "--calibrate-only", "--x0", "adjoint", *net]) == 2
    assert "--x0" in capsys.readouterr().err


def test_train_never_overwrites_a_run_and_resume_checks_the_network(tmp_path, capsys):
    """A second run into the same --out without --resume is a usage error (the first run's
    checkpoint survives); --resume with another network names the difference in one line;
    --resume without a checkpoint says it starts afresh."""
    net = ["--batch-size", "2", "--sizes", "16", "--n-layers", "2", "--no-progress",
           "--no-calibrate", "--out", str(tmp_path / "run")]
    assert main(["train", "--steps", "2", "--width", "4", *net]) == 0
    assert "learned.pt" in capsys.readouterr().out
    ckpt = tmp_path / "run" / "checkpoint.pt"
    before = torch.load(ckpt, weights_only=False)["step"]
    with pytest.raises(SystemExit) as exc:
        main(["train", "--steps", "1", "--width", "4", *net])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "argument --out:" in err[0] and "--resume" in err[0], err
    assert torch.load(ckpt, weights_only=False)["step"] == before == 2
    assert main(["train", "--steps", "3", "--width", "8", "--resume", *net]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "width=4 (got 8)" in err[0], err
    assert main(["train", "--steps", "3", "--width", "4", "--resume", *net]) == 0
    assert torch.load(ckpt, weights_only=False)["step"] == 3
    capsys.readouterr()
    fresh = [a if a != str(tmp_path / "run") else str(tmp_path / "new") for a in net]
    assert main(["train", "--steps", "1", "--width", "4", "--resume", *fresh]) == 0
    assert "starting at step 0" in capsys.readouterr().err


@pytest.mark.parametrize("cmd", [["demo"], ["bench", "operators"], ["export", "g2"],
                                 ["train"], ["reproduce", "--quick"]])
def test_out_that_is_a_file_is_a_usage_error(cmd, tmp_path, capsys):
    f = tmp_path / "a_file"
    f.write_text("keep me")
    with pytest.raises(SystemExit) as exc:
        main([*cmd, "--out", str(f)])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"argument --out: expected a folder, {f} is a file" in err[0], err
    assert f.read_text() == "keep me"


@pytest.mark.parametrize(("argv", "msg"), [
    (["--depth", "steps", "--scene", "sky"], "argument --scene: not used with --depth"),
    (["--depth", "--methods", "CGI"], "argument --methods: not used with --depth"),
    (["--depth", "--auto"], "argument --auto: not used with --depth"),
    (["--auto", "--methods", "CGI"], "argument --methods: not used with --auto"),
    (["--auto", "--realisations", "3"], "argument --realisations: --auto runs one"),
])
def test_demo_modes_refuse_options_they_would_ignore(argv, msg, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["demo", *argv])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and msg in err[0], err


def test_demo_defaults_and_the_auto_maximum_sr(monkeypatch):
    """Without --sr the demo runs at 12.5 % and --auto up to 37.5 %; --auto --sr S makes S the
    maximum (it was raised to 37.5 % silently)."""
    import torchtof.apps.auto_demo as auto_demo
    import torchtof.apps.demo as demo

    seen = []
    monkeypatch.setattr(demo, "run_demo", lambda a: seen.append((a.sr, a.scene)) or 0)
    monkeypatch.setattr(auto_demo, "demo_auto", lambda a: seen.append((a.sr, a.scene)) or 0)
    for argv in (["demo"], ["demo", "--auto"], ["demo", "--auto", "--sr", "0.25"],
                 ["demo", "--sr", "0.5", "--scene", "steps"]):
        assert main(argv) == 0
    assert seen == [(0.125, "sky"), (0.375, "sky"), (0.25, "sky"), (0.5, "steps")]


@pytest.mark.parametrize(("argv", "msg"), [
    (["onnx", "--n", "64"], "argument --n: used by bench operators only, not by bench onnx"),
    (["onnx", "--sr", "0.5"], "argument --sr: used by bench operators only"),
    (["operators", "--quick"], "argument --quick: used by bench recon / tradeoff / adaptive"),
    (["operators", "--plot"], "argument --plot: used by bench recon only"),
    (["recon", "--models", "g2"], "argument --models: used by bench onnx only"),
    (["stability", "--seeds", "0-2"], "argument --seeds: used by bench adaptive only"),
    # an option given at its default value is still one the benchmark would ignore
    (["onnx", "--n", "32"], "argument --n: used by bench operators only"),
    (["recon", "--seed", "0"], "argument --seed: used by bench adaptive only"),
])
def test_bench_refuses_options_of_another_benchmark(argv, msg, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["bench", *argv])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and msg in err[0], err


def test_every_bench_option_is_either_common_or_assigned():
    """BENCH_OPTIONS lists every benchmark-specific option of the parser, for benchmarks that
    exist: a new option must say whom it serves."""
    from torchtof.cli import BENCH_OPTIONS, BENCHES, build_parser

    sub = next(a for a in build_parser()._actions if a.dest == "cmd").choices["bench"]
    dests = {a.dest for a in sub._actions} - {"help", "which", "out", "json"}
    assert dests == set(BENCH_OPTIONS)
    assert all(set(w) <= set(BENCHES) for w in BENCH_OPTIONS.values())


@pytest.mark.parametrize(("argv", "flag"), [
    (["demo", "--n", "8", "--out", "{f}/sub"], "--out"),
    (["bench", "operators", "--n", "4", "--batch", "1", "--json", "{f}/x.json"], "--json"),
    (["export", "g2", "--n", "4", "-o", "{f}/x.onnx"], "-o/--output"),
    (["acquire", "--simulated", "--n", "16", "-o", "{f}/run.zarr"], "-o/--output"),
])
def test_destination_under_a_file_is_refused_before_any_work(argv, flag, tmp_path, capsys):
    """A destination whose parent is a file failed only after the whole run (mkdir), with a
    traceback or an error that did not name the option."""
    f = tmp_path / "a_file"
    f.write_text("keep me")
    with pytest.raises(SystemExit) as exc:
        main([a.format(f=f) for a in argv])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"argument {flag}: expected a path under a folder, {f} is a file" \
        in err[0], err
    assert f.read_text() == "keep me"


def test_file_destination_that_is_a_folder_is_refused(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["bench", "operators", "--n", "4", "--batch", "1", "--json", str(tmp_path)])
    assert exc.value.code == 2
    assert f"argument --json: expected a file path, {tmp_path} is a folder" in \
        capsys.readouterr().err


def test_bench_operators_at_a_tiny_sampling_rate_reports_the_rows_used(tmp_path):
    """round(sr·n²) was 0 where the operator takes one row, and the benchmark crashed."""
    import json

    out = tmp_path / "b.json"
    assert main(["bench", "operators", "--n", "4", "--sr", "0.01", "--batch", "1",
                 "--json", str(out)]) == 0
    assert json.loads(out.read_text())["rows"][0]["M"] == 1


def test_bench_seed_with_seeds_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["bench", "adaptive", "--seed", "7", "--seeds", "0-1"])
    assert exc.value.code == 2
    assert "argument --seed: not used with --seeds" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:  # the default seed, written out, too
        main(["bench", "adaptive", "--seed", "0", "--seeds", "0-1"])
    assert "argument --seed: not used with --seeds" in capsys.readouterr().err


@pytest.mark.parametrize("opts, flag", [
    (["--steps", "5"], "--steps"), (["--lr", "0.1"], "--lr"), (["--resume"], "--resume"),
    (["--no-calibrate"], "--no-calibrate"), (["--max-minutes", "1"], "--max-minutes"),
    (["--init", "shipped"], "--init"), (["--workers", "1"], "--workers"),
    # at their default values too (they would still be ignored)
    (["--steps", "8000"], "--steps"), (["--lr=0.002"], "--lr")])
def test_calibrate_only_refuses_a_training_option(opts, flag, tmp_path, capsys):
    """A training option beside --calibrate-only would be ignored: a one-line usage error
    that names it, before the run is read (no checkpoint here)."""
    with pytest.raises(SystemExit) as exc:
        main(["train", "--calibrate-only", *opts, "--out", str(tmp_path / "run")])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert f"argument {flag}: a training option, not used with --calibrate-only" in err, err


@pytest.mark.parametrize("opts, step, bad", [
    (["--sizes", "8", "32", "--shuffle", "8"], 16, "8"),
    (["--sizes", "16", "32", "--scales", "6"], 32, "16")])
def test_train_sizes_the_prior_cannot_take_are_a_usage_error(opts, step, bad, tmp_path,
                                                             capsys):
    out = tmp_path / "run"
    with pytest.raises(SystemExit) as exc:
        main(["train", *opts, "--out", str(out)])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "argument --sizes: with --scales" in err and f"= {step}, got {bad} " in err, err
    assert not out.exists()  # refused before any work


def test_bench_tradeoff_json_is_the_only_json(tmp_path, capsys, monkeypatch):
    """--json names the tradeoff's JSON: no second OUT/tradeoff.json beside it."""
    import torchtof.apps.bench.tradeoff as tradeoff

    row = {"n": 8, "sr": 0.25, "label": "PINV", "method": "PINV", "budget": None,
           "time_s": 1e-4, "psnr": 10.0, "ssim": 0.5, "rmse": 0.1, "rmse_unit": "m"}
    monkeypatch.setattr(tradeoff, "sweep", lambda *a: [row])
    monkeypatch.setattr(tradeoff, "plot_sweep", lambda pts, path, title="": None)
    out, js = tmp_path / "out", tmp_path / "elsewhere" / "t.json"
    assert main(["bench", "tradeoff", "--quick", "--out", str(out), "--json", str(js)]) == 0
    assert not (out / "tradeoff.json").exists()
    saved = json.loads(js.read_text())
    assert saved["json"] == str(js) and saved["points"][0]["label"] == "PINV"
    assert set(saved["machine"]) == {"start", "end"}
    table = out / "budget_table.json"
    assert capsys.readouterr().out.strip().splitlines()[-1].endswith(f"wrote {js}, {table}")
    # the budget table is the shipped format: choose_method reads it as it is
    from torchtof.adaptive import choose_method

    pick = choose_method(8, 0.25, time_budget_s=1.0, table=table)
    assert pick.method == "PINV" and pick.psnr == 10.0 and pick.met
