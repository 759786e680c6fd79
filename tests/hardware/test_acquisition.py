"""Acquisition on the simulated bench: equality with the pure simulation, fault handling,
resume, the early-stop hook and the store layout."""

from dataclasses import asdict, replace

import numpy as np
import pytest
import torch
import zarr

from torchtof.experiment import ExperimentConfig, PaperExperiment
from torchtof.hardware import acquire, load_buckets, load_run
from torchtof.hardware.errors import (
    DeviceLostError,
    FrameError,
    FrameSequenceError,
    FrameTimeoutError,
    ProtocolError,
)
from torchtof.hardware.simulated import Faults, SimulatedBench
from torchtof.methods import build_method
from torchtof.operators import DMDSplit, Hadamard

N, SR = 8, 0.25  # 16 ±1 patterns = 32 frames of 16x16 px
CLEAN = ExperimentConfig(n=N, roi_px=16, srs=(SR,), shot=None, read_noise_e=0.0)
NOISY = replace(CLEAN, shot="poisson", read_noise_e=12.0)


def run(path, cfg=CLEAN, seed=0, faults=None, mode="quad", **kw):
    bench = SimulatedBench(cfg, seed=seed, faults=Faults(**(faults or {})))
    kw = {"n": cfg.n, "sr": SR, "progress": False, "retries": 3,
          "metadata": {"simulation": {"config": asdict(cfg), "seed": seed}}, **kw}
    return acquire(path, bench.lightcrafter(), bench.camera(mode=mode), **kw), bench


def pure(cfg, seed=0):
    """The pure simulation, one frame per sensor call (as the camera renders them)."""
    fields = {k: v for k, v in asdict(cfg).items() if k not in ("scattering", "gate_m")}
    fields["chunk_frames"] = 1
    return PaperExperiment(sr=SR, scattering=cfg.scattering, gate_m=cfg.gate_m, **fields).run(seed)


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    path = tmp_path_factory.mktemp("ref") / "run.zarr"
    res, _ = run(path)
    return path, res, load_buckets(path)[0]


def test_noise_free_buckets_and_reconstruction_equal_pure_simulation(reference):
    path, res, got = reference
    assert (res.m_acquired, res.m_planned, res.retries, res.stopped_early) == (16, 16, 0, False)
    ref = pure(CLEAN)
    for kind in ("depth", "depth_gated", "intensity", "taps"):
        assert got[kind].shape == ref.buckets[kind].shape
        assert torch.equal(got[kind], ref.buckets[kind]), kind
    data = load_run(path)
    assert torch.equal(data.x, ref.x)
    for name, gate in (("TVAL3", False), ("PINV", True), ("CGI", False)):
        with torch.no_grad():
            a = build_method(name, data, SR, gate)()
            b = build_method(name, ref, SR, gate)()
        assert torch.equal(a, b), name


def test_noisy_same_seed_same_buckets(tmp_path):
    run(tmp_path / "a.zarr", NOISY, seed=5)
    got = load_buckets(tmp_path / "a.zarr")[0]
    ref = pure(NOISY, seed=5)
    for kind in got:
        assert torch.equal(got[kind], ref.buckets[kind]), kind
    other = pure(NOISY, seed=6)
    assert not torch.equal(got["depth"], other.buckets["depth"])


def test_store_layout_and_metadata(reference):
    path, _, _ = reference
    g = zarr.open_group(str(path), mode="r")
    pats = DMDSplit(Hadamard(N, sr=SR)).patterns().numpy()
    np.testing.assert_array_equal(g["patterns"][:], pats)
    assert g["frames_depth"].shape == (32, 16, 16) and g["frames_depth"].chunks == (24, 16, 16)
    assert g["frames_taps"].shape == (32, 4, 16, 16)
    assert g["buckets_taps"].shape == (1, 4, 32) and g["buckets_depth"].chunks == (1, 1, 24)
    assert g["frames_ok"][:].all() and (np.diff(g["frames_id"][:]) == 1).all()
    a = g.attrs
    assert (a["status"], a["m_acquired"], a["n"], a["m"], a["order"]) == (
        "complete", 16, N, 16, "cake_cutting")
    assert a["camera"]["freq_hz"] == 30e6 and a["dmd"]["exposure_us"] == 10_000
    assert {"torch", "numpy", "zarr", "pyusb", "torchtof"} <= set(a["versions"])
    assert a["simulation"]["config"]["n"] == N
    # the recorded depth frame sums to its bucket (Eq. 10)
    assert float(g["frames_depth"][5].sum()) == pytest.approx(float(g["buckets_depth"][0, 0, 5]))


