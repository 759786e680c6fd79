"""``torchtof train --model learned``: the command line of
:func:`torchtof.recon.learned_train.train_learned` (options, calibration-only runs)."""

from __future__ import annotations

import argparse
import functools
import json
import os
import shlex
import sys
import time
from pathlib import Path

import torch

from ..data import FAMILIES
from ..operators.hadamard import Hadamard
from ..operators.patterns import ORDERS
from ..recon.learned import (
    DEFAULT_N_LAYERS,
    DEFAULT_SCALES,
    DEFAULT_SHUFFLE,
    DEFAULT_WIDTH,
    WEIGHTS_FILE,
    X0_CHOICES,
    Learned,
)
from ..recon.learned_train import (
    NOISE_REF,
    P_NOISE_REF,
    atomic_write,
    calibrate_tau,
    read_checkpoint,
    train_learned,
    write_text,
)
from .args import nonneg_int, positive_float, positive_int, power_of_two, sampling_rate

__all__ = ["add_arguments", "main"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``torchtof train --model learned`` (defaults: the shipped run)."""
    d = " (default: %(default)s)"
    p.add_argument("--steps", type=positive_int, default=8000,
                   help="optimiser steps (--resume may change it: the schedule follows the new "
                        "steps from the resumed step on, recorded in recipe.json)" + d)
    p.add_argument("--batch-size", type=positive_int, default=12, help="global batch" + d)
    p.add_argument("--lr", type=positive_float, default=2e-3,
                   help="peak Adam learning rate" + d)
    p.add_argument("--seed", type=nonneg_int, default=0,
                   help="seed of every draw" + d)
    p.add_argument("--sizes", type=_size, nargs="+", default=[32, 64],
                   help=f"image sides, powers of two in [{MIN_SIZE}, 256]" + d)
    p.add_argument("--p-large", type=_probability, default=0.3,
                   help="probability of the largest size, in [0, 1]" + d)
    p.add_argument("--sr-range", type=sampling_rate, nargs=2, default=[0.0625, 0.5],
                   metavar=("LO", "HI"),
                   help="range of the sampling rate, in (0, 1]" + d)
    p.add_argument("--orders", nargs="+", default=list(ORDERS), choices=list(ORDERS),
                   metavar="ORDER",
                   help=f"Hadamard orders, from {', '.join(ORDERS)}" + d)
    p.add_argument("--n-layers", type=positive_int, default=DEFAULT_N_LAYERS,
                   help="unrolled steps K" + d)
    p.add_argument("--width", type=positive_int, default=DEFAULT_WIDTH,
                   help="channels of the prior" + d)
    p.add_argument("--shuffle", type=positive_int, default=DEFAULT_SHUFFLE,
                   help="pixel-unshuffle factor of the prior" + d)
    p.add_argument("--scales", type=_scales, default=DEFAULT_SCALES,
                   help="resolutions of the prior's U-Net, >= 2 (image sides divisible by "
                        "2^(SCALES-1)*SHUFFLE)" + d)
    p.add_argument("--x0", choices=list(X0_CHOICES), default=None,
                   help="the network's starting estimate: adjoint (A^T b) or markov (the "
                        "Gaussian-Markov completion) (default: adjoint; --calibrate-only: the "
                        "run's, from OUT/recipe.json)")
    p.add_argument("--noise-ref", type=nonneg_int, default=NOISE_REF,
                   help="scale the top Gaussian noise level by max(1, NOISE_REF/n); 0: the same "
                        "levels at every size" + d)
    p.add_argument("--p-noise-ref", type=_probability, default=P_NOISE_REF,
                   help="with --noise-ref, the probability that a noisy sample's level is drawn "
                        "from the scaled levels (else from the unscaled ones)" + d)
    p.add_argument("--p-clean", type=_probability, default=0.3,
                   help="probability of a noise-free training sample" + d)
    p.add_argument("--families", type=_family, nargs="+", default=None, metavar="NAME=P",
                   help="probabilities of the scene families, summing to 1, from "
                        f"{', '.join(FAMILIES)} (default: {_default_families()})")
    p.add_argument("--images", nargs="+", default=None, metavar="PATH",
                   help="your own scenes for the 'user' family, to adapt the network to your "
                        "domain (with --init shipped): image files (png, jpg, tif, bmp; grey "
                        "or RGB), .npy (a 2-D image or a 3-D stack), .npz, or folders of them; "
                        "each min-max normalised; random crops as for 'natural'. Without "
                        "--families: user=0.5 and the default mixture halved (default: none)")
    p.add_argument("--out", default="train_learned_out",
                   help="folder of checkpoint.pt, log.json, learned.pt, recipe.json" + d)
    p.add_argument("--checkpoint-every", type=nonneg_int, default=100,
                   help="steps between checkpoints, 0: only the final one (written when the run "
                        "ends or stops; --resume and --calibrate-only read it)" + d)
    p.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint.pt")
    p.add_argument("--init", type=_weights_file, default=None, metavar="WEIGHTS",
                   help="fine-tune from this weights file ('shipped': the package's own) "
                        "instead of a random start; give a smaller --lr and another --seed than "
                        "its run")
    p.add_argument("--log-every", type=positive_int, default=10,
                   help="steps between log records" + d)
    p.add_argument("--max-minutes", type=positive_float, default=None,
                   help="stop and save after this wall time (default: no limit)")
    p.add_argument("--device", default="cpu",
                   help="torch device the model trains on, e.g. cuda (under torchrun: "
                        "cuda:LOCAL_RANK); the data are drawn on the CPU" + d)
    p.add_argument("--workers", type=nonneg_int, default=0,
                   help="processes drawing the data ahead of the optimiser, 0: none (the same "
                        "run either way)" + d)
    p.add_argument("--no-progress", action="store_true", help="no tqdm progress bar")
    p.add_argument("--no-calibrate", action="store_true",
                   help="leave the final data-consistency step off (no calibrate_tau)")
    p.add_argument("--calibrate-only", action="store_true",
                   help="load OUT/checkpoint.pt, run calibrate_tau on the run's data recipe "
                        "(--seed, --sizes, --p-large, --sr-range, --orders, --noise-ref, "
                        "--p-noise-ref, --p-clean, and the scene mixture unless --families or "
                        "--images is given) and network (--n-layers/--width/--shuffle/--scales), "
                        "from OUT/recipe.json, else from the checkpoint (one of them given with "
                        "another value: a usage error), rewrite OUT/learned.pt and add the "
                        "calibration to OUT/recipe.json")


#: Smallest image side ``train_learned`` trains on.
MIN_SIZE = 8


def _size(text: str) -> int:
    """An image side of ``train_learned``: a power of two in ``[8, 256]`` (an argparse type)."""
    return power_of_two(text, lo=MIN_SIZE)


def _scales(text: str) -> int:
    """An int ``>= 2`` (an argparse type: the prior's resolutions)."""
    try:
        v = int(text)
    except ValueError:
        v = 0
    if v < 2:
        raise argparse.ArgumentTypeError(f"expected an int >= 2, got {text!r}")
    return v


def _probability(text: str) -> float:
    """A number in ``[0, 1]`` (an argparse type)."""
    try:
        v = float(text)
    except ValueError:
        v = float("nan")
    if not 0.0 <= v <= 1.0:
        raise argparse.ArgumentTypeError(f"expected a number in [0, 1], got {text!r}")
    return v


def _default_families() -> str:
    return " ".join(f"{k}={v:g}" for k, v in FAMILIES.items() if v > 0)


def _family(text: str) -> tuple[str, float]:
    """``NAME=P``: a family of :data:`torchtof.data.FAMILIES` and its probability in
    ``[0, 1]`` (an argparse type; the sum is checked with the other options)."""
    name, sep, value = text.partition("=")
    if not sep or name not in FAMILIES:
        raise argparse.ArgumentTypeError(
            f"expected NAME=P with NAME from {', '.join(FAMILIES)}, got {text!r}")
    return name, _probability(value)


def _weights_file(text: str) -> str:
    """An existing file, or ``shipped`` for the package's weights (an argparse type; the
    contents are checked when they load)."""
    if text == "shipped":
        return os.fspath(WEIGHTS_FILE)
    if not Path(text).is_file():
        raise argparse.ArgumentTypeError(f"no such weights file: {text!r}")
    return text


def main(args: argparse.Namespace) -> int:
    """Run :func:`train_learned` from parsed :func:`add_arguments` options."""
    command = shlex.join(["torchtof", *sys.argv[1:]]) if sys.argv else None
    if args.calibrate_only:
        return _calibrate_only(args, command)
    rank0 = int(os.environ.get("RANK", "0")) == 0  # under torchrun every process runs this
    if args.resume and rank0 and not (Path(args.out) / "checkpoint.pt").is_file():
        print(f"torchtof train: no {Path(args.out) / 'checkpoint.pt'} to resume: starting at "
              "step 0", file=sys.stderr)
    r = train_learned(
        steps=args.steps, batch_size=args.batch_size, lr=args.lr, seed=args.seed,
        sizes=tuple(args.sizes), p_large=args.p_large, sr_range=tuple(args.sr_range),
        orders=tuple(args.orders), n_layers=args.n_layers, width=args.width,
        shuffle=args.shuffle, scales=args.scales, noise_ref=args.noise_ref or None,
        p_clean=args.p_clean, p_noise_ref=args.p_noise_ref,
        out=args.out,
        checkpoint_every=args.checkpoint_every, resume=args.resume, log_every=args.log_every,
        progress=not args.no_progress, max_minutes=args.max_minutes,
        command=command, calibrate=not args.no_calibrate, device=args.device,
        workers=args.workers, init=args.init, x0=args.x0 or "adjoint",
        families=None if args.families is None else dict(args.families),
        user_images=args.images,
    )
    if int(os.environ.get("RANK", "0")) == 0:  # one line per run, not per torchrun process
        out = Path(args.out)
        print(f"wrote {out / 'learned.pt'}, {out / 'recipe.json'}, {out / 'log.json'}"
              + (f", {out / 'checkpoint.pt'}" if (out / "checkpoint.pt").is_file() else "")
              + f"; {len(r.losses)} steps in {r.wall_s:.0f} s")
    return 0


#: What ``--calibrate-only`` does not know about a run (neither recipe.json nor the
#: checkpoint records it): the option's value is used.
_UNKNOWN = object()


def _run_options(recipe: dict, state: dict) -> dict:
    """The run's value of each option ``--calibrate-only`` takes from it, in the options'
    form (``--noise-ref 0``: none): ``recipe.json``'s, else the checkpoint's records
    (``"meta"``: the network, ``"run"``: the data recipe), else :data:`_UNKNOWN`. ``None``:
    a setting without effect in that run (``--p-large`` with one size, ``--p-noise-ref``
    without ``--noise-ref``)."""
    meta, run = state.get("meta") or {}, state.get("run") or {}
    noise = (recipe.get("data") or {}).get("noise") or {}

    def pick(*sources):
        for src, key in sources:
            if key in src:
                return src[key]
        return _UNKNOWN

    values = {k: pick((recipe, k), (meta, k)) for k in ("n_layers", "width", "shuffle", "scales")}
    for k in ("seed", "sizes", "p_large", "sr_range", "orders"):
        values[k] = pick((recipe, k), (run, k))
    values["noise_ref"] = pick((noise, "levels_scaled_to_n"), (run, "noise_ref"))
    values["p_clean"] = pick((noise, "p_clean"), (run, "p_clean"))
    values["p_noise_ref"] = pick((noise, "p_levels_scaled"), (run, "p_noise_ref"))
    if values["noise_ref"] is None:
        values["noise_ref"] = 0  # the option's "none"
    if values["noise_ref"] == 0:
        values["p_noise_ref"] = None
    if values["sizes"] is not _UNKNOWN and len(values["sizes"]) == 1:
        values["p_large"] = None
    return values


def _option_value(key: str, v):
    """An option's value in the form the run records it (sorted sizes, lists, floats)."""
    if key == "sizes":
        return sorted(int(n) for n in v)
    if key in ("sr_range", "orders"):
        return [float(x) for x in v] if key == "sr_range" else list(v)
    if key in ("p_large", "p_clean", "p_noise_ref"):
        return None if v is None else float(v)
    return v


def _show(v) -> str:
    return " ".join(map(str, v)) if isinstance(v, list) else str(v)


def _calibrate_only(args: argparse.Namespace, command: str | None) -> int:
    """``--calibrate-only``: calibrate the run in ``OUT`` on its own data recipe and network
    (:func:`_run_options`); an option given with another value than the run's is a one-line
    usage error (``argument --x: ...``), except ``--families``/``--images``, which calibrate
    on another scene mixture (recorded as ``calibration_families``)."""
    out = Path(args.out)
    ckpt = out / "checkpoint.pt"
    state = read_checkpoint(ckpt, "torchtof train")
    recipe_path = out / "recipe.json"
    recipe = json.loads(recipe_path.read_text()) if recipe_path.is_file() else {}
    given = args.given  # the options on the command line (torchtof.cli)
    opts = {}
    for key, run in _run_options(recipe, state).items():
        value = _option_value(key, getattr(args, key))
        run = run if run is _UNKNOWN else _option_value(key, run)
        if key in given and run is not _UNKNOWN and run is not None and value != run:
            flag = "--" + key.replace("_", "-")
            raise ValueError(f"argument {flag}: the run in {out} was trained with {flag} "
                             f"{_show(run)}, got {_show(value)}")
        opts[key] = value if run is _UNKNOWN or run is None else run
    arch = {k: opts[k] for k in ("n_layers", "width", "shuffle", "scales")}
    sizes = tuple(opts["sizes"])
    noise_ref, p_noise_ref = opts["noise_ref"] or None, opts["p_noise_ref"]
    model = Learned(Hadamard(sizes[0], sr=0.25), pretrained=False, **arch)
    try:
        missing, unexpected = model.load_state_dict(state["model"], strict=False)
    except RuntimeError as exc:  # a size mismatch
        missing, unexpected = [], [str(exc).strip().splitlines()[-1].strip()]
    if unexpected or set(missing) - {"log_tau"}:
        flags = "/".join("--" + k.replace("_", "-") for k in arch)
        raise ValueError(f"argument {flags}: {ckpt} does not hold the network {arch}: "
                         f"missing {sorted(missing)}, unexpected {unexpected}")
    run_x0 = recipe.get("x0", state.get("x0", "adjoint"))
    if args.x0 is not None and args.x0 != run_x0:
        raise ValueError(f"argument --x0: the run in {out} was trained with --x0 {run_x0}, "
                         f"got {args.x0}")
    model.x0 = run_x0
    data = recipe.get("data") or state.get("data") or {}
    # the run's own mixture unless --families says otherwise
    families = dict(args.families) if args.families is not None else data.get("families")
    # ... and its own images unless --images says otherwise
    images = args.images or [r["path"] for r in data.get("user_images", [])]
    t0 = time.perf_counter()
    calib = calibrate_tau(model, opts["seed"], sizes=sizes, p_large=opts["p_large"],
                          sr_range=tuple(opts["sr_range"]), orders=tuple(opts["orders"]),
                          noise_ref=noise_ref, p_clean=opts["p_clean"], p_noise_ref=p_noise_ref,
                          families=families, user_images=images or None)
    recipe.update(final_step_calibration=calib, calibration_command=command,
                  calibration_families=families,
                  calibration_wall_s=round(time.perf_counter() - t0, 1))
    model.A = Hadamard(sizes[0], sr=0.25)
    atomic_write(out / "learned.pt", functools.partial(
        model.save_weights, seed=opts["seed"], steps=state["step"],
        torch_version=str(torch.__version__), noise_ref=noise_ref,
        p_noise_ref=p_noise_ref if noise_ref else None, p_clean=opts["p_clean"]))
    write_text(recipe_path, json.dumps(recipe, indent=1))
    print(f"tau = {calib['tau']}; wrote {out / 'learned.pt'}")
    return 0
