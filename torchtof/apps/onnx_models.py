"""The models of ``torchtof export MODEL`` and ``torchtof bench onnx``, with example inputs.

:data:`MODELS` maps a name to a :class:`ModelSpec`; ``MODELS[name](n, sr)`` builds the module
and realistic example inputs (buckets of synthetic scenes at the scales of the paper's
experiment) for a DMD side ``n`` and a sampling rate ``sr``; :func:`export_model` exports one
with :func:`torchtof.onnx.export` (the exporter of its spec: the legacy tracer for the
iterative solvers, which :mod:`torchtof.onnx` explains).
"""

from __future__ import annotations

import dataclasses
import os
import warnings
from collections.abc import Callable
from pathlib import Path

import torch
from torch import nn

from .._memory import check_memory
from ..bucket import PAPER_GATE_M, DepthBucket, DepthGate, IntensityBucket, TapBuckets
from ..onnx import DEFAULT_OPSET, EXPORT_BATCH, DepthAmplitude, OperatorMethod, export
from ..operators import DMDSplit, Hadamard, PatternOperator, random_binary_patterns
from ..operators.split import combine_split
from ..recon.bp import BasisPursuit
from ..recon.correlation import CGI, DGI, TGI
from ..recon.depth import DepthResolved
from ..recon.dip import default_unet, dip_input, fit_dip
from ..recon.learned import Learned
from ..recon.pinv import PseudoInverse
from ..recon.synthetic import synthetic_scenes
from ..recon.tgv import TGV
from ..recon.tval3 import TVAL3
from ..recon.unrolled import UnrolledTVAL3, available_weights
from ..sensor import CameraReadout, correlation_taps, phasor_from_depth

__all__ = ["MODELS", "ModelSpec", "export_model", "export_checked", "MODULATION_HZ", "PAPER_STEP_M"]

#: Modulation frequency of the example inputs (the paper's camera, 30 MHz).
MODULATION_HZ = 30e6
#: Depth step of the paper's camera output (§2.2: "from 1 to 5 m with a step of 0.25 m").
PAPER_STEP_M = 0.25


#: Depth of the object (m) and sensor pixels per DMD pixel (a 64×64 ROI for 32×32 DMD pixels).
_OBJECT_M, _PIX_PER_DMD = 2.0, 4


@dataclasses.dataclass(frozen=True)
class ModelSpec:
    """One exportable model: ``spec(n, sr)`` returns ``(module, example_inputs)``.

    Attributes:
        build: ``build(n, sr, batch, seed, n_iter) -> (module, inputs tuple)``.
        inputs, outputs: graph names, with their shapes in ``shapes``.
        shapes: human-readable shape of every input/output name.
        doc: one line for the README.
        exporter: the default exporter (see the module docstring).
        n_iter: default iteration count of an iterative model (``None``: not iterative).
        weights: whether ``build`` takes a ``weights`` file (a trained model's own weights
            instead of the shipped ones).
    """

    build: Callable[..., tuple[nn.Module, tuple[torch.Tensor, ...]]]
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    shapes: dict[str, str]
    doc: str
    exporter: str = "dynamo"
    n_iter: int | None = None
    weights: bool = False

    def __call__(
        self,
        n: int = 32,
        sr: float = 0.25,
        *,
        batch: int = EXPORT_BATCH,
        seed: int = 0,
        n_iter: int | None = None,
        weights: str | os.PathLike | None = None,
    ) -> tuple[nn.Module, tuple[torch.Tensor, ...]]:
        if n_iter is not None and self.n_iter is None:
            raise ValueError(f"ModelSpec: n_iter given for a model without iterations: {self.doc}")
        if isinstance(batch, bool) or not isinstance(batch, int) or batch < 1:
            raise ValueError(f"ModelSpec: expected batch to be an int >= 1, got {batch!r}")
        n_iter = self.n_iter if n_iter is None else n_iter
        if weights is None:
            return self.build(n, sr, batch, seed, n_iter)
        if not self.weights:
            raise ValueError(f"ModelSpec: weights given for a model that loads none: {self.doc}")
        if not isinstance(weights, (str, os.PathLike)) or not Path(weights).is_file():
            raise ValueError(f"ModelSpec: expected weights to be a weights file, got {weights!r}")
        return self.build(n, sr, batch, seed, n_iter, weights=weights)


