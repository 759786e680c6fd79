"""Training of the learned reconstructor (:class:`~torchtof.recon.learned.Learned`).

Each step draws one operator for the whole global batch, from a generator seeded by
``(seed, step)``: ``n`` from ``sizes`` (the largest with probability ``p_large``), the
sampling rate uniform in ``sr_range`` and the Hadamard order uniform over ``orders``; then
``batch_size`` procedural scenes (:func:`torchtof.data.draw_scenes`) and their noise
(:func:`torchtof.data.training_noise`, :func:`torchtof.data.noisy_buckets`), each from its
own generator seeded by ``(seed, step, index)``. The loss is the negative mean PSNR of the
reconstructions against the clean scenes (:func:`psnr_loss`: ``10 log10`` of each sample's
mean squared error, so that a noisy sample's large error does not drown the clean ones);
Adam (Kingma & Ba, 2015) with a cosine decay of the
learning rate (Loshchilov & Hutter, 2017) to 5 % of its peak and gradient-norm clipping at 1.

Data parallel under ``torchrun`` exactly as :func:`torchtof.recon.train_unrolled` (same
set-up, :func:`torchtof.recon.train.dist_setup`): rank ``r`` of ``W`` draws scenes
``[r B/W, (r+1) B/W)`` of the same global batch, and DDP averages the gradients. The model
trains on ``device`` (e.g. a GPU; the data are drawn on the CPU and moved there), and
``workers`` processes can draw the steps' data ahead of the optimiser (at most two steps per
process in flight): since each step's data depend only on ``(seed, step, index)``, the run
is the same with or without them.

The final data-consistency step of :class:`Learned` is off while the prior trains; its one
scalar ``τ`` is then set by :func:`calibrate_tau`: a grid search of the mean PSNR on batches
of the same recipe at steps ``10⁶ …`` (never drawn by a run of fewer steps, and disjoint
from the evaluation seeds).

Outputs in ``out``: ``checkpoint.pt`` (model, optimiser, scheduler, step, the run's settings
and per-step losses; written every ``checkpoint_every`` steps and when the run ends or stops,
``resume=True`` continues from it with the same settings, so that the resumed run writes
the log records and ``final_loss`` of the uninterrupted one), ``log.json`` (one record per
logged step), and at the end ``learned.pt`` (:meth:`Learned.save_weights`) with
``recipe.json`` (the command, seed, data recipe, torch version, wall time and load). Every
file is written to a temporary file, flushed to disk and renamed over the old one.

Under ``torchrun`` with ``device="cuda"`` (no index) each process trains on
``cuda:LOCAL_RANK`` (:func:`rank_device`), and a ``max_minutes`` stop is decided by the
ranks together (:func:`stop_after_step`).

Command line: ``torchtof train --model learned`` (:func:`add_arguments`, :func:`main`).
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
import os
import sys
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch
import torch.distributed as dist
from torch import nn

from .._checks import built_for_cache, check_device, check_in_range, check_int, check_positive
from ..data import (
    FAMILIES,
    TRAIN_IMAGES,
    TRAIN_LEVELS,
    check_families,
    draw_scenes,
    image_files,
    load_images,
    noisy_buckets,
    training_noise,
)
from ..operators.hadamard import Hadamard
from ..operators.patterns import N_MAX, ORDERS
from .learned import (
    DEFAULT_N_LAYERS,
    DEFAULT_SCALES,
    DEFAULT_SHUFFLE,
    DEFAULT_WIDTH,
    Learned,
    check_x0,
)
from .train import dist_setup

__all__ = [
    "train_learned",
    "LearnedTrainResult",
    "step_config",
    "psnr_loss",
    "calibrate_tau",
    "TAU_GRID",
    "noise_levels",
]

#: Grid of ``τ`` searched by :func:`calibrate_tau`.
TAU_GRID = (0.02, 0.03, 0.05, 0.07, 0.1, 0.14, 0.2, 0.3, 0.5)
#: First step of the calibration batches (beyond any training run).
CALIBRATION_STEP0 = 1_000_000
#: Default probability of a noise-free sample (:func:`~torchtof.data.training_noise`; the
#: shipped run's).
P_CLEAN = 0.3
#: Default size the top noise level is scaled to (:func:`noise_levels`) and the probability
#: that a sample draws its level from the scaled range (the shipped run's).
NOISE_REF = 128
P_NOISE_REF = 0.5


class LearnedTrainResult(NamedTuple):
    """What :func:`train_learned` returns: the model (not DDP-wrapped), the per-step losses
    of this run (from the resumed step on) and the wall time in seconds."""

    model: Learned
    losses: list[float]
    wall_s: float


#: Probability of the ``"user"`` family when a run gets its own images but no ``families``
#: (the rest: the shipped mixture, scaled).
P_USER = 0.5


@functools.lru_cache(maxsize=4)
@built_for_cache
def _user_images(paths: tuple[str, ...]) -> tuple[torch.Tensor, ...]:
    """The images of ``paths`` (:func:`torchtof.data.load_images`), read once per process: a
    run draws from the images as they were when it (or its data process) first read them.
    :func:`train_learned` and :func:`calibrate_tau` clear this cache when they start, so a
    later run in the same process reads the files again."""
    return load_images(list(paths), "train_learned") if paths else ()


def user_image_record(paths: tuple[str, ...]) -> list[dict]:
    """What ``recipe.json`` records of a run's own images: each file's path, SHA-256 and the
    number of images in it (a folder is listed file by file)."""
    out = []
    for p in paths:
        for f in image_files(Path(p), "train_learned"):
            out.append({"path": os.fspath(f.resolve()),
                        "sha256": hashlib.sha256(f.read_bytes()).hexdigest(),
                        "images": len(load_images(f, "train_learned"))})
    return out


def user_mixture(families: dict[str, float] | None, user_paths: tuple[str, ...],
                 func: str) -> dict[str, float]:
    """The checked family probabilities of a run: ``families``, or with images and no
    ``families`` the shipped mixture scaled by ``1 − P_USER`` and ``user`` at ``P_USER``; the
    ``"user"`` family needs images and images need the family."""
    if families is None:
        if not user_paths:
            return FAMILIES
        families = {k: v * (1 - P_USER) for k, v in FAMILIES.items() if v > 0}
        families["user"] = P_USER
    families = check_families(families, func)
    if families.get("user", 0) > 0 and not user_paths:
        raise ValueError(f"{func}: expected user_images for families['user'] = "
                         f"{families['user']:g}, got none")
    if user_paths and not families.get("user", 0) > 0:
        raise ValueError(f"{func}: expected families['user'] > 0 with user_images, got "
                         f"{families.get('user', 0):g}")
    return families


def _resumed_data(run: dict | None, given: tuple, families: dict, user_paths: tuple,
                  ckpt: Path, func: str) -> tuple[dict, tuple[str, ...]]:
    """The scene mixture and images a resumed run continues with: the checkpoint's own
    (``run``, recorded since user images exist) when the call names neither images nor
    families, else the call's, which must be the same (another mixture is a fine-tune:
    ``init``); the images' contents must not have changed (SHA-256)."""
    if run is None:  # a checkpoint from before the record: the call's (as before)
        return families, user_paths
    adopted = given == (None, None)
    if adopted:
        families = run["families"]
        user_paths = tuple(dict.fromkeys(r["path"] for r in run["user_images"]))  # each once
    same = (sorted(r["sha256"] for r in user_image_record(user_paths))
            == sorted(r["sha256"] for r in run["user_images"]))
    if not adopted and (not same_mixture(families, run["families"]) or not same):
        raise ValueError(f"{func}: checkpoint {ckpt} was trained on families="
                         f"{run['families']} with {len(run['user_images'])} image file(s); "
                         "resume with the same (or give neither families nor user_images to "
                         "continue with the run's own); another mixture is a fine-tune (init)")
    if not same:
        raise ValueError(f"{func}: the run's images changed since checkpoint {ckpt} was "
                         "written (SHA-256 differ); restore them or start a new run")
    return families, user_paths


