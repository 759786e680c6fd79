"""``torchtof acquire`` and ``torchtof reconstruct``: the hardware subcommands of the CLI.

``add_parsers(sub)`` registers both on the main parser's subparsers (``torchtof/cli.py``).
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import asdict
from pathlib import Path

import torch

__all__ = ["add_parsers", "cmd_acquire", "cmd_reconstruct"]

#: ``acquire`` options that only the simulated bench uses.
SIMULATED_ONLY = ("scene", "roi_px", "scattering", "noise_free", "seed")
#: ``acquire`` options that only the real bench uses.
REAL_ONLY = ("display",)
#: ``acquire --auto``: patterns per block of the stopping rule (torchtof.adaptive's default).
AUTO_BLOCK = 32


def _sim_config(args: argparse.Namespace):
    from ..experiment import ExperimentConfig

    kw = {"n": args.n, "scene": args.scene, "roi_px": args.roi_px or 2 * args.n,
          "srs": (args.sr,), "scattering": args.scattering,
          "freq_hz": args.mod_freq_mhz * 1e6}  # the simulated light at the camera's frequency
    if args.noise_free:
        kw.update(shot=None, read_noise_e=0.0)
    return ExperimentConfig(**kw).validate()


def _zarr_ok(cmd: str) -> bool:
    from .acquisition import require_zarr3

    try:
        require_zarr3()
    except ImportError as exc:
        print(f"torchtof {cmd}: {exc}", file=sys.stderr)
        return False
    return True


def _open_devices(args: argparse.Namespace, metadata: dict):
    """The two devices: simulated (``--simulated``) or the real bench — LightCrafter 4500
    (USB 0451:6401) with a :class:`~torchtof.hardware.video.WindowVideoPort` on display
    ``--display``, OPT8241 (USB 0451:9105). Everything after this is the same code."""
    cam_kw = {"mode": args.camera_mode, "quads": args.quads,
              "mod_freq_hz": args.mod_freq_mhz * 1e6,
              "check_overflow": not args.no_overflow_check}
    if args.simulated:
        from .simulated import Faults, SimulatedBench

        cfg = _sim_config(args)
        faults = Faults.from_dict(args.sim_faults) if args.sim_faults else None
        bench = SimulatedBench(cfg, seed=args.seed, faults=faults, video_hz=args.video_hz)
        metadata["simulation"] = {"config": asdict(cfg), "seed": args.seed}
        cam = bench.camera(**cam_kw)
        cam.check_initialised()  # before any register write (OPT8241 class docstring)
        if args.camera_roi:
            cam.set_roi(*args.camera_roi)
        return bench.lightcrafter(), cam, None
    from .dlpc350 import LightCrafter4500
    from .opt8241 import OPT8241
    from .video import WindowVideoPort

    opened: list = []
    try:
        lcr = LightCrafter4500.open()
        opened.append(lcr)
        cam = OPT8241.open(width=320, height=240, **cam_kw)
        opened.append(cam)
        cam.check_initialised()  # before any register write (OPT8241 class docstring)
        # the region asked for, else the whole sensor (an earlier run's region stays set)
        cam.set_roi(*(args.camera_roi or (0, 0, 240, 320)))
        lcr.video = WindowVideoPort(display=args.display)
    except BaseException:
        for dev in reversed(opened):  # close what was opened before the failure
            dev.close()
        raise
    return lcr, cam, lcr.video


def cmd_acquire(args: argparse.Namespace) -> int:
    from .acquisition import StoreDamagedError, acquire
    from .errors import HardwareError

    if not _zarr_ok("acquire"):
        return 1
    metadata: dict = {}
    lcr = cam = video = None
    try:
        lcr, cam, video = _open_devices(args, metadata)
        block = args.block or (AUTO_BLOCK if args.auto else 12)
        rule = stop = None
        if args.auto:  # progressive acquisition (torchtof.adaptive, README "--auto")
            from ..adaptive import ProgressiveStop

            # σ̂ from the pair sums y⁺ + y⁻ of the blocks so far: no repeated patterns
            rule = ProgressiveStop(args.n, block=block, kind="gated", order=args.order,
                                   noise_sigma="pairs")
            metadata["auto"] = {"rule": rule.rule, "kind": rule.kind, "block": block,
                                "min_patterns": rule.min_patterns, "noise": "pairs"}

            def stop(buckets: dict, n: int = args.n) -> bool:
                # the hook passes y⁺ ∓ y⁻; the rule reads orthonormal coefficients (÷ n)
                return rule({k: v / n for k, v in buckets.items()})

        res = acquire(args.output, lcr, cam, n=args.n, sr=args.sr, order=args.order,
                      exposure_us=args.exposure_us, period_us=args.period_us, block=block,
                      stop=stop, resume=args.resume, retries=args.retries,
                      progress=not args.no_progress, metadata=metadata,
                      frame_ids=args.frame_ids, trigger=args.trigger, video_hz=args.video_hz)
    except KeyboardInterrupt:
        print(f"torchtof acquire: interrupted; the recorded sequences are kept: run the same "
              f"command with --resume to continue {args.output}", file=sys.stderr)
        return 130
    except StoreDamagedError as exc:
        print(f"torchtof acquire: {exc}", file=sys.stderr)
        return 2
    except (HardwareError, FileExistsError, ImportError) as exc:
        print(f"torchtof acquire: {_bare(exc, 'acquire: ')}", file=sys.stderr)
        return 1
    except ValueError as exc:  # a store recorded with other settings
        print(f"torchtof acquire: {_bare(exc, 'acquire: ')}", file=sys.stderr)
        return 2
    finally:  # every exit path: streaming stopped, USB released, window closed
        for dev in (cam, lcr, video):
            if dev is not None and hasattr(dev, "close"):
                try:
                    dev.close()
                except Exception:  # noqa: BLE001 - closing must not mask the real error
                    pass
    print(f"recorded {res.m_acquired}/{res.m_planned} pattern pairs to {res.path} "
          f"({res.retries} retries, {res.duplicates} duplicate frames discarded)")
    if rule is not None and res.stopped_early:
        print(f"--auto: stopped after {res.m_acquired} of {res.m_planned} patterns "
              f"({res.m_acquired / res.m_planned:.0%}): {rule.last.get('reason')}")
    return 0


def cmd_reconstruct(args: argparse.Namespace) -> int:
    from ..methods import build_method, score_image
    from ..report import save_image
    from .acquisition import StoreDamagedError, load_run

    if not _zarr_ok("reconstruct"):
        return 1
    try:
        data = load_run(args.store)
    except (StoreDamagedError, FileNotFoundError) as exc:
        print(f"torchtof reconstruct: {exc}", file=sys.stderr)
        return 2
    status = _store_status(args.store, data.hadamard.m)
    if status is not None:  # an interrupted run: say so before the image hides it
        print(f"torchtof reconstruct: note: {args.store} is incomplete ({status}); "
              f"'torchtof acquire --resume -o {args.store}' with the run's options finishes "
              "it", file=sys.stderr)
    name = args.method  # a label: checked by _method
    sr = data.config.srs[0]
    method = build_method(name, data, sr, args.gate, args.kind, weights=args.weights)
    with torch.enable_grad() if name == "DIP" else torch.no_grad():
        img = method().detach()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    tag = f"{name}_{args.kind}{'_gate' if args.gate else ''}"
    pt = out / f"{tag}.pt"
    torch.save(img, pt)
    polarity = data.polarity(args.gate, args.kind)
    s = score_image(img, data, polarity) if data.x.abs().sum() > 0 else None  # simulated run
    kind = f"{args.kind} buckets" + (f", {data.config.gate_m:g} m gate" if args.gate else "")
    png = save_image(out / f"{tag}.png", img,
                     f"{name}, {kind}, SR {sr:.2%} ({data.hadamard.m} pattern pairs) from "
                     f"{Path(args.store).name}", polarity=polarity, score=s)
    line = f"{name} from {data.hadamard.m} pattern pairs (SR {sr:.2%}): wrote {pt} and {png}"
    if s is not None:
        line += f"; PSNR {s['psnr']:.2f} dB, SSIM {s['ssim']:.3f} vs the simulated object"
    print(line)
    return 0


def _store_status(path, recorded: int) -> str | None:
    """``None`` for a finished run (``--auto`` runs stopped by their rule included), else
    what the store holds of its plan (``recorded``: the verified pattern pairs)."""
    from .acquisition import store_attributes

    attrs = store_attributes(path)
    if attrs.get("status") == "complete":
        return None
    return (f"status {attrs.get('status', 'unknown')!r}: {recorded} of "
            f"{int(attrs.get('m', 0))} planned pattern pairs recorded")


def _method(text: str) -> str:
    """``reconstruct --method``: a name of :mod:`torchtof.recon.registry` (case-insensitive),
    returned as its label."""
    from ..recon import registry

    try:
        return registry.get(text).label
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"unknown method {text!r}; choose from {', '.join(_method_labels())}") from None


def _method_labels() -> list[str]:
    """Every method of :mod:`torchtof.recon.registry`, by label (``--help`` and the error)."""
    from ..recon import registry

    return [s.label for s in registry.specs()]


def _check_reconstruct(args: argparse.Namespace) -> None:
    """``reconstruct STORE``: a directory holding a zarr group, checked after the options'
    types (a wrong ``--method`` is named first) and before the store is opened."""
    from ..methods import WEIGHTS_OPTION

    if args.gate and args.kind != "depth":
        raise ValueError(f"argument --gate: the depth gate applies to the depth buckets only, "
                         f"got --kind {args.kind}")
    if args.weights is not None:
        if args.method not in WEIGHTS_OPTION:
            raise ValueError(f"argument --weights: only {' and '.join(WEIGHTS_OPTION)} load a "
                             f"weights file, got --method {args.method}")
        from ..recon.learned import check_weights_file

        check_weights_file(args.weights, "argument --weights")
    path = Path(args.store)
    if not path.exists():
        raise ValueError(f"argument STORE: no such store: {args.store}")
    if not ((path / "zarr.json").is_file() or (path / ".zgroup").is_file()):
        raise ValueError(f"argument STORE: {args.store} is not a torchtof store (no zarr "
                         f"group): {path.resolve()}")


def _check_acquire(args: argparse.Namespace) -> None:
    """Cross-option checks of ``acquire`` (each option alone is checked by its type)."""
    if not args.simulated:  # the real bench records what is in front of it
        for dest in SIMULATED_ONLY:
            if dest in args.given:  # even at its default value
                flag = "--" + dest.replace("_", "-")
                raise ValueError(f"argument {flag}: used with --simulated only (the real bench "
                                 "records the scene in front of it, with its own noise)")
    if args.auto and args.block is not None and args.block < 4:  # ProgressiveStop's minimum
        raise ValueError(f"argument --block: expected >= 4 with --auto (the stopping rule "
                         f"compares blocks of at least 4 pattern pairs), got {args.block}")
    if args.simulated:  # the simulated bench has no video output to choose
        for dest in REAL_ONLY:
            if dest in args.given:
                flag = "--" + dest.replace("_", "-")
                raise ValueError(f"argument {flag}: used on the real bench only (the simulated "
                                 "bench sends its patterns to no display)")
    if args.simulated and args.n < 8:
        raise ValueError(f"argument --n: the simulated scenes need n >= 8, got {args.n}")
    if args.roi_px is not None and args.roi_px < args.n:
        raise ValueError(f"argument --roi-px: expected >= --n ({args.n}), got {args.roi_px}")
    if args.camera_roi:
        from .opt8241 import ROI_COL_STEP, SENSOR_COLS, SENSOR_ROWS

        row, col, h, w = args.camera_roi
        if col % ROI_COL_STEP or w % ROI_COL_STEP or h < 1 or w < ROI_COL_STEP or \
                row + h > SENSOR_ROWS or col + w > SENSOR_COLS:
            raise ValueError(f"argument --camera-roi: expected COL and WIDTH multiples of 16 "
                             f"and a region inside the 320x240 sensor, got {row} {col} {h} {w}")
    if args.simulated and args.camera_roi:
        row, col, h, w = args.camera_roi
        px = args.roi_px or 2 * args.n  # the simulated sensor: px + 1 rows (guard row) x px
        if row + h > px + 1 or col + w > px:
            raise ValueError(f"argument --camera-roi: rows {row}..{row + h - 1}, columns "
                             f"{col}..{col + w - 1} lie beyond the simulated sensor "
                             f"({px + 1} rows x {px} columns, --roi-px)")
    from ..apps.args import check_patterns

    check_patterns(args.n, args.sr)
    _check_mod_freq(args)
    _check_timing(args)
    if args.sim_faults is not None:
        if not args.simulated:
            raise ValueError("argument --sim-faults: a fault plan for the simulator needs "
                             "--simulated")
        from .simulated import Faults

        try:
            Faults.from_dict(args.sim_faults)
        except ValueError as exc:
            raise ValueError(f"argument --sim-faults: {_bare(exc, 'Faults: ')}") from None
    _check_output(args)


def _check_mod_freq(args: argparse.Namespace) -> None:
    """``--mod-freq-mhz``: a frequency the OPT8241's PLL makes with ``--quads``
    (:func:`~torchtof.hardware.opt8241.pll_settings`) whose unambiguous range ``c/(2f)``
    reaches the camera rules' ``max_m`` (5 m, paper §2.2;
    :func:`~torchtof.hardware.opt8241.check_unambiguous_range`), named in the message."""
    from . import opt8241 as opt

    f = args.mod_freq_mhz * 1e6
    try:
        opt.pll_settings(f, args.quads)
    except ValueError as exc:
        raise ValueError(f"argument --mod-freq-mhz: the OPT8241's PLL cannot make "
                         f"{args.mod_freq_mhz:g} MHz with --quads {args.quads} "
                         f"({_bare(exc, 'pll_settings: ')})") from None
    # the camera rules' max_m: CameraRules' on the real bench, ExperimentConfig's simulated
    # (rules_from_config); both are the paper's 5 m and acquire has no option to change them
    opt.check_unambiguous_range(f, opt.CameraRules().max_m, "argument --mod-freq-mhz",
                                "--mod-freq-mhz")


def _check_timing(args: argparse.Namespace) -> None:
    """``--exposure-us``, ``--period-us``, ``--trigger`` and ``--video-hz`` against the DLPC350's
    rules (:func:`~torchtof.hardware.dlpc350.payload_exposure_period`: PAT_EXPO_PRD takes
    ``exposure == period`` or ``exposure <= period - 230 µs``, 32-bit values;
    :func:`~torchtof.hardware.dlpc350.patterns_per_vsync`: on the VSYNC trigger a pattern
    fits one video frame), each message naming the options."""
    from . import dlpc350 as dlp

    dlp.check_video_hz(args.video_hz, "argument --video-hz", "--video-hz")
    exposure = args.exposure_us
    period = exposure if args.period_us is None else args.period_us
    for flag, v in (("--exposure-us", exposure), ("--period-us", period)):
        if v >= 2**32:  # PAT_EXPO_PRD's u32 fields
            raise ValueError(f"argument {flag}: expected at most {2**32 - 1} (a 32-bit value "
                             f"of the DLPC350), got {v}")
    try:
        dlp.payload_exposure_period(exposure, period)
    except ValueError:
        raise ValueError(f"argument --period-us: the DLPC350 needs --period-us equal to "
                         f"--exposure-us or at least {dlp.MIN_DARK_US} us longer (PAT_EXPO_PRD), "
                         f"got --period-us {period} with --exposure-us {exposure}") from None
    if args.trigger == "vsync":
        try:
            dlp.patterns_per_vsync(exposure, period, args.video_hz)
        except ValueError:
            flag = "--exposure-us" if args.period_us is None else "--period-us"
            raise ValueError(f"argument {flag}: on the VSYNC trigger a pattern must fit one "
                             f"video frame ({1e6 / args.video_hz:.0f} us at --video-hz "
                             f"{args.video_hz:g}), got --exposure-us {exposure}, --period-us "
                             f"{period} (lower them, raise --video-hz or use --trigger "
                             f"internal)") from None


def _check_output(args: argparse.Namespace) -> None:
    """``-o``: a new path, an empty folder, or with ``--resume`` a store (the settings are
    compared once the devices are open). Never a file or a folder of other files: the store is
    created with zarr's mode ``"w"``, which would delete them."""
    out = Path(args.output)
    if not out.exists():
        return
    if (out / "zarr.json").is_file():
        if not args.resume:
            raise ValueError(f"argument -o/--output: {args.output} exists; pass --resume to "
                             "continue it or choose a new path")
    elif not out.is_dir():
        raise ValueError(f"argument -o/--output: {args.output} exists and is not a folder; "
                         "choose a new path")
    elif any(out.iterdir()):
        raise ValueError(f"argument -o/--output: {args.output} is a folder holding other files, "
                         "not a torchtof store; choose a new path or an empty folder")


