"""Acquisition on the simulated bench: equality with the pure simulation, fault handling,
resume, the early-stop hook and the store layout."""

from dataclasses import asdict, replace

import numpy as np
import pytest
import torch

from torchtof.bucket import depth_bucket, intensity_bucket, tap_buckets
from torchtof.experiment import ExperimentConfig, PaperExperiment, simulate_frames
from torchtof.hardware import acquire, load_buckets, load_run
from torchtof.hardware.errors import (
    DeviceLostError,
    FrameError,
    FrameTimeoutError,
    FrameTimingError,
    HardwareError,
    ProtocolError,
)
from torchtof.hardware.opt8241 import QUAD_OFFSET
from torchtof.hardware.simulated import Faults, SimulatedBench
from torchtof.methods import build_method
from torchtof.operators import DMDSplit, Hadamard

# the recorder needs zarr >= 3 (Python >= 3.11; torchtof.hardware.require_zarr3)
zarr = pytest.importorskip("zarr", minversion="3")

N, SR = 8, 0.25  # 16 ±1 patterns = 32 frames of 16x16 px
CLEAN = ExperimentConfig(n=N, roi_px=16, srs=(SR,), shot=None, read_noise_e=0.0)
NOISY = replace(CLEAN, shot="poisson", read_noise_e=12.0)


def run(path, cfg=CLEAN, seed=0, faults=None, mode="quad", start=0, **kw):
    bench = SimulatedBench(cfg, seed=seed, faults=Faults(**(faults or {})),
                           frame_number_start=start)
    kw = {"n": cfg.n, "sr": SR, "progress": False, "retries": 3, "frame_timeout_s": 0.15,
          "metadata": {"simulation": {"config": asdict(cfg), "seed": seed}}, **kw}
    return acquire(path, bench.lightcrafter(timeout_ms=100), bench.camera(mode=mode), **kw), bench


def pure(cfg, seed=0):
    """The pure simulation, one frame per sensor call (as the camera renders them); the
    tap buckets as the signed quad samples give them (each model tap - QUAD_OFFSET)."""
    fields = {k: v for k, v in asdict(cfg).items() if k not in ("scattering", "gate_m")}
    fields["chunk_frames"] = 1
    data = PaperExperiment(sr=SR, scattering=cfg.scattering, gate_m=cfg.gate_m,
                           **fields).run(seed)
    data.buckets["taps"] = data.buckets["taps"] - QUAD_OFFSET * cfg.roi_px ** 2
    return data


def pure_noisy(cfg, seed):
    """Reference buckets of a noisy run: each frame simulated with the generator of its
    pattern (SimulatedBench.noise_generator), summed over the whole sensor ROI."""
    bench = SimulatedBench(cfg, seed=seed)
    pats = DMDSplit(Hadamard(cfg.n, sr=SR)).patterns(torch.float32).to(torch.uint8).numpy()
    out = {"depth": [], "depth_gated": [], "intensity": [], "taps": []}
    for p in pats:
        fr = simulate_frames(bench.scene, torch.from_numpy(p.astype(np.float32))[None], cfg,
                             bench.noise_generator(p), bench.dust, bench.stray)
        out["depth"].append(depth_bucket(fr.depth[:, 0][None]))
        out["depth_gated"].append(depth_bucket(fr.depth[:, 0][None], gate_m=cfg.gate_m))
        out["intensity"].append(intensity_bucket(fr.amplitude[:, 0][None]))
        out["taps"].append(tap_buckets(fr.taps[None]) - QUAD_OFFSET * cfg.roi_px ** 2)
    return {k: torch.cat(v, -1) for k, v in out.items()}


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
    ref = pure_noisy(NOISY, seed=5)
    for kind in got:
        assert torch.equal(got[kind], ref[kind]), kind
    other = pure_noisy(NOISY, seed=6)
    assert not torch.equal(got["depth"], other["depth"])


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
    "split_transfer": {"split": {7}},
    "endpoint_stall": {"stall": {9}},
    "nack": {"nack": {"PAT_EXPO_PRD": {1}}},
    "no_reply": {"reply_timeout": {"MBOX_DATA": {0}}},
    "late_reply": {"late_reply": {"PAT_CONFIG": {1}}},  # re-sent; the stale reply discarded
}


@pytest.mark.parametrize("fault", list(FAULTS))
def test_transient_fault_is_retried_to_the_same_buckets(fault, reference, tmp_path):
    res, bench = run(tmp_path / "f.zarr", faults=FAULTS[fault])
    got = load_buckets(tmp_path / "f.zarr")[0]
    for kind, ref in reference[2].items():
        assert torch.equal(got[kind], ref), (fault, kind)
    if fault == "duplicated":
        assert (res.duplicates, res.retries) == (1, 0)
    elif fault == "late_reply":
        assert res.retries == 0 and bench.lightcrafter_usb.counts["PAT_CONFIG"] == 3
    else:
        assert res.retries == 1
    ids = zarr.open_group(str(tmp_path / "f.zarr"), mode="r")["frames_id"][:]
    assert len(set(ids.tolist())) == 32  # every recorded frame is a distinct camera frame


