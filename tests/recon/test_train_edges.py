"""Edges of the training code: resumes, DDP stops, the calibration-only command, atomic
writes, input checks of the training entry points, ``dip``'s up-front noise check and the
functional unrolled TVAL3.

Every training run here is tiny (batch 2, n = 16, a 2-layer width-4 network, no
calibration); the tests that launch ``torch.distributed.run`` are marked slow.
"""

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

import torchtof.recon.learned_train as lt
from torchtof.cli import main
from torchtof.data import FAMILIES, training_noise
from torchtof.operators import Hadamard
from torchtof.recon.dip import dip, fit_dip
from torchtof.recon.learned_train import (
    rank_device,
    same_mixture,
    stop_after_step,
    train_learned,
)
from torchtof.recon.train import dist_setup
from torchtof.recon.unrolled import UnrolledTVAL3, unrolled_tval3

ROOT = Path(__file__).resolve().parents[2]
TINY = dict(batch_size=2, sizes=(16,), n_layers=2, width=4, progress=False, calibrate=False)
CLI_TINY = ["--batch-size", "2", "--sizes", "16", "--n-layers", "2", "--width", "4",
            "--no-progress", "--no-calibrate"]


def _records(path):
    """log.json without the wall times (the only field a resume may change)."""
    return [{k: v for k, v in r.items() if k != "wall_s"}
            for r in json.loads(Path(path).read_text())]


def _torchrun_env():
    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1", GLOO_SOCKET_IFNAME="lo")
    for k in ("RANK", "WORLD_SIZE", "LOCAL_RANK", "MASTER_ADDR", "MASTER_PORT"):
        env.pop(k, None)
    return env


# -- 1. the --max-minutes stop under DDP is the ranks' decision ---------------------------------


def test_stop_decision_without_ddp_and_with_another_rank_late(monkeypatch):
    now = time.perf_counter()
    assert stop_after_step(now - 61, 1.0, False) and not stop_after_step(now, 1.0, False)
    assert not stop_after_step(now - 1e6, None, True)  # no limit: no collective either
    calls = []

    def other_rank_late(t, op):  # what the all-reduce MAX gives when another rank is late
        calls.append(op)
        t.fill_(1.0)

    monkeypatch.setattr(lt.dist, "all_reduce", other_rank_late)
    assert stop_after_step(time.perf_counter(), 1.0, True)  # this rank is early, stops too
    assert calls == [lt.dist.ReduceOp.MAX]


@pytest.mark.slow  # two processes: ~5 s on 2 cores
def test_stop_decision_is_the_same_on_two_gloo_ranks(tmp_path):
    script = tmp_path / "stop.py"
    script.write_text(
        "import time\n"
        "import torch.distributed as dist\n"
        "from torchtof.recon.learned_train import stop_after_step\n"
        "dist.init_process_group('gloo')\n"
        "r = dist.get_rank()\n"
        "late = stop_after_step(time.perf_counter() - (120 if r == 0 else 0), 1.0, True)\n"
        "none = stop_after_step(time.perf_counter(), 1.0, True)\n"
        "print(f'rank {r}: {late} {none}', flush=True)\n"
        "dist.destroy_process_group()\n")
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node",
           "2", str(script)]
    proc = subprocess.run(cmd, cwd=ROOT, env=_torchrun_env(), capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "rank 0: True False" in proc.stdout and "rank 1: True False" in proc.stdout


@pytest.mark.slow  # two processes training: ~15 s; hung before the shared decision
def test_ddp_max_minutes_stop_with_a_slow_rank0_checkpoint_finishes(tmp_path):
    """Rank 0 (the one that writes checkpoints) takes 2 s per checkpoint: with each rank
    deciding the time limit alone it stopped a step before the other and both waited."""
    script = tmp_path / "slowsave.py"
    script.write_text(
        "import os, sys, time, torch\n"
        "from torchtof.cli import main\n"
        "orig = torch.save\n"
        "def save(*a, **k):\n"
        "    if os.environ.get('RANK') == '0':\n"
        "        time.sleep(2)\n"
        "    return orig(*a, **k)\n"
        "torch.save = save\n"
        "sys.exit(main(sys.argv[1:]))\n")
    args = ["train", "--model", "learned", "--steps", "400", "--checkpoint-every", "3",
            "--batch-size", "2", "--sizes", "16", "32", "--n-layers", "2", "--width", "4",
            "--no-progress", "--log-every", "2", "--no-calibrate", "--max-minutes", "0.05",
            "--out", str(tmp_path / "run")]
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node",
           "2", str(script), *args]
    proc = subprocess.run(cmd, cwd=ROOT, env=_torchrun_env(), capture_output=True, text=True,
                          timeout=150)
    assert proc.returncode == 0, proc.stderr[-3000:]
    recipe = json.loads((tmp_path / "run" / "recipe.json").read_text())
    assert recipe["world_size"] == 2 and 1 <= recipe["steps_run"] < 400