def _gen(seed: int, salt: int) -> torch.Generator:
    return torch.Generator().manual_seed(1_000_003 * seed + salt)


def _scenes(n: int, batch: int, seed: int) -> torch.Tensor:
    """``(B, 1, n, n)`` synthetic scenes in ``[0, 1]`` (:mod:`torchtof.recon.synthetic`)."""
    return synthetic_scenes(n, seed=seed, step=0, indices=range(batch))


def _dmd_buckets(S: DMDSplit, x: torch.Tensor, seed: int) -> torch.Tensor:
    """Depth-gated DMD buckets ``D_i`` (metres summed over the ROI, paper Eq. 10): object at
    2 m, 2×2 sensor pixels per DMD pixel, Gaussian noise of 0.2 % of the spread."""
    d = S(x) * (_OBJECT_M * _PIX_PER_DMD)
    sigma = 2e-3 * (d.amax(-1, keepdim=True) - d.amin(-1, keepdim=True))
    return d + sigma * torch.randn(d.shape, generator=_gen(seed, 1))


def _hadamard_buckets(A: Hadamard, x: torch.Tensor, seed: int) -> torch.Tensor:
    """Orthonormal measurements from the differential DMD buckets, ``(D⁺ − D⁻)/n``."""
    return combine_split(_dmd_buckets(DMDSplit(A), x, seed), A.n)


#: Peak bytes per frame pixel of the frame models' inputs (the example frames and the
#: tensors made from them: bool mask, float32 noise and amplitude, complex64 phasor, four
#: float32 taps and their intermediates), for the memory check before they are drawn; about
#: 1.2x the peak measured with the model's forward (53 / 18 / 13 bytes per pixel, n = 64).
_FRAME_BYTES = {"depth": 24, "intensity": 16, "taps": 64}


def _frames(n: int, m: int, x: torch.Tensor, seed: int, kind: str = "depth"
            ) -> tuple[torch.Tensor, torch.Tensor]:
    """``(lit (B, m, H, W) bool, noise (B, m, H, W))`` of the ToF frames of ``m`` DMD
    patterns: ``H = W = 2n + 8`` (2×2 sensor pixels per DMD pixel and a 4-pixel margin).
    The peak of the ``kind`` model's inputs is checked against the memory limit first."""
    side = 2 * n + 8
    check_memory(_FRAME_BYTES[kind] * x.shape[0] * m * side * side,
                 f"{x.shape[0]}x{m} ToF frames of {side}x{side} px ({kind})",
                 "onnx_models", "use a smaller n or sampling rate: the frame models take "
                 "every frame of the run")
    g = _gen(seed, 2)
    pats = random_binary_patterns(m, n, generator=g)
    lit = (pats[None] * (x > 0.5)).repeat_interleave(2, -1).repeat_interleave(2, -2) > 0
    lit = nn.functional.pad(lit, (4, 4, 4, 4))
    return lit, torch.randn(lit.shape, generator=g)


def _depth_frames(n: int, m: int, x: torch.Tensor, seed: int) -> torch.Tensor:
    """ToF depth frames (m): lit pixels at 2 m ± 3 cm, 10 % far multipath at 3.5–4.5 m,
    the rest "no photon" at 5 m (paper §2.2, §3.1)."""
    lit, noise = _frames(n, m, x, seed, "depth")
    far = noise.abs() < 0.125
    depth = torch.where(far, 4.0 + 0.2 * noise.clamp(-2.5, 2.5), torch.full_like(noise, 5.0))
    return torch.where(lit, _OBJECT_M + 0.03 * noise, depth)


