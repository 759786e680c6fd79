"""Reconstruction methods of the paper's comparison, built for an experiment run, and scoring.

Which buckets each method sees:

- **CGI** (g2, paper Eq. 10) and **DGI** correlate the raw interleaved DMD buckets
  ``D_i`` with the 0/1 patterns the DMD showed (:class:`~torchtof.operators.DMDSplit`),
  exactly as the paper's Eq. 10 is written;
- **PINV**, **BP**, **TVAL3**, **Unrolled** and **DIP** solve ``y = A x`` with the orthonormal
  ±1 operator and the differential measurements ``y = (y⁺ − y⁻)/n``.

Noisy buckets: BP runs in its noise-aware form (``‖Ax − y‖ ≤ ε``, ``eps="auto"``: ε from the
noise level estimated on the high-sequency tail of ``y``) and TVAL3 with its noise-aware
default ``mu="auto"``; the equality-constrained forms over-fit the noise (and BP then needs
thousands of iterations).

DIP fits ``−y`` for negative-polarity buckets and negates the result (:class:`_SignedDIP`).

Every image is scored by :func:`torchtof.metrics.compare` with the physics polarity of its
buckets (ungated depth → negative, paper §3.1).
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial

import torch

from .experiment import ExperimentData
from .metrics import compare
from .recon import registry
from .recon.registry import ReconSpec

__all__ = ["METHODS", "DEFAULT_METHODS", "Method", "build_method", "evaluate", "raw_tof_scores",
           "score_image"]


@dataclass
class Method:
    """A reconstructor bound to an experiment: ``module(y)`` with ``y`` its input buckets."""

    name: str
    module: torch.nn.Module
    y: torch.Tensor
    per_sample: bool = False  # solve one realisation at a time (DIP)

    def __call__(self) -> torch.Tensor:
        if self.per_sample:
            return torch.cat([self.module(self.y[i : i + 1]) for i in range(self.y.shape[0])])
        return self.module(self.y)


def _no_options(name: str, kwargs: dict) -> None:
    if kwargs:
        raise TypeError(f"build_method: {name} takes no options, got {sorted(kwargs)}")


class _SignedDIP(torch.nn.Module):
    """DIP on ``sign·y``, result times ``sign``: the U-Net's sigmoid output is a bright object
    on a dark background, so negative images (ungated depth buckets, a polarity known from the
    physics, paper §3.1) are fitted as ``A(−x) = −y`` and negated back (A is linear)."""

    def __init__(self, module: torch.nn.Module, sign: float) -> None:
        super().__init__()
        self.dip, self.sign = module, sign

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        return self.sign * self.dip(self.sign * y)


def _build(spec: ReconSpec, data, sr, gate, kind, _weights=None, **kwargs) -> Method:
    if spec.operator == "split":  # raw 0/1 DMD buckets (module docstring)
        _no_options(spec.label, kwargs)
        A, y = data.split_operator(sr), data.split_buckets(sr, kind, gate)
    else:
        if not spec.iterative:
            _no_options(spec.label, kwargs)
        A, y = data.measurements(sr, kind, gate)
    if _weights is not None:  # (option, file): build_method checked the pair
        kwargs = {**kwargs, _weights[0]: _weights[1]}
    module = spec.build(A, **kwargs)
    if spec.positive_prior:
        sign = -1.0 if data.polarity(gate, kind) == "negative" else 1.0
        module = _SignedDIP(module, sign)
    return Method(spec.label, module, y, per_sample=spec.per_sample)


#: label -> builder(data, sr, gate, kind, **options) -> Method, read from the registry
#: (:mod:`torchtof.recon.registry`).
METHODS: dict[str, Callable[..., Method]] = {
    s.label: partial(_build, s) for s in registry.specs()
}
#: the demo's columns, in order.
DEFAULT_METHODS: tuple[str, ...] = ("CGI", "DGI", "PINV", "BP", "TVAL3", "Auto", "Unrolled",
                                     "Learned", "DIP")


#: The methods that load a learned network's weights file, and the constructor option that
#: takes it (``build_method(..., weights=FILE)``, ``torchtof reconstruct --weights``).
WEIGHTS_OPTION: dict[str, str] = {"Learned": "pretrained", "Auto": "learned"}


def build_method(name: str, data: ExperimentData, sr: float, gate: bool, kind: str = "depth",
                 weights: str | os.PathLike | None = None, **options):
    """Bind method ``name`` (a registry label or name) to the run; ``options`` go to its
    constructor (iterative methods only) over the registry's defaults. ``weights``: a learned
    network's weights file (e.g. from ``torchtof train``) for the methods of
    :data:`WEIGHTS_OPTION` (``Learned`` reconstructs with it, ``Auto`` stacks it)."""
    try:
        spec = registry.get(name)
    except (ValueError, TypeError):
        raise ValueError(f"build_method: expected name in {tuple(METHODS)}, got {name!r}") from None
    _check_data(data, "build_method")
    if weights is None:
        return _build(spec, data, sr, gate, kind, **options)
    if spec.label not in WEIGHTS_OPTION:
        raise ValueError(f"build_method: expected weights only for {tuple(WEIGHTS_OPTION)}, "
                         f"got {spec.label}")
    if not isinstance(weights, (str, os.PathLike)):
        raise TypeError(f"build_method: expected weights to be a path, got "
                        f"{type(weights).__name__}")
    return _build(spec, data, sr, gate, kind, _weights=(WEIGHTS_OPTION[spec.label], weights),
                  **options)


def _label_or_name(name: str) -> str:
    """The registry's label of ``name`` (any accepted spelling), or ``name`` itself when it
    names no method (:func:`build_method` then raises its error)."""
    try:
        return registry.get(name).label
    except (ValueError, TypeError):
        return name


def _check_data(data: object, func: str) -> None:
    if not isinstance(data, ExperimentData):
        raise TypeError(f"{func}: expected data to be an ExperimentData (PaperExperiment.run), "
                        f"got {type(data).__name__}")


def _scores(img: torch.Tensor, data: ExperimentData, polarity: str) -> dict[str, float]:
    x = data.x.to(img.dtype).expand(img.shape[0], -1, -1, -1)
    s = compare(img, x, polarity)
    p, q = s["psnr"], s["ssim"]
    std = (lambda t: float(t.std())) if p.numel() > 1 else (lambda t: 0.0)
    return {"psnr": float(p.mean()), "psnr_std": std(p), "ssim": float(q.mean()),
            "ssim_std": std(q)}


def score_image(img: torch.Tensor, data: ExperimentData, polarity: str) -> dict[str, float]:
    """Mean ± std PSNR/SSIM of ``img`` (one image per realisation) against the object."""
    _check_data(data, "score_image")
    if not isinstance(img, torch.Tensor):
        raise TypeError(f"score_image: expected img to be a torch.Tensor, got {type(img).__name__}")
    return _scores(img, data, polarity)


def _synchronize(t: torch.Tensor) -> None:
    """Wait for the device of ``t`` (CUDA kernels run asynchronously)."""
    if t.device.type == "cuda":
        torch.cuda.synchronize(t.device)


def raw_tof_scores(data: ExperimentData) -> dict[str, float]:
    """Scores of the raw ToF depth image (negative polarity: near = small depth)."""
    return _scores(data.raw_tof_image, data, "negative")


def evaluate(
    data: ExperimentData, sr: float, gate: bool, methods=DEFAULT_METHODS, kind: str = "depth",
    progress: Callable[[str], None] | None = None, options: dict[str, dict] | None = None,
) -> tuple[list[dict], dict[str, torch.Tensor]]:
    """Run and score ``methods`` at ``sr``; returns (rows, images) — rows hold mean ± std over
    the realisations and the wall time of the whole batch. ``options[name]`` are constructor
    keyword arguments of that method (e.g. ``{"DIP": {"max_iter": 100}}``; any spelling the
    registry accepts, ``"dip"`` too; a key naming no method is a ``ValueError``, options for
    a method not in ``methods`` are unused)."""
    func = "evaluate"
    _check_data(data, func)
    if isinstance(methods, str) or not all(isinstance(m, str) for m in methods):
        raise TypeError(f"{func}: expected methods to be a sequence of method names, got "
                        f"{methods!r}")
    if options is not None and not (isinstance(options, dict) and all(
            isinstance(v, dict) for v in options.values())):
        raise TypeError(f"{func}: expected options to be a dict of name -> dict of constructor "
                        f"options, got {options!r}")
    # options by the registry's label, so "tval3" and "TVAL3" name the same method; a key that
    # names no method at all (a typo) is an error, options for a method not run are unused
    by_label = {}
    for key, opts in (options or {}).items():
        try:
            label = registry.get(key).label
        except (ValueError, TypeError):
            raise ValueError(f"{func}: options names an unknown method {key!r}") from None
        if label in by_label:
            raise ValueError(f"{func}: options gives {label} twice (as {key!r})")
        by_label[label] = opts
    run_labels = [_label_or_name(m) for m in methods]
    rows, images = [], {}
    polarity = data.polarity(gate, kind)
    for name, label in zip(methods, run_labels, strict=True):
        if progress is not None:
            progress(name)
        method = build_method(name, data, sr, gate, kind, **by_label.get(label, {}))
        if not method.per_sample:  # one-off initialisation is not the method's run time
            with torch.no_grad():
                method.module(method.y[:1])
        with torch.enable_grad() if registry.get(name).per_sample else torch.no_grad():
            _synchronize(method.y)
            t0 = time.perf_counter()
            img = method()
            _synchronize(img)  # the wall time of the work, not of its launch
            dt = time.perf_counter() - t0
        img = img.detach()
        images[name] = img
        rows.append({"method": name, "sr": sr, "gate": gate, "time_s": dt,
                     **_scores(img, data, polarity)})
    return rows, images