# -- 2./3. a resume repeats the run's settings and never rewinds its step -----------------------


@pytest.fixture(scope="module")
def run2(tmp_path_factory):
    """A finished 2-step run (its checkpoint at step 2)."""
    out = tmp_path_factory.mktemp("run2")
    train_learned(steps=2, out=out, checkpoint_every=1, sizes=(16, 32), **{
        k: v for k, v in TINY.items() if k != "sizes"})
    return out


def test_resume_below_the_checkpoints_step_is_refused(run2):
    kw = {k: v for k, v in TINY.items() if k != "sizes"}
    with pytest.raises(ValueError, match=r"train_learned: checkpoint .* is at step 2, beyond "
                                         r"steps=1"):
        train_learned(steps=1, out=run2, resume=True, sizes=(16, 32), **kw)
    assert torch.load(run2 / "checkpoint.pt", weights_only=False)["step"] == 2


def test_cli_resume_below_the_checkpoints_step_is_one_line(run2, capsys):
    argv = ["train", "--steps", "1", "--resume", "--out", str(run2), "--batch-size", "2",
            "--sizes", "16", "32", *CLI_TINY[4:]]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "steps=1" in err[0], err


@pytest.mark.parametrize(("kw", "named"), [
    ({"seed": 1}, "seed=0 (got 1)"),
    ({"lr": 1e-3}, "lr=0.002 (got 0.001)"),
    ({"batch_size": 4}, "batch_size=2 (got 4)"),
    ({"sizes": (16, 64)}, "sizes=[16, 32] (got [16, 64])"),
    ({"p_large": 0.5}, "p_large=0.3 (got 0.5)"),
    ({"sr_range": (0.1, 0.5)}, "sr_range=[0.0625, 0.5] (got [0.1, 0.5])"),
    ({"orders": ("natural",)}, "orders="),
    ({"noise_ref": None}, "noise_ref=128 (got None)"),
    ({"p_clean": 0.5}, "p_clean=0.3 (got 0.5)"),
    ({"p_noise_ref": 1.0}, "p_noise_ref=0.5 (got 1.0)"),
])
def test_resume_with_other_settings_names_them(run2, kw, named):
    base = {**{k: v for k, v in TINY.items() if k != "sizes"}, "sizes": (16, 32)}
    with pytest.raises(ValueError, match="other settings") as exc:
        train_learned(steps=3, out=run2, resume=True, **{**base, **kw})
    assert named in str(exc.value)


def test_resume_may_change_steps_and_records_it(tmp_path):
    train_learned(steps=2, out=tmp_path, **TINY)
    train_learned(steps=3, out=tmp_path, resume=True, **TINY)
    recipe = json.loads((tmp_path / "recipe.json").read_text())
    assert recipe["steps_run"] == 3
    assert recipe["steps_changes"] == [{"step": 2, "from": 2, "to": 3}]


def test_old_checkpoint_without_the_records_still_resumes(tmp_path):
    """Checkpoints from before the settings and losses records: the comparison is skipped."""
    train_learned(steps=1, out=tmp_path, **TINY)
    ckpt = tmp_path / "checkpoint.pt"
    state = torch.load(ckpt, weights_only=False)
    for k in ("run", "losses", "steps_changes"):
        del state[k]
    torch.save(state, ckpt)
    r = train_learned(steps=2, out=tmp_path, resume=True, **{**TINY, "seed": 5})
    assert len(r.losses) == 1


