"""Reliability of the acquisition from the outside: faults at every position of a short
run (one and two per sequence, both frame-id modes), realistic timing and a slow host,
resume of a store recorded with other settings, damaged stores and bit flips."""

import json
import os
import random
import signal
import subprocess
import sys
import time
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
import pytest
import torch

from torchtof.cli import main
from torchtof.experiment import ExperimentConfig
from torchtof.hardware import acquire, load_buckets
from torchtof.hardware.acquisition import StoreDamagedError
from torchtof.hardware.simulated import Faults, SimulatedBench

zarr = pytest.importorskip("zarr", minversion="3")

REPO = Path(__file__).resolve().parents[2]
# an 8x8 DMD, 8x8 px, SR 12.5 %: 8 patterns = 16 frames in one sequence (block 8)
TINY = ExperimentConfig(n=8, roi_px=8, srs=(0.125,), shot=None, read_noise_e=0.0)
NOISY = replace(TINY, shot="poisson", read_noise_e=12.0)


def run(path, cfg=TINY, seed=0, faults=None, ids="device", **kw):
    bench = SimulatedBench(cfg, seed=seed, faults=Faults(**(faults or {})),
                           frame_number_start=kw.pop("start", 0))
    kw = {"n": cfg.n, "sr": 0.125, "block": 8, "progress": False, "retries": 4,
          "frame_timeout_s": 0.15, "frame_ids": ids,
          "metadata": {"simulation": {"config": asdict(cfg), "seed": seed}}, **kw}
    return acquire(path, bench.lightcrafter(timeout_ms=100), bench.camera(), **kw), bench


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    path = tmp_path_factory.mktemp("clean") / "run.zarr"
    run(path)
    return load_buckets(path)[0]


KINDS = ("drop", "extra", "duplicate", "frame_timeout", "corrupt", "split", "stall")


def _faults(pairs):
    out: dict = {}
    for kind, pos in pairs:
        out.setdefault(kind, set()).add(pos)
    return out


def _check(tmp_path, clean, pairs, ids):
    path = tmp_path / f"{ids}-{'-'.join(f'{k}{p}' for k, p in pairs)}.zarr"
    res, _ = run(path, faults=_faults(pairs), ids=ids)
    got = load_buckets(path)[0]
    wrong = sum(int((~torch.eq(got[k], clean[k])).sum()) for k in clean)
    return wrong, res


# the double faults the default run checks (the full set is the slow test below)
DOUBLES = [(("extra", 6), ("drop", 7)), (("drop", 3), ("extra", 9)), (("extra", 0), ("drop", 15)),
           (("duplicate", 4), ("drop", 5)), (("corrupt", 2), ("extra", 2)),
           (("split", 8), ("drop", 11))]


@pytest.mark.parametrize("ids", ["device", "count"])
@pytest.mark.parametrize("pairs", DOUBLES, ids=lambda p: "+".join(f"{k}{i}" for k, i in p))
def test_double_fault_in_one_sequence_gives_zero_wrong_buckets(pairs, ids, clean, tmp_path):
    wrong, res = _check(tmp_path, clean, pairs, ids)
    assert wrong == 0
    assert res.retries >= 1 or all(k == "duplicate" for k, _ in pairs)


# every single and double fault: benchmarks/fault_sweep.py (the full sweep's JSON is
# committed; the default run checks a seeded sample of it, the slow run all of it)
sys.path.insert(0, str(REPO / "benchmarks"))
import fault_sweep  # noqa: E402

SWEEP_JSON = REPO / "docs" / "reliability" / "fault_sweep.json"


def test_the_sweep_covers_every_single_and_every_unordered_pair_of_faults():
    singles, doubles = fault_sweep.singles(), fault_sweep.doubles()
    assert len(singles) == 7 * 16 == 112 and len(set(singles)) == 112
    assert len(doubles) == 112 * 111 // 2 == 6216
    assert len({frozenset(d) for d in doubles}) == 6216  # unordered, no repeats
    assert all(a != b for a, b in doubles)
    assert (("drop", 3), ("extra", 3)) in doubles  # two kinds at one frame
    assert (("stall", 0), ("stall", 15)) in doubles  # one kind at two frames
    assert set(fault_sweep.KINDS) == set(KINDS)