def _roi_box(n: int) -> tuple[int, int, int, int]:
    return (4, 4, 2 * n, 2 * n)


def _build_hadamard(method):
    def build(n, sr, batch, seed, n_iter):
        A = Hadamard(n, sr=sr)
        x = _scenes(n, batch, seed)
        if method == "forward":
            return OperatorMethod(A, "forward"), (x,)
        return OperatorMethod(A, method), (_hadamard_buckets(A, x, seed),)

    return build


def _random_operator(n: int, sr: float) -> PatternOperator:
    """``M = round(sr·n²)`` random 0/1 DMD patterns, fixed (seed 0) so that every input seed
    sees the same model."""
    m = max(1, round(sr * n * n))
    return PatternOperator(random_binary_patterns(m, n, generator=_gen(0, 3)))


def _build_pattern_operator(n, sr, batch, seed, n_iter):
    return _random_operator(n, sr), (_scenes(n, batch, seed),)


def _build_readout(n, sr, batch, seed, n_iter):
    """Taps of a noisy scene: depths at the centres of the 0.25 m output steps ± 0.1 m
    (away from the rounding boundaries, where 1-ulp differences of atan2 would flip a step),
    amplitudes 0 (dark) or 20–400 e⁻, ambient offset 100 e⁻."""
    g = _gen(seed, 4)
    side = 2 * n
    shape = (batch, 1, side, side)
    step = torch.randint(0, 16, shape, generator=g).to(torch.float32)
    frac = 0.1 + 0.3 * torch.rand(shape, generator=g)
    frac = torch.where(torch.rand(shape, generator=g) < 0.5, frac, 1.0 - frac)
    depth = 1.0 + 0.25 * (step + frac - 0.5)  # steps of 0.25 m from 0.875 m, inside the range
    amp = 20.0 + 380.0 * torch.rand(shape, generator=g)
    amp = torch.where(torch.rand(shape, generator=g) < 0.1, torch.zeros_like(amp), amp)
    taps = correlation_taps(phasor_from_depth(amp, depth, MODULATION_HZ), offset=100.0 + amp / 2)
    return CameraReadout(freq_hz=MODULATION_HZ, step_m=PAPER_STEP_M), (taps,)


def _build_frames(kind):
    def build(n, sr, batch, seed, n_iter):
        m = max(1, round(sr * n * n))
        x = _scenes(n, batch, seed)
        if kind == "gate":
            return DepthGate(PAPER_GATE_M), (_depth_frames(n, m, x, seed),)
        if kind == "depth":
            return DepthBucket(_roi_box(n), PAPER_GATE_M), (_depth_frames(n, m, x, seed),)
        lit, noise = _frames(n, m, x, seed, "taps" if kind == "taps" else "intensity")
        amp = lit * 200.0 + 5.0 + noise  # e⁻: signal on lit pixels, a dim background
        if kind == "intensity":
            return IntensityBucket(_roi_box(n)), (amp,)
        # Eq. 6 taps (Fig. 1 order) of a return at the object's depth, ambient offset 100 e⁻
        b, _, h, w = amp.shape
        a = amp.reshape(-1, 1, h, w).clamp_min(0.0)  # a return's magnitude: the noise's tail
        # below −5σ would make it negative (phasor_from_depth refuses that)
        p = phasor_from_depth(a, torch.full_like(a, _OBJECT_M), MODULATION_HZ)
        taps = correlation_taps(p, offset=100.0).view(b, m, 4, h, w)
        return TapBuckets(_roi_box(n)), (taps,)

    return build


def _build_correlation(cls):
    def build(n, sr, batch, seed, n_iter):
        S = DMDSplit(Hadamard(n, sr=sr))
        return cls(S), (_dmd_buckets(S, _scenes(n, batch, seed), seed),)

    return build


