"""``torchtof acquire`` / ``torchtof reconstruct``, a killed acquisition resumed, lazy imports,
and device discovery without any USB device."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from torchtof.cli import main
from torchtof.experiment import PaperExperiment
from torchtof.hardware import dlpc350, opt8241
from torchtof.hardware.errors import DeviceBusyError, DeviceNotFoundError
from torchtof.methods import build_method

# the recorder needs zarr >= 3 (Python >= 3.11; torchtof.hardware.require_zarr3)
zarr = pytest.importorskip("zarr", minversion="3")

REPO = Path(__file__).resolve().parents[2]
ARGS = ["acquire", "--simulated", "--scene", "sky", "--sr", "0.25", "--n", "8", "--roi-px", "16",
        "--noise-free", "--no-progress"]
ARRAYS = ("buckets_depth", "buckets_gated", "buckets_intensity", "buckets_taps", "frames_depth",
          "frames_amplitude", "frames_phase", "frames_taps", "frames_ok")  # not frames_id: a
# resumed run talks to a re-opened camera whose frame counter restarted


def _env():
    return {**os.environ, "PYTHONPATH": str(REPO)}


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    path = tmp_path_factory.mktemp("cli") / "run.zarr"
    assert main([*ARGS, "-o", str(path)]) == 0
    return path


def test_uninitialised_camera_is_refused_before_the_region_is_written(monkeypatch, tmp_path,
                                                                     capsys):
    # --camera-roi writes the region registers first (OPT8241.set_roi): the board check
    # (tillum_slv_addr, written 0x72 by TintinCDKCamera::_init) must come before it
    from torchtof.hardware import simulated

    cams = []

    class Uninitialised(simulated.SimulatedBench):
        def __init__(self, *a, **kw):
            super().__init__(*a, sdk_initialised=False, **kw)

        def camera(self, **kw):
            cams.append(super().camera(**kw))
            return cams[-1]

    monkeypatch.setattr(simulated, "SimulatedBench", Uninitialised)
    path = tmp_path / "u.zarr"
    assert main([*ARGS, "--camera-roi", "0", "0", "16", "16", "-o", str(path)]) != 0
    assert "tillum_slv_addr reads 0x71" in capsys.readouterr().err
    assert len(cams) == 1 and cams[0].dev.writes == [] and not path.exists()


def test_reconstruct_says_when_a_store_is_incomplete(uninterrupted, tmp_path, capsys):
    import shutil

    assert main(["reconstruct", str(uninterrupted), "--method", "pinv", "--out",
                 str(tmp_path / "a")]) == 0
    assert "incomplete" not in capsys.readouterr().err  # a finished run: no note
    part = tmp_path / "part.zarr"
    shutil.copytree(uninterrupted, part)
    g = zarr.open_group(str(part), mode="r+")
    g.attrs["status"] = "interrupted"  # as after Ctrl-C: the first 8 pattern pairs verified
    ok = g["frames_ok"][:]
    ok[16:] = False
    g["frames_ok"][:] = ok
    assert main(["reconstruct", str(part), "--method", "pinv", "--out", str(tmp_path / "b")]) == 0
    cap = capsys.readouterr()
    assert "PINV from 8 pattern pairs" in cap.out
    assert (f"note: {part} is incomplete (status 'interrupted': 8 of 16 planned pattern pairs "
            "recorded); 'torchtof acquire --resume") in cap.err


def test_acquire_then_reconstruct_equals_pure_simulation(uninterrupted, tmp_path, capsys):
    out = tmp_path / "rec"
    assert main(["reconstruct", str(uninterrupted), "--method", "tval3", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "TVAL3 from 16 pattern pairs (SR 25.00%)" in text and "PSNR" in text
    # the summary names every file written
    assert str(out / "TVAL3_depth.pt") in text and str(out / "TVAL3_depth.png") in text
    img = torch.load(out / "TVAL3_depth.pt")
    ref = PaperExperiment(sr=0.25, n=8, roi_px=16, srs=(0.25,), shot=None, read_noise_e=0.0,
                          chunk_frames=1).run(seed=0)
    g = zarr.open_group(str(uninterrupted), mode="r")
    assert torch.equal(torch.from_numpy(g["buckets_depth"][:]), ref.buckets["depth"])
    with torch.no_grad():
        expected = build_method("TVAL3", ref, 0.25, False)()
    assert torch.equal(img, expected)
    assert (out / "TVAL3_depth.png").stat().st_size > 1000


def test_acquire_refuses_existing_store_and_unknown_method(uninterrupted, capsys):
    # an existing store without --resume: a one-line usage error before any device is opened
    with pytest.raises(SystemExit) as exc:
        main([*ARGS, "-o", str(uninterrupted)])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "argument -o/--output:" in err[0] and \
        "exists; pass --resume" in err[0], err
    with pytest.raises(SystemExit) as exc:
        main(["reconstruct", str(uninterrupted), "--method", "nope"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "argument --method: unknown method 'nope'" in err[0], err
    assert "TVAL3" in err[0] and "CGI" in err[0]  # the valid names


@pytest.mark.slow  # kill and resume in the default run: test_reliability.py (inside a write)
@pytest.mark.parametrize("ids,hang,kept", [
    # SIGKILL while the host waits for frame 27 (frames 0-26 have arrived, 27 is in flight)
    # or while the camera renders it: the sequence 24-31 in flight is lost, 0-23 recorded
    ("device", {"hang_at_read": 27}, 24),
    ("count", {"hang_at_frame": 27}, 24),
])
def test_killed_acquisition_resumes_to_the_same_data(ids, hang, kept, uninterrupted, tmp_path):
    """A SIGKILLed run: every frame received (device ids) or every checked sequence (count)
    is in the store, equal to the uninterrupted run, and --resume ends with its data."""
    path, flag = tmp_path / "killed2.zarr", tmp_path / "hang2"
    faults = json.dumps({**hang, "hang_file": str(flag), "hang_s": 120})
    args = [*ARGS, "-o", str(path), "--frame-ids", ids]
    proc = subprocess.Popen([sys.executable, "-m", "torchtof.cli", *args,
                             "--sim-faults", faults], env=_env(), cwd=tmp_path,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        t0 = time.monotonic()
        while not flag.exists():
            assert proc.poll() is None and time.monotonic() - t0 < 120
            time.sleep(0.05)
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL
    g = zarr.open_group(str(path), mode="r")
    assert g.attrs["status"] == "running"
    assert g["frames_ok"][:].tolist() == [1] * kept + [0] * (32 - kept)
    ref = zarr.open_group(str(uninterrupted), mode="r")
    for name in ARRAYS:  # what was recorded before the kill is the uninterrupted run's data
        np.testing.assert_array_equal(g[name][:kept] if name.startswith("frames") else
                                      g[name][..., :kept], ref[name][:kept] if
                                      name.startswith("frames") else ref[name][..., :kept],
                                      err_msg=name)
    with pytest.raises(SystemExit) as exc:  # exists: needs --resume (a usage error)
        main(args)
    assert exc.value.code == 2
    assert main([*args, "--resume"]) == 0
    a, b = zarr.open_group(str(path), mode="r"), zarr.open_group(str(uninterrupted), mode="r")
    for name in ARRAYS:
        np.testing.assert_array_equal(a[name][:], b[name][:], err_msg=name)
    assert a.attrs["status"] == "complete" and a.attrs["m_acquired"] == 16


def test_import_torchtof_does_not_load_the_hardware_layer():
    code = ("import sys, torchtof\n"
            "print('torchtof.hardware' in sys.modules, 'usb' in sys.modules)\n"
            "import torchtof.cli\n"  # registers the acquire/reconstruct subcommands
            "bad = [m for m in sys.modules if m == 'usb' or m.startswith('usb.') or "
            "m.startswith('torchtof.hardware.') and m != 'torchtof.hardware.cli' or m == 'zarr']\n"
            "print(bad)\n"
            "import torchtof.hardware as h\n"
            "h.Frame\n"
            "print([m for m in sys.modules if m == 'usb' or m == 'zarr'])\n"
            "print(callable(h.acquire), 'torchtof.hardware.acquisition' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", code], env=_env(), capture_output=True, text=True,
                         check=True).stdout.split("\n")
    assert out[:4] == ["False False", "[]", "[]", "True True"]


def test_no_device_found_gives_udev_hint(monkeypatch):
    import usb.core

    monkeypatch.setattr(usb.core, "find", lambda **kw: None)
    with pytest.raises(DeviceNotFoundError, match=r"(?s)no DLP LightCrafter 4500 found \(USB "
                       r"0451:6401\).*udev rule.*idProduct}==\"6401\".*udevadm"):
        dlpc350.LightCrafter4500.open()
    with pytest.raises(DeviceNotFoundError, match=r"OPT8241 ToF camera found \(USB 0451:9105\)"):
        opt8241.OPT8241.open()


def test_no_usb_backend_gives_libusb_hint(monkeypatch):
    import usb.core

    def no_backend(**kw):
        raise usb.core.NoBackendError("No backend available")

    monkeypatch.setattr(usb.core, "find", no_backend)
    with pytest.raises(DeviceNotFoundError, match="(?s)no libusb backend: install libusb.*udev"):
        dlpc350.LightCrafter4500.open()


def test_real_usb_discovery_without_device():
    """The real pyusb call on this machine (no device, maybe no libusb): never a crash."""
    with pytest.raises(DeviceNotFoundError, match="0451:6401"):
        dlpc350.LightCrafter4500.open()


def test_cli_acquire_without_device_reports_the_hint(monkeypatch, tmp_path, capsys):
    import usb.core

    monkeypatch.setattr(usb.core, "find", lambda **kw: None)
    assert main(["acquire", "-o", str(tmp_path / "x.zarr")]) == 1
    err = capsys.readouterr().err
    assert "no DLP LightCrafter 4500 found" in err and "udevadm" in err


def test_busy_device(monkeypatch):
    import usb.core

    class Busy:
        def is_kernel_driver_active(self, i):
            return False

        def get_active_configuration(self):
            return None

        def set_configuration(self):
            raise usb.core.USBError("Resource busy", errno=16)

    monkeypatch.setattr(usb.core, "find", lambda **kw: Busy())
    with pytest.raises(DeviceBusyError, match="DLP LightCrafter 4500 is busy"):
        dlpc350.LightCrafter4500.open()
    with pytest.raises(DeviceBusyError, match="OPT8241 ToF camera is busy"):
        opt8241.OPT8241.open()


@pytest.mark.parametrize("active", [True, False])
def test_camera_open_keeps_an_active_configuration_and_claims_the_interface(active,
                                                                           monkeypatch):
    """TI's USBIO opens the device and claims interface 0; re-selecting an active
    configuration would reset the device's USB state, so only an unconfigured one is set."""
    import usb.core
    import usb.util

    calls = []

    class Camera:
        def get_active_configuration(self):
            if active:
                return object()
            raise usb.core.USBError("Configuration not set")

        def set_configuration(self):
            calls.append("set_configuration")

    monkeypatch.setattr(usb.core, "find", lambda **kw: Camera())
    monkeypatch.setattr(usb.util, "claim_interface", lambda dev, i: calls.append(("claim", i)))
    opt8241.OPT8241.open()
    assert calls == ([] if active else ["set_configuration"]) + [("claim", 0)]