def same_mixture(a: dict[str, float], b: dict[str, float]) -> bool:
    """Whether two family mixtures draw the same scenes: the same probabilities of the
    families drawn at all (a zero entry, e.g. :data:`~torchtof.data.FAMILIES`' ``leaves`` and
    ``user``, is the family left out)."""
    return ({k: v for k, v in a.items() if v > 0} == {k: v for k, v in b.items() if v > 0})


def read_checkpoint(ckpt: Path, func: str, device="cpu") -> dict:
    """The state of a :func:`train_learned` checkpoint file; a one-line ``ValueError`` naming
    ``func`` for a file that is unreadable (truncated, another format) or is no such
    checkpoint (e.g. a weights file)."""
    try:
        state = torch.load(ckpt, weights_only=False, map_location=device)
    except Exception as exc:  # noqa: BLE001 - any unpickling failure: not a checkpoint
        raise ValueError(f"{func}: {ckpt} is not a readable training checkpoint "
                         f"({type(exc).__name__}); delete it to start the run anew") from None
    need = ("model", "opt", "sched", "step", "log", "wall_s")
    lacks = [k for k in need if k not in state] if isinstance(state, dict) else list(need)
    if lacks:
        raise ValueError(f"{func}: {ckpt} is not a training checkpoint of train_learned "
                         f"(no {', '.join(lacks)}); delete it to start the run anew")
    return state


def run_settings(seed: int, steps: int, lr: float, batch_size: int, sizes: tuple[int, ...],
                 p_large: float, sr_range: tuple[float, float], orders: tuple[str, ...],
                 noise_ref: int | None, p_clean: float, p_noise_ref: float) -> dict:
    """The settings of a run that ``checkpoint.pt`` records (key ``"run"``): a resume must
    repeat every one but ``steps`` (:func:`check_run_settings`), since the draws and the
    optimiser depend on them. A setting without effect is recorded as ``None``: ``p_large``
    with one size, ``p_noise_ref`` without ``noise_ref``.

    Example:
        >>> run_settings(0, 10, 2e-3, 4, (16,), 0.3, (0.1, 0.5), ("natural",), None, 0.3,
        ...              0.5)["p_large"] is None
        True
    """
    return {"seed": int(seed), "steps": int(steps), "lr": float(lr),
            "batch_size": int(batch_size), "sizes": [int(n) for n in sorted(sizes)],
            "p_large": float(p_large) if len(sizes) > 1 else None,
            "sr_range": [float(v) for v in sr_range], "orders": list(orders),
            "noise_ref": noise_ref, "p_clean": float(p_clean),
            "p_noise_ref": float(p_noise_ref) if noise_ref else None}


