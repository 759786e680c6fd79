"""ONNX export of the inference modules and parity checks against onnxruntime (CPU).

:func:`export` writes a module to an ``.onnx`` file with ``torch.onnx.export`` (batch axis
dynamic, opset :data:`DEFAULT_OPSET`) and validates it with ``onnx.checker``; :func:`check`
runs the file under onnxruntime's ``CPUExecutionProvider`` and compares every output with
eager PyTorch. :data:`MODELS` is the registry of exportable models: each entry builds the
module and realistic example inputs (buckets of synthetic scenes at the scales of the
paper's experiment) for a DMD side ``n`` and a sampling rate ``sr``;
:func:`export_model` exports one of them (``torchtof export MODEL``).

**Exporters.** ``torch.onnx.export`` has two back ends and both are used:

- ``"dynamo"`` (``torch.export`` + onnxscript, the default of torch >= 2.9): every model
  without a long unrolled loop (operators, camera readout, buckets, correlation images,
  U-Nets). It is the maintained exporter, and its onnxscript optimiser folds constants,
  so graphs come out smaller.
- ``"torchscript"`` (the legacy tracer): the iterative solvers (basis pursuit, TVAL3,
  unrolled TVAL3). Their fixed-iteration loops unroll into 10³–10⁵ ONNX nodes, and
  ``torch.export`` propagates fake tensors with a symbolic batch through every one of them
  and decomposes them again: on 2 CPU cores the 12-iteration unrolled TVAL3 at n = 32
  takes 48 s to export (the tracer: 1.6 s) for the same onnxruntime result. The
  TorchScript exporter is deprecated upstream; ``exporter="dynamo"`` works for them too,
  only slower to export (its unrolled-TVAL3 graph runs ~25 % faster in onnxruntime).
  ``dgi`` also uses the tracer while onnxscript cannot lower ``amax()`` without ``dim``.

**Dynamic batch.** Models are exported at a batch of 2 with the first axis of every input
and output dynamic (``dynamic_batch=True``); :func:`check` then runs onnxruntime at other
batch sizes, which catches batch sizes baked into the graph.

**Fixed iterations.** Exported graphs hold no data-dependent control flow: the solvers run
a fixed number of iterations (``adaptive=False``). The adaptive solvers of
:mod:`torchtof.recon` stop each sample at a tolerance instead, so an exported solver can
differ from the default eager one: it may stop before convergence or run past it (see
``export/README.md``).
"""

from __future__ import annotations

import dataclasses
import os
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import onnx
import torch
import torch.onnx
from torch import nn

from .bucket import PAPER_GATE_M, DepthBucket, DepthGate, IntensityBucket, TapBuckets
from .operators import DMDSplit, Hadamard, PatternOperator, random_binary_patterns
from .operators.split import combine_split
from .recon.bp import BasisPursuit
from .recon.correlation import CGI, DGI, TGI
from .recon.depth import DepthResolved
from .recon.dip import default_unet, dip_input, fit_dip
from .recon.pinv import PseudoInverse
from .recon.synthetic import synthetic_scenes
from .recon.tval3 import TVAL3
from .recon.unrolled import UnrolledTVAL3, available_weights
from .sensor.functional import (
    camera_rules,
    correlation_taps,
    phase_to_depth,
    phasor_from_depth,
    tap_amplitude,
    tap_phase,
)

__all__ = [
    "DEFAULT_OPSET",
    "EXPORTERS",
    "MODELS",
    "ModelSpec",
    "CameraReadout",
    "DepthAmplitude",
    "OperatorMethod",
    "export",
    "check",
    "export_model",
    "ort_session",
]

#: Opset of every exported file (the dynamo exporter's native opset).
DEFAULT_OPSET = 18
#: The two back ends of ``torch.onnx.export`` (see the module docstring).
EXPORTERS = ("dynamo", "torchscript")
#: Example batch of the exports; :func:`check` compares at other batch sizes.
EXPORT_BATCH = 2


