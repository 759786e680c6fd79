"""``torchtof train --model learned``: the command line of
:func:`torchtof.recon.learned_train.train_learned` (options, calibration-only runs)."""

from __future__ import annotations

import argparse
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
from ..recon.learned_train import NOISE_REF, P_NOISE_REF, calibrate_tau, train_learned
from .args import nonneg_int, positive_float, positive_int, power_of_two, sampling_rate

__all__ = ["add_arguments", "main"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``torchtof train --model learned`` (defaults: the shipped run)."""
    d = " (default: %(default)s)"
    p.add_argument("--steps", type=positive_int, default=8000, help="optimiser steps" + d)
    p.add_argument("--batch-size", type=positive_int, default=12, help="global batch" + d)
    p.add_argument("--lr", type=positive_float, default=2e-3,
                   help="peak Adam learning rate" + d)
    p.add_argument("--seed", type=nonneg_int, default=0, help="seed of every draw" + d)
    p.add_argument("--sizes", type=power_of_two, nargs="+", default=[32, 64],
                   help="image sides, powers of two in [4, 256]" + d)
    p.add_argument("--p-large", type=_probability, default=0.3,
                   help="probability of the largest size, in [0, 1]" + d)
    p.add_argument("--sr-range", type=sampling_rate, nargs=2, default=[0.0625, 0.5],
                   metavar=("LO", "HI"), help="range of the sampling rate, in (0, 1]" + d)
    p.add_argument("--orders", nargs="+", default=list(ORDERS), choices=list(ORDERS),
                   metavar="ORDER", help=f"Hadamard orders, from {', '.join(ORDERS)}" + d)
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
                   help="steps between checkpoints, 0: none" + d)
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
                   help="torch device the model trains on, e.g. cuda; the data are drawn on the "
                        "CPU" + d)
    p.add_argument("--workers", type=nonneg_int, default=0,
                   help="processes drawing the data ahead of the optimiser, 0: none (the same "
                        "run either way)" + d)
    p.add_argument("--no-progress", action="store_true", help="no tqdm progress bar")
    p.add_argument("--no-calibrate", action="store_true",
                   help="leave the final data-consistency step off (no calibrate_tau)")
    p.add_argument("--calibrate-only", action="store_true",
                   help="load OUT/checkpoint.pt, run calibrate_tau (on the run's scene mixture "
                        "from OUT/recipe.json unless --families is given; the network's "
                        "--n-layers/--width/--shuffle/--scales from it too), rewrite "
                        "OUT/learned.pt and add the calibration to OUT/recipe.json")


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
        out = Path(args.out)
        state = torch.load(out / "checkpoint.pt", weights_only=False)
        recipe_path = out / "recipe.json"
        recipe = json.loads(recipe_path.read_text()) if recipe_path.is_file() else {}
        # the run's network: an option left at its default takes the run's value
        arch = {}
        for key, default in (("n_layers", DEFAULT_N_LAYERS), ("width", DEFAULT_WIDTH),
                             ("shuffle", DEFAULT_SHUFFLE), ("scales", DEFAULT_SCALES)):
            given, run = getattr(args, key), recipe.get(key)
            if run is not None and given != run and given != default:
                flag = "--" + key.replace("_", "-")
                raise ValueError(f"argument {flag}: the run in {out} was trained with "
                                 f"{flag} {run}, got {given}")
            arch[key] = run if run is not None else given
        model = Learned(Hadamard(args.sizes[0], sr=0.25), pretrained=False, **arch)
        model.load_state_dict(state["model"], strict=False)
        run_x0 = recipe.get("x0", state.get("x0", "adjoint"))
        if args.x0 is not None and args.x0 != run_x0:
            raise ValueError(f"argument --x0: the run in {out} was trained with --x0 {run_x0}, "
                             f"got {args.x0}")
        model.x0 = run_x0
        # the run's own mixture unless --families says otherwise
        families = (dict(args.families) if args.families is not None
                    else recipe.get("data", {}).get("families"))
        # ... and its own images unless --images says otherwise
        images = args.images or [r["path"] for r in recipe.get("data", {}).get("user_images", [])]
        t0 = time.perf_counter()
        calib = calibrate_tau(model, args.seed, sizes=tuple(args.sizes), p_large=args.p_large,
                              sr_range=tuple(args.sr_range), orders=tuple(args.orders),
                              noise_ref=args.noise_ref or None, p_clean=args.p_clean,
                              p_noise_ref=args.p_noise_ref, families=families,
                              user_images=images or None)
        recipe.update(final_step_calibration=calib, calibration_command=command,
                      calibration_families=families,
                      calibration_wall_s=round(time.perf_counter() - t0, 1))
        model.A = Hadamard(args.sizes[0], sr=0.25)
        model.save_weights(out / "learned.pt", seed=args.seed, steps=state["step"],
                           torch_version=str(torch.__version__))
        recipe_path.write_text(json.dumps(recipe, indent=1))
        print(f"tau = {calib['tau']}; wrote {out / 'learned.pt'}")
        return 0
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
