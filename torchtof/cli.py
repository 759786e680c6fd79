"""``torchtof`` command line: ``demo``, ``bench``, ``reproduce``, ``export``, ``train``,
``acquire``, ``reconstruct``.

One error path: option values are checked by argparse types (and cross-option checks) before
any work is done; a mistake prints one line naming the option and exits with status 2
(``--debug`` prints the usage above it; for an error inside a command it shows the traceback).
Options are never abbreviated. Every command prints a one-line summary naming the files it
wrote.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import os
import sys
import threading
import time
from pathlib import Path

import torch

from ._checks import check_device
from .apps.args import (
    OneLineParser,
    check_patterns,
    csv_list,
    positive_float,
    positive_int,
    power_of_two,
    sampling_rate,
    scene_side,
)
from .apps.args import scene as _scene

__all__ = ["main", "build_parser"]

#: ``bench`` subcommands.
BENCHES = ("operators", "recon", "onnx", "tradeoff", "stability", "adaptive")


class _Formatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows every option's default (``(default: …)``), leaves ``None`` defaults unsaid."""

    def _get_help_string(self, action):
        if action.default is None or action.default is False:
            return action.help
        return super()._get_help_string(action)


class _Parser(OneLineParser):
    """The parser of ``torchtof`` and of every subcommand: an option mistake is one line
    (``torchtof demo: error: argument --n: …``) and exit status 2; ``--debug`` adds the usage.
    Options are never abbreviated (``--n`` must not silently mean ``--n-layers``)."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", _Formatter)
        super().__init__(*args, **kwargs)

    def parse_args(self, args=None, namespace=None):
        ns, extras = self.parse_known_args(args, namespace)
        if extras:  # reported by the subcommand that got them, with the option it resembles
            target = getattr(ns, "parser", None) or self
            word = extras[0].split("=")[0]
            longer = [o for a in target._actions for o in a.option_strings
                      if word.startswith("--") and o.startswith(word)]
            longer = [o for o in longer if o.startswith(word + "-")] or longer
            hint = (f" (options are not abbreviated: did you mean {' or '.join(longer)}?)"
                    if longer else "")
            target.error(f"unrecognized arguments: {' '.join(extras)}{hint}")
        return ns


def _methods() -> list[str]:
    from .methods import METHODS

    return list(METHODS)


def _default_methods() -> list[str]:
    from .methods import DEFAULT_METHODS

    return list(DEFAULT_METHODS)


def _check_experiment(args: argparse.Namespace) -> None:
    """``demo``'s options that do not go together, then its defaults: ``--depth`` takes its
    own scene and methods, ``--auto`` chooses the method and runs one realisation; ``--sr``
    and ``--n`` together give at least one pattern (each alone is checked by its type)."""
    if args.depth is not None:
        for flag, given in (("--scene", args.scene is not None),
                            ("--methods", args.methods is not None), ("--auto", args.auto)):
            if given:
                raise ValueError(f"argument {flag}: not used with --depth (its scene is "
                                 "--depth SCENE, its methods the depth-resolved ones)")
    if args.auto:
        if args.methods is not None:
            raise ValueError("argument --methods: not used with --auto (it chooses the method)")
        if args.realisations > 1:
            raise ValueError("argument --realisations: --auto runs one realisation (its noise "
                             "level comes from the DMD pair sums)")
    from .apps.auto_demo import AUTO_MAX_SR

    args.scene = args.scene or "sky"
    args.sr = args.sr if args.sr is not None else (AUTO_MAX_SR if args.auto else 0.125)
    check_patterns(args.n, args.sr)


# ---------------------------------------------------------------------------------------------
# commands
# ---------------------------------------------------------------------------------------------
def cmd_demo(args: argparse.Namespace) -> int:
    if args.depth:  # depth-resolved ghost imaging
        from .apps.depth_demo import run_depth_demo

        return run_depth_demo(args)
    if args.auto:  # scene-adaptive acquisition and reconstruction (torchtof.adaptive)
        from .apps.auto_demo import demo_auto

        return demo_auto(args)
    from .apps.demo import run_demo

    return run_demo(args)


def _bench_result(args: argparse.Namespace):
    name = args.which
    if name == "operators":
        from .apps.bench.operators import bench_operators, print_operators

        res = bench_operators(ns=tuple(args.n or (32, 64, 128, 256)), batch=args.batch,
                              sr=args.sr, progress=True)
        return res, print_operators
    if name == "recon":
        from .apps.bench.recon import bench_recon, print_recon

        return bench_recon(quick=args.quick, plot=args.plot, out=args.out), print_recon
    if name == "onnx":
        from .apps.bench.onnx import bench_onnx, print_onnx

        return (bench_onnx(models=args.models, compile=not args.no_compile, progress=True),
                print_onnx)
    if name == "tradeoff":
        from .apps.bench.tradeoff import bench_tradeoff, print_tradeoff

        return bench_tradeoff(quick=args.quick, out=args.out, json_path=args.json), print_tradeoff
    if name == "adaptive":
        from .apps.bench.adaptive import (
            bench_adaptive,
            bench_adaptive_seeds,
            parse_seeds,
            print_adaptive,
            print_adaptive_seeds,
        )

        kw = dict(realisations=args.realisations or (3 if args.quick else 6), progress=True)
        if args.signal_e is not None:
            kw["signal_e"] = args.signal_e
        if args.noise is not None:
            kw["pipeline"] = {"noise": args.noise}
        if args.seeds is not None:
            return bench_adaptive_seeds(parse_seeds(args.seeds), **kw), print_adaptive_seeds
        return bench_adaptive(seed=args.seed, **kw), print_adaptive
    from .apps.bench.stability import bench_stability, print_stability

    return bench_stability(progress=True), print_stability


def cmd_bench(args: argparse.Namespace) -> int:
    from .apps.bench.timing import machine_load

    t0, start = time.perf_counter(), machine_load()
    res, show = _bench_result(args)
    if isinstance(res, dict):  # seconds only mean something with the load they ran under
        res["machine"] = {"start": start, "end": machine_load()}
    show(res)
    own = res.get("json") if isinstance(res, dict) else None  # a bench's own JSON file
    path = Path(args.json or own or Path(args.out) / f"bench_{args.which}.json")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(res, indent=2, default=str))
    rows = res.get("rows") if isinstance(res, dict) else None
    count = f"{len(rows)} rows" if isinstance(rows, list) else "done"
    files = [str(path)] + [str(res[k]) for k in ("plot", "budget_table")
                           if isinstance(res, dict) and res.get(k)]
    if isinstance(res, dict) and res.get("json") and res["json"] != str(path):
        files.append(str(res["json"]))
    print(f"\ntorchtof bench {args.which}: {count} in {time.perf_counter() - t0:.1f} s; "
          f"wrote {', '.join(files)}")
    return 0


def cmd_reproduce(args: argparse.Namespace) -> int:
    from .apps.reproduce import reproduce

    reproduce(out=Path(args.out), quick=args.quick, realisations=args.realisations)
    return 0


@contextlib.contextmanager
def _elapsed_bar(desc: str, enabled: bool = True, interval_s: float = 0.25):
    """A tqdm bar on stderr with the elapsed time and a spinner for one long call that reports
    no progress itself (``torch.onnx.export``), redrawn by a background thread. No bar with
    ``enabled=False``, when stderr is not a terminal (tqdm's ``disable=None``) or without
    tqdm."""
    from ._optional import progress_bar

    bar = progress_bar(total=None, desc=desc, file=sys.stderr, leave=False,
                       bar_format="{desc} {elapsed}",
                       disable=None if enabled else True)
    stop = threading.Event()

    def spin() -> None:
        k, spinner = 0, "|/-\\"
        while not stop.wait(interval_s):
            k += 1
            bar.set_description_str(f"{desc} {spinner[k % 4]}")  # redraws with the time

    thread = threading.Thread(target=spin, daemon=True)
    if not getattr(bar, "disable", True):
        thread.start()
    try:
        yield bar
    finally:
        stop.set()
        if thread.is_alive():
            thread.join()
        bar.close()


def _size(nbytes: int) -> str:
    return f"{nbytes / 1e6:.1f} MB" if nbytes >= 1e6 else f"{nbytes / 1e3:.0f} kB"


def cmd_export(args: argparse.Namespace) -> int:
    from .apps import onnx_models

    t0 = time.perf_counter()
    path = args.output or Path(args.out) / f"{args.model}_n{args.n}_sr{args.sr:g}.onnx"
    what = f"{args.model} (n={args.n}, SR {args.sr:.2%})"
    if args.weights is not None:
        what = f"{args.model} from {args.weights} (n={args.n}, SR {args.sr:.2%})"
    with _elapsed_bar(f"torchtof export: tracing {what}", enabled=not args.no_progress):
        extra = {} if args.weights is None else {"weights": args.weights}
        res = onnx_models.export_checked(args.model, n=args.n, sr=args.sr, path=path,
                                         opset=args.opset, **extra)
    par = res["parity"]
    if par["ok"]:
        err = max(o["max_abs_err"] for o in par["outputs"])
        parity = f"matches PyTorch at batch 3 (max abs error {err:.1e})"
        judged = [o for o in par["outputs"] if "float64_err_ort" in o]
        if judged:  # passed only against the float64 run: say so
            e_t = max(o["float64_err_torch"] for o in judged)
            e_o = max(o["float64_err_ort"] for o in judged)
            parity += (f", float32 rounding: from a float64 run PyTorch is {e_t:.1e} off, "
                       f"onnxruntime {e_o:.1e}")
    else:
        parity = f"DIFFERS from PyTorch at batch 3: {par['error']}"
    print(f"torchtof export: {what} in {time.perf_counter() - t0:.1f} s; wrote {res['path']} "
          f"({_size(res['bytes'])}); onnxruntime {parity}")
    return 0 if par["ok"] else 1


def cmd_train(args: argparse.Namespace) -> int:
    from .apps.train import main as train_main  # options: apps.train.add_arguments

    return train_main(args)


# ---------------------------------------------------------------------------------------------
# parser
# ---------------------------------------------------------------------------------------------
def _export_models() -> list[str] | None:
    """Names of :data:`torchtof.apps.onnx_models.MODELS`; ``None`` without the onnx extra
    (``export`` then reports the missing extra when run)."""
    try:
        from .apps.onnx_models import MODELS
    except ImportError:
        return None
    return list(MODELS)


def build_parser() -> argparse.ArgumentParser:
    """The ``torchtof`` parser with every subcommand (the hardware ones included)."""
    p = _Parser(
        prog="torchtof",
        description="Depth imaging with a ToF camera as the bucket detector of computational "
        "ghost imaging: simulate the paper's experiment, reconstruct, benchmark, export to "
        "ONNX, acquire from the hardware. A mistake in an option prints one line and exits "
        "with status 2; --debug adds the usage (or the traceback of an error inside a command).")
    p.add_argument("--threads", type=positive_int, default=1,
                   help="torch intra-op threads for this run (the library itself keeps torch's "
                        "default; one thread is fastest for these problem sizes and does not "
                        "collapse on a busy machine, see README 'Threads')")
    p.add_argument("--debug", action="store_true",
                   help="an option mistake: print the usage above its line; an error inside a "
                        "command: show the Python traceback instead of one line")
    sub = p.add_subparsers(dest="cmd", required=True, metavar="COMMAND", parser_class=_Parser,
                           help="run `torchtof COMMAND --help` for its options")

    d = sub.add_parser("demo", help="reconstruct the paper's experiment (SR 12.5 %%) and plot it",
                       description="Simulate the paper's experiment and reconstruct it with "
                       "every method, without and with the 3 m depth gate.")
    d.add_argument("--sr", type=sampling_rate, default=None,
                   help="sampling rate M/n² of the Hadamard patterns, in (0, 1] (default: "
                        "0.125; with --auto the maximum the acquisition may reach, default "
                        "0.375)")
    d.add_argument("--scene", type=_scene, default=None,
                   help="scene: sky, steps, motorcycle, slanted, steps_far, skimage:<image>, "
                        "binary:<image> (default: sky)")
    d.add_argument("--n", type=scene_side, default=32,
                   help="DMD side in pixels (a power of two in [8, 256])")
    d.add_argument("--scattering", action="store_true",
                   help="image through the scattering sheet (paper Fig. 6)")
    d.add_argument("--realisations", type=positive_int, default=1,
                   help="noise realisations (PSNR mean ± std over them)")
    d.add_argument("--methods", type=csv_list(_methods()), default=None,
                   help=f"comma-separated subset of {','.join(_methods())} (default: "
                        f"{','.join(_default_methods())})")
    d.add_argument("--seed", type=int, default=0, help="random seed of the noise")
    d.add_argument("--out", default="demo_out", help="folder for the PNG and JSON")
    d.add_argument("--depth", nargs="?", const="motorcycle", default=None, metavar="SCENE",
                   type=_scene, help="depth-resolved GI from per-tap buckets on SCENE "
                   "(motorcycle when given without a value)")
    d.add_argument("--auto", action="store_true",
                   help="adaptive pipeline vs the fixed one (skip what the scene doesn't need)")
    d.set_defaults(func=cmd_demo, check=_check_experiment, parser=d)

    b = sub.add_parser("bench", help="benchmarks: " + ", ".join(BENCHES),
                       description="Run one benchmark, print its table and write its JSON.")
    b.add_argument("which", choices=BENCHES, help="the benchmark")
    b.add_argument("--n", type=power_of_two, nargs="+", default=None,
                   help="operators: DMD sides, powers of two in [4, 256] (default 32 64 128 256)")
    b.add_argument("--batch", type=positive_int, default=16, help="operators: batch size")
    b.add_argument("--sr", type=sampling_rate, default=0.25, help="operators: sampling rate")
    b.add_argument("--quick", action="store_true",
                   help="recon, tradeoff, adaptive: a smaller grid")
    b.add_argument("--plot", action="store_true", help="recon: also write recon.png")
    b.add_argument("--out", default="bench_out", help="folder for the JSON and PNGs")
    b.add_argument("--json", default=None,
                   help="write the result to this JSON file instead of OUT/bench_WHICH.json "
                        "(tradeoff: OUT/tradeoff.json)")
    models = _export_models()
    b.add_argument("--models", type=csv_list(models) if models else str, default=None,
                   help="onnx: comma-separated subset of the export models (default: all)")
    b.add_argument("--no-compile", action="store_true",
                   help="onnx: time onnxruntime and eager PyTorch only, not torch.compile")
    b.add_argument("--seed", type=int, default=0, help="adaptive: noise seed")
    b.add_argument("--seeds", default=None,
                   help="adaptive: several seeds, e.g. 0-5 or 0,3,7 (one table per seed)")
    b.add_argument("--signal-e", type=positive_float, default=None,
                   help="adaptive: signal electrons (the paper's set-up: 400; 4000 = 10x light)")
    b.add_argument("--noise", choices=["repeat", "pairs"], default=None,
                   help="adaptive: noise estimate of the adaptive pipeline (default: "
                        "run_adaptive's)")
    b.add_argument("--realisations", type=positive_int, default=None,
                   help="adaptive: noise realisations per scene (default 6, --quick 3; the "
                        "empty field 4x)")
    b.set_defaults(func=cmd_bench, check=_check_bench, parser=b)

    r = sub.add_parser("reproduce", help="regenerate the paper's figures and PSNR table",
                       description="Regenerate the paper's figures, PSNR table and claims.")
    r.add_argument("--out", default="reproduce_out", help="folder for the figures and tables")
    r.add_argument("--quick", action="store_true",
                   help="the PSNR table with 2 realisations and 100 DIP steps (instead of 5 "
                        "and the full schedule); the depth curves with 1 realisation on one "
                        "scene, SR 6.25-25 %%, multipath on (instead of 3, every scene and SR, "
                        "multipath on and off)")
    r.add_argument("--realisations", type=positive_int, default=None,
                   help="noise realisations per case, for the PSNR table and the depth curves "
                        "alike (default 5 and 3; --quick 2 and 1)")
    r.set_defaults(func=cmd_reproduce)

    e = sub.add_parser("export", help="export a model to ONNX (needs torchtof[onnx])",
                       description="Export a registered model with realistic example inputs to "
                       "ONNX (dynamic batch axis, validated by onnx.checker).")
    models = _export_models()
    e.add_argument("model", choices=models, metavar="MODEL",
                   help="one of " + ", ".join(models) if models else "a model name (needs the "
                   "onnx extra: pip install 'torchtof[onnx]')")
    e.add_argument("--n", type=power_of_two, default=32,
                   help="DMD side (a power of two in [4, 256])")
    e.add_argument("--sr", type=sampling_rate, default=0.25, help="sampling rate M/n²")
    e.add_argument("--opset", type=int, choices=[17, 18], default=18, help="ONNX opset")
    e.add_argument("--out", default="export_out", help="folder of the .onnx file")
    e.add_argument("-o", "--output", default=None,
                   help="the .onnx file (default OUT/MODEL_nN_srSR.onnx)")
    e.add_argument("--no-progress", action="store_true",
                   help="no elapsed-time bar on stderr during the export (none is drawn when "
                        "stderr is not a terminal either)")
    e.add_argument("--weights", default=None, metavar="FILE",
                   help="learned only: export this weights file's network (e.g. a torchtof "
                        "train run's OUT/learned.pt) instead of the shipped one")
    e.set_defaults(func=cmd_export, check=_check_export, parser=e)

    t = sub.add_parser("train", help="train the learned reconstructor (weights + recipe.json)",
                       description="Train torchtof.recon.Learned on synthetic scenes; writes "
                       "OUT/checkpoint.pt, log.json, learned.pt and recipe.json.")
    t.add_argument("--model", choices=["learned"], default="learned", help="the model to train")
    from .apps.train import add_arguments as add_train_arguments

    add_train_arguments(t)
    t.set_defaults(func=cmd_train, check=_check_train, parser=t)

    from .hardware.cli import add_parsers as add_hardware_parsers  # acquire, reconstruct

    add_hardware_parsers(sub)
    for sp in sub.choices.values():
        sp.set_defaults(parser=sp)  # the subcommand that reports its own mistakes
    return p


#: The options of ``train`` that only a training run uses: ``--calibrate-only`` refuses them.
TRAIN_ONLY_OPTIONS = ("steps", "batch_size", "lr", "checkpoint_every", "resume", "init",
                      "log_every", "max_minutes", "device", "workers", "no_calibrate")


def _check_train(args: argparse.Namespace) -> None:
    lo, hi = args.sr_range
    if lo > hi:
        raise ValueError(f"argument --sr-range: expected LO <= HI, got {lo:g} {hi:g}")
    if args.families is not None:
        from .data import check_families

        names = [k for k, _ in args.families]
        if len(set(names)) != len(names):
            raise ValueError(f"argument --families: a family named twice: {' '.join(names)}")
        try:
            check_families(dict(args.families), "train")
        except ValueError as exc:
            raise ValueError(f"argument --families: {exc}") from None
    if args.calibrate_only:  # a training option would be silently ignored
        for dest in TRAIN_ONLY_OPTIONS:
            if dest in args.given:
                flag = "--" + dest.replace("_", "-")
                raise ValueError(f"argument {flag}: a training option, not used with "
                                 "--calibrate-only (which calibrates a finished run)")
    else:
        from .recon.learned import prior_multiple

        step = prior_multiple(args.scales, args.shuffle)
        bad = [n for n in args.sizes if n % step]
        if bad:
            raise ValueError(f"argument --sizes: with --scales {args.scales} and --shuffle "
                             f"{args.shuffle} every size must be divisible by "
                             f"2^(scales-1)·shuffle = {step}, got {' '.join(map(str, bad))}")
    ckpt = Path(args.out) / "checkpoint.pt"
    if not args.calibrate_only and not args.resume and ckpt.is_file():
        raise ValueError(f"argument --out: {args.out} holds a training run ({ckpt.name}); pass "
                         "--resume to continue it, or another --out")
    if args.calibrate_only and not ckpt.is_file():
        raise ValueError(f"argument --calibrate-only: no {ckpt}")
    if not args.calibrate_only or args.images:
        from .recon.learned_train import check_user_paths, user_mixture

        try:
            paths = check_user_paths(args.images, "train")
        except (TypeError, OSError, ValueError) as exc:  # OSError: an unreadable image
            raise ValueError(f"argument --images: {_one_line(exc)}") from None
        try:
            user_mixture(None if args.families is None else dict(args.families), paths, "train")
        except ValueError as exc:
            flag = "--images" if args.images else "--families"
            raise ValueError(f"argument {flag}: {exc} (give --images with user=P in "
                             "--families, or --images alone)") from None
    check_device(args.device, "the device", "argument --device")


def _check_export(args: argparse.Namespace) -> None:
    check_patterns(args.n, args.sr)
    if args.weights is not None:
        if args.model != "learned":
            raise ValueError(f"argument --weights: only the learned model loads a weights file, "
                             f"got {args.model}")
        from .recon.learned import check_weights_file

        check_weights_file(args.weights, "argument --weights")


#: The options of ``bench`` that only some benchmarks use (the others are common to all).
BENCH_OPTIONS: dict[str, tuple[str, ...]] = {
    "n": ("operators",), "batch": ("operators",), "sr": ("operators",),
    "quick": ("recon", "tradeoff", "adaptive"), "plot": ("recon",),
    "models": ("onnx",), "no_compile": ("onnx",),
    "seed": ("adaptive",), "seeds": ("adaptive",), "signal_e": ("adaptive",),
    "noise": ("adaptive",), "realisations": ("adaptive",),
}


def _check_bench(args: argparse.Namespace) -> None:
    for dest, which in BENCH_OPTIONS.items():  # an option the benchmark would ignore
        if args.which not in which and dest in args.given:
            flag = "--" + dest.replace("_", "-")
            raise ValueError(f"argument {flag}: used by bench {' / '.join(which)} only, "
                             f"not by bench {args.which}")
    if args.which == "operators":
        for n in args.n or (32,):
            check_patterns(n, args.sr)
    if args.which == "adaptive" and args.seeds is not None:
        if "seed" in args.given:  # --seeds replaces it
            raise ValueError("argument --seed: not used with --seeds (give the seeds there)")
        from .apps.bench.adaptive import parse_seeds

        try:
            parse_seeds(args.seeds)
        except ValueError as exc:
            raise ValueError(f"argument --seeds: {exc}") from None


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


class _Unset(list):
    """The value every option starts from in ``_given_options`` (a list, so that ``append``
    actions can copy and extend it)."""


def _given_options(sub: argparse.ArgumentParser, tokens: list[str]) -> set[str]:
    """The destinations of the options written in ``tokens`` (the command's own, after its
    name), whatever their value: an option given at its default value (``--steps 8000``)
    counts as given. They have already parsed, so this second parse cannot fail."""
    dests = {a.dest for a in sub._actions if a.dest != argparse.SUPPRESS}
    ns = argparse.Namespace(**{d: _Unset() for d in dests})
    sub.parse_known_args(tokens, namespace=ns)
    return {d for d in dests if not (isinstance(getattr(ns, d), _Unset) and not getattr(ns, d))}


def _check_global_options(parser: argparse.ArgumentParser, argv: list[str]) -> int:
    """Name an unknown option given before the command (``torchtof --thr 2 demo``) instead of
    argparse's reading of its value as the command; returns the command's index in ``argv``."""
    takes_value = {"--threads"}
    known = takes_value | {"--debug", "-h", "--help"}
    i = 0
    while i < len(argv) and argv[i].startswith("-"):
        name = argv[i].split("=", 1)[0]
        if name not in known:
            parser.error(f"unrecognized arguments: {argv[i]} (the options before the command: "
                         "--threads, --debug)")
        i += 2 if name in takes_value and "=" not in argv[i] else 1
    return i


def _check_destination(parser, flag: str, path: str, folder: bool | None,
                       make: bool = False) -> None:
    """Before any work: ``path`` (a folder to write into, a file to write, ``None``: the
    command checks the path itself) must not be the other kind, its nearest existing
    ancestor must be a folder; with ``make`` (after every option check passed) the folder (a
    file's parent) is made now (``mkdir`` would fail after the whole run otherwise)."""
    p = Path(path)
    if folder is not None and p.exists() and p.is_dir() != folder:
        parser.error(f"argument {flag}: expected {'a folder' if folder else 'a file path'}, "
                     f"{path} is {'a file' if p.is_file() else 'a folder'}")
    for up in p.parents:
        if up.exists():
            if not up.is_dir():
                parser.error(f"argument {flag}: expected a path under a folder, {up} is a file")
            break
    if folder is None or not make:  # acquire makes its store itself
        return
    try:  # made now: a folder that cannot be made is a usage error before the work
        (p if folder else p.parent).mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        parser.error(f"argument {flag}: cannot make the folder "
                     f"{os.fspath(p if folder else p.parent)!r}: {exc.strerror or exc}")


def _check_destinations(args: argparse.Namespace, make: bool = False) -> None:
    """Every command's ``--out`` is a folder it writes into, unless a file option replaces it
    (``export -o``, ``bench --json``: files); ``acquire -o`` is a zarr store (a folder).
    ``make``: also make the folders (once the other checks passed)."""
    out, output = getattr(args, "out", None), getattr(args, "output", None)
    store = getattr(args, "cmd", None) == "acquire"
    files = {"-o/--output": None if store else output, "--json": getattr(args, "json", None)}
    if isinstance(out, str) and not any(files.values()):
        _check_destination(args.parser, "--out", out, folder=True, make=make)
    if store and isinstance(output, str):  # acquire names an existing non-store itself
        _check_destination(args.parser, "-o/--output", output, folder=None)
    for flag, path in files.items():
        if isinstance(path, str):
            _check_destination(args.parser, flag, path, folder=False, make=make)


def main(argv: list[str] | None = None) -> int:
    """Run ``torchtof ARGV``; returns the exit status (2 for a usage mistake)."""
    parser = build_parser()
    given = list(sys.argv[1:] if argv is None else argv)
    OneLineParser.debug = "--debug" in given
    command = _check_global_options(parser, given)
    args = parser.parse_args(argv)
    _check_destinations(args)
    args.given = _given_options(args.parser, given[command + 1:])
    check = getattr(args, "check", None)
    if check is not None:  # cross-option checks, before any work
        try:
            check(args)
        except ValueError as exc:
            if args.debug:
                raise
            args.parser.error(_one_line(exc))
    _check_destinations(args, make=True)
    # The library keeps torch's default thread count; the CLI sets --threads (default 1): the
    # problems are small (32–128 px images, ≤ 1k patterns), and OpenMP spin-waiting on a
    # loaded machine makes two threads many times slower than one (README 'Threads').
    torch.set_num_threads(args.threads)
    logging.getLogger("torch.onnx._internal.exporter._registration").setLevel(logging.ERROR)
    try:
        return args.func(args)
    except (ValueError, TypeError, FileNotFoundError, NotADirectoryError, ImportError) as exc:
        if args.debug:
            raise
        print(f"torchtof {args.cmd}: error: {_one_line(exc)} (--debug shows the traceback)",
              file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