@pytest.mark.parametrize("fake", [None, "2.18.2", "3.1.5"])
def test_missing_or_old_zarr_names_the_requirement(fake, monkeypatch, tmp_path, capsys):
    """zarr 3 needs Python >= 3.11; the package allows 3.10: a clear error, not a crash deep
    in the v2 API."""
    import types

    from torchtof.hardware.acquisition import require_zarr3

    if fake is None:
        monkeypatch.setitem(sys.modules, "zarr", None)  # import zarr -> ImportError
        first = "zarr is not installed"
    else:
        monkeypatch.setitem(sys.modules, "zarr", types.SimpleNamespace(__version__=fake))
        first = f"zarr {fake} is installed"
    # 3.1.5: chunk writes are not atomic before 3.1.6
    with pytest.raises(ImportError, match=rf"{first}.*zarr>=3.1.6, which needs Python>=3.11"):
        require_zarr3()
    assert main([*ARGS, "-o", str(tmp_path / "z.zarr")]) == 1
    store = tmp_path / "r.zarr"  # a zarr group (checked before zarr is needed)
    store.mkdir()
    (store / "zarr.json").write_text("{}")
    assert main(["reconstruct", str(store), "--method", "cgi"]) == 1
    err = capsys.readouterr().err
    assert f"torchtof acquire: {first}" in err and f"torchtof reconstruct: {first}" in err
    assert "pip install 'zarr>=3.1.6'" in err and not (tmp_path / "z.zarr").exists()