def check_run_settings(have: dict | None, want: dict, ckpt: os.PathLike, func: str) -> None:
    """``ValueError`` naming every setting (:func:`run_settings`) but ``steps`` in which a
    resumed call differs from the run of checkpoint ``ckpt`` (``have``; ``None`` or a missing
    key, a checkpoint from before the record: not compared). ``steps`` may change (extend or
    shorten a run, not below the checkpoint's step): :func:`train_learned` records it."""
    if not have:
        return
    diff = [f"{k}={have[k]!r} (got {v!r})" for k, v in want.items()
            if k != "steps" and k in have and have[k] != v]
    if diff:
        raise ValueError(f"{func}: checkpoint {os.fspath(ckpt)} was written by a run with "
                         f"other settings: {', '.join(diff)}; a resume repeats the run's "
                         "settings; another recipe is a new run (another out), or a fine-tune "
                         "(init)")


def stop_after_step(t0: float, max_minutes: float | None, is_dist: bool,
                    device: torch.device | str = "cpu") -> bool:
    """Whether a run started at ``t0`` (``time.perf_counter()``) stops after this step for
    ``max_minutes``. Under DDP (``is_dist``) the decision is the ranks' together (an
    all-reduce MAX of every rank's flag: one collective per step), so that every rank stops
    after the same step: rank 0 writes the checkpoints and would otherwise wait at a
    collective the others never reach. ``max_minutes = None``: never, and no collective."""
    if max_minutes is None:
        return False
    late = time.perf_counter() - t0 > 60 * max_minutes
    if not is_dist:
        return late
    flag = torch.tensor(float(late), device=device)
    dist.all_reduce(flag, op=dist.ReduceOp.MAX)
    return bool(flag.item())


def rank_device(device, distributed: bool | None = None):
    """The device this process trains on: under ``torchrun`` (``LOCAL_RANK`` set and
    ``distributed`` not ``False``) a CUDA device given without an index is
    ``cuda:LOCAL_RANK``, so that the processes of a node use one GPU each; else ``device``.

    Example:
        >>> rank_device("cpu", True)
        'cpu'
    """
    local = os.environ.get("LOCAL_RANK")
    if distributed is False or local is None:
        return device
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError):
        return device  # check_device names it
    if dev.type == "cuda" and dev.index is None:
        return torch.device("cuda", int(local))
    return device