def test_the_sweep_counts_a_changed_bit_as_a_wrong_bucket(clean, tmp_path):
    """The comparison is bit for bit: one flipped mantissa bit, a NaN for a value, a short
    recording are wrong; NaN bits equal to the reference's are not."""
    ref = {k: v.numpy().copy() for k, v in clean.items()}
    assert fault_sweep.wrong_buckets(ref, ref) == 0
    got = {k: v.copy() for k, v in ref.items()}
    got["depth"].view(np.uint32)[0, 0, 5] ^= 1
    got["taps"][0, 2, 9] = np.nan
    assert fault_sweep.wrong_buckets(got, ref) == 2
    short = {k: v[..., :14] for k, v in ref.items()}
    assert fault_sweep.wrong_buckets(short, ref) == sum(v.size for v in ref.values())
    assert fault_sweep.wrong_buckets(short, ref, prefix=True) == 0
    nan_ref = {k: v.copy() for k, v in ref.items()}
    nan_ref["intensity"][0, 0, 1] = np.nan
    assert fault_sweep.wrong_buckets({k: v.copy() for k, v in nan_ref.items()}, nan_ref) == 0
    # and through a real run: the store of a clean run against a reference off by one bucket
    bad_ref = {k: v.copy() for k, v in ref.items()}
    bad_ref["depth_gated"][0, 0, 3] += 1.0
    out = fault_sweep.check_case((), "device", bad_ref, tmp_path, reuse=None)
    assert out["wrong"] == 1 and out["error"] is None


@pytest.mark.slow  # 4 s; every single and double fault: benchmarks/fault_sweep.py
def test_a_seeded_sample_of_single_and_double_faults_gives_zero_wrong_buckets():
    """6 cases drawn from the full sweep's 6328 (seed 19), in both frame-id modes, through
    the sweep's own code (a fresh bench and store per run, buckets read back)."""
    cases = random.Random(19).sample(fault_sweep.all_cases(), 6)
    out = fault_sweep.sweep(cases, workers=0, progress=False)
    assert out["runs"] == 12 and out["wrong_buckets"] == 0, out["failures"]
    assert out["failed_runs"] == 0 and out["failures"] == []
    assert sum(out["modes"]["count"]["retries"].values()) == 6


def test_the_committed_sweep_ran_every_case_in_both_modes_with_zero_wrong_buckets():
    d = json.loads(SWEEP_JSON.read_text())
    assert d["setup"] == {**fault_sweep.SETUP, "kinds": list(fault_sweep.KINDS),
                          "positions": 16, "frames": 16}
    assert d["runs"] == 2 * (112 + 6216) == 12656
    for ids in ("device", "count"):
        m = d["modes"][ids]
        assert (m["runs"], m["singles"], m["doubles"]) == (6328, 112, 6216), ids
        assert m["wrong_buckets"] == 0 and m["runs_with_wrong_buckets"] == 0, ids
        assert m["failures"] == 0 and sum(m["retries"].values()) == 6328, ids
    assert d["wrong_buckets"] == 0 and d["failed_runs"] == 0 and d["failures"] == []


@pytest.mark.slow
def test_every_single_and_double_fault_gives_zero_wrong_buckets():
    """All 112 single faults and all 6216 pairs in one 16-frame sequence, both frame-id
    modes (12 656 runs, two worker processes): 0 buckets wrong, every run completes."""
    out = fault_sweep.sweep(workers=2, progress=False)
    assert out["runs"] == 12656
    assert out["wrong_buckets"] == 0 and out["failed_runs"] == 0, out["failures"][:10]


def test_a_halted_simulated_camera_read_times_out_without_waiting():
    """Streaming halted (tg_dis = 1), nothing queued: on the instant bench a bulk read's
    timeout passes in simulated time, so a driver's stop() need not wait for it."""
    import usb.core

    from torchtof.hardware import opt8241 as opt

    bench = SimulatedBench(TINY)
    cam = bench.camera_usb
    assert cam.field("tg_dis") == 1
    t0 = time.monotonic()
    with pytest.raises(usb.core.USBTimeoutError):
        cam.read(opt.EP_FRAMES, 1 << 16, timeout=3000)
    assert time.monotonic() - t0 < 1.5  # a 3 s timeout, not waited for
    rt = SimulatedBench(TINY, realtime=True).camera_usb  # the realtime bench waits it out
    t0 = time.monotonic()
    with pytest.raises(usb.core.USBTimeoutError):
        rt.read(opt.EP_FRAMES, 1 << 16, timeout=300)
    assert time.monotonic() - t0 >= 0.29