def test_require_zarr3_passes_with_the_installed_zarr():
    from torchtof.hardware.acquisition import require_zarr3

    assert require_zarr3() is zarr and int(zarr.__version__.split(".")[0]) >= 3


@pytest.mark.slow
def test_acquire_auto_stops_where_the_offline_rule_stops(tmp_path, capsys):
    """``acquire --auto``: the progressive rule (torchtof.adaptive.ProgressiveStop) ends the
    run early; the recorded prefix equals the pure simulation, and replaying the rule offline
    on the simulation's gated buckets stops at the same block."""
    from torchtof.adaptive import ProgressiveStop
    from torchtof.hardware.cli import AUTO_BLOCK

    path = tmp_path / "auto.zarr"
    args = ["acquire", "--simulated", "--auto", "--scene", "sky", "--n", "16", "--roi-px", "16",
            "--sr", "1.0", "--no-progress", "-o", str(path)]
    assert main(args) == 0
    assert "--auto: stopped after" in capsys.readouterr().out
    g = zarr.open_group(str(path), mode="r")
    m = int(g.attrs["m_acquired"])
    assert g.attrs["stopped_early"] and m < 256 and m % AUTO_BLOCK == 0
    assert g.attrs["auto"]["block"] == AUTO_BLOCK and g.attrs["auto"]["kind"] == "gated"
    # the recorded frames are the simulation's first 2m frames, each with the noise of its
    # pattern (SimulatedBench.noise_generator, seed 0)
    from torchtof.bucket import depth_bucket
    from torchtof.experiment import ExperimentConfig, simulate_frames
    from torchtof.hardware.simulated import SimulatedBench
    from torchtof.operators import DMDSplit, Hadamard

    cfg = ExperimentConfig(n=16, roi_px=16, srs=(1.0,))
    bench = SimulatedBench(cfg, seed=0)
    pats = DMDSplit(Hadamard(16, sr=1.0)).patterns(torch.float32).to(torch.uint8).numpy()
    gated = torch.cat([depth_bucket(simulate_frames(
        bench.scene, torch.from_numpy(p.astype(np.float32))[None], cfg,
        bench.noise_generator(p), None, bench.stray).depth[:, 0][None], gate_m=cfg.gate_m)
        for p in pats[: 2 * m]], -1)
    got = torch.from_numpy(g["buckets_gated"][:])[..., : 2 * m]
    assert torch.equal(got, gated)
    assert g.attrs["auto"]["noise"] == "pairs"
    # the same rule, replayed block by block on y⁺ − y⁻ and y⁺ + y⁻ (÷ n), first says stop at m
    rule = ProgressiveStop(16, block=AUTO_BLOCK, kind="gated", noise_sigma="pairs")
    y = (gated[..., 0::2] - gated[..., 1::2])[:1] / 16
    s = (gated[..., 0::2] + gated[..., 1::2])[:1] / 16
    first = next(k for k in range(AUTO_BLOCK, m + 1, AUTO_BLOCK)
                 if rule({"gated": y[..., :k], "gated_sum": s[..., :k]}))
    assert first == m