# one transient fault each: the run retries and ends with exactly the fault-free buckets
FAULTS = {
    "frame_timeout": {"frame_timeout": {3}},
    "dropped": {"drop": {5}},
    "dropped_last_of_sequence": {"drop": {23}},
    "duplicated": {"duplicate": {4}},
    "extra_frame": {"extra": {5}},
    "corrupt": {"corrupt": {6}},
    "nack": {"nack": {"PAT_EXPO_PRD": {1}}},
    "no_reply": {"reply_timeout": {"MBOX_DATA": {0}}},
}


@pytest.mark.parametrize("fault", list(FAULTS))
def test_transient_fault_is_retried_to_the_same_buckets(fault, reference, tmp_path):
    res, bench = run(tmp_path / "f.zarr", faults=FAULTS[fault])
    got = load_buckets(tmp_path / "f.zarr")[0]
    for kind, ref in reference[2].items():
        assert torch.equal(got[kind], ref), (fault, kind)
    if fault == "duplicated":
        assert (res.duplicates, res.retries) == (1, 0)
    else:
        assert res.retries == 1
    ids = zarr.open_group(str(tmp_path / "f.zarr"), mode="r")["frames_id"][:]
    assert len(set(ids.tolist())) == 32  # every recorded frame is a distinct camera frame


@pytest.mark.parametrize("faults,error,match,first", [
    # a sequence is recorded only once all its frames arrived: nothing of sequence 0 is kept
    ({"frame_timeout": set(range(3, 99))}, FrameTimeoutError, r"pattern \d+ within", 0),
    ({"corrupt": set(range(3, 99))}, FrameError, r"corrupt frame for pattern \d+: reserved bits",
     0),
    # PAT_START_STOP #0, #1 are the first sequence's stop/start; the second sequence fails
    ({"extra": set(range(99))}, FrameSequenceError,
     "48 frame.s. in the sequence from pattern 0, expected 24", 0),  # one extra per frame
    ({"nack": {"PAT_START_STOP": set(range(2, 99))}}, ProtocolError,
     "PAT_START_STOP: device answered NACK", 24),
])
def test_persistent_fault_gives_a_clear_error(faults, error, match, first, tmp_path):
    with pytest.raises(error, match=match):
        run(tmp_path / "p.zarr", faults=faults, retries=2)
    g = zarr.open_group(str(tmp_path / "p.zarr"), mode="r")
    assert g.attrs["status"] == "interrupted" and g.attrs["retries"] == 3
    ok = g["frames_ok"][:]
    assert ok[:first].all() and not ok[first:].any()  # nothing from the failing pattern on
    assert np.isnan(g["buckets_depth"][0, 0, first:]).all()


def test_device_vanishing_then_resume(reference, tmp_path):
    path = tmp_path / "v.zarr"
    with pytest.raises(DeviceLostError, match="--resume"):
        run(path, faults={"vanish_after_frames": 27})
    g = zarr.open_group(str(path), mode="r")
    # vanished while frame 27 was in flight: the second sequence (24-31) is lost as a whole
    assert g["frames_ok"][:].tolist() == [1] * 24 + [0] * 8
    with pytest.raises(FileExistsError, match="resume=True"):
        run(path)
    res, bench = run(path, resume=True)
    assert bench.camera_usb.rendered == 8  # resumed at the pair boundary 24
    got = load_buckets(path)[0]
    for kind, ref in reference[2].items():
        assert torch.equal(got[kind], ref), kind
    again, bench = run(path, resume=True)  # a complete store: nothing left to do
    assert again.m_acquired == 16 and bench.camera_usb.rendered == 0


def test_resume_refuses_a_different_run(reference, tmp_path):
    path = tmp_path / "r.zarr"
    with pytest.raises(DeviceLostError):
        run(path, faults={"vanish_after_frames": 4})
    with pytest.raises(ValueError, match="recorded with m=16, this run has m=32"):
        run(path, resume=True, sr=0.5)
    with pytest.raises(ValueError, match="order"):
        run(path, resume=True, order="natural")