def test_resume_keeps_the_runs_origin(tmp_path):
    """A checkpoint records where its run started; a resume keeps that origin in
    recipe.json and refuses another init (which would not be loaded anyway)."""
    train_learned(steps=1, out=tmp_path / "w", **TINY)
    w = tmp_path / "w" / "learned.pt"
    train_learned(steps=1, out=tmp_path / "a", **TINY)  # random initialisation
    with pytest.raises(ValueError, match="started from its random initialisation"):
        train_learned(steps=2, out=tmp_path / "a", resume=True, init=w, **TINY)
    train_learned(steps=1, out=tmp_path / "b", init=w, **{**TINY, "seed": 1})
    train_learned(steps=2, out=tmp_path / "b", resume=True, **{**TINY, "seed": 1})
    recipe = json.loads((tmp_path / "b" / "recipe.json").read_text())
    assert recipe["init"]["path"] == os.fspath(w)
    train_learned(steps=3, out=tmp_path / "b", resume=True, init=w, **{**TINY, "seed": 1})
    assert json.loads((tmp_path / "b" / "recipe.json").read_text())["init"] == recipe["init"]


def test_resume_from_a_corrupt_or_foreign_checkpoint_is_one_line(tmp_path, capsys):
    train_learned(steps=1, out=tmp_path, **TINY)
    ckpt = tmp_path / "checkpoint.pt"
    (tmp_path / "learned.pt").replace(ckpt)  # a weights file where the checkpoint belongs
    with pytest.raises(ValueError, match=r"is not a training checkpoint of train_learned \(no "):
        train_learned(steps=2, out=tmp_path, resume=True, **TINY)
    ckpt.write_text("\n")
    with pytest.raises(ValueError, match="is not a readable training checkpoint"):
        train_learned(steps=2, out=tmp_path, resume=True, **TINY)
    assert main(["train", "--model", "learned", "--steps", "2", "--resume", "--out",
                 str(tmp_path), *CLI_TINY]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a readable training checkpoint" in err[0], err
    assert main(["train", "--model", "learned", "--calibrate-only", "--out", str(tmp_path),
                 "--no-progress"]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a readable training checkpoint" in err[0], err


# -- 4. a resumed run writes the uninterrupted run's log and final loss -------------------------


def test_crash_and_resume_writes_the_uninterrupted_log(tmp_path, monkeypatch):
    kw = dict(TINY, steps=6, checkpoint_every=3, log_every=2)
    train_learned(out=tmp_path / "full", **kw)
    calls = {"n": 0}
    orig = torch.optim.Adam.step

    class Crash(Exception):
        pass

    def crash_at_5(self, *a, **k):
        calls["n"] += 1
        if calls["n"] == 5:  # during step 5, after the checkpoint at step 3
            raise Crash
        return orig(self, *a, **k)

    monkeypatch.setattr(torch.optim.Adam, "step", crash_at_5)
    with pytest.raises(Crash):
        train_learned(out=tmp_path / "crash", **kw)
    monkeypatch.setattr(torch.optim.Adam, "step", orig)
    assert torch.load(tmp_path / "crash" / "checkpoint.pt", weights_only=False)["step"] == 3
    r = train_learned(out=tmp_path / "crash", resume=True, **kw)
    assert len(r.losses) == 3  # this call's steps
    assert _records(tmp_path / "crash" / "log.json") == _records(tmp_path / "full" / "log.json")
    a, b = (json.loads((tmp_path / d / "recipe.json").read_text()) for d in ("full", "crash"))
    assert a["final_loss"] == b["final_loss"] and a["steps_run"] == b["steps_run"] == 6
    wa, wb = (torch.load(tmp_path / d / "learned.pt", weights_only=True) for d in ("full", "crash"))
    assert all(torch.equal(wa["prior"][k], wb["prior"][k]) for k in wa["prior"])


# -- 5. --calibrate-only: the run's data recipe, metadata, one-line mistakes --------------------


def _fake_calibration(monkeypatch):
    import torchtof.apps.train as app

    seen = {}

    def fake(model, seed, **kw):
        seen.update(kw, seed=seed, width=model.prior.width)
        return {"tau": 0.1, "losses": {}, "loss_off": 0.0}

    monkeypatch.setattr(app, "calibrate_tau", fake)
    return seen


RUN_RECIPE = ["--seed", "3", "--sizes", "16", "--sr-range", "0.1", "0.3", "--orders", "natural",
              "--noise-ref", "64", "--p-noise-ref", "0.25", "--p-clean", "0.5"]
WANT = {"seed": 3, "sizes": (16,), "sr_range": (0.1, 0.3), "orders": ("natural",),
        "noise_ref": 64, "p_noise_ref": 0.25, "p_clean": 0.5, "width": 4}


@pytest.fixture
def cal_run(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["train", "--steps", "1", *CLI_TINY, *RUN_RECIPE, "--out", str(out)]) == 0
    capsys.readouterr()
    return out


@pytest.mark.parametrize("drop_recipe", [False, True], ids=["recipe", "checkpoint"])
def test_calibrate_only_takes_the_runs_data_recipe(cal_run, monkeypatch, capsys, drop_recipe):
    """From recipe.json, or without it from the checkpoint's records; learned.pt keeps the
    noise options in its metadata."""
    if drop_recipe:
        (cal_run / "recipe.json").unlink()
    seen = _fake_calibration(monkeypatch)
    assert main(["train", "--calibrate-only", "--out", str(cal_run)]) == 0
    assert {k: seen[k] for k in WANT} == WANT
    meta = torch.load(cal_run / "learned.pt", weights_only=True)["meta"]
    assert (meta["noise_ref"], meta["p_noise_ref"], meta["p_clean"], meta["seed"]) == (
        64, 0.25, 0.5, 3)
    capsys.readouterr()


@pytest.mark.parametrize("argv", [["--sizes", "32"], ["--seed", "0"], ["--sr-range", "0.1", "0.5"],
                                  ["--orders", "sequency"], ["--noise-ref", "0"],
                                  ["--p-clean", "0.3"], ["--p-noise-ref", "0.5"],
                                  ["--width", "16"]])
def test_calibrate_only_refuses_another_explicit_value(cal_run, monkeypatch, capsys, argv):
    """An option given explicitly, even at its default, with another value than the run's."""
    _fake_calibration(monkeypatch)
    assert main(["train", "--calibrate-only", *argv, "--out", str(cal_run)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"argument {argv[0]}: the run in" in err[0], err


def test_calibrate_only_same_explicit_value_is_fine(cal_run, monkeypatch, capsys):
    seen = _fake_calibration(monkeypatch)
    assert main(["train", "--calibrate-only", *RUN_RECIPE, "--width", "4", "--out",
                 str(cal_run)]) == 0
    assert {k: seen[k] for k in WANT} == WANT
    capsys.readouterr()


def test_calibrate_only_network_mismatch_is_one_line(cal_run, monkeypatch, capsys):
    """No recipe.json and a checkpoint without its network record: the options' network does
    not hold the weights -- one line, not a load_state_dict traceback."""
    _fake_calibration(monkeypatch)
    (cal_run / "recipe.json").unlink()
    state = torch.load(cal_run / "checkpoint.pt", weights_only=False)
    del state["meta"]
    torch.save(state, cal_run / "checkpoint.pt")
    assert main(["train", "--calibrate-only", "--out", str(cal_run)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "does not hold the network" in err[0], err


# -- 6. the default mixture given explicitly resumes -----------------------------------------


def test_resume_accepts_the_default_mixture_given_explicitly(tmp_path):
    explicit = {k: v for k, v in FAMILIES.items() if v > 0}
    assert same_mixture(explicit, FAMILIES) and not same_mixture({"planar": 1.0}, FAMILIES)
    train_learned(steps=1, out=tmp_path, **TINY)
    r = train_learned(steps=2, out=tmp_path, resume=True, families=explicit, **TINY)
    assert len(r.losses) == 1
    with pytest.raises(ValueError, match="families="):
        train_learned(steps=3, out=tmp_path, resume=True, families={"planar": 1.0}, **TINY)


# -- 7. unrolled_tval3(y, A): the caller's operator untouched, the file read once ----------------


def test_functional_unrolled_leaves_A_alone_and_reads_the_file_once(monkeypatch):
    import importlib

    un = importlib.import_module("torchtof.recon.unrolled")

    A = Hadamard(32, sr=0.25)
    y = A(torch.rand(2, 1, 32, 32, generator=torch.Generator().manual_seed(3)))
    moved = []
    monkeypatch.setattr(A, "_apply", lambda *a, **k: moved.append(a))  # Module.to's recursion
    loads = []
    orig = un.torch.load
    monkeypatch.setattr(un.torch, "load", lambda *a, **k: loads.append(a) or orig(*a, **k))
    un._read_cached.cache_clear()
    x1, x2 = unrolled_tval3(y, A), unrolled_tval3(y, A)
    assert moved == [] and len(loads) == 1
    monkeypatch.undo()
    torch.testing.assert_close(x1, UnrolledTVAL3(A)(y), rtol=0, atol=0)
    assert torch.equal(x1, x2)


# -- 8. named errors for bad inputs --------------------------------------------------------------


@pytest.mark.parametrize(("kw", "exc", "match"), [
    ({"p_large": 1.5}, ValueError, "p_large"),
    ({"p_large": float("nan")}, ValueError, "p_large"),
    ({"max_minutes": -1.0}, ValueError, "max_minutes"),
    ({"max_minutes": float("nan")}, ValueError, "max_minutes"),
    ({"lr": True}, TypeError, "lr"),
    ({"seed": -1}, ValueError, "expected seed >= 0"),
    ({"seed": 2**64}, ValueError, "expected seed <= "),
    ({"seed": 1.0}, TypeError, "seed"),
    ({"sizes": (16.0,)}, TypeError, "sizes"),
    ({"sizes": 16}, TypeError, "sizes"),
    ({"sizes": (512,)}, ValueError, r"sizes to be powers of two in \[8, 256\]"),
    ({"sr_range": (0.1,)}, TypeError, "sr_range"),
    ({"sr_range": (0.1, "a")}, TypeError, "sr_range"),
    ({"orders": None}, TypeError, "orders"),
])
def test_train_learned_bad_inputs_are_named(kw, exc, match):
    with pytest.raises(exc, match=f"train_learned: .*{match}"):
        train_learned(steps=1, **{**TINY, **kw})


@pytest.mark.parametrize(("kw", "exc", "match"), [
    ({"levels": (0, 0.1)}, ValueError, r"levels\[0\]"),
    ({"levels": (0.1, 0.01)}, ValueError, r"levels\[0\] <= levels\[1\]"),
    ({"levels": (0.1,)}, TypeError, "levels"),
    ({"p_clean": float("nan")}, ValueError, "p_clean"),
    ({"p_shot": 2.0}, ValueError, "p_shot"),
])
def test_training_noise_bad_inputs_are_named(kw, exc, match):
    with pytest.raises(exc, match=f"training_noise: expected {match}"):
        training_noise(torch.Generator().manual_seed(0), **kw)


def test_training_noise_draws_are_unchanged():
    """The checks draw nothing: the recipe of a seeded generator is the one before them."""
    r = [training_noise(torch.Generator().manual_seed(s), p_clean=0.3) for s in range(40)]
    assert sum(x.level == 0 for x in r) > 0 and sum(x.photons is not None for x in r) > 0


def test_fit_dip_seed_beyond_the_generator_range_is_named():
    A = Hadamard(16, sr=0.25)
    y = A(torch.rand(1, 1, 16, 16, generator=torch.Generator().manual_seed(0)))
    with pytest.raises(ValueError, match="fit_dip: expected seed <= "):
        fit_dip(y, A, max_iter=1, seed=2**64)
    with pytest.raises(ValueError, match="^dip: expected seed <= "):
        dip(y, A, max_iter=1, seed=2**64)


# -- 9. dip(noise_sigma="auto") checks every sample before any fit ----------------------------


def test_dip_auto_noise_checks_every_sample_before_fitting(monkeypatch):
    import importlib

    dm = importlib.import_module("torchtof.recon.dip")  # the module (the package exports dip())
    A = Hadamard(16, sr=0.25)
    x = torch.zeros(1, 1, 16, 16)
    x[..., 4:12, 6:10] = 1  # piecewise constant, noise-free: the tail estimate is 0
    y = A(x)
    noisy = y + 0.05 * torch.randn(y.shape, generator=torch.Generator().manual_seed(0))
    fits = []
    monkeypatch.setattr(dm, "fit_dip", lambda *a, **k: fits.append(a) or pytest.fail("fitted"))
    with pytest.raises(ValueError, match=r"dip: noise_sigma='auto' estimated 0 for sample "
                                         r"\(1, 0\)"):
        dip(torch.cat([noisy, y]), A, max_iter=2, noise_sigma="auto")
    assert fits == []


# -- 10. atomic writes, the final checkpoint, torchrun set-up and devices, --sizes --------------


def test_outputs_are_flushed_and_renamed(tmp_path, monkeypatch):
    synced = []
    orig = os.fsync
    monkeypatch.setattr(lt.os, "fsync", lambda fd: synced.append(fd) or orig(fd))
    train_learned(steps=2, out=tmp_path, checkpoint_every=0, **TINY)
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == ["checkpoint.pt", "learned.pt", "log.json", "recipe.json"]  # no .tmp left
    assert len(synced) == 4  # the final checkpoint, log.json, learned.pt, recipe.json


def test_checkpoint_every_0_help_names_the_final_checkpoint(capsys):
    with pytest.raises(SystemExit):
        main(["train", "-h"])
    text = " ".join(capsys.readouterr().out.split())
    assert "0: only the final one" in text and "powers of two in [8, 256]" in text


def test_cli_sizes_below_8_is_refused_by_argparse(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["train", "--sizes", "4", "--out", str(tmp_path / "x")])
    assert exc.value.code == 2
    assert "argument --sizes: expected a power of two in [8, 256], got '4'" in (
        capsys.readouterr().err)


def test_torchrun_setup_error_names_the_caller(monkeypatch):
    for k in ("RANK", "WORLD_SIZE", "MASTER_ADDR", "MASTER_PORT"):
        monkeypatch.delenv(k, raising=False)
    with pytest.raises(ValueError, match="^train_learned: distributed=True needs torchrun"):
        dist_setup(True, "train_learned")
    with pytest.raises(ValueError, match="^train_learned: distributed=True needs torchrun"):
        train_learned(steps=1, distributed=True, **TINY)


def test_rank_device_uses_local_rank_under_torchrun(monkeypatch):
    monkeypatch.delenv("LOCAL_RANK", raising=False)
    assert rank_device("cuda", None) == "cuda"
    monkeypatch.setenv("LOCAL_RANK", "1")
    assert rank_device("cuda", None) == torch.device("cuda", 1)
    assert rank_device(torch.device("cuda"), True) == torch.device("cuda", 1)
    assert rank_device("cuda:0", None) == "cuda:0"  # an explicit index is kept
    assert rank_device("cuda", False) == "cuda"  # not distributed
    assert rank_device("cpu", None) == "cpu"
    assert rank_device("nope", None) == "nope"  # check_device names it


def test_train_unrolled_makes_the_out_folder_before_training(tmp_path):
    from torchtof.recon.train import train_unrolled
    out = tmp_path / "new" / "deeper" / "w.pt"
    train_unrolled(n=16, sr=0.25, n_layers=2, steps=1, batch_size=2, out=out, log_every=0)
    assert out.is_file()
    (tmp_path / "file").write_text("x")
    with pytest.raises(ValueError, match="train_unrolled: out's folder .* is not a directory"):
        train_unrolled(n=16, sr=0.25, n_layers=2, steps=1, batch_size=2,
                       out=tmp_path / "file" / "w.pt", log_every=0)