@pytest.mark.parametrize("ids,faults,error,match,first", [
    # a sequence is recorded only once all its checks passed: the first (0-23) fails
    ("device", {"frame_timeout": set(range(3, 99))}, FrameTimeoutError, r"pattern \d+ within",
     0),
    ("device", {"corrupt": set(range(3, 99))}, FrameError,
     r"corrupt frame for pattern \d+: \d+ bytes", 0),
    # the camera's spurious frame takes the next number: its arrival time gives it away
    ("device", {"extra": set(range(99))}, FrameTimingError, r"pattern 1 arrived", 0),
    # PAT_START_STOP #0, #1: the first sequence's stop/start; the second sequence fails
    ("device", {"nack": {"PAT_START_STOP": set(range(2, 99))}}, ProtocolError,
     "PAT_START_STOP: device answered NACK", 24),
    ("count", {"frame_timeout": set(range(3, 99))}, FrameTimeoutError, r"pattern \d+ within",
     0),
    ("count", {"extra": set(range(99))}, FrameTimingError, r"pattern 1 arrived", 0),
    ("count", {"nack": {"PAT_START_STOP": set(range(2, 99))}}, ProtocolError,
     "PAT_START_STOP: device answered NACK", 24),
])
def test_persistent_fault_gives_a_clear_error(ids, faults, error, match, first, tmp_path):
    with pytest.raises(error, match=match):
        run(tmp_path / "p.zarr", faults=faults, retries=2, frame_ids=ids)
    g = zarr.open_group(str(tmp_path / "p.zarr"), mode="r")
    assert g.attrs["status"] == "interrupted" and g.attrs["retries"] == 3
    ok = g["frames_ok"][:]
    assert ok[:first].all() and not ok[first:].any()
    assert np.isnan(g["buckets_depth"][0, 0, first:]).all()


@pytest.mark.parametrize("ids", ["device", "count"])
def test_device_vanishing_then_resume(ids, reference, tmp_path):
    path = tmp_path / "v.zarr"
    with pytest.raises(DeviceLostError, match="--resume"):
        run(path, faults={"vanish_after_frames": 27}, frame_ids=ids)
    g = zarr.open_group(str(path), mode="r")
    # vanished while frame 27 was in flight: the sequence 24-31 is lost as a whole
    assert g["frames_ok"][:].tolist() == [1] * 24 + [0] * 8
    with pytest.raises(FileExistsError, match="resume=True"):
        run(path, frame_ids=ids)
    res, bench = run(path, resume=True, frame_ids=ids)
    assert bench.camera_usb.rendered == 8
    got = load_buckets(path)[0]
    for kind, ref in reference[2].items():
        assert torch.equal(got[kind], ref), kind
    again, bench = run(path, resume=True, frame_ids=ids)  # complete: nothing left to do
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
        assert torch.equal(calls[1][f"{key}_sum"], (y[..., 0] + y[..., 1])[..., :6]), key
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


def test_uninitialised_camera_is_refused_before_any_write_or_store(tmp_path):
    # TI's board initialisation (TintinCDKCamera::_init) writes tillum_slv_addr = 0x72; on a
    # board it never set up, nothing may be programmed and no store left behind
    bench = SimulatedBench(CLEAN, sdk_initialised=False)
    cam = bench.camera()
    before = list(cam.dev.writes)
    with pytest.raises(HardwareError, match="tillum_slv_addr reads 0x71"):
        acquire(tmp_path / "u.zarr", bench.lightcrafter(timeout_ms=100), cam, n=N, sr=SR,
                progress=False)
    assert cam.dev.writes == before
    assert not (tmp_path / "u.zarr").exists()


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
    # the first sequence (0-23) was interrupted before its checks: nothing recorded
    assert g.attrs["status"] == "interrupted" and g["frames_ok"][:].sum() == 0
    res, bench = run(path, resume=True)
    assert bench.camera_usb.rendered == 32
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


# -- device frame ids (OPT9221 debug_frame_number_en) ------------------------------------------
def test_device_ids_enable_the_counter_and_wrap_at_256(reference, tmp_path):
    """The counter starts at 250: ids 250..255, 0..25 across the run, buckets unchanged."""
    path = tmp_path / "w.zarr"
    res, bench = run(path, start=250)
    assert bench.camera_usb.field("debug_frame_number_en") == 1
    g = zarr.open_group(str(path), mode="r")
    np.testing.assert_array_equal(g["frames_id"][:], (250 + np.arange(32)) % 256)
    assert g.attrs["frame_ids"] == "device" and g.attrs["roi"] == [1, 0, 16, 16]
    for kind, ref in reference[2].items():
        assert torch.equal(load_buckets(path)[0][kind], ref), kind
    assert res.retries == 0


