"""Host throughput of the acquisition path: ``python -m torchtof.hardware.throughput``.

A fake OPT8241 serves one pre-encoded frame of the real size (320 × 240 by default) as fast
as the host reads, so the measurement is the host's own path — USB reader thread, frame-id /
count / timing checks, decoding (:func:`~torchtof.hardware.opt8241.decode_frame`), the ROI
bucket sums and the zarr writes per sequence — through :func:`~torchtof.hardware.acquire`
itself, with a simulated LightCrafter. Prints frames per second (wall) and frames per
CPU-second (all threads; what one dedicated core would sustain) per camera mode; the host
keeps up when that is above the pattern rate (60 patterns/s on the 60 Hz VSYNC trigger, 100/s
at 10 ms patterns on the internal trigger).
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from pathlib import Path

import numpy as np

from ..experiment import ExperimentConfig
from . import opt8241 as opt
from .simulated import FakeOPT8241, SimulatedBench

__all__ = ["ReplayCamera", "measure", "main"]


class ReplayCamera(FakeOPT8241):
    """A :class:`~torchtof.hardware.simulated.FakeOPT8241` whose frames are one fixed
    ``width × height`` frame (random 12-bit taps), encoded once per mode; only the frame
    number changes."""

    def __init__(self, bench: SimulatedBench, width: int, height: int) -> None:
        super().__init__(bench)
        self.sensor = (height, width)
        self.select_whole_sensor()  # the frame size and region the registers report
        rng = np.random.default_rng(0)
        self._taps = rng.integers(0, 4096, size=(4, height, width)).astype(np.int64)
        self._cache: dict = {}

    def _output(self, pattern: np.ndarray, ready: float) -> None:
        taps = self.crop(self._taps)
        key = (self.mode, self.field("quad_cnt_max"), taps.shape)
        if key not in self._cache:
            self._cache[key] = opt.encode_frame(key[0], taps, quads=key[1])
        self.rendered += 1
        self._fifo.append((self.rendered - 1, self._numbered(self._cache[key]), ready))


def measure(mode: str, n: int = 32, sr: float = 0.25, width: int = 320, height: int = 240,
            store: str | Path | None = None, trigger: str = "vsync") -> dict:
    """Acquire ``2 · sr · n²`` frames of ``width × height`` px in ``mode`` from the replay
    camera into a fresh zarr store; returns frames, seconds and frames per second.

    The pattern period is the camera's: 10 ms, or longer where the OPT9221 needs longer to
    send a frame (:meth:`~torchtof.hardware.opt8241.OPT8241.output_time_us`, e.g. 32 ms for a
    320×240 quad frame), on the internal trigger when that exceeds a 60 Hz video frame. The
    simulated clock does not wait for it: the time measured is the host's."""
    bench = SimulatedBench(ExperimentConfig(n=n, roi_px=n, srs=(sr,)))
    bench.camera_usb = ReplayCamera(bench, width, height)
    lcr = bench.lightcrafter()
    cam = opt.OPT8241(bench.camera_usb, width=width, height=height, mode=mode,
                      clock=lambda: bench.camera_usb.time_s)
    from .acquisition import acquire

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(store) if store is not None else Path(tmp) / "run.zarr"
        t0, c0 = time.perf_counter(), time.process_time()
        exposure_us = max(10_000, math.ceil(cam.output_time_us() / 1000) * 1000)
        if exposure_us > 1e6 / 60:
            trigger = "internal"
        res = acquire(path, lcr, cam, n=n, sr=sr, progress=False, trigger=trigger,
                      exposure_us=exposure_us)
        dt, cpu = time.perf_counter() - t0, time.process_time() - c0
    frames = 2 * res.m_acquired
    return {"mode": mode, "frames": frames, "seconds": dt, "fps": frames / dt,
            "exposure_us": exposure_us, "trigger": trigger,
            "cpu_s": cpu, "fps_per_cpu": frames / cpu, "retries": res.retries}


def main(argv: list[str] | None = None) -> int:
    class Parser(argparse.ArgumentParser):  # mistakes in one line, as torchtof's commands
        def error(self, message: str):
            self.exit(2, f"{self.prog}: error: {message}\n")

    p = Parser(prog="python -m torchtof.hardware.throughput",
               description=__doc__.split("\n\n")[0])
    p.add_argument("--modes", default="depth,quad",
                   help=f"camera modes, comma-separated, of {', '.join(opt.FRAME_MODES)}")
    p.add_argument("--n", type=int, default=32, help="DMD side, a power of two in [4, 256]")
    p.add_argument("--sr", type=float, default=0.25, help="sampling rate in (0, 1]")
    p.add_argument("--width", type=int, default=320)
    p.add_argument("--height", type=int, default=240)
    args = p.parse_args(argv)
    args.modes = [m.strip() for m in args.modes.split(",") if m.strip()]
    bad = [m for m in args.modes if m not in opt.FRAME_MODES]
    if bad or not args.modes:
        p.error(f"argument --modes: expected a comma-separated subset of "
                f"{', '.join(opt.FRAME_MODES)}, got {','.join(bad) or 'nothing'}")
    if not (4 <= args.n <= 256 and args.n & (args.n - 1) == 0):
        p.error(f"argument --n: expected a power of two in [4, 256], got {args.n}")
    if not 0 < args.sr <= 1:
        p.error(f"argument --sr: expected a sampling rate in (0, 1], got {args.sr}")
    for flag, v in (("--width", args.width), ("--height", args.height)):
        if v < 1:
            p.error(f"argument {flag}: expected a positive int, got {v}")
    for mode in args.modes:
        r = measure(mode, args.n, args.sr, args.width, args.height)
        print(f"{mode:6s} {args.width}x{args.height}: {r['frames']} frames in "
              f"{r['seconds']:.2f} s = {r['fps']:.1f} frames/s; {r['cpu_s']:.2f} s of CPU "
              f"(all threads) = {r['fps_per_cpu']:.1f} frames per CPU-second "
              f"({r['retries']} retries)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
