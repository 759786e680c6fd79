"""Reconstruction methods of the paper's comparison, built for an experiment run, and scoring.

Which buckets each method sees (DESIGN.md §2):

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

import time
from collections.abc import Callable
from dataclasses import dataclass

import torch

from .experiment import ExperimentData
from .metrics import compare
from .recon.correlation import CGI, DGI
from .recon.pinv import PseudoInverse

__all__ = ["METHODS", "DEFAULT_METHODS", "Method", "build_method", "evaluate", "raw_tof_scores"]


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


def _split(data: ExperimentData, sr: float, gate: bool, kind: str):
    return data.split_operator(sr), data.split_buckets(sr, kind, gate)


def _no_options(name: str, kwargs: dict) -> None:
    if kwargs:
        raise TypeError(f"build_method: {name} takes no options, got {sorted(kwargs)}")


def _cgi(data, sr, gate, kind, **kwargs):
    _no_options("CGI", kwargs)
    s, y = _split(data, sr, gate, kind)
    return Method("CGI", CGI(s), y)


def _dgi(data, sr, gate, kind, **kwargs):
    _no_options("DGI", kwargs)
    s, y = _split(data, sr, gate, kind)
    return Method("DGI", DGI(s), y)


def _pinv(data, sr, gate, kind, **kwargs):
    _no_options("PINV", kwargs)
    A, y = data.measurements(sr, kind, gate)
    return Method("PINV", PseudoInverse(A), y)


def _bp(data, sr, gate, kind, **kwargs):
    from .recon.bp import BasisPursuit

    A, y = data.measurements(sr, kind, gate)
    # noise-aware BPDN by default (module docstring)
    return Method("BP", BasisPursuit(A, **{"eps": "auto", **kwargs}), y)


def _tval3(data, sr, gate, kind, **kwargs):
    from .recon.tval3 import TVAL3

    A, y = data.measurements(sr, kind, gate)
    return Method("TVAL3", TVAL3(A, **kwargs), y)


def _unrolled(data, sr, gate, kind, **kwargs):
    from .recon.unrolled import UnrolledTVAL3

    A, y = data.measurements(sr, kind, gate)
    return Method("Unrolled", UnrolledTVAL3(A, **kwargs), y)


class _SignedDIP(torch.nn.Module):
    """DIP on ``sign·y``, result times ``sign``: the U-Net's sigmoid output is a bright object
    on a dark background, so negative images (ungated depth buckets, a polarity known from the
    physics, paper §3.1) are fitted as ``A(−x) = −y`` and negated back (A is linear)."""

    def __init__(self, A, sign: float, **kwargs) -> None:
        super().__init__()
        from .recon.dip import DIP

        self.dip, self.sign = DIP(A, **kwargs), sign

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        return self.sign * self.dip(self.sign * y)


def _dip(data, sr, gate, kind, **kwargs):
    A, y = data.measurements(sr, kind, gate)
    sign = -1.0 if data.polarity(gate, kind) == "negative" else 1.0
    return Method("DIP", _SignedDIP(A, sign, **kwargs), y, per_sample=True)


#: name -> builder(data, sr, gate, kind) -> Method, in the demo's column order.
METHODS: dict[str, Callable[..., Method]] = {
    "CGI": _cgi,
    "DGI": _dgi,
    "PINV": _pinv,
    "BP": _bp,
    "TVAL3": _tval3,
    "Unrolled": _unrolled,
    "DIP": _dip,
}
DEFAULT_METHODS: tuple[str, ...] = tuple(METHODS)


def build_method(name: str, data: ExperimentData, sr: float, gate: bool, kind: str = "depth",
                 **options):
    """Bind method ``name`` to the run; ``options`` go to its constructor (DIP only)."""
    if name not in METHODS:
        raise ValueError(f"build_method: expected name in {tuple(METHODS)}, got {name!r}")
    return METHODS[name](data, sr, gate, kind, **options)


def _scores(img: torch.Tensor, data: ExperimentData, polarity: str) -> dict[str, float]:
    x = data.x.to(img.dtype).expand(img.shape[0], -1, -1, -1)
    s = compare(img, x, polarity)
    p, q = s["psnr"], s["ssim"]
    std = (lambda t: float(t.std())) if p.numel() > 1 else (lambda t: 0.0)
    return {"psnr": float(p.mean()), "psnr_std": std(p), "ssim": float(q.mean()),
            "ssim_std": std(q)}


def raw_tof_scores(data: ExperimentData) -> dict[str, float]:
    """Scores of the raw ToF depth image (negative polarity: near = small depth)."""
    return _scores(data.raw_tof_image, data, "negative")


def evaluate(
    data: ExperimentData, sr: float, gate: bool, methods=DEFAULT_METHODS, kind: str = "depth",
    progress: Callable[[str], None] | None = None, options: dict[str, dict] | None = None,
) -> tuple[list[dict], dict[str, torch.Tensor]]:
    """Run and score ``methods`` at ``sr``; returns (rows, images) — rows hold mean ± std over
    the realisations and the wall time of the whole batch. ``options[name]`` are constructor
    keyword arguments of that method (e.g. ``{"DIP": {"n_iter": 100}}``)."""
    rows, images = [], {}
    polarity = data.polarity(gate, kind)
    for name in methods:
        if progress is not None:
            progress(name)
        method = build_method(name, data, sr, gate, kind, **(options or {}).get(name, {}))
        if not method.per_sample:  # one-off initialisation is not the method's run time
            with torch.no_grad():
                method.module(method.y[:1])
        with torch.no_grad() if name != "DIP" else torch.enable_grad():
            t0 = time.perf_counter()
            img = method()
            dt = time.perf_counter() - t0
        img = img.detach()
        images[name] = img
        rows.append({"method": name, "sr": sr, "gate": gate, "time_s": dt,
                     **_scores(img, data, polarity)})
    return rows, images