def test_gap_across_the_wrap_is_a_lost_frame(reference, tmp_path):
    """Frame 6 (id 255) dropped: id 0 follows id 254 — a gap, not a wrap."""
    res, bench = run(tmp_path / "g.zarr", start=250, faults={"drop": {5}})
    assert res.retries == 1
    for kind, ref in reference[2].items():
        assert torch.equal(load_buckets(tmp_path / "g.zarr")[0][kind], ref), kind


@pytest.mark.parametrize("ids", ["device", "count"])
def test_lost_frame_discards_and_reacquires_the_whole_sequence(ids, reference, tmp_path):
    """Frame 5 dropped: the gap shows on the next frame (device: id 6 for pattern 5; count:
    its arrival time), nothing of the sequence is recorded, and it is shown again."""
    seen = []
    res, bench = run(tmp_path / "d.zarr", faults={"drop": {5}}, on_frame=seen.append,
                     frame_ids=ids)
    assert seen == [0, 1, 2, 3, 4, *range(32)] and res.retries == 1
    assert bench.camera_usb.rendered == 24 + 32  # sequence 0-23 shown twice
    got = load_buckets(tmp_path / "d.zarr")[0]
    for kind, ref in reference[2].items():
        assert torch.equal(got[kind], ref), kind


def test_spurious_then_lost_frame_in_one_sequence_is_never_recorded(reference, tmp_path):
    """A spurious frame after frame 6 and frame 7 lost: the ids stay consecutive (the
    spurious frame takes 7's number), but the whole sequence is re-acquired, not patched."""
    for ids in ("device", "count"):
        res, _ = run(tmp_path / f"{ids}.zarr", faults={"extra": {6}, "drop": {7}},
                     frame_ids=ids)
        assert res.retries == 1
        got = load_buckets(tmp_path / f"{ids}.zarr")[0]
        for kind, ref in reference[2].items():
            assert torch.equal(got[kind], ref), (ids, kind)


def test_duplicate_is_dropped_and_a_repeated_id_on_other_bytes_retried(reference, tmp_path):
    res, _ = run(tmp_path / "a.zarr", faults={"duplicate": {4, 23, 31}})
    assert (res.duplicates, res.retries) == (3, 0)  # also after a sequence's last frame

    bench = SimulatedBench(CLEAN, faults=Faults(duplicate={7}))
    fifo = bench.camera_usb._fifo

    class Fifo(type(fifo)):
        def append(self, item):  # the duplicate of frame 7 arrives with other pixel bytes
            if item[0] == 7 and any(o == 7 for o, _, _ in self):
                b = bytearray(item[1])
                b[40] ^= 0x01
                item = (7, bytes(b), item[2])
            super().append(item)

    bench.camera_usb._fifo = Fifo()
    res = acquire(tmp_path / "b.zarr", bench.lightcrafter(), bench.camera(), n=N, sr=SR,
                  progress=False, frame_timeout_s=0.15)
    assert (res.duplicates, res.retries) == (0, 1)
    for kind, ref in reference[2].items():
        assert torch.equal(load_buckets(tmp_path / "b.zarr")[0][kind], ref), kind


def test_count_mode_run_equals_pure_simulation(reference, tmp_path):
    res, bench = run(tmp_path / "c.zarr", frame_ids="count")
    assert bench.camera_usb.field("debug_frame_number_en") == 0
    g = zarr.open_group(str(tmp_path / "c.zarr"), mode="r")
    np.testing.assert_array_equal(g["frames_id"][:], np.arange(32))  # host numbering
    for kind, ref in reference[2].items():
        assert torch.equal(load_buckets(tmp_path / "c.zarr")[0][kind], ref), kind


@pytest.mark.parametrize("kw,error,match", [
    ({"frame_ids": "host"}, ValueError, "frame_ids"),
    ({"roi": (0, 0, 16, 16)}, ValueError, r"contains pixel \(0, 0\)"),
    ({"roi": (1, 0, 17, 16)}, ValueError, "does not fit the 16x17 px frame"),
    ({"roi": "top"}, TypeError, "roi"),
])
def test_bad_frame_id_mode_and_roi(kw, error, match, tmp_path):
    with pytest.raises(error, match=match):
        run(tmp_path / "b.zarr", **kw)


def test_roi_at_pixel_zero_is_allowed_in_count_mode(tmp_path):
    run(tmp_path / "z.zarr", frame_ids="count", roi=(0, 0, 17, 16))
    g = zarr.open_group(str(tmp_path / "z.zarr"), mode="r")
    assert g["frames_depth"].shape == (32, 17, 16)
    assert (g["frames_depth"][:, 0] == 5.0).all()  # the dark guard row: no photons -> 5 m