def _build_pinv(n, sr, batch, seed, n_iter):
    P = _random_operator(n, sr)
    y = P(_scenes(n, batch, seed)) * (_OBJECT_M * _PIX_PER_DMD)
    return PseudoInverse(P), (y,)


def _build_bp(n, sr, batch, seed, n_iter):
    A = Hadamard(n, sr=sr)
    bp = BasisPursuit(A, n_iter=n_iter, adaptive=False)
    return bp, (_hadamard_buckets(A, _scenes(n, batch, seed), seed),)


def _build_unrolled(n, sr, batch, seed, n_iter):
    A = Hadamard(n, sr=sr)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # raised below instead
        net = UnrolledTVAL3(A, n_layers=n_iter, pretrained=True)
    if net.weights_file is None:
        raise ValueError(
            f"MODELS['unrolled_tval3']: no shipped weights for n={n}, sr={sr}, K={n_iter}; "
            f"shipped: {available_weights()}"
        )
    return net, (_hadamard_buckets(A, _scenes(n, batch, seed), seed),)


def _build_learned(n, sr, batch, seed, n_iter, weights=None):
    """:class:`~torchtof.recon.learned.Learned` with its shipped weights (one file, any n), or
    those of ``weights`` (e.g. a ``torchtof train`` run's ``learned.pt``)."""
    A = Hadamard(n, sr=sr)
    net = Learned(A, pretrained=True if weights is None else weights)
    return net.eval(), (_hadamard_buckets(A, _scenes(n, batch, seed), seed),)


def _build_depth_resolved(n, sr, batch, seed, n_iter):
    """:class:`~torchtof.recon.DepthResolved` around :class:`~torchtof.recon.UnrolledTVAL3`
    (shipped weights where they exist, else TVAL3's defaults), 30 MHz, I/Q mode. Inputs: tap
    buckets (Fig. 1 order) of synthetic 3-D scenes: reflectance 0.3–1, depth 1–4 m (phase
    away from the 0/2π wrap), ambient offset, Gaussian noise of 0.2 % of the spread."""
    A = Hadamard(n, sr=sr)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # said below, in this model's words
        net = UnrolledTVAL3(A, n_layers=n_iter, pretrained=True)
    if net.weights_file is None:  # unrolled_tval3 refuses; this model documents its fallback
        warnings.warn(f"MODELS['depth_resolved']: no shipped unrolled weights for n={n}, "
                      f"sr={sr}, K={n_iter}: its unrolled TVAL3 holds TVAL3's default scalars "
                      f"(untrained); shipped: {available_weights()}", UserWarning, stacklevel=2)
    refl = 0.3 + 0.7 * _scenes(n, batch, seed)
    depth = 1.0 + 3.0 * synthetic_scenes(n, seed=seed + 1, step=0, indices=range(batch))
    taps = correlation_taps(phasor_from_depth(400.0 * refl, depth, MODULATION_HZ), offset=2600.0)
    y = A(taps)
    sigma = 2e-3 * (y.amax(-1, keepdim=True) - y.amin(-1, keepdim=True))
    y = y + sigma * torch.randn(y.shape, generator=_gen(seed, 5))
    return DepthAmplitude(DepthResolved(net, freq_hz=MODULATION_HZ)), (y,)


def _build_tval3(n, sr, batch, seed, n_iter):
    A = Hadamard(n, sr=sr)
    rec = TVAL3(A, max_iter=n_iter, adaptive=False)
    return rec, (_hadamard_buckets(A, _scenes(n, batch, seed), seed),)


def _build_tgv(n, sr, batch, seed, n_iter):
    A = Hadamard(n, sr=sr)
    rec = TGV(A, max_iter=n_iter, adaptive=False)
    return rec, (_hadamard_buckets(A, _scenes(n, batch, seed), seed),)


def _dip_data(n: int, sr: float, batch: int, seed: int) -> tuple[Hadamard, torch.Tensor]:
    A = Hadamard(n, sr=sr)
    return A, _hadamard_buckets(A, _scenes(n, batch, seed), seed)