def atomic_write(path: Path, write) -> None:
    """Write ``path`` through ``write(tmp_path)`` into a temporary file beside it, flushed to
    disk (``os.fsync``) and renamed over ``path``: a crash leaves the old file or the new one,
    never a torn one."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    write(tmp)
    with open(tmp, "rb+") as f:
        os.fsync(f.fileno())
    tmp.replace(path)


def write_text(path: Path, text: str) -> None:
    """``path.write_text(text)`` through :func:`atomic_write`."""
    atomic_write(path, lambda tmp: Path(tmp).write_text(text))


def check_user_paths(user_images, func: str) -> tuple[str, ...]:
    """``user_images`` (``None``, a path or paths) as absolute path strings, every image read
    once here so that a bad file fails before training (``TypeError``/``ValueError``)."""
    if user_images is None:
        return ()
    if isinstance(user_images, (str, os.PathLike)):
        user_images = [user_images]
    if not isinstance(user_images, (list, tuple)) or not user_images or not all(
            isinstance(p, (str, os.PathLike)) for p in user_images):
        raise TypeError(f"{func}: expected user_images to be None, a path or a non-empty list "
                        f"of paths, got {user_images!r}")
    paths = tuple(os.fspath(Path(p).resolve()) for p in user_images)
    load_images(list(paths), func)
    return paths


#: Floor of the per-sample MSE inside :func:`psnr_loss` (PSNR 60 dB on [0, 1]).
MSE_FLOOR = 1e-6


def psnr_loss(x_hat: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """``mean_i 10 log10(MSE_i + MSE_FLOOR)``: the negative mean PSNR (peak 1, paper Eqs.
    13–14 without quantisation) over the samples of a batch ``(B, C, n, n)``."""
    mse = ((x_hat - x) ** 2).mean(dim=(-3, -2, -1))
    return 10 * torch.log10(mse + MSE_FLOOR).mean()


def _seq(*ints: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([int(i) for i in ints]))


def step_config(
    seed: int,
    step: int,
    sizes: tuple[int, ...],
    p_large: float,
    sr_range: tuple[float, float],
    orders: tuple[str, ...],
) -> tuple[int, int, str]:
    """``(n, m, order)`` of the operator of ``step`` (the same on every rank).

    Example:
        >>> step_config(0, 3, (32, 64), 0.3, (0.0625, 0.5), ("cake_cutting",))[2]
        'cake_cutting'
    """
    r = _seq(seed, step, 2)
    if len(sizes) == 1:
        n = sizes[0]
    elif r.random() < p_large:
        n = sizes[-1]
    else:
        n = sizes[int(r.integers(0, len(sizes) - 1))]
    sr = r.uniform(*sr_range)
    m = max(1, min(n * n, int(round(sr * n * n))))
    return n, m, orders[int(r.integers(0, len(orders)))]


def noise_levels(n: int, noise_ref: int | None = None) -> tuple[float, float]:
    """The Gaussian levels drawn at size ``n``: :data:`~torchtof.data.TRAIN_LEVELS` with the
    upper end multiplied by ``max(1, noise_ref / n)``.

    The level is a fraction of the spread of ``y``, which grows like ``n·mean(x)`` (the first
    Hadamard row is the sum of the scene over ``n``), while the per-pixel noise of ``Aᵀy`` is
    ``σ·√SR``: the same level is ``n/n'`` times more noise in the image at size ``n`` than at
    ``n'``. ``noise_ref = None``: the same levels at every size.

    Example:
        >>> noise_levels(32, 128)
        (0.002, 0.24)
    """
    lo, hi = TRAIN_LEVELS
    if noise_ref is None:
        return lo, hi
    return lo, hi * max(1.0, noise_ref / n)


def _recipes(seed: int, step: int, n: int, indices: range, noise_ref: int | None = None,
             p_clean: float = P_CLEAN, p_noise_ref: float = 1.0):
    """Each sample's noise generator and :class:`~torchtof.data.NoiseRecipe`.

    With ``noise_ref``, sample ``i`` draws its Gaussian level from ``noise_levels(n,
    noise_ref)`` with probability ``p_noise_ref`` (a uniform number from its own stream
    ``(seed, step, i, 3)``) and from ``noise_levels(n)`` otherwise; ``p_noise_ref = 1`` (every
    sample scaled) draws nothing extra, so runs before the option reproduce."""
    gens = [torch.Generator().manual_seed(int(_seq(seed, step, i, 1).integers(0, 2**62)))
            for i in indices]
    scaled, plain = noise_levels(n, noise_ref), noise_levels(n)
    recipes = []
    for i, g in zip(indices, gens, strict=True):
        use = p_noise_ref >= 1 or _seq(seed, step, i, 3).random() < p_noise_ref
        recipes.append(training_noise(g, p_clean=p_clean, levels=scaled if use else plain))
    return gens, recipes


def _batch(seed: int, step: int, n: int, m: int, order: str, indices: range,
           noise_ref: int | None = None, p_clean: float = P_CLEAN, p_noise_ref: float = 1.0,
           families: dict[str, float] | None = None, user_paths: tuple[str, ...] = ()):
    x = draw_scenes(n, seed, step, indices, images=TRAIN_IMAGES, families=families,
                    user_images=_user_images(user_paths))
    gens, recipes = _recipes(seed, step, n, indices, noise_ref, p_clean, p_noise_ref)
    A = Hadamard(n, m=m, order=order)
    with torch.no_grad():
        y = noisy_buckets(A, x, recipes, gens)
    return A, x, y


def _step_data(args: tuple) -> tuple:
    """``(n, m, order, x, y)`` of one training step (a top-level function, so that data
    processes can run it): ``args = (seed, step, sizes, p_large, sr_range, orders, indices,
    noise_ref, p_clean, p_noise_ref, families, user_paths)``."""
    (seed, step, sizes, p_large, sr_range, orders, indices, noise_ref, p_clean, p_noise_ref,
     families, user_paths) = args
    n, m, order = step_config(seed, step, sizes, p_large, sr_range, orders)
    _, x, y = _batch(seed, step, n, m, order, indices, noise_ref, p_clean, p_noise_ref,
                     families, user_paths)
    return n, m, order, x, y


def _one_thread() -> None:  # initializer of the data processes
    torch.set_num_threads(1)


def _step_stream(steps: range, workers: int, common: tuple):
    """Yield :func:`_step_data` for every step of ``steps`` in order: in this process
    (``workers = 0``) or computed ahead by ``workers`` processes, at most ``2 · workers`` steps
    in flight (bounded memory). Every step's data depends only on ``(seed, step, index)``, so
    the stream is the same either way."""
    seed, rest = common[0], common[1:]
    if workers == 0:
        for s in steps:
            yield _step_data((seed, s, *rest))
        return
    import collections
    import itertools
    import multiprocessing

    # fork where the platform has it (no re-import per process); spawn elsewhere
    method = "fork" if "fork" in multiprocessing.get_all_start_methods() else "spawn"
    with multiprocessing.get_context(method).Pool(workers, initializer=_one_thread) as pool:
        it = iter(steps)

        def submit(n: int) -> list:
            return [pool.apply_async(_step_data, ((seed, s, *rest),))
                    for s in itertools.islice(it, n)]

        pending = collections.deque(submit(2 * workers))
        while pending:
            out = pending.popleft().get()
            pending.extend(submit(1))
            yield out


def calibrate_tau(
    model: Learned,
    seed: int = 0,
    batches: int = 24,
    batch_size: int = 8,
    sizes: tuple[int, ...] = (32, 64),
    p_large: float = 0.3,
    sr_range: tuple[float, float] = (0.0625, 0.5),
    orders: tuple[str, ...] = ORDERS,
    grid: tuple[float, ...] = TAU_GRID,
    noise_ref: int | None = None,
    p_clean: float = P_CLEAN,
    p_noise_ref: float = 1.0,
    families: dict[str, float] | None = None,
    user_images: tuple[str, ...] | None = None,
) -> dict:
    """Set ``model.log_tau`` to the ``τ`` of ``grid`` with the best mean PSNR (the lowest
    :func:`psnr_loss`) on ``batches`` batches of the training recipe at steps
    ``CALIBRATION_STEP0 + k``, and switch the final data-consistency step on.

    The network up to the last prior step is run once per batch; each ``τ`` then costs one
    ``A`` and one ``Aᵀ``. Returns ``{"tau": τ, "losses": {τ: loss}, "loss_off": loss}``
    (``loss_off``: without the final step). ``user_images``: the run's own images (paths,
    as :func:`train_learned`), needed where ``families`` gives ``"user"`` a probability.
    """
    user_paths = check_user_paths(user_images, "calibrate_tau")
    families = user_mixture(families, user_paths, "calibrate_tau")
    _user_images.cache_clear()
    outs = []
    model.final_dc = False
    device = model.log_tau.device
    with torch.no_grad():
        for k in range(batches):
            step = CALIBRATION_STEP0 + k
            n, m, order = step_config(seed, step, tuple(sorted(sizes)), p_large, sr_range, orders)
            A, x, y = _batch(seed, step, n, m, order, range(batch_size), noise_ref, p_clean,
                             p_noise_ref, families, user_paths)
            A, x, y = A.to(device), x.to(device), y.to(device)
            model.A = A
            outs.append((A, x, y, model(y)))
    model.final_dc = True
    losses = {}
    with torch.no_grad():
        off = float(np.mean([float(psnr_loss(xk, x)) for _, x, _, xk in outs]))
        for tau in grid:
            model.log_tau.fill_(math.log(tau))
            tot = []
            for A, x, y, _ in outs:
                model.A = A
                tot.append(float(psnr_loss(model(y), x)))
            losses[tau] = float(np.mean(tot))
        best = min(losses, key=losses.get)
        model.log_tau.fill_(math.log(best))
    return {"tau": best, "losses": losses, "loss_off": off}


def train_learned(
    steps: int = 8000,
    batch_size: int = 12,
    lr: float = 2e-3,
    seed: int = 0,
    sizes: tuple[int, ...] = (32, 64),
    p_large: float = 0.3,
    sr_range: tuple[float, float] = (0.0625, 0.5),
    orders: tuple[str, ...] = ORDERS,
    n_layers: int = DEFAULT_N_LAYERS,
    width: int = DEFAULT_WIDTH,
    shuffle: int = DEFAULT_SHUFFLE,
    scales: int = DEFAULT_SCALES,
    noise_ref: int | None = NOISE_REF,
    p_clean: float = P_CLEAN,
    p_noise_ref: float = P_NOISE_REF,
    out: str | os.PathLike | None = None,
    checkpoint_every: int = 100,
    resume: bool = False,
    log_every: int = 10,
    progress: bool = True,
    distributed: bool | None = None,
    max_minutes: float | None = None,
    command: str | None = None,
    calibrate: bool = True,
    device: str | torch.device = "cpu",
    workers: int = 0,
    init: str | os.PathLike | None = None,
    families: dict[str, float] | None = None,
    x0: str = "adjoint",
    user_images: str | os.PathLike | list | tuple | None = None,
) -> LearnedTrainResult:
    """Train :class:`Learned` from its random initialisation, or fine-tune it from a weights
    file (``init``) (module docstring).

    Args:
        steps: optimiser steps ``>= 1`` (the cosine schedule spans them). A resume may
            change it (not below the checkpoint's step): the learning rate follows the new
            schedule from the resumed step on, and ``recipe.json`` records the change
            (``steps_changes``).
        batch_size: global batch, divisible by the number of processes.
        lr: peak Adam learning rate.
        seed: base seed of every draw (operators, scenes, noise, initialisation), an int in
            ``[0, 2⁶⁴)``.
        sizes: image sides drawn (powers of two in ``[8, 256]``).
        p_large: probability of the largest size, in ``[0, 1]``.
        sr_range: ``(lo, hi)`` sampling rates, ``0 < lo <= hi <= 1``.
        orders: Hadamard orders drawn.
        n_layers, width, shuffle, scales: the network (:class:`Learned`).
        noise_ref: Gaussian noise levels scaled to this size (:func:`noise_levels`;
            ``None``: the same levels at every size).
        p_clean: probability of a noise-free sample, in ``[0, 1]``.
        p_noise_ref: with ``noise_ref``, the probability in ``[0, 1]`` that a sample's
            Gaussian level is drawn from the scaled levels (else from the unscaled ones): a
            mixture of the two ranges.
        out: folder of the checkpoint, log and final weights (``None``: nothing written).
        checkpoint_every: steps between checkpoints (0: only the final one, written when the
            run ends or stops, which ``resume`` and a calibration-only run need).
        resume: continue from ``out/checkpoint.pt`` if it exists. The call must repeat the
            run's settings (:func:`run_settings`: ``seed``, ``lr``, ``batch_size``, ``sizes``,
            ``p_large``, ``sr_range``, ``orders``, ``noise_ref``, ``p_clean``,
            ``p_noise_ref``; the network, ``x0`` and the scene mixture), else a ``ValueError``
            names what differs; ``steps`` may change (see ``steps``). Checkpoints from
            before a record skip its comparison.
        log_every: steps between ``log.json`` records and progress updates.
        progress: show a tqdm progress bar on rank 0.
        distributed: ``None`` detects torchrun, ``True`` requires it, ``False`` never.
        max_minutes: stop (and save) after that much wall time (``>= 0``), even before
            ``steps``; under DDP every rank stops after the same step.
        command: the command line recorded in ``recipe.json``.
        calibrate: set the final step's ``τ`` by :func:`calibrate_tau` at the end (else the
            final step stays off).
        device: where the model trains (``"cpu"``, ``"cuda"``, ...; under ``torchrun``
            ``"cuda"`` is ``cuda:LOCAL_RANK``); the data are drawn on the CPU and moved there.
            The returned model and the weights file are on the CPU.
        workers: processes that draw the data ahead of the optimiser (0: this process). The
            draws depend only on ``(seed, step, index)``, so the run is the same.
        families: the scene families' probabilities (:func:`torchtof.data.draw_scene`;
            ``None``: :data:`torchtof.data.FAMILIES`, the shipped weights' mixture).
        init: a weights file (:meth:`Learned.save_weights`, e.g. the shipped
            :data:`~torchtof.recon.learned.WEIGHTS_FILE`) to start from instead of the random
            initialisation: fine-tuning on another data recipe. Its ``n_layers``, ``width``,
            ``shuffle`` and ``scales`` must equal these arguments. The schedule starts again
            at ``lr`` (give a smaller one, and another ``seed`` than the file's run so that its
            batches are not replayed). ``recipe.json`` records the file and its SHA-256. A
            resumed run (``resume``) keeps the origin its checkpoint records: ``init`` may be
            left out then, and another file (or one for a run started at random) is refused.
        x0: the network's starting estimate (:class:`Learned`, ``x0``), also when ``init``
            was trained with another; the weights file records it.
        user_images: the caller's own scenes for the ``"user"`` family: a path or paths of
            image files, ``.npy``/``.npz`` arrays or folders (:func:`torchtof.data.load_images`;
            read once at the entry and once per data process). Without ``families`` the run
            draws ``"user"`` with probability ``P_USER`` = 0.5 and the shipped mixture, scaled,
            otherwise; with ``families`` it must give ``"user"`` a probability. With ``init``
            this adapts the network to a domain. ``recipe.json`` records each file's SHA-256.

    Returns:
        :class:`LearnedTrainResult`.

    Raises:
        ValueError, TypeError: for invalid arguments (named in the message), or a resume
            whose settings differ from the checkpoint's run.
    """
    func = "train_learned"
    for name, v, least in (("steps", steps, 1), ("batch_size", batch_size, 1),
                           ("checkpoint_every", checkpoint_every, 0), ("log_every", log_every, 1),
                           ("workers", workers, 0)):
        if isinstance(v, bool) or not isinstance(v, int) or v < least:
            raise ValueError(f"{func}: expected {name} to be an int >= {least}, got {v!r}")
    if noise_ref is not None and (isinstance(noise_ref, bool) or not isinstance(noise_ref, int)
                                  or noise_ref < 1):
        raise ValueError(f"{func}: expected noise_ref to be None or an int >= 1, got {noise_ref!r}")
    for name, v in (("p_clean", p_clean), ("p_noise_ref", p_noise_ref), ("p_large", p_large)):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 <= v <= 1:
            raise ValueError(f"{func}: expected {name} in [0, 1], got {v!r}")
    check_int(seed, "seed", func, 0, 2**64 - 1)  # torch.manual_seed's range
    check_positive(lr, "lr", func)
    if max_minutes is not None:
        check_positive(max_minutes, "max_minutes", func, strict=False)
    if not isinstance(sr_range, (tuple, list)) or len(sr_range) != 2:
        raise TypeError(f"{func}: expected sr_range to be a pair (lo, hi), got {sr_range!r}")
    lo, hi = sr_range
    check_in_range(lo, 0.0, 1.0, "sr_range[0]", func, lo_open=True)
    check_in_range(hi, 0.0, 1.0, "sr_range[1]", func, lo_open=True)
    if not 0 < lo <= hi <= 1:
        raise ValueError(f"{func}: expected 0 < sr_range[0] <= sr_range[1] <= 1, got {sr_range}")
    if not isinstance(sizes, (tuple, list)) or not all(
            isinstance(n, int) and not isinstance(n, bool) for n in sizes):
        raise TypeError(f"{func}: expected sizes to be a tuple of ints, got {sizes!r}")
    if not sizes or any(s < 8 or s > N_MAX or s & (s - 1) for s in sizes):
        raise ValueError(f"{func}: expected sizes to be powers of two in [8, {N_MAX}], "
                         f"got {sizes}")
    if not isinstance(orders, (tuple, list)):
        raise TypeError(f"{func}: expected orders to be a tuple of names, got {orders!r}")
    bad = [o for o in orders if o not in ORDERS]
    if not orders or bad:
        raise ValueError(f"{func}: expected orders from {ORDERS}, got {orders}")
    orders = tuple(orders)
    given_data = (user_images, families)
    user_paths = check_user_paths(user_images, func)
    families = user_mixture(families, user_paths, func)
    if init is not None and not isinstance(init, (str, os.PathLike)):
        raise TypeError(f"{func}: expected init to be a path or None, got {type(init).__name__}")
    if init is not None and not Path(init).is_file():
        raise ValueError(f"{func}: expected init to be a weights file, got {os.fspath(init)!r}")
    check_x0(x0, func, optional=False)
    sizes = tuple(sorted(sizes))
    device = check_device(rank_device(device, distributed), "device", func)
    settings = run_settings(seed, steps, lr, batch_size, sizes, p_large, (lo, hi), orders,
                            noise_ref, p_clean, p_noise_ref)

    torch.manual_seed(seed)
    model = Learned(Hadamard(sizes[0], sr=0.25), n_layers=n_layers, pretrained=False,
                    width=width, shuffle=shuffle, scales=scales).to(device)
    init_record = None
    if init is not None:
        init_path = Path(init)
        model.load_weights(init_path)  # raises ValueError naming a different architecture
        if not model.clean_scale:
            raise ValueError(f"{func}: init {os.fspath(init)!r} uses the noisy-norm scale of "
                             f"older weights files; training uses the noise-corrected scale")
        init_record = {"path": os.fspath(init_path),
                       "sha256": hashlib.sha256(init_path.read_bytes()).hexdigest()}
    model.x0 = x0
    model.final_dc = False  # the prior trains without the final step (calibrate_tau sets it)
    model.log_tau.requires_grad_(False)  # so DDP sees no unused parameter
    params = list(model.prior.parameters()) + [model.step_raw]
    opt = torch.optim.Adam(params, lr=lr)
    sched = torch.optim.lr_scheduler.LambdaLR(
        opt, lambda s: 0.05 + 0.475 * (1 + math.cos(math.pi * min(s, steps) / steps))
    )
    outdir = Path(out) if out is not None else None
    start, log, wall0, history, steps_changes = 0, [], 0.0, [], []
    ckpt = outdir / "checkpoint.pt" if outdir is not None else None
    if resume and ckpt is not None and ckpt.is_file():
        state = read_checkpoint(ckpt, func, device)
        if state["step"] > steps:
            raise ValueError(f"{func}: checkpoint {ckpt} is at step {state['step']}, beyond "
                             f"steps={steps}; resume with the run's steps")
        check_run_settings(state.get("run"), settings, ckpt, func)
        steps_changes = list(state.get("steps_changes", []))
        if state.get("run") and state["run"].get("steps", steps) != steps:
            # the schedule is the new steps' from here on (a jump in the learning rate)
            steps_changes.append({"step": state["step"], "from": state["run"]["steps"],
                                  "to": steps})
        want = {k: v for k, v in model.meta().items() if k != "model"}
        have = state.get("meta")  # checkpoints before it: the shapes below say it
        if have is not None and {k: have.get(k) for k in want} != want:
            diff = ", ".join(f"{k}={have.get(k)} (got {v})" for k, v in want.items()
                             if have.get(k) != v)
            raise ValueError(f"{func}: checkpoint {ckpt} was trained with another network: "
                             f"{diff}")
        try:
            missing, unexpected = model.load_state_dict(state["model"], strict=False)
        except RuntimeError as exc:  # a size mismatch of a checkpoint without "meta"
            raise ValueError(f"{func}: checkpoint {ckpt} does not match the network "
                             f"{want}: {str(exc).strip().splitlines()[-1].strip()}") from None
        if unexpected or set(missing) - {"log_tau"}:  # log_tau: calibrated after training
            raise ValueError(f"{func}: checkpoint {ckpt} does not match the model: "
                             f"missing {missing}, unexpected {unexpected}")
        if state.get("x0", "adjoint") != x0:
            raise ValueError(f"{func}: checkpoint {ckpt} was trained with x0="
                             f"{state.get('x0', 'adjoint')!r}, got x0={x0!r}")
        families, user_paths = _resumed_data(state.get("data"), given_data, families,
                                             user_paths, ckpt, func)
        if "init" in state:  # the run's origin (checkpoints before the record: as given)
            had = state["init"]
            if init is not None and (had is None or had["sha256"] != init_record["sha256"]):
                origin = "its random initialisation" if had is None else repr(had["path"])
                raise ValueError(f"{func}: checkpoint {ckpt} was started from {origin}; init "
                                 f"{os.fspath(init)!r} only starts a new run (resume without "
                                 "init)")
            init_record = had
        opt.load_state_dict(state["opt"])
        sched.load_state_dict(state["sched"])
        start, log, wall0 = state["step"], state["log"], state["wall_s"]
        # the run's per-step losses (checkpoints before the record: this process's only)
        history = list(state.get("losses", []))

    _user_images.cache_clear()  # this run reads its images afresh
    data_record = {"families": families, "user_images": user_image_record(user_paths)}
    is_dist, rank, world, created = dist_setup(distributed, func)
    t0 = time.perf_counter()
    losses: list[float] = []  # this call's; history: the run's, from step 1
    try:
        if batch_size % world:
            raise ValueError(f"{func}: expected batch_size divisible by the world size {world}, "
                             f"got {batch_size}")
        shard = batch_size // world
        indices = range(rank * shard, (rank + 1) * shard)
        bar = None
        if progress and rank == 0:
            from tqdm import tqdm

            bar = tqdm(total=steps, initial=start, desc="train learned", file=sys.stderr,
                       mininterval=5.0)

        def save_checkpoint(step: int) -> None:
            if ckpt is None or rank != 0:
                return
            outdir.mkdir(parents=True, exist_ok=True)
            state = {"model": model.state_dict(), "opt": opt.state_dict(),
                     "sched": sched.state_dict(), "step": step, "log": log, "x0": x0,
                     "meta": model.meta(), "data": data_record, "run": settings,
                     "steps_changes": steps_changes, "losses": history, "init": init_record,
                     "wall_s": wall0 + time.perf_counter() - t0}
            atomic_write(ckpt, functools.partial(torch.save, state))
            write_text(outdir / "log.json", json.dumps(log, indent=0))

        net: nn.Module = model
        if is_dist:  # A has no parameters: swapping it per step leaves DDP's buckets intact
            net = nn.parallel.DistributedDataParallel(model, broadcast_buffers=False)
        step = start
        stream = _step_stream(range(start, steps), workers, (
            seed, sizes, p_large, sr_range, orders, indices, noise_ref, p_clean, p_noise_ref,
            families, user_paths))
        for step, (n, m, order, x, y) in zip(range(start, steps), stream):
            x, y = x.to(device), y.to(device)
            model.A = Hadamard(n, m=m, order=order).to(device)
            loss = psnr_loss(net(y), x)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            nn.utils.clip_grad_norm_(params, 1.0)
            opt.step()
            sched.step()
            mean = loss.detach().clone()
            if is_dist:
                dist.all_reduce(mean)
                mean /= world
            losses.append(float(mean))
            history.append(losses[-1])
            if rank == 0 and ((step + 1) % log_every == 0 or step == steps - 1):
                recent = history[-log_every:]
                log.append({"step": step + 1, "loss": float(np.mean(recent)), "n": n,
                            "sr": m / (n * n), "order": order, "lr": sched.get_last_lr()[0],
                            "wall_s": round(wall0 + time.perf_counter() - t0, 1)})
                if bar is not None:
                    bar.update(step + 1 - bar.n)
                    bar.set_postfix(loss=f"{log[-1]['loss']:.5f}")
            if checkpoint_every and (step + 1) % checkpoint_every == 0:
                save_checkpoint(step + 1)
            if stop_after_step(t0, max_minutes, is_dist, device):  # the ranks together
                step += 1
                break
        else:
            step = steps
        stream.close()  # stops the data processes (a --max-minutes stop leaves steps queued)
        save_checkpoint(step)
        if bar is not None:
            bar.close()
        wall = wall0 + time.perf_counter() - t0
        model.log_tau.requires_grad_(True)
        t_cal = time.perf_counter()
        calib = calibrate_tau(model, seed, sizes=sizes, p_large=p_large, sr_range=(lo, hi),
                              orders=orders, noise_ref=noise_ref, p_clean=p_clean,
                              p_noise_ref=p_noise_ref, families=families,
                              user_images=user_paths or None) if calibrate else None
        if outdir is not None and rank == 0:
            recipe = {
                "command": command,
                "init": init_record,
                "seed": seed,
                "steps_run": step,
                "steps": steps,
                "steps_changes": steps_changes,
                "batch_size": batch_size,
                "world_size": world,
                "lr": lr,
                "sizes": list(sizes),
                "p_large": p_large,
                "sr_range": [lo, hi],
                "orders": list(orders),
                "n_layers": n_layers,
                "width": width,
                "shuffle": shuffle,
                "scales": scales,
                "x0": x0,
                "data": {
                    "families": families,
                    "train_images": list(TRAIN_IMAGES),
                    "user_images": data_record["user_images"],
                    "noise": {"p_clean": p_clean, "gaussian_levels": list(TRAIN_LEVELS),
                              "levels_scaled_to_n": noise_ref,
                              "p_levels_scaled": p_noise_ref if noise_ref else None,
                              "p_shot": 0.25, "photons": [3.0, 300.0], "stray": [0.0, 2.0]},
                },
                "final_step_calibration": calib,
                "calibration_wall_s": round(time.perf_counter() - t_cal, 1),
                "final_loss": (float(np.mean(history[-max(1, len(history) // 10):]))
                               if history else None),
                "torch_version": str(torch.__version__),
                "wall_s": round(wall, 1),
                "load_avg_end": list(os.getloadavg()),
                "threads": torch.get_num_threads(),
                "device": str(device),
                "data_workers": workers,
            }
            model.to("cpu")
            model.A = Hadamard(sizes[0], sr=0.25)
            atomic_write(outdir / "learned.pt", functools.partial(
                model.save_weights, seed=seed, steps=step, torch_version=str(torch.__version__),
                noise_ref=noise_ref, p_noise_ref=p_noise_ref if noise_ref else None,
                p_clean=p_clean))
            write_text(outdir / "recipe.json", json.dumps(recipe, indent=1))
        if is_dist:
            dist.barrier()
    finally:
        if created:
            dist.destroy_process_group()
    return LearnedTrainResult(model=model.to("cpu"), losses=losses, wall_s=wall)