def _bare(exc: BaseException, prefix: str) -> str:
    """The message of ``exc`` without the library's ``prefix`` (the CLI names the command)."""
    return str(exc).removeprefix(prefix)


def add_parsers(sub) -> None:
    """Add ``acquire`` and ``reconstruct`` to the CLI's subparsers."""
    from ..apps.args import (
        json_object,
        nonneg_int,
        positive_float,
        positive_int,
        power_of_two,
        sampling_rate,
        scene,
    )
    from ..operators.patterns import ORDERS

    a = sub.add_parser("acquire", help="acquire buckets from a LightCrafter 4500 + OPT8241 "
                       "(or --simulated) into a zarr store",
                       description="Project Hadamard pattern pairs with a LightCrafter 4500 and "
                       "record the OPT8241's frames into a zarr store (or simulate both with "
                       "--simulated).")
    a.add_argument("--simulated", action="store_true",
                   help="simulated devices (no USB); without it the real bench is opened")
    a.add_argument("--scene", type=scene, default="sky",
                   help="simulated scene: sky, steps, motorcycle, slanted, steps_far, "
                   "skimage:<image>, binary:<image>")
    a.add_argument("--sr", type=sampling_rate, default=0.25,
                   help="sampling rate M/n² of the Hadamard patterns, in (0, 1]")
    a.add_argument("--n", type=power_of_two, default=32,
                   help="DMD side in pixels (a power of two in [4, 256])")
    a.add_argument("--roi-px", type=positive_int, default=None,
                   help="simulated camera ROI side in pixels, >= n (default 2n)")
    a.add_argument("--order", default="cake_cutting", choices=list(ORDERS),
                   help="order of the Hadamard patterns")
    a.add_argument("--scattering", action="store_true",
                   help="simulated: image through the scattering sheet")
    a.add_argument("--noise-free", action="store_true", help="simulation without shot/read noise")
    a.add_argument("--seed", type=int, default=0, help="simulated: random seed of the noise")
    a.add_argument("--exposure-us", type=positive_int, default=10_000,
                   help="exposure per pattern in microseconds")
    a.add_argument("--period-us", type=positive_int, default=None,
                   help="pattern period in microseconds (default: the exposure)")
    a.add_argument("--trigger", default="vsync", choices=["vsync", "internal"],
                   help="vsync: each pattern starts at a VSYNC of the video input, exposures "
                   "within one video frame (TI's video-mode examples); internal: the DMD paces")
    a.add_argument("--video-hz", type=positive_float, default=60.0,
                   help="video input frame rate in Hz, at most 120 (the DLPC350's video display "
                        "mode limit; pattern mode states none); "
                   "checked against the rate the LightCrafter measures before a run")
    a.add_argument("--display", type=nonneg_int, default=1,
                   help="display index of the LightCrafter's HDMI input (real bench)")
    a.add_argument("--camera-mode", default="quad", choices=["quad", "iq", "depth", "depth8",
                                                             "depth2"],
                   help="OPT8241 output: quad (raw samples, per-tap buckets), iq, depth; at "
                   "320x240 the camera sends at most 31 quad (N=4) or 62 depth frames/s, and "
                   "a pattern spacing shorter than that is refused (README 'Real hardware')")
    a.add_argument("--camera-roi", type=nonneg_int, nargs=4, default=None,
                   metavar=("ROW", "COL", "HEIGHT", "WIDTH"),
                   help="read out only this sensor region (COL and WIDTH multiples of 16; "
                   "with --frame-ids device its first row carries the frame number and is left "
                   "out of the buckets): smaller frames take less time to send "
                   "(OPT8241.set_roi); default on the real bench: the whole 320x240 sensor")
    a.add_argument("--quads", type=int, default=4, choices=[4, 6],
                   help="quad_cnt_max: samples per pixel and frame (TI's profiles use 6, its No "
                        "Calibration profile 4)")
    a.add_argument("--mod-freq-mhz", type=positive_float, default=30.0, metavar="MHZ",
                   help="OPT8241 modulation frequency programmed into PLL 1 and PLL 2 (default "
                   "30, the paper's: unambiguous range c/2f = 5.0 m). TI's optimal band for "
                   "the board is 39-60 MHz (2.5-3.8 m): above 30 MHz the range is shorter "
                   "than the camera rules' 5 m and is refused (docs/hardware.md, 'Modulation "
                   "frequency')")
    a.add_argument("--no-overflow-check", action="store_true",
                   help="do not read the OPT9221's op_overflow flag after each sequence (a set "
                   "flag discards and repeats the sequence; that it fires only on an output "
                   "overrun is unconfirmed on a device: turn it off if it stops every run)")
    a.add_argument("--block", type=positive_int, default=None,
                   help=f"pattern pairs per block (default 12; {AUTO_BLOCK} with --auto, "
                   "which needs at least 4)")
    a.add_argument("--auto", action="store_true",
                   help="stop acquiring when new blocks of patterns no longer change the image "
                   "beyond the noise (torchtof.adaptive.ProgressiveStop on the gated buckets)")
    a.add_argument("--retries", type=nonneg_int, default=3,
                   help="retries of a sequence whose frames failed the checks")
    a.add_argument("--resume", action="store_true", help="continue an interrupted store")
    a.add_argument("--frame-ids", default="device", choices=["device", "count"],
                   help="device: OPT9221 frame numbers checked to be consecutive; count: host "
                   "numbering. Either way a sequence (<= 24 frames) is recorded only after all "
                   "its checks pass, so a kill loses at most the sequence in flight")
    a.add_argument("--no-progress", action="store_true", help="no progress bar")
    a.add_argument("--sim-faults", default=None, type=json_object,
                   help="JSON fault plan for the simulator (torchtof.hardware.simulated.Faults; "
                   "the fields and their values: docs/hardware.md)")
    a.add_argument("-o", "--output", required=True, help="zarr store (directory) to write")
    a.set_defaults(func=cmd_acquire, check=_check_acquire, parser=a)

    r = sub.add_parser("reconstruct", help="reconstruct an image from a recorded zarr store",
                       description="Reconstruct one image from a store written by `torchtof "
                       "acquire`; writes METHOD_KIND[_gate].pt (the tensor) and .png to OUT.")
    r.add_argument("store", metavar="STORE", help="zarr store written by `torchtof acquire`")
    r.add_argument("--method", type=_method, default="tval3",
                   help="reconstruction method (case-insensitive): "
                   f"{', '.join(_method_labels())}")
    r.add_argument("--kind", default="depth", choices=["depth", "intensity"],
                   help="buckets to reconstruct from")
    r.add_argument("--gate", action="store_true",
                   help="use the depth-gated buckets (--kind depth only)")
    r.add_argument("--out", default="reconstruct_out", help="folder of the .pt and .png")
    r.add_argument("--weights", default=None, metavar="FILE",
                   help="Learned and Auto only: a learned network's weights file (e.g. a "
                        "torchtof train run's OUT/learned.pt, trained on your own recordings "
                        "with --images); Learned reconstructs with it, Auto stacks it "
                        "(default: the shipped weights)")
    r.set_defaults(func=cmd_reconstruct, check=_check_reconstruct, parser=r)