def test_camera_roi_option_reads_out_the_region(uninterrupted, tmp_path):
    """--camera-roi over the whole simulated sensor (17 x 16) records the same buckets as no
    ROI; a 9-row region records 9-row frames, the top rows of the full ones."""
    whole, top = tmp_path / "whole.zarr", tmp_path / "top.zarr"
    assert main([*ARGS, "--camera-roi", "0", "0", "17", "16", "-o", str(whole)]) == 0
    assert main([*ARGS, "--camera-roi", "0", "0", "9", "16", "-o", str(top)]) == 0
    ref, g, t = (zarr.open_group(str(p), mode="r") for p in (uninterrupted, whole, top))
    for name in ("buckets_depth", "frames_taps"):
        np.testing.assert_array_equal(g[name][:], ref[name][:])
    assert t.attrs["camera"]["height"] == 9 and t["frames_taps"].shape[-2] == 8  # row 0 left out
    np.testing.assert_array_equal(t["frames_taps"][:], ref["frames_taps"][..., :8, :])


def test_resume_refuses_another_camera_region(tmp_path, capsys):
    """The region is part of the set-up: a resume reading another region of the same size
    would mix two parts of the sensor in one store."""
    path = tmp_path / "run.zarr"
    assert main([*ARGS, "--camera-roi", "0", "0", "9", "16", "-o", str(path)]) == 0
    g = zarr.open_group(str(path), mode="r")
    assert g.attrs["camera"]["roi"] == [0, 0, 9, 16]
    rc = main([*ARGS, "--camera-roi", "8", "0", "9", "16", "--resume", "-o", str(path)])
    assert rc != 0
    assert "camera.roi" in capsys.readouterr().err