# ---------------------------------------------------------------------------------------------
# export wrappers
# ---------------------------------------------------------------------------------------------
class OperatorMethod(nn.Module):
    """Export wrapper whose ``forward`` is one method of a linear operator.

    ``torch.onnx.export`` exports ``forward``; this makes ``A.adjoint`` and ``A.pinv``
    exportable as models of their own.

    Args:
        A: the operator.
        method: ``"forward"``, ``"adjoint"`` or ``"pinv"``.

    Shape:
        ``forward``: ``(B, C, n, n) -> (B, C, M)``; ``adjoint``/``pinv``:
        ``(B, C, M) -> (B, C, n, n)``.
    """

    METHODS = ("forward", "adjoint", "pinv")

    def __init__(self, A: nn.Module, method: str) -> None:
        super().__init__()
        if method not in self.METHODS:
            raise ValueError(f"OperatorMethod: expected method in {self.METHODS}, got {method!r}")
        self.A = A
        self.method = method

    def forward(self, t: torch.Tensor) -> torch.Tensor:
        return getattr(self.A, self.method)(t)

    def extra_repr(self) -> str:
        return f"method={self.method!r}"


def camera_readout(
    taps: torch.Tensor,
    freq_hz: float = 30e6,
    min_m: float = 1.0,
    max_m: float = 5.0,
    amp_threshold: float = 0.0,
    no_photon_m: float = 5.0,
    step_m: float | None = 0.25,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The ToF camera's on-chip computation: taps → amplitude, phase, depth (paper §2.1–2.2).

    Amplitude by Eq. 8, phase by Eq. 7 (Fig. 1 tap order), depth by Eq. 1 followed by the
    camera rules of §2.2 (:func:`~torchtof.sensor.functional.camera_rules`): clip to
    ``[min_m, max_m]``, round to ``step_m`` (paper: 0.25 m), ``no_photon_m`` where the
    amplitude is ``<= amp_threshold``. The noise-free half of
    :func:`~torchtof.sensor.cw_tof_sensor` (which starts from complex phasors, which
    ONNX cannot carry), so the deployed camera model starts from the measured taps.

    Args:
        taps: real taps ``(B, 4, H, W)`` in the Fig. 1 order (``τ = 0, π, π/2, 3π/2``).
        freq_hz, min_m, max_m, amp_threshold, no_photon_m, step_m: as in
            :func:`~torchtof.sensor.functional.camera_rules` and
            :func:`~torchtof.sensor.functional.phase_to_depth`.

    Returns:
        ``(amplitude, phase, depth)``, each ``(B, 1, H, W)``.

    Raises:
        TypeError, ValueError: as the sensor functions (wrong shape, dtype, parameters).

    Example:
        >>> taps = correlation_taps(torch.full((1, 1, 2, 2), 3.0 + 4.0j), offset=5.0)
        >>> [t.shape[1] for t in camera_readout(taps)]
        [1, 1, 1]
    """
    amplitude = tap_amplitude(taps)
    phase = tap_phase(taps)
    depth = camera_rules(
        phase_to_depth(phase, freq_hz),
        amplitude,
        min_m,
        max_m,
        amp_threshold,
        no_photon_m,
        step_m,
    )
    return amplitude, phase, depth


class CameraReadout(nn.Module):
    """Module of :func:`camera_readout` (taps → amplitude, phase, depth), paper defaults."""

    def __init__(
        self,
        freq_hz: float = 30e6,
        min_m: float = 1.0,
        max_m: float = 5.0,
        amp_threshold: float = 0.0,
        no_photon_m: float = 5.0,
        step_m: float | None = 0.25,
    ) -> None:
        super().__init__()
        self.config = dict(
            freq_hz=freq_hz,
            min_m=min_m,
            max_m=max_m,
            amp_threshold=amp_threshold,
            no_photon_m=no_photon_m,
            step_m=step_m,
        )
        camera_rules(
            torch.ones(1, 1, 1, 1),
            torch.ones(1, 1, 1, 1),
            min_m,
            max_m,
            amp_threshold,
            no_photon_m,
            step_m,
        )  # validates the configuration

    def forward(self, taps: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        return camera_readout(taps, **self.config)


class DepthAmplitude(nn.Module):
    """Export wrapper of :class:`~torchtof.recon.DepthResolved`: buckets → ``(depth, amplitude)``.

    ``DepthResolved.forward`` returns the depth map only; this returns both maps of
    :meth:`~torchtof.recon.DepthResolved.depth_amplitude` (Eq. 1 depth in metres, Eq. 8
    amplitude), each ``(B, 1, n, n)``, from tap buckets ``(B, 4, M)`` or I/Q ``(B, 2, M)``.
    """

    def __init__(self, net: DepthResolved) -> None:
        super().__init__()
        if not isinstance(net, DepthResolved):
            raise TypeError(f"DepthAmplitude: expected a DepthResolved, got {type(net).__name__}")
        self.net = net

    def forward(self, y: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.net.depth_amplitude(y)


# ---------------------------------------------------------------------------------------------
# export and check
# ---------------------------------------------------------------------------------------------
def _as_tuple(inputs: torch.Tensor | Sequence[torch.Tensor]) -> tuple[torch.Tensor, ...]:
    t = (inputs,) if isinstance(inputs, torch.Tensor) else tuple(inputs)
    if not t or not all(isinstance(i, torch.Tensor) for i in t):
        raise TypeError("expected example inputs as a tensor or a non-empty sequence of tensors")
    return t


def _flat_outputs(out: object) -> tuple[torch.Tensor, ...]:
    if isinstance(out, torch.Tensor):
        return (out,)
    return tuple(out)


def export(
    module: nn.Module,
    example_inputs: torch.Tensor | Sequence[torch.Tensor],
    path: str | os.PathLike,
    dynamic_batch: bool = True,
    opset: int | None = DEFAULT_OPSET,
    *,
    input_names: Sequence[str] | None = None,
    output_names: Sequence[str] | None = None,
    exporter: str = "dynamo",
) -> Path:
    """Export ``module`` to ONNX and validate the file with ``onnx.checker``.

    The module is run once eagerly on ``example_inputs`` first (the eager input checks,
    skipped while tracing, validate them, and caches are filled with real tensors), then
    exported in ``eval`` mode (its training flag is restored afterwards).

    Args:
        module: the model; ``forward`` takes tensors and returns a tensor or a tuple.
        example_inputs: a tensor or a tuple of tensors (their batch should not be 1 when
            ``dynamic_batch``: a batch of 1 would be specialised).
        path: the ``.onnx`` file to write (parent folders are created).
        dynamic_batch: make axis 0 of every input and output dynamic (name ``"batch"``).
        opset: ONNX opset, 17 or 18 (``None``: :data:`DEFAULT_OPSET`).
        input_names, output_names: graph names (default ``input_0 …``/``output_0 …``).
        exporter: ``"dynamo"`` or ``"torchscript"`` (module docstring).

    Returns:
        The path written.

    Raises:
        TypeError: ``module`` is not an ``nn.Module`` or inputs are not tensors.
        ValueError: unknown ``exporter``, an opset other than 17/18, a batch of 1 with
            ``dynamic_batch``, or names of the wrong length.
        onnx.checker.ValidationError: the written file is not valid ONNX.

    Example:
        >>> A = Hadamard(8, sr=0.5)
        >>> p = export(A, torch.rand(2, 1, 8, 8), "/tmp/hadamard.onnx")  # doctest: +SKIP
    """
    func = "export"
    if not isinstance(module, nn.Module):
        raise TypeError(f"{func}: expected module to be an nn.Module, got {type(module).__name__}")
    if exporter not in EXPORTERS:
        raise ValueError(f"{func}: expected exporter in {EXPORTERS}, got {exporter!r}")
    opset = DEFAULT_OPSET if opset is None else opset
    if opset not in (17, 18):
        raise ValueError(f"{func}: expected opset 17 or 18, got {opset!r}")
    inputs = _as_tuple(example_inputs)
    if dynamic_batch and any(t.ndim == 0 or t.shape[0] == 1 for t in inputs):
        raise ValueError(
            f"{func}: expected example inputs with a batch axis of size > 1 for dynamic_batch "
            f"(a batch of 1 is specialised), got shapes {[tuple(t.shape) for t in inputs]}"
        )
    training = module.training
    module.eval()
    try:
        with torch.no_grad():
            outs = _flat_outputs(module(*inputs))
        in_names = list(input_names or [f"input_{i}" for i in range(len(inputs))])
        out_names = list(output_names or [f"output_{i}" for i in range(len(outs))])
        if len(in_names) != len(inputs) or len(out_names) != len(outs):
            raise ValueError(
                f"{func}: expected {len(inputs)} input and {len(outs)} output names, got "
                f"{in_names} and {out_names}"
            )
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)  # the legacy exporter's notice
            warnings.simplefilter("ignore", FutureWarning)
            # the tracer flags the static shape checks; check() verifies other batch sizes
            warnings.simplefilter("ignore", torch.jit.TracerWarning)
            if exporter == "dynamo":
                kw = {}
                if dynamic_batch:
                    batch = torch.export.Dim("batch")
                    kw["dynamic_shapes"] = tuple({0: batch} for _ in inputs)
                program = torch.onnx.export(
                    module,
                    inputs,
                    dynamo=True,
                    opset_version=opset,
                    input_names=in_names,
                    output_names=out_names,
                    verbose=False,
                    **kw,
                )
                program.save(path)
            else:
                axes = {name: {0: "batch"} for name in in_names + out_names}
                torch.onnx.export(
                    module,
                    inputs,
                    path,
                    dynamo=False,
                    opset_version=opset,
                    input_names=in_names,
                    output_names=out_names,
                    dynamic_axes=axes if dynamic_batch else None,
                )
    finally:
        module.train(training)
    onnx.checker.check_model(onnx.load(path), full_check=True)
    return path


def ort_session(path: str | os.PathLike, threads: int | None = None):
    """An onnxruntime ``InferenceSession`` on the CPU provider (``threads`` intra-op)."""
    import onnxruntime as ort

    opts = ort.SessionOptions()
    if threads is not None:
        opts.intra_op_num_threads = int(threads)
    return ort.InferenceSession(os.fspath(path), opts, providers=["CPUExecutionProvider"])


def check(
    path: str | os.PathLike,
    module: nn.Module,
    inputs: torch.Tensor | Sequence[torch.Tensor],
    rtol: float = 1e-4,
    atol: float = 1e-5,
) -> dict:
    """Compare onnxruntime (CPU) on ``path`` with eager ``module`` on ``inputs``.

    The file is validated with ``onnx.checker`` and every output is compared elementwise,

    .. math::
        |o_{ort} - o_{torch}| \\le atol \\cdot \\max(1, \\max|o_{torch}|) + rtol \\cdot |o_{torch}|,

    with matching shapes: ``numpy.allclose`` for outputs of magnitude up to 1, and ``atol``
    relative to the output's peak above that. Images reconstructed from buckets of size
    ``Y`` carry float32 rounding of about ``eps₃₂·Y`` in PyTorch itself (traditional GI
    subtracts the mean bucket), so an absolute ``atol`` below the output's own rounding
    level would test the summation order, not the export. Use inputs of a batch size other
    than the export's to test the dynamic batch axis.

    Args:
        path: the ``.onnx`` file.
        module: the eager module (run in ``eval`` mode under ``no_grad``).
        inputs: a tensor or a tuple of tensors, float32.
        rtol, atol: tolerances.

    Returns:
        ``{"outputs": [{"name", "shape", "peak", "max_abs_err", "max_rel_err"}...],
        "ok": True}``.

    Raises:
        AssertionError: a shape differs or an output is not within tolerance (the message
            gives the worst error of each output).
    """
    inputs = _as_tuple(inputs)
    onnx.checker.check_model(onnx.load(path), full_check=True)
    sess = ort_session(path)
    if len(sess.get_inputs()) != len(inputs):
        raise ValueError(
            f"check: {os.fspath(path)} takes {len(sess.get_inputs())} inputs, got {len(inputs)}"
        )
    feeds = {
        i.name: t.detach().cpu().numpy() for i, t in zip(sess.get_inputs(), inputs, strict=True)
    }
    got = sess.run(None, feeds)
    training = module.training
    module.eval()
    try:
        with torch.no_grad():
            want = [t.cpu().numpy() for t in _flat_outputs(module(*inputs))]
    finally:
        module.train(training)
    report, bad = [], []
    for meta, g, w in zip(sess.get_outputs(), got, want, strict=False):  # counted below
        if g.shape != w.shape:
            bad.append(f"{meta.name}: shape {g.shape} != torch {w.shape}")
            continue
        err = np.abs(g.astype(np.float64) - w)
        rel = err / np.maximum(np.abs(w), np.finfo(np.float64).tiny)
        peak = float(np.abs(w).max(initial=0))
        row = dict(
            name=meta.name,
            shape=tuple(g.shape),
            peak=peak,
            max_abs_err=float(err.max(initial=0)),
            max_rel_err=float(rel.max(initial=0)),
        )
        report.append(row)
        excess = err - (atol * max(1.0, peak) + rtol * np.abs(w))
        if not (np.isfinite(g).all() and float(excess.max(initial=0)) <= 0):
            bad.append(
                f"{meta.name}: max |err| {row['max_abs_err']:.3g} (peak {peak:.3g}), "
                f"excess over the tolerance {float(excess.max(initial=0)):.3g}"
            )
    if len(got) != len(want):
        bad.append(f"{len(got)} onnxruntime outputs, {len(want)} torch outputs")
    if bad:
        raise AssertionError(
            f"check: {os.fspath(path)} differs from PyTorch "
            f"(rtol={rtol}, atol={atol}): " + "; ".join(bad)
        )
    return {"outputs": report, "ok": True}


# ---------------------------------------------------------------------------------------------
# registry
# ---------------------------------------------------------------------------------------------
#: Depth of the object (m) and sensor pixels per DMD pixel (64×64 ROI for 32×32, DESIGN §3).
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
    """

    build: Callable[..., tuple[nn.Module, tuple[torch.Tensor, ...]]]
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    shapes: dict[str, str]
    doc: str
    exporter: str = "dynamo"
    n_iter: int | None = None

    def __call__(
        self,
        n: int = 32,
        sr: float = 0.25,
        *,
        batch: int = EXPORT_BATCH,
        seed: int = 0,
        n_iter: int | None = None,
    ) -> tuple[nn.Module, tuple[torch.Tensor, ...]]:
        if n_iter is not None and self.n_iter is None:
            raise ValueError(f"ModelSpec: n_iter given for a model without iterations: {self.doc}")
        if isinstance(batch, bool) or not isinstance(batch, int) or batch < 1:
            raise ValueError(f"ModelSpec: expected batch to be an int >= 1, got {batch!r}")
        return self.build(n, sr, batch, seed, self.n_iter if n_iter is None else n_iter)


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


def _frames(n: int, m: int, x: torch.Tensor, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    """``(lit (B, m, H, W) bool, noise (B, m, H, W))`` of the ToF frames of ``m`` DMD
    patterns: ``H = W = 2n + 8`` (2×2 sensor pixels per DMD pixel and a 4-pixel margin)."""
    g = _gen(seed, 2)
    pats = random_binary_patterns(m, n, generator=g)
    lit = (pats[None] * (x > 0.5)).repeat_interleave(2, -1).repeat_interleave(2, -2) > 0
    lit = nn.functional.pad(lit, (4, 4, 4, 4))
    return lit, torch.randn(lit.shape, generator=g)


def _depth_frames(n: int, m: int, x: torch.Tensor, seed: int) -> torch.Tensor:
    """ToF depth frames (m): lit pixels at 2 m ± 3 cm, 10 % far multipath at 3.5–4.5 m,
    the rest "no photon" at 5 m (paper §2.2, §3.1)."""
    lit, noise = _frames(n, m, x, seed)
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
    taps = correlation_taps(phasor_from_depth(amp, depth, 30e6), offset=100.0 + amp / 2)
    return CameraReadout(), (taps,)


def _build_frames(kind):
    def build(n, sr, batch, seed, n_iter):
        m = max(1, round(sr * n * n))
        x = _scenes(n, batch, seed)
        if kind == "gate":
            return DepthGate(PAPER_GATE_M), (_depth_frames(n, m, x, seed),)
        if kind == "depth":
            return DepthBucket(_roi_box(n), PAPER_GATE_M), (_depth_frames(n, m, x, seed),)
        lit, noise = _frames(n, m, x, seed)
        amp = lit * 200.0 + 5.0 + noise  # e⁻: signal on lit pixels, a dim background
        if kind == "intensity":
            return IntensityBucket(_roi_box(n)), (amp,)
        phase = 4 * torch.pi * 30e6 * _OBJECT_M / 299_792_458.0
        tau = torch.tensor([0.0, torch.pi, torch.pi / 2, 3 * torch.pi / 2])  # Fig. 1 order
        taps = 100.0 + 0.5 * amp[:, :, None] * torch.cos(phase + tau)[:, None, None]
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


def _build_depth_resolved(n, sr, batch, seed, n_iter):
    """:class:`~torchtof.recon.DepthResolved` around :class:`~torchtof.recon.UnrolledTVAL3`
    (shipped weights where they exist, else TVAL3's defaults), 30 MHz, I/Q mode. Inputs: tap
    buckets (Fig. 1 order) of synthetic 3-D scenes: reflectance 0.3–1, depth 1–4 m (phase
    away from the 0/2π wrap), ambient offset, Gaussian noise of 0.2 % of the spread."""
    A = Hadamard(n, sr=sr)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # no shipped weights: TVAL3 defaults
        net = UnrolledTVAL3(A, n_layers=n_iter, pretrained=True)
    refl = 0.3 + 0.7 * _scenes(n, batch, seed)
    depth = 1.0 + 3.0 * synthetic_scenes(n, seed=seed + 1, step=0, indices=range(batch))
    taps = correlation_taps(phasor_from_depth(400.0 * refl, depth, 30e6), offset=2600.0)
    y = A(taps)
    sigma = 2e-3 * (y.amax(-1, keepdim=True) - y.amin(-1, keepdim=True))
    y = y + sigma * torch.randn(y.shape, generator=_gen(seed, 5))
    return DepthAmplitude(DepthResolved(net, freq_hz=30e6)), (y,)


def _build_tval3(n, sr, batch, seed, n_iter):
    A = Hadamard(n, sr=sr)
    rec = TVAL3(A, max_iter=n_iter, adaptive=False)
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

    Returns:
        The path written.

    Raises:
        ValueError: unknown ``name`` (or as :func:`export`).
    """
    if name not in MODELS:
        raise ValueError(f"export_model: expected name in {sorted(MODELS)}, got {name!r}")
    spec = MODELS[name]
    module, inputs = spec(n, sr, n_iter=n_iter)
    if path is None:
        path = f"{name}_n{n}_sr{sr:g}.onnx"
    return export(
        module,
        inputs,
        path,
        dynamic_batch,
        opset,
        input_names=spec.inputs,
        output_names=spec.outputs,
        exporter=exporter or spec.exporter,
    )