def _build_unet(n, sr, batch, seed, n_iter):
    """A fresh :func:`default_unet` (initialised from seed 0), eval mode; the input is the
    DIP input :func:`dip_input` (z-scored ``A⁺y``) of the buckets."""
    A, y = _dip_data(n, sr, batch, seed)
    with torch.random.fork_rng():
        torch.manual_seed(0)
        net = default_unet(n).eval()
    return net, (dip_input(y, A),)


def _build_dip(n, sr, batch, seed, n_iter):
    """The U-Net of :func:`fit_dip` fitted for ``n_iter`` steps to the buckets of scene 0 of
    seed 0 (fixed, whatever ``seed``); inputs: :func:`dip_input` of the buckets."""
    A, y0 = _dip_data(n, sr, 1, 0)
    net = fit_dip(y0, A, max_iter=n_iter, seed=0).unet
    _, y = _dip_data(n, sr, batch, seed)
    return net, (dip_input(y, A),)


_IMG = "(batch, 1, n, n)"
_MEAS = "(batch, 1, M)"

#: Registry of exportable models: ``MODELS[name](n, sr) -> (module, example_inputs)``.
MODELS: dict[str, ModelSpec] = {
    "hadamard": ModelSpec(
        _build_hadamard("forward"),
        ("x",),
        ("y",),
        {"x": _IMG, "y": _MEAS},
        "Hadamard operator A x (orthonormal rows, cake-cutting order)",
    ),
    "hadamard_adjoint": ModelSpec(
        _build_hadamard("adjoint"),
        ("y",),
        ("x",),
        {"y": _MEAS, "x": _IMG},
        "Hadamard adjoint A^T y",
    ),
    "hadamard_pinv": ModelSpec(
        _build_hadamard("pinv"),
        ("y",),
        ("x",),
        {"y": _MEAS, "x": _IMG},
        "Hadamard pseudo-inverse A^+ y (= A^T y)",
    ),
    "pattern_operator": ModelSpec(
        _build_pattern_operator,
        ("x",),
        ("y",),
        {"x": _IMG, "y": _MEAS},
        "dense PatternOperator of M random 0/1 DMD patterns",
    ),
    "camera": ModelSpec(
        _build_readout,
        ("taps",),
        ("amplitude", "phase", "depth"),
        {
            "taps": "(batch, 4, 2n, 2n)",
            "amplitude": "(batch, 1, 2n, 2n)",
            "phase": "(batch, 1, 2n, 2n)",
            "depth": "(batch, 1, 2n, 2n)",
        },
        "ToF camera readout: taps (Fig. 1 order) -> Eq. 8 amplitude, Eq. 7 phase, Eq. 1 "
        "depth with the camera rules ([1, 5] m, 0.25 m step, no photon -> 5 m)",
    ),
    "depth_gate": ModelSpec(
        _build_frames("gate"),
        ("depth",),
        ("gated",),
        {"depth": "(batch, M, 2n+8, 2n+8)", "gated": "(batch, M, 2n+8, 2n+8)"},
        "depth gate (paper's low-pass filter): depth > 3 m -> 0",
    ),
    "depth_bucket": ModelSpec(
        _build_frames("depth"),
        ("depth",),
        ("y",),
        {"depth": "(batch, M, 2n+8, 2n+8)", "y": _MEAS},
        "depth bucket D_i (Eq. 10) over a 2n x 2n ROI after the 3 m depth gate",
    ),
    "intensity_bucket": ModelSpec(
        _build_frames("intensity"),
        ("amplitude",),
        ("y",),
        {"amplitude": "(batch, M, 2n+8, 2n+8)", "y": _MEAS},
        "intensity bucket S_i over a 2n x 2n ROI",
    ),
    "tap_buckets": ModelSpec(
        _build_frames("taps"),
        ("taps",),
        ("y",),
        {"taps": "(batch, M, 4, 2n+8, 2n+8)", "y": "(batch, 4, M)"},
        "per-tap buckets C_k,i over a 2n x 2n ROI",
    ),
    "g2": ModelSpec(
        _build_correlation(CGI),
        ("y",),
        ("x",),
        {"y": "(batch, 1, 2M)", "x": _IMG},
        "g2 correlation image (Eq. 9/10) from the 2M depth buckets of the DMD-split patterns",
    ),
    "tgi": ModelSpec(
        _build_correlation(TGI),
        ("y",),
        ("x",),
        {"y": "(batch, 1, 2M)", "x": _IMG},
        "traditional ghost image <(y - <y>) phi> of the DMD-split patterns",
    ),
    "dgi": ModelSpec(
        _build_correlation(DGI),
        ("y",),
        ("x",),
        {"y": "(batch, 1, 2M)", "x": _IMG},
        "differential ghost image (Ferri 2010) of the DMD-split patterns",
    ),
    "pinv": ModelSpec(
        _build_pinv,
        ("y",),
        ("x",),
        {"y": _MEAS, "x": _IMG},
        "pseudo-inverse A^T (A A^T)^-1 y of M random 0/1 patterns",
    ),
    "bp": ModelSpec(
        _build_bp,
        ("y",),
        ("x",),
        {"y": _MEAS, "x": _IMG},
        "basis pursuit (DCT, ADMM), fixed n_iter iterations (adaptive=False)",
        exporter="torchscript",
        n_iter=100,
    ),
    "unrolled_tval3": ModelSpec(
        _build_unrolled,
        ("y",),
        ("x",),
        {"y": _MEAS, "x": _IMG},
        "unrolled TVAL3 with the shipped weights (K = 12)",
        exporter="torchscript",
        n_iter=12,
    ),
    "depth_resolved": ModelSpec(
        _build_depth_resolved,
        ("taps",),
        ("depth", "amplitude"),
        {"taps": "(batch, 4, M)", "depth": _IMG, "amplitude": _IMG},
        "depth-resolved GI: tap buckets -> I/Q -> unrolled TVAL3 (K = 12) -> Eq. 7/1 depth "
        "(m) and Eq. 8 amplitude per DMD pixel, 30 MHz",
        exporter="torchscript",
        n_iter=12,
    ),
    "tval3": ModelSpec(
        _build_tval3,
        ("y",),
        ("x",),
        {"y": _MEAS, "x": _IMG},
        "TVAL3 (mu='auto', BB steps, nonmonotone search), fixed n_iter iterations (adaptive=False)",
        exporter="torchscript",
        n_iter=50,
    ),
    "tgv": ModelSpec(
        _build_tgv,
        ("y",),
        ("x",),
        {"y": _MEAS, "x": _IMG},
        "TGV² (constrained, alpha='auto'), fixed n_iter primal-dual iterations (adaptive=False; "
        "the graph grows with n_iter)",
        exporter="torchscript",
        n_iter=100,
    ),
    "unet": ModelSpec(
        _build_unet,
        ("x0",),
        ("x",),
        {"x0": _IMG, "x": _IMG},
        "fresh (untrained) DIP U-Net, eval mode; input: z-scored A^+ y (dip_input)",
    ),
    "dip": ModelSpec(
        _build_dip,
        ("x0",),
        ("x",),
        {"x0": _IMG, "x": _IMG},
        "DIP U-Net fitted by fit_dip for n_iter steps (batch statistics folded, eval mode); "
        "input: z-scored A^+ y (dip_input)",
        n_iter=300,
    ),
    "learned": ModelSpec(
        _build_learned, ("y",), ("x",), {"y": _MEAS, "x": _IMG},
        "learned proximal-gradient network, shipped weights (one file for every n, SR, order) "
        "or a trained file's (--weights)",
        exporter="torchscript",
        weights=True,
    ),
}