def test_real_bench_sets_the_whole_sensor_without_camera_roi(monkeypatch):
    """An earlier run's region stays on the device: without --camera-roi the real bench sets
    the whole 320x240 sensor (the frames it decodes)."""
    import torchtof.hardware.cli as hcli
    import torchtof.hardware.dlpc350 as dl
    import torchtof.hardware.opt8241 as op

    seen = []

    class Cam:
        def check_initialised(self):
            seen.append("checked")

        def set_roi(self, *roi):
            seen.append(roi)

        def close(self):
            pass

    monkeypatch.setattr(dl.LightCrafter4500, "open", classmethod(lambda cls: type(
        "L", (), {"close": lambda self: None})()))
    opened = []
    monkeypatch.setattr(op.OPT8241, "open", classmethod(lambda cls, **kw: opened.append(kw)
                                                        or Cam()))
    monkeypatch.setattr("torchtof.hardware.video.WindowVideoPort", lambda display: None)
    for (roi, want), off in zip(((None, (0, 0, 240, 320)), ([80, 96, 65, 128], (80, 96, 65, 128))),
                                (False, True)):
        args = type("A", (), {"camera_mode": "quad", "quads": 4, "simulated": False,
                              "camera_roi": roi, "display": 1, "mod_freq_mhz": 30.0,
                              "no_overflow_check": off})()
        hcli._open_devices(args, {})
        assert seen[-2:] == ["checked", want]  # the board check before the region's writes
        assert opened[-1]["mod_freq_hz"] == 30e6  # --mod-freq-mhz reaches the camera
        assert opened[-1]["check_overflow"] is (not off)  # so does --no-overflow-check


def test_reconstruct_with_a_trained_weights_file(uninterrupted, tmp_path, capsys):
    """``--weights`` reconstructs with that file's network (Learned) or stacks it (Auto):
    the images equal what the library gives with the same file, and differ from the shipped
    network's; any other method, or a missing file, is a one-line usage error."""
    from torchtof.recon.learned_train import train_learned

    train_learned(steps=1, batch_size=2, sizes=(8,), n_layers=2, width=4, progress=False,
                  calibrate=False, out=tmp_path / "run")
    w = str(tmp_path / "run" / "learned.pt")
    ref = PaperExperiment(sr=0.25, n=8, roi_px=16, srs=(0.25,), shot=None, read_noise_e=0.0,
                          chunk_frames=1).run(seed=0)
    out = tmp_path / "rec"
    assert main(["reconstruct", str(uninterrupted), "--method", "learned", "--weights", w,
                 "--out", str(out)]) == 0
    img = torch.load(out / "Learned_depth.pt")
    with torch.no_grad():
        mine = build_method("Learned", ref, 0.25, False, weights=w)()
        shipped = build_method("Learned", ref, 0.25, False)()
    assert torch.equal(img, mine) and not torch.allclose(mine, shipped)
    capsys.readouterr()
    for argv, msg in ((["--method", "tval3", "--weights", w], "only Learned and Auto"),
                      (["--method", "learned", "--weights", w + ".none"], "no such weights"),
                      (["--method", "learned", "--weights",
                        str(tmp_path / "run" / "checkpoint.pt")], "not a learned weights file")):
        with pytest.raises(SystemExit) as exc:
            main(["reconstruct", str(uninterrupted), *argv, "--out", str(tmp_path / "x")])
        assert exc.value.code == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "argument --weights:" in err[0] and msg in err[0], err
    with pytest.raises(ValueError, match="weights"):
        build_method("TVAL3", ref, 0.25, False, weights=w)