# -- realistic timing ------------------------------------------------------------------------
def test_realtime_bench_with_the_camera_default_frame_time_is_configured_to_fit(tmp_path):
    """10 ms patterns (internal trigger), realtime simulated devices: acquire programs the
    camera's frame time (33.3 ms at power-up) to fit the period, so no trigger is missed."""
    cfg = replace(TINY, n=8, roi_px=8, srs=(0.5,))
    bench = SimulatedBench(cfg, realtime=True, speed=0.25)  # 10 ms patterns take 40 ms
    cam = bench.camera()
    assert cam.frame_time_us == pytest.approx(100000 * 4 * 4 / 48)  # power-up: 33.3 ms
    res = acquire(tmp_path / "rt.zarr", bench.lightcrafter(timeout_ms=200), cam, n=8, sr=0.5,
                  exposure_us=10_000, trigger="internal", progress=False, block=12)
    assert cam.frame_time_us <= 9_500 and bench.camera_usb.missed_triggers == 0
    assert res.retries == 0 and bench.camera_usb.fifo_dropped == 0
    ref_bench = SimulatedBench(cfg)
    ref = acquire(tmp_path / "ref.zarr", ref_bench.lightcrafter(), ref_bench.camera(), n=8,
                  sr=0.5, progress=False)
    a, b = load_buckets(tmp_path / "rt.zarr")[0], load_buckets(tmp_path / "ref.zarr")[0]
    assert ref.m_acquired == res.m_acquired == 32
    for k in a:
        assert torch.equal(a[k], b[k]), k


def test_slow_host_loses_frames_which_are_detected_and_reacquired(tmp_path):
    """The host stalls 250 ms (6 pattern periods) on each of the first 6 frames of a
    realtime run whose reader queue holds 3 frames: frames are dropped on the host, seen,
    and the sequences re-acquired; the buckets equal an unhurried run's."""
    cfg = replace(TINY, n=8, roi_px=8, srs=(0.25,))
    bench = SimulatedBench(cfg, realtime=True, speed=0.25)  # 10 ms patterns take 40 ms
    cam = bench.camera(queue_frames=3)
    slow = {"left": 6}

    def on_frame(k):
        if slow["left"] > 0:
            slow["left"] -= 1
            time.sleep(0.25)

    res = acquire(tmp_path / "slow.zarr", bench.lightcrafter(timeout_ms=200), cam, n=8,
                  sr=0.25, exposure_us=10_000, trigger="internal", progress=False,
                  on_frame=on_frame, frame_timeout_s=1.0, retries=6)
    assert cam.stats["host_dropped"] + bench.camera_usb.fifo_dropped > 0 and res.retries >= 1
    ref_bench = SimulatedBench(cfg)
    acquire(tmp_path / "ref.zarr", ref_bench.lightcrafter(), ref_bench.camera(), n=8, sr=0.25,
            progress=False)
    a, b = load_buckets(tmp_path / "slow.zarr")[0], load_buckets(tmp_path / "ref.zarr")[0]
    for k in a:
        assert torch.equal(a[k], b[k]), k


@pytest.mark.slow
def test_two_by_512_patterns_at_10_ms_with_0_lost_or_mislabelled(tmp_path):
    """n = 32, SR 0.5: 512 ±1 patterns = 1024 frames at 10 ms (internal trigger) on the
    realtime bench (frames rendered in the camera's thread); every recorded frame has the id
    that follows its predecessor's, and the buckets equal the instant bench's."""
    cfg = ExperimentConfig(n=32, roi_px=32, srs=(0.5,), shot=None, read_noise_e=0.0)
    bench = SimulatedBench(cfg, realtime=True, speed=0.5)  # frames are 20 ms of wall time
    res = acquire(tmp_path / "big.zarr", bench.lightcrafter(timeout_ms=500), bench.camera(),
                  n=32, sr=0.5, exposure_us=10_000, trigger="internal", progress=False)
    g = zarr.open_group(str(tmp_path / "big.zarr"), mode="r")
    ids = g["frames_id"][:]
    assert res.m_acquired == 512 and g["frames_ok"][:].all()
    for s0 in range(0, 1024, 24):  # consecutive ids within every recorded sequence
        d = np.diff(ids[s0:s0 + 24]) % 256
        assert (d == 1).all(), s0
    ref_bench = SimulatedBench(cfg)
    acquire(tmp_path / "ref.zarr", ref_bench.lightcrafter(), ref_bench.camera(), n=32, sr=0.5,
            progress=False)
    a, b = load_buckets(tmp_path / "big.zarr")[0], load_buckets(tmp_path / "ref.zarr")[0]
    for k in a:
        assert torch.equal(a[k], b[k]), k