def export_model(
    name: str,
    n: int = 32,
    sr: float = 0.25,
    path: str | os.PathLike | None = None,
    opset: int | None = DEFAULT_OPSET,
    *,
    n_iter: int | None = None,
    exporter: str | None = None,
    dynamic_batch: bool = True,
    weights: str | os.PathLike | None = None,
) -> Path:
    """Build ``MODELS[name]`` for ``(n, sr)`` and export it (``torchtof export MODEL``).

    Args:
        name: a key of :data:`MODELS`.
        n: DMD side; sr: sampling rate ``M / n²``.
        path: output file (default ``{name}_n{n}_sr{sr}.onnx`` in the working folder).
        opset: ONNX opset (17 or 18; ``None``: :data:`DEFAULT_OPSET`).
        n_iter: iterations of an iterative model (default: the registry's).
        exporter: ``"dynamo"``/``"torchscript"`` (default: the registry's choice).
        dynamic_batch: dynamic batch axis.
        weights: a weights file for a model that loads one (``learned``: e.g. a
            ``torchtof train`` run's ``learned.pt``; default: the shipped weights).

    Returns:
        The path written.

    Raises:
        ValueError: unknown ``name`` (or as :func:`export`).
    """
    return _export_spec(name, n, sr, path, opset, n_iter=n_iter, exporter=exporter,
                        dynamic_batch=dynamic_batch, weights=weights)[0]


