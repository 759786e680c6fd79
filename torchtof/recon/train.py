"""Training of the unrolled TVAL3 on synthetic scenes, single process or data-parallel.

Each step draws a global batch of ``batch_size`` scenes (:mod:`.synthetic`), measures
them with the Hadamard operator, adds the Gaussian bucket-noise approximation of
:func:`~torchtof.recon.synthetic.measurement_noise` at a per-scene level drawn uniformly
from ``noise_level``, and takes one Adam step (Kingma & Ba, 2015) on the mean squared
error of the reconstruction against the clean scene, with a cosine learning-rate decay
(Loshchilov & Hutter, 2017) and gradient-norm clipping at 1.

Data parallel: under ``torchrun`` (the ``WORLD_SIZE``/``RANK``/``MASTER_ADDR`` environment
variables) the model is wrapped in ``DistributedDataParallel`` on the ``gloo`` backend (CPU)
and rank ``r`` of ``W`` draws scenes ``[r B/W, (r+1) B/W)`` of the same global batch; the
scene and noise seeds depend only on ``(seed, step, index)``, so the ranks' shards together
are exactly the single-process batch and the averaged gradients are the single-process
gradient (up to floating-point summation order).
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch
import torch.distributed as dist
from torch import nn

from .._checks import check_in_range, check_positive
from ..constants import PAPER_SRS
from ..operators.hadamard import Hadamard
from .base import renamed_option
from .synthetic import measurement_noise, synthetic_scenes
from .unrolled import DEFAULT_N_LAYERS, UnrolledTVAL3

__all__ = ["train_unrolled", "TrainResult", "PAPER_SRS", "noisy_measurements"]



class TrainResult(NamedTuple):
    """What :func:`train_unrolled` returns.

    Attributes:
        model: the trained :class:`~torchtof.recon.UnrolledTVAL3` (not wrapped in DDP).
        losses: the mean training loss over the global batch at every step.
    """

    model: UnrolledTVAL3
    losses: list[float]


def _noise_seed(seed: int, step: int, index: int) -> int:
    """Seed of the noise stream of scene ``index`` (independent of its scene stream)."""
    return int(np.random.SeedSequence([seed, step, index, 1]).generate_state(1)[0])


def noisy_measurements(
    A: nn.Module,
    x: torch.Tensor,
    seed: int,
    step: int,
    indices: range,
    noise_level: tuple[float, float],
) -> torch.Tensor:
    """``A x`` plus bucket noise, scene ``indices[j]`` with its own seeded noise draw.

    The level of each scene is uniform in ``noise_level`` and the noise follows
    :func:`~torchtof.recon.synthetic.measurement_noise`; both come from a generator seeded by
    ``(seed, step, index)``, so the draw does not depend on how the batch is sharded.

    Args:
        A: measurement operator.
        x: clean scenes ``(len(indices), C, n, n)``.
        seed, step: base seed and training step.
        indices: global-batch positions of the rows of ``x``.
        noise_level: ``(lo, hi)`` range of the noise level, ``0 <= lo <= hi``.

    Returns:
        Noisy measurements ``(len(indices), C, M)``.
    """
    y = A(x)
    out = []
    for j, i in enumerate(indices):
        g = torch.Generator().manual_seed(_noise_seed(seed, step, i))
        lo, hi = noise_level
        level = lo + (hi - lo) * float(torch.rand((), generator=g, dtype=torch.float64))
        out.append(measurement_noise(y[j : j + 1], level, g))
    return torch.cat(out)


def _dist_setup(distributed: bool | None,
                func: str = "train_unrolled") -> tuple[bool, int, int, bool]:
    """``(distributed, rank, world, created_group)`` from the torchrun environment (``func``:
    the caller, named in the error)."""
    env = all(k in os.environ for k in ("RANK", "WORLD_SIZE", "MASTER_ADDR", "MASTER_PORT"))
    if distributed is None:
        distributed = env and int(os.environ["WORLD_SIZE"]) > 1
    if not distributed:
        return False, 0, 1, False
    created = False
    if not dist.is_initialized():
        if not env:
            raise ValueError(
                f"{func}: distributed=True needs torchrun's RANK, WORLD_SIZE, MASTER_ADDR "
                "and MASTER_PORT environment variables (or an initialised process group)"
            )
        dist.init_process_group("gloo")
        created = True
    return True, dist.get_rank(), dist.get_world_size(), created


def train_unrolled(
    n: int = 32,
    sr: float = 0.25,
    n_layers: int = DEFAULT_N_LAYERS,
    order: str = "cake_cutting",
    steps: int = 300,
    batch_size: int = 16,
    lr: float = 0.05,
    noise_level: tuple[float, float] = (0.0, 0.02),
    seed: int = 0,
    distributed: bool | None = None,
    out: str | os.PathLike | None = None,
    log_every: int = 0,
    n_iter: int | None = None,
) -> TrainResult:
    """Train :class:`~torchtof.recon.UnrolledTVAL3` for ``Hadamard(n, sr, order)`` from TVAL3's
    defaults on scenes drawn on the fly (module docstring).

    Args:
        n: image side (power of two, ``Hadamard``'s range).
        sr: sampling rate in (0, 1].
        n_layers: unrolled iterations ``K``.
        order: Hadamard order.
        steps: optimiser steps ``>= 1``.
        batch_size: global batch (scenes per step), divisible by the number of processes.
        lr: peak Adam learning rate on the raw (log) parameters.
        noise_level: ``(lo, hi)``: each scene's noise level is uniform in it.
        seed: base seed of the scene and noise streams (held-out sets use another seed).
        distributed: ``None`` detects torchrun's environment, ``True`` requires it (or an
            initialised process group), ``False`` trains in this process only.
        out: if given, rank 0 writes the weights there (:meth:`UnrolledTVAL3.save_weights`);
            its folder is made first, before any training step.
        log_every: print the loss every that many steps on rank 0 (0: never).
        n_iter: old name of ``n_layers`` (``DeprecationWarning``; removed in the next release).

    Returns:
        :class:`TrainResult` with the trained model and the per-step losses.

    Raises:
        ValueError: for invalid sizes, a batch not divisible by the world size, or
            ``distributed=True`` without a process group or torchrun environment.
    """
    n_layers = renamed_option("train_unrolled", "n_iter", "n_layers", n_iter, n_layers,
                              DEFAULT_N_LAYERS)
    func = "train_unrolled"
    for name, v, least in (
        ("steps", steps, 1),
        ("batch_size", batch_size, 1),
        ("log_every", log_every, 0),
    ):
        if isinstance(v, bool) or not isinstance(v, int) or v < least:
            raise ValueError(f"{func}: expected {name} to be an int >= {least}, got {v!r}")
    check_positive(lr, "lr", func)
    lo, hi = noise_level
    check_in_range(lo, 0.0, math.inf, "noise_level[0]", func)
    check_in_range(hi, lo, math.inf, "noise_level[1]", func)

    if out is not None:  # before the training, not after it: a missing folder lost the run
        if not isinstance(out, (str, os.PathLike)):
            raise TypeError(f"{func}: expected out to be a path or None, got "
                            f"{type(out).__name__}")
        parent = Path(out).parent
        if parent.exists() and not parent.is_dir():
            raise ValueError(f"{func}: out's folder {os.fspath(parent)!r} is not a directory")
        parent.mkdir(parents=True, exist_ok=True)
    A = Hadamard(n, sr=sr, order=order)
    model = UnrolledTVAL3(A, n_layers=n_layers, pretrained=False)
    is_dist, rank, world, created = _dist_setup(distributed, func)
    try:
        if batch_size % world:
            raise ValueError(
                f"{func}: expected batch_size divisible by the world size {world}, got {batch_size}"
            )
        shard = batch_size // world
        indices = range(rank * shard, (rank + 1) * shard)
        net: nn.Module = model
        if is_dist:
            net = nn.parallel.DistributedDataParallel(model, broadcast_buffers=False)
        opt = torch.optim.Adam(model.parameters(), lr=lr)
        sched = torch.optim.lr_scheduler.LambdaLR(
            opt, lambda s: 0.1 + 0.45 * (1 + math.cos(math.pi * s / steps))
        )
        losses: list[float] = []
        for step in range(steps):
            x = synthetic_scenes(n, seed, step, indices)
            with torch.no_grad():
                y = noisy_measurements(A, x, seed, step, indices, (lo, hi))
            loss = torch.mean((net(y) - x) ** 2)
            opt.zero_grad(set_to_none=True)
            loss.backward()  # DDP averages the shard gradients: the global-batch gradient
            nn.utils.clip_grad_norm_(model.parameters(), 1.0)
            opt.step()
            sched.step()
            mean_loss = loss.detach().clone()
            if is_dist:
                dist.all_reduce(mean_loss)
                mean_loss /= world
            losses.append(float(mean_loss))
            if log_every and rank == 0 and (step % log_every == 0 or step == steps - 1):
                print(f"step {step:5d}  loss {losses[-1]:.6f}", flush=True)
        if out is not None and rank == 0:
            model.save_weights(
                out,
                steps=steps,
                batch_size=batch_size,
                world_size=world,
                lr=lr,
                noise_level=[lo, hi],
                seed=seed,
                final_loss=float(np.mean(losses[-max(1, steps // 10) :])),
                torch_version=str(torch.__version__),
            )
        if is_dist:
            dist.barrier()
    finally:
        if created:
            dist.destroy_process_group()
    return TrainResult(model=model, losses=losses)


#: Public name of the torchrun/DDP set-up, shared with :mod:`torchtof.recon.learned_train`.
dist_setup = _dist_setup