# -- resume and damaged stores ---------------------------------------------------------------
@pytest.mark.parametrize("change,field", [
    ({"cfg": replace(TINY, scene="motorcycle")}, "simulation.config.scene"),
    ({"seed": 3}, "simulation.seed"),
    ({"cfg": NOISY}, "simulation.config.read_noise_e"),
    ({"ids": "count"}, "frame_ids"),
    ({"gate_m": 2.5}, "gate_m"),
    ({"exposure_us": 8_000}, "dmd.exposure_us"),
])
def test_resume_refuses_a_store_recorded_with_other_settings(change, field, tmp_path):
    path = tmp_path / "r.zarr"
    with pytest.raises(Exception):  # noqa: B017 - any stop; the store keeps sequence 0
        run(path, faults={"vanish_after_frames": 3})
    kw = dict(change)
    with pytest.raises(ValueError, match=f"cannot resume .*recorded with {field}="):
        run(path, resume=True, **kw)


def _one_chunk(path, array):
    files = sorted(p for p in (path / array).rglob("*") if p.is_file() and p.name != "zarr.json")
    assert files, array
    return files[0]


def test_every_single_bit_flip_in_a_recorded_chunk_is_detected(tmp_path):
    path = tmp_path / "b.zarr"
    run(path)
    chunk = _one_chunk(path, "buckets_depth")
    good = chunk.read_bytes()
    for bit in range(8 * len(good)):
        bad = bytearray(good)
        bad[bit // 8] ^= 1 << (bit % 8)
        chunk.write_bytes(bytes(bad))
        with pytest.raises(ValueError):  # the chunk's CRC-32C (or its framing) fails
            zarr.open_group(str(path), mode="r")["buckets_depth"][:]
    chunk.write_bytes(good)
    assert load_buckets(path)[0]["depth"].shape == (1, 1, 16)
    # through the public entries: a damaged store, named, never data
    bad = bytearray(good)
    bad[len(bad) // 2] ^= 0x10
    chunk.write_bytes(bytes(bad))
    with pytest.raises(StoreDamagedError, match=f"damaged store {path}.*buckets_depth"):
        load_buckets(path)
    with pytest.raises(StoreDamagedError, match="buckets_depth"):
        run(path, resume=True)


@pytest.mark.parametrize("damage", ["delete_bucket_chunk", "truncate_chunk", "garbage_json",
                                    "bad_frames_ok", "delete_frames_ok_chunk",
                                    "m_acquired_changed"])
def test_damaged_store_is_reported_with_its_path(damage, tmp_path, capsys):
    path = tmp_path / "d.zarr"
    args = ["acquire", "--simulated", "--n", "8", "--roi-px", "8", "--sr", "0.125",
            "--noise-free", "--no-progress", "-o", str(path)]
    assert main(args) == 0
    if damage == "delete_bucket_chunk":
        _one_chunk(path, "buckets_gated").unlink()
    elif damage == "truncate_chunk":
        c = _one_chunk(path, "frames_depth")
        c.write_bytes(c.read_bytes()[:-7])
    elif damage == "garbage_json":
        (path / "zarr.json").write_text("{not json")
    elif damage == "delete_frames_ok_chunk":  # reads back as 0: "unrecorded", data NaN
        _one_chunk(path, "frames_ok").unlink()
    elif damage == "m_acquired_changed":  # the attributes carry no checksum of their own
        g = zarr.open_group(str(path), mode="a")
        g.attrs["m_acquired"] = int(g.attrs["m_acquired"]) - 1
    else:
        g = zarr.open_group(str(path), mode="a")
        g["frames_ok"][3] = 7
    capsys.readouterr()
    assert main([*args, "--resume"]) == 2
    err = capsys.readouterr().err
    assert f"damaged store {path}" in err and "Traceback" not in err
    assert main(["reconstruct", str(path), "--method", "cgi", "--out", str(tmp_path / "o")]) == 2
    assert f"damaged store {path}" in capsys.readouterr().err


def test_resumed_noisy_run_reproduces_the_uninterrupted_one(tmp_path):
    """Noise is drawn per pattern: a run stopped after its first sequence and resumed has
    the uninterrupted run's buckets bit for bit (also after retries that re-render)."""
    cfg = replace(NOISY, n=8, roi_px=8, srs=(0.25,))
    full = tmp_path / "full.zarr"
    run(full, cfg=cfg, seed=4, sr=0.25, block=12)
    part = tmp_path / "part.zarr"
    with pytest.raises(Exception):  # noqa: B017 - the device vanishes in the 2nd sequence
        run(part, cfg=cfg, seed=4, sr=0.25, block=12,
            faults={"vanish_after_frames": 27, "drop": {3}})
    run(part, cfg=cfg, seed=4, sr=0.25, block=12, resume=True)
    a, b = load_buckets(full)[0], load_buckets(part)[0]
    for k in a:
        assert torch.equal(a[k], b[k]), k


def _env():
    return {**os.environ, "PYTHONPATH": str(REPO)}


@pytest.mark.slow
def test_kill_9_at_random_times_then_resume_is_bit_identical(tmp_path):
    """A noisy CLI acquisition SIGKILLed at 10 random times (each attempt resumes the last),
    then resumed to the end: every array equals the uninterrupted run's."""
    args = ["acquire", "--simulated", "--scene", "sky", "--sr", "0.5", "--n", "8",
            "--roi-px", "16", "--no-progress", "--seed", "7"]
    full = tmp_path / "full.zarr"
    assert main([*args, "-o", str(full)]) == 0
    path = tmp_path / "killed.zarr"
    rng = np.random.default_rng(11)
    kills = attempts = 0
    while kills < 10 and attempts < 30:
        attempts += 1
        extra = ["--resume"] if (path / "zarr.json").exists() else []
        proc = subprocess.Popen([sys.executable, "-m", "torchtof.cli", *args, "-o", str(path),
                                 *extra], env=_env(), cwd=tmp_path, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL)
        time.sleep(float(rng.uniform(0.8, 3.0)))
        if proc.poll() is None:
            os.kill(proc.pid, signal.SIGKILL)
            kills += 1
        proc.wait(timeout=60)
    assert kills == 10
    assert main([*args, "-o", str(path), "--resume"]) == 0
    a, b = zarr.open_group(str(path), mode="r"), zarr.open_group(str(full), mode="r")
    for name in ("buckets_depth", "buckets_gated", "buckets_intensity", "buckets_taps",
                 "frames_depth", "frames_amplitude", "frames_phase", "frames_taps", "frames_ok"):
        np.testing.assert_array_equal(a[name][:], b[name][:], err_msg=name)


# -- bad inputs to the bench, a full disk, control-transfer failures --------------------------
@pytest.mark.parametrize("kw,error,match", [
    ({"config": replace(TINY, chunk_frames=0)}, ValueError, "chunk_frames"),
    ({"config": replace(TINY, chunk_frames=-1)}, ValueError, "chunk_frames"),
    ({"config": replace(TINY, gain_e_per_dn=0.0)}, ValueError, "gain_e_per_dn"),
    ({"seed": 1.5}, TypeError, "seed"),
    ({"speed": 0.0}, ValueError, "speed"),
    ({"fifo_frames": 0}, ValueError, "fifo_frames"),
])
def test_bench_refuses_bad_settings_naming_them(kw, error, match):
    kw = {"config": TINY, **kw}
    with pytest.raises(error, match=match):
        SimulatedBench(**kw)


def test_full_disk_marks_the_store_interrupted(tmp_path, monkeypatch):
    import errno

    import zarr.core.array as za

    calls = {"n": 0}
    real = za.Array.__setitem__

    def full(self, key, value):
        if self.path == "frames_depth":
            calls["n"] += 1
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(self, key, value)

    monkeypatch.setattr(za.Array, "__setitem__", full)
    with pytest.raises(OSError, match="No space left"):
        run(tmp_path / "full.zarr")
    monkeypatch.undo()
    g = zarr.open_group(str(tmp_path / "full.zarr"), mode="r")
    assert calls["n"] == 1 and g.attrs["status"] == "interrupted"
    assert not g["frames_ok"][:].any()  # nothing marked recorded
    res, _ = run(tmp_path / "full.zarr", resume=True)  # space again: resume completes it
    assert res.m_acquired == 8


def test_a_stalled_control_transfer_is_repeated(clean, tmp_path):
    """Two stalled control transfers (EPIPE) while configuring: each register access is
    repeated (reads and writes are idempotent) and the run is the clean one."""
    run(tmp_path / "c.zarr", faults={"ctrl_fail": {3, 10}})
    got = load_buckets(tmp_path / "c.zarr")[0]
    for k in clean:
        assert torch.equal(got[k], clean[k]), k


# a CLI acquisition that hangs inside its n-th chunk write: half the chunk's bytes are in
# zarr's temporary file when the test kills it (zarr >= 3.1.6 renames the file over the chunk
# only when it is complete)
_HANG_IN_WRITE = """
import os, sys, time
import zarr.storage._local as L
orig, count = L._put, [0]
def put(path, value, exclusive=False):
    if "/c/" in str(path).replace(os.sep, "/"):
        count[0] += 1
        if count[0] == int(os.environ["HANG_AT_WRITE"]):
            path.parent.mkdir(parents=True, exist_ok=True)
            with L._atomic_write(path, "wb", exclusive=exclusive) as f:
                data = value.to_bytes()
                f.write(data[: len(data) // 2])
                f.flush()
                open(os.environ["HANG_FLAG"], "w").close()
                time.sleep(120)
    return orig(path, value, exclusive)
L._put = put
from torchtof.cli import main
sys.exit(main(sys.argv[1:]))
"""

KILL_ARGS = ["acquire", "--simulated", "--scene", "sky", "--sr", "0.25", "--n", "8",
             "--roi-px", "16", "--no-progress", "--seed", "3"]


def _kill_inside_write(tmp_path, path, write):
    flag = tmp_path / f"hang{write}"
    extra = ["--resume"] if (path / "zarr.json").exists() else []
    proc = subprocess.Popen([sys.executable, "-c", _HANG_IN_WRITE, *KILL_ARGS, "-o", str(path),
                             *extra], cwd=tmp_path, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL,
                            env={**_env(), "HANG_AT_WRITE": str(write), "HANG_FLAG": str(flag)})
    try:
        t0 = time.monotonic()
        while not flag.exists():
            if proc.poll() is not None:  # finished before that many writes
                return False
            assert time.monotonic() - t0 < 120
            time.sleep(0.05)
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait(timeout=60)
    assert list(path.rglob("*.partial"))  # killed with a half-written temporary chunk file
    return True


def _same_as(path, full):
    a, b = zarr.open_group(str(path), mode="r"), zarr.open_group(str(full), mode="r")
    assert a.attrs["status"] == "complete"
    for name in ("buckets_depth", "buckets_gated", "buckets_intensity", "buckets_taps",
                 "frames_depth", "frames_amplitude", "frames_phase", "frames_taps", "frames_ok"):
        np.testing.assert_array_equal(a[name][:], b[name][:], err_msg=name)


@pytest.fixture(scope="module")
def noisy_full(tmp_path_factory):
    full = tmp_path_factory.mktemp("full") / "full.zarr"
    assert main([*KILL_ARGS, "-o", str(full)]) == 0
    return full


def test_kill_inside_a_chunk_write_then_resume_is_bit_identical(noisy_full, tmp_path):
    path = tmp_path / "k.zarr"
    # chunk writes: 1 the patterns, 2-12 the first sequence's arrays (frames_ok last), 13-23
    # the second's: killed while writing the second sequence's frames_taps chunk
    assert _kill_inside_write(tmp_path, path, 16)
    assert main([*KILL_ARGS, "-o", str(path), "--resume"]) == 0
    _same_as(path, noisy_full)


@pytest.mark.slow
def test_ten_kills_inside_chunk_writes_then_resume_is_bit_identical(noisy_full, tmp_path):
    """Killed inside 10 different chunk writes — each of the first sequence's 11 arrays but
    one, frames_ok (the commit) included, each run resuming the last — then resumed to the
    end: bit-identical to the uninterrupted run."""
    path = tmp_path / "k10.zarr"
    # a fresh run writes the patterns first (write 1); a resumed one starts at the sequence
    kills = sum(_kill_inside_write(tmp_path, path, w) for w in (2, 3, 4, 5, 6, 7, 8, 9, 10, 11))
    assert kills == 10
    assert main([*KILL_ARGS, "-o", str(path), "--resume"]) == 0
    _same_as(path, noisy_full)


def test_run_interrupted_while_its_stop_rule_decides_resumes_to_the_same_store(tmp_path):
    """The rule is asked again at every recorded block end on resume: a run stopped (Ctrl-C)
    inside stop() at the block where the uninterrupted run stopped ends there too, bit for
    bit (it recorded 4 more pairs before)."""
    cfg = replace(TINY, srs=(0.5,))
    kw = dict(cfg=cfg, sr=0.5, block=4)
    rule = lambda y: y["gated"].shape[-1] >= 8  # noqa: E731 - stop once 8 pairs are in
    ref, _ = run(tmp_path / "u.zarr", stop=rule, **kw)

    def ctrl_c(y):
        if y["gated"].shape[-1] >= 8:
            raise KeyboardInterrupt
        return False

    with pytest.raises(KeyboardInterrupt):
        run(tmp_path / "i.zarr", stop=ctrl_c, **kw)
    got, _ = run(tmp_path / "i.zarr", stop=rule, resume=True, **kw)
    assert (got.m_acquired, got.stopped_early) == (ref.m_acquired, ref.stopped_early) == (8, True)
    assert (ref.resumed_from, got.resumed_from) == (0, 8)  # pattern pairs held at the start
    again, _ = run(tmp_path / "i.zarr", stop=rule, resume=True, **kw)  # already complete
    assert (again.m_acquired, again.resumed_from) == (8, 8)
    a, b = load_buckets(tmp_path / "u.zarr")[0], load_buckets(tmp_path / "i.zarr")[0]
    assert all(torch.equal(a[k], b[k]) for k in a)


def test_a_failing_stop_rule_leaves_the_devices_idle_and_the_store_resumable(tmp_path):
    def broken(y):
        raise ValueError("my rule failed")

    path = tmp_path / "f.zarr"
    bench = SimulatedBench(TINY, seed=0)
    with pytest.raises(ValueError, match="my rule failed"):
        acquire(path, bench.lightcrafter(), bench.camera(), n=TINY.n, sr=0.125, block=4,
                progress=False, stop=broken)
    assert bench.camera_usb.field("tg_dis") == 1  # the camera stopped streaming
    assert zarr.open_group(str(path), mode="r").attrs["status"] == "interrupted"


@pytest.mark.parametrize("kw, err, msg", [
    (dict(metadata={"order": "natural"}), ValueError,
     r"metadata may not replace the store's own attributes \['order'\]"),
    (dict(metadata={"n": 99, "gate_m": 1.0}), ValueError, r"\['gate_m', 'n'\]"),
    (dict(gate_m="3"), ValueError, "expected gate_m a positive finite number"),
    (dict(gate_m=float("nan")), ValueError, "expected gate_m"),
    (dict(on_frame=5), TypeError, "expected on_frame to be callable"),
    (dict(check_timing="no"), TypeError, "expected check_timing a bool"),
    (dict(frame_timeout_s=float("inf")), ValueError, "positive finite frame_timeout_s"),
])
def test_acquire_checks_its_arguments_before_the_store_exists(kw, err, msg, tmp_path):
    # metadata={'order': 'natural'} made the store describe natural rows over cake-cutting
    # patterns (reconstructed with the wrong operator, exit 0); the others were refused
    # only after the store existed and the camera streamed, or taken as truthy
    bench = SimulatedBench(TINY, seed=0)
    path = tmp_path / "a.zarr"
    with pytest.raises(err, match=msg):
        acquire(path, bench.lightcrafter(), bench.camera(), n=TINY.n, sr=0.125,
                progress=False, **kw)
    assert not path.exists()