def _export_spec(name, n, sr, path, opset, *, n_iter=None, exporter=None, dynamic_batch=True,
                 func="export_model", weights=None):
    """:func:`export_model`, returning ``(path, module, example inputs)``."""
    if name not in MODELS:
        raise ValueError(f"{func}: expected name in {sorted(MODELS)}, got {name!r}")
    spec = MODELS[name]
    if weights is not None and not spec.weights:
        raise ValueError(f"{func}: expected weights only for a model that loads them "
                         f"({', '.join(k for k, v in MODELS.items() if v.weights)}), got {name!r}")
    module, inputs = spec(n, sr, n_iter=n_iter, weights=weights)
    if path is None:
        path = f"{name}_n{n}_sr{sr:g}.onnx"
    path = export(
        module,
        inputs,
        path,
        dynamic_batch,
        opset,
        input_names=spec.inputs,
        output_names=spec.outputs,
        exporter=exporter or spec.exporter,
    )
    return path, module, inputs


def export_checked(
    name: str,
    n: int = 32,
    sr: float = 0.25,
    path: str | os.PathLike | None = None,
    opset: int | None = DEFAULT_OPSET,
    *,
    n_iter: int | None = None,
    exporter: str | None = None,
    rtol: float = 1e-4,
    atol: float = 1e-5,
    weights: str | os.PathLike | None = None,
) -> dict:
    """:func:`export_model`, then onnxruntime against eager PyTorch on the file
    (:func:`torchtof.onnx.check`, ``rtol``/``atol``) at a batch of 3, one more than the
    export's, so the dynamic batch axis is exercised (``torchtof export MODEL``).

    Returns:
        ``{"path", "bytes", "parity"}``; ``parity`` is the report of
        :func:`~torchtof.onnx.check` (``"ok": True``, each output's ``max_abs_err``) or
        ``{"ok": False, "error": message}`` when an output is out of tolerance.

    Raises:
        ValueError: as :func:`export_model`.
    """
    from ..onnx import check

    path, module, inputs = _export_spec(name, n, sr, path, opset, n_iter=n_iter,
                                        exporter=exporter, func="export_checked",
                                        weights=weights)
    batch3 = tuple(torch.cat([t, t[:1]]) for t in inputs)  # EXPORT_BATCH + 1 samples
    try:
        parity = check(path, module, batch3, rtol=rtol, atol=atol)
    except AssertionError as exc:  # check's way of saying "out of tolerance"
        parity = {"ok": False, "error": str(exc).strip().splitlines()[0]}
    return {"path": Path(path), "bytes": Path(path).stat().st_size, "parity": parity}