def test_stop_hook_after_two_blocks(reference, tmp_path):
    calls = []

    def stop(y):
        calls.append({k: v.clone() for k, v in y.items()})
        return len(calls) == 2

    path = tmp_path / "s.zarr"
    res, bench = run(path, block=3, stop=stop)
    assert (res.m_acquired, res.stopped_early) == (6, True)
    assert bench.camera_usb.rendered == 12
    assert [c["depth"].shape for c in calls] == [(1, 1, 3), (1, 1, 6)]
    full = reference[2]
    for key, kind in (("depth", "depth"), ("gated", "depth_gated"), ("intensity", "intensity")):
        y = full[kind].reshape(1, 1, -1, 2)
        signed = y[..., 0] - y[..., 1]
        assert torch.equal(calls[1][key], signed[..., :6]), key
    g = zarr.open_group(str(path), mode="r")
    assert (g.attrs["m_acquired"], g.attrs["stopped_early"]) == (6, True)
    data = load_run(path)
    assert data.hadamard.m == 6 and data.buckets["depth"].shape == (1, 1, 12)
    A, y = data.measurements(data.config.srs[0])
    assert A.m == 6 and torch.equal(y, calls[1]["depth"] / N)


@pytest.mark.parametrize("kw,error,match", [
    ({"block": 0}, ValueError, "block"),
    ({"retries": -1}, ValueError, "retries"),
    ({"stop": 3}, TypeError, "stop"),
])
def test_bad_arguments(kw, error, match, tmp_path):
    with pytest.raises(error, match=match):
        run(tmp_path / "b.zarr", **kw)


def test_load_rejects_foreign_and_empty_stores(tmp_path):
    zarr.open_group(str(tmp_path / "x.zarr"), mode="w")
    with pytest.raises(ValueError, match="not a torchtof acquisition"):
        load_buckets(tmp_path / "x.zarr")
    with pytest.raises(DeviceLostError):
        run(tmp_path / "e.zarr", faults={"vanish_after_frames": 1})
    with pytest.raises(ValueError, match="no complete pattern pair"):
        load_buckets(tmp_path / "e.zarr")


def test_scattering_sheet_run_equals_pure_simulation(tmp_path):
    cfg = replace(CLEAN, scattering=True)
    run(tmp_path / "s.zarr", cfg)
    got, ref = load_buckets(tmp_path / "s.zarr")[0], pure(cfg)
    for kind in got:
        assert torch.equal(got[kind], ref.buckets[kind]), kind


def test_ctrl_c_marks_the_store_interrupted_and_resume_completes_it(reference, tmp_path):
    path = tmp_path / "c.zarr"

    def on_frame(k):
        if k == 6:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run(path, on_frame=on_frame)
    g = zarr.open_group(str(path), mode="r")
    assert g.attrs["status"] == "interrupted" and g["frames_ok"][:].sum() == 7
    res, bench = run(path, resume=True)
    assert bench.camera_usb.rendered == 26  # from pair boundary 6
    for kind, ref in reference[2].items():
        assert torch.equal(load_buckets(path)[0][kind], ref), kind


def test_iq_mode_run_equals_pure_simulation_except_the_taps(reference, tmp_path):
    """Raw I/Q frames (SDK-documented layout) give the depth, gated and intensity buckets
    bit for bit; the four taps are not in the stream, so the tap buckets stay NaN."""
    path = tmp_path / "iq.zarr"
    res, _ = run(path, mode="iq")
    got = load_buckets(path)[0]
    for kind in ("depth", "depth_gated", "intensity"):
        assert torch.equal(got[kind], reference[2][kind]), kind
    assert torch.isnan(got["taps"]).all()
    assert zarr.open_group(str(path), mode="r").attrs["camera"]["mode"] == "iq"


@pytest.mark.parametrize("mode", ["depth", "depth8"])
def test_depth_mode_run_is_the_12_bit_rounding_of_the_pure_simulation(reference, mode,
                                                                        tmp_path):
    res, _ = run(tmp_path / "d.zarr", mode=mode)
    got, ref = load_buckets(tmp_path / "d.zarr")[0], reference[2]
    pixels = 16 * 16
    # amplitude rounded to integers: each frame's intensity bucket within half an ADC unit/px
    assert float((got["intensity"] - ref["intensity"]).abs().max()) <= 0.5 * pixels
    # depth from the 12-bit phase: a pixel may land on the neighbouring 0.25 m step
    assert float((got["depth"] - ref["depth"]).abs().max()) <= 0.25 * pixels
    assert float((got["depth"] - ref["depth"]).abs().mean()) < 0.25
    assert torch.isnan(got["taps"]).all() and res.retries == 0
