"""ONNX export of inference modules and parity checks against onnxruntime (CPU).

:func:`export` writes a module to an ``.onnx`` file with ``torch.onnx.export`` (batch axis
dynamic, opset :data:`DEFAULT_OPSET`) and validates it with ``onnx.checker``; :func:`check`
runs the file under onnxruntime's ``CPUExecutionProvider`` and compares every output with
eager PyTorch. :class:`OperatorMethod` and :class:`DepthAmplitude` make an operator's adjoint
or pseudo-inverse and the depth-and-amplitude output of
:class:`~torchtof.recon.DepthResolved` exportable. The models of ``torchtof export MODEL``,
with realistic example inputs, are built by :mod:`torchtof.apps.onnx_models`.

Needs the ``onnx`` extra (``pip install 'torchtof[onnx]'``: onnx, onnxruntime, onnxscript).

**Exporters.** ``torch.onnx.export`` has two back ends; :func:`export` picks one per model
unless told (``exporter=None``):

- ``"dynamo"`` (``torch.export`` + onnxscript, the default of torch >= 2.9) for every model
  without an iteration loop (operators, camera readout, buckets, correlation images,
  U-Nets). It is the maintained exporter, and its onnxscript optimiser folds constants,
  so graphs come out smaller.
- ``"torchscript"`` (the legacy tracer) for iterative solvers (any submodule with a
  ``max_iter``, ``n_iter`` or ``n_layers`` attribute or option: basis pursuit, TVAL3, the
  unrolled TVAL3). Their fixed-iteration loops unroll into 10³–10⁵ ONNX nodes, and
  ``torch.export`` propagates fake tensors with a symbolic batch through every one of them:
  on 2 CPU cores the 12-iteration unrolled TVAL3 at n = 32 takes 48 s to export (the
  tracer: 1.6 s) for the same onnxruntime result. ``exporter="dynamo"`` works for them
  too, only slower to export.

**Opset 17.** The dynamo exporter implements opset 18 only and down-converts; when the
conversion fails (torch logs it and keeps 18), :func:`export` writes the file with the
tracer instead, or refuses the opset. The exporter that wrote a file is in its
``metadata_props`` (:data:`EXPORTER_KEY`).

**Fixed iterations.** Exported graphs hold no data-dependent control flow, so a solver that
stops each sample at a tolerance (``adaptive=True``, the default of TVAL3 and basis pursuit)
is refused with a one-line error: construct it with ``adaptive=False`` and the fixed
iteration budget to export. The exported solver then runs exactly that many iterations, so
it may stop before convergence or run past it (see ``export/README.md``).

**Dynamic batch.** Models are exported at a batch of 2 with the first axis of every input
and output dynamic (``dynamic_batch=True``); :func:`check` then runs onnxruntime at other
batch sizes, which catches batch sizes baked into the graph.
"""

from __future__ import annotations

import contextlib
import copy
import logging
import os
import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
from torch import nn

from ._checks import check_bool, check_positive
from ._optional import require
from .recon.depth import DepthResolved

onnx = require("onnx", "torchtof.onnx")

__all__ = [
    "DEFAULT_OPSET",
    "OPSETS",
    "EXPORTERS",
    "EXPORTER_KEY",
    "EXPORT_BATCH",
    "model_opset",
    "DepthAmplitude",
    "OperatorMethod",
    "default_exporter",
    "export",
    "check",
    "ort_session",
]

#: Opset of every exported file (the dynamo exporter's native opset).
DEFAULT_OPSET = 18
#: The opsets :func:`export` writes (17: down-converted, or by the tracer).
OPSETS = (17, 18)
#: The two back ends of ``torch.onnx.export`` (see the module docstring).
EXPORTERS = ("dynamo", "torchscript")
#: Example batch of the exports; :func:`check` compares at other batch sizes.
EXPORT_BATCH = 2
#: ``metadata_props`` key of every exported file naming the back end that wrote it.
EXPORTER_KEY = "torchtof.exporter"


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
def _as_tuple(inputs: torch.Tensor | Sequence[torch.Tensor], func: str = "export",
              name: str = "example_inputs") -> tuple[torch.Tensor, ...]:
    if isinstance(inputs, torch.Tensor):
        return (inputs,)
    t = tuple(inputs) if isinstance(inputs, Sequence) else ()
    if not t or not all(isinstance(i, torch.Tensor) for i in t):
        raise TypeError(f"{func}: expected {name} as a tensor or a non-empty sequence of "
                        f"tensors, got {type(inputs).__name__}")
    return t


def _onnx_file(path: object, func: str, must_exist: bool) -> Path:
    """``path`` as a Path: TypeError unless path-like, ValueError for a folder (or, with
    ``must_exist``, a missing file)."""
    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(f"{func}: expected path to be a str or os.PathLike, got "
                        f"{type(path).__name__}")
    p = Path(path)
    if p.is_dir():
        raise ValueError(f"{func}: expected path to be an .onnx file, got the folder {p}")
    if must_exist and not p.is_file():
        raise ValueError(f"{func}: expected path to be an existing .onnx file, got {p}")
    return p


def _names(names: object, name: str, func: str) -> list[str] | None:
    if names is None:
        return None
    if isinstance(names, str) or not isinstance(names, (tuple, list)) or not all(
            isinstance(v, str) for v in names):
        raise TypeError(f"{func}: expected {name} to be a sequence of str, got {names!r}")
    return list(names)


@contextlib.contextmanager
def _eval_mode(module: nn.Module):
    """``module`` in eval mode; every submodule's own training flag restored afterwards
    (``module.train(flag)`` would overwrite a submodule deliberately left in another mode)."""
    flags = [(m, m.training) for m in module.modules()]
    module.eval()
    try:
        yield
    finally:
        for m, flag in flags:
            m.training = flag


def _flat_outputs(out: object) -> tuple[torch.Tensor, ...]:
    if isinstance(out, torch.Tensor):
        return (out,)
    return tuple(out)


_ITER_KEYS = ("max_iter", "n_iter", "n_layers")


def _options(m: nn.Module) -> dict:
    opts = getattr(m, "options", None)
    return opts if isinstance(opts, dict) else {}


def _adaptive_solvers(module: nn.Module) -> list[str]:
    """Class names of the submodules that stop at a tolerance (``adaptive`` true as an
    attribute or in their ``options`` dict)."""
    return [type(m).__name__ for m in module.modules()
            if getattr(m, "adaptive", None) is True or _options(m).get("adaptive") is True]


def _not_exportable(module: nn.Module) -> list[str]:
    """Labels of the registry's reconstructors inside ``module`` that do not export
    (``ReconSpec.exportable`` false: ``Auto`` chooses its model by host-side cross-validation,
    ``DIP`` trains a network per sample)."""
    from .recon import registry

    closed = {s.module: s.label for s in registry.specs() if not s.exportable}
    return [closed[type(m)] for m in module.modules() if type(m) in closed]


def default_exporter(module: nn.Module) -> str:
    """``"torchscript"`` for a module holding an iterative solver (a submodule with a
    ``max_iter``, ``n_iter`` or ``n_layers`` attribute or option), else ``"dynamo"``: the
    faster exporter of each (module docstring).

    Example:
        >>> from torchtof.operators import Hadamard
        >>> default_exporter(Hadamard(8, sr=0.5))
        'dynamo'
    """
    for m in module.modules():
        if any(hasattr(m, k) or k in _options(m) for k in _ITER_KEYS):
            return "torchscript"
    return "dynamo"


def export(
    module: nn.Module,
    example_inputs: torch.Tensor | Sequence[torch.Tensor],
    path: str | os.PathLike,
    dynamic_batch: bool = True,
    opset: int | None = DEFAULT_OPSET,
    *,
    input_names: Sequence[str] | None = None,
    output_names: Sequence[str] | None = None,
    exporter: str | None = None,
) -> Path:
    """Export ``module`` to ONNX and validate the file with ``onnx.checker``.

    The module is run once eagerly on ``example_inputs`` first (the eager input checks,
    skipped while tracing, validate them, and caches are filled with real tensors), then
    exported in ``eval`` mode (every submodule's training flag is restored afterwards).

    Args:
        module: the model; ``forward`` takes tensors and returns a tensor or a tuple.
        example_inputs: a tensor or a tuple of tensors (their batch should not be 1 when
            ``dynamic_batch``: a batch of 1 would be specialised).
        path: the ``.onnx`` file to write (parent folders are created).
        dynamic_batch: make axis 0 of every input and output dynamic (name ``"batch"``).
        opset: ONNX opset, 17 or 18 (``None``: :data:`DEFAULT_OPSET`); the file holds
            exactly this opset. The dynamo exporter writes 18 and down-converts to 17; where
            that conversion fails (it only logs it) the tracer (``"torchscript"``) writes the
            file instead, and if it fails too the export is refused.
        input_names, output_names: graph names (default ``input_0 …``/``output_0 …``).
        exporter: ``"dynamo"``, ``"torchscript"`` or ``None``: :func:`default_exporter`
            (the faster one for this module, see the module docstring).

    Returns:
        The path written. Its ``metadata_props`` name the exporter that wrote it (key
        :data:`EXPORTER_KEY`); every output axis but the batch is declared with its size
        (the tracer's symbolic axes are replaced by the sizes of the eager outputs).

    Raises:
        TypeError: ``module`` is not an ``nn.Module``, inputs are not tensors, ``path`` is
            not path-like, ``dynamic_batch`` is not a bool or names are not strings.
        ValueError: ``path`` is a folder, example inputs of different batch sizes with
            ``dynamic_batch``, an adaptive solver inside ``module`` (the message says what to pass),
            unknown ``exporter``, an opset other than 17/18 (or one neither exporter writes
            for this model: no file is left), a batch of 1 with ``dynamic_batch``, or names of
            the wrong length.
        onnx.checker.ValidationError: the written file is not valid ONNX.

    Example:
        >>> from torchtof.operators import Hadamard
        >>> A = Hadamard(8, sr=0.5)
        >>> p = export(A, torch.rand(2, 1, 8, 8), "/tmp/hadamard.onnx")  # doctest: +SKIP
    """
    func = "export"
    if not isinstance(module, nn.Module):
        raise TypeError(f"{func}: expected module to be an nn.Module, got {type(module).__name__}")
    closed = _not_exportable(module)
    if closed:
        raise ValueError(f"{func}: {closed[0]} does not export to ONNX (torchtof.recon.registry"
                         f": exportable=False; its work is not a fixed graph); export a "
                         "fixed-iteration reconstructor instead")
    adaptive = _adaptive_solvers(module)
    if adaptive:
        raise ValueError(
            f"{func}: {adaptive[0]} stops each sample at a tolerance (adaptive=True), which an "
            f"ONNX graph cannot hold; construct it with adaptive=False and a fixed max_iter "
            f"(or n_iter) to export"
        )
    exporter = default_exporter(module) if exporter is None else exporter
    if exporter not in EXPORTERS:
        raise ValueError(f"{func}: expected exporter in {EXPORTERS}, got {exporter!r}")
    opset = DEFAULT_OPSET if opset is None else opset
    if isinstance(opset, bool) or not isinstance(opset, int) or opset not in OPSETS:
        raise ValueError(f"{func}: expected opset 17 or 18, got {opset!r}")
    check_bool(dynamic_batch, "dynamic_batch", func)
    input_names = _names(input_names, "input_names", func)
    output_names = _names(output_names, "output_names", func)
    path = _onnx_file(path, func, must_exist=False)
    inputs = _as_tuple(example_inputs)
    if any(t.dtype == torch.float64 for t in inputs):
        warnings.warn(f"{func}: float64 example inputs give a float64 graph; onnxruntime's CPU "
                      "provider has no float64 kernel for some operators (Conv, Atan), so "
                      "such a file may not run there: check() it, or export with float32 "
                      "inputs (the deployment dtype)", UserWarning, stacklevel=2)
    if dynamic_batch and any(t.ndim == 0 or t.shape[0] == 1 for t in inputs):
        raise ValueError(
            f"{func}: expected example inputs with a batch axis of size > 1 for dynamic_batch "
            f"(a batch of 1 is specialised), got shapes {[tuple(t.shape) for t in inputs]}"
        )
    if dynamic_batch and len({t.shape[0] for t in inputs}) > 1:
        raise ValueError(
            f"{func}: expected example inputs of one batch size for dynamic_batch (one shared "
            f"batch axis), got shapes {[tuple(t.shape) for t in inputs]}"
        )
    with _eval_mode(module):
        with torch.no_grad():
            outs = _flat_outputs(module(*inputs))
        in_names = list(input_names or [f"input_{i}" for i in range(len(inputs))])
        out_names = list(output_names or [f"output_{i}" for i in range(len(outs))])
        if len(in_names) != len(inputs) or len(out_names) != len(outs):
            raise ValueError(
                f"{func}: expected {len(inputs)} input and {len(outs)} output names, got "
                f"{in_names} and {out_names}"
            )
        path.parent.mkdir(parents=True, exist_ok=True)
        with warnings.catch_warnings(), _quiet_registration():
            warnings.simplefilter("ignore", DeprecationWarning)  # the legacy exporter's notice
            warnings.simplefilter("ignore", FutureWarning)
            # the tracer flags the static shape checks; check() verifies other batch sizes
            warnings.simplefilter("ignore", torch.jit.TracerWarning)
            args = (module, inputs, path, opset, in_names, out_names, dynamic_batch)
            _run_exporter(exporter, *args)
            model = onnx.load(path)
            got = model_opset(model)
            if got != opset and exporter == "dynamo":
                # torch's dynamo exporter writes its native opset 18 and down-converts; where
                # the conversion fails it only logs and keeps 18: the tracer writes 17 itself
                try:
                    _run_exporter("torchscript", *args)
                except Exception as e:  # any failure of the tracer: the opset cannot be met
                    path.unlink(missing_ok=True)
                    reason = (str(e).strip().splitlines() or [type(e).__name__])[0]
                    raise ValueError(
                        f"{func}: expected an opset this model exports at, got opset={opset}: "
                        f"the dynamo exporter wrote opset {got} (its down-conversion failed) "
                        f"and the torchscript exporter failed ({reason}); export at opset "
                        f"{DEFAULT_OPSET}") from e
                exporter, model = "torchscript", onnx.load(path)
                got = model_opset(model)
            if got != opset:
                path.unlink(missing_ok=True)
                raise ValueError(f"{func}: expected an opset this model exports at, got "
                                 f"opset={opset}: the {exporter} exporter wrote opset {got}")
    if exporter == "torchscript":  # the tracer names the non-batch output axes symbolically
        _fix_output_dims(model, outs, dynamic_batch)
    model.metadata_props.add(key=EXPORTER_KEY, value=exporter)
    onnx.save(model, path)
    onnx.checker.check_model(model, full_check=True)
    return path


def _run_exporter(exporter: str, module: nn.Module, inputs: tuple[torch.Tensor, ...],
                  path: Path, opset: int, in_names: list[str], out_names: list[str],
                  dynamic_batch: bool) -> None:
    """Write ``module`` to ``path`` with one back end of ``torch.onnx.export``."""
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


def model_opset(model) -> int | None:
    """The version of the default (``ai.onnx``) domain an ``onnx.ModelProto`` imports (its
    opset; ``None`` if it imports none)."""
    for o in model.opset_import:
        if o.domain in ("", "ai.onnx"):
            return int(o.version)
    return None


def _fix_output_dims(model, outs: tuple[torch.Tensor, ...], dynamic_batch: bool) -> None:
    """Declare every output axis but the batch (``dynamic_batch``) with its size from the
    eager outputs ``outs``: fixed by the export (``n`` and ``M``), which the tracer leaves as
    symbols (``"Castx_dim_1"``)."""
    if len(model.graph.output) != len(outs):  # (not expected: left as the tracer wrote it)
        return
    for value, t in zip(model.graph.output, outs, strict=True):
        shape = value.type.tensor_type.shape
        shape.ClearField("dim")
        for axis, size in enumerate(t.shape):
            d = shape.dim.add()
            if dynamic_batch and axis == 0:
                d.dim_param = "batch"
            else:
                d.dim_value = int(size)


class _NoTorchvisionNote(logging.Filter):
    """Drops the dynamo exporter's "torchvision is not installed. Skipping torchvision::nms"
    note, logged once per export: torchtof uses no torchvision operator."""

    def filter(self, record: logging.LogRecord) -> bool:
        return "torchvision is not installed" not in record.getMessage()


@contextlib.contextmanager
def _quiet_registration():
    log = logging.getLogger("torch.onnx._internal.exporter._registration")
    note = _NoTorchvisionNote()
    log.addFilter(note)
    # the opset down-conversion's own reports: a failed conversion logs a traceback and a
    # warning, and export() falls back to the tracer (or says why not) itself
    quiet = [logging.getLogger(n) for n in ("onnxscript.version_converter",
                                            "torch.onnx._internal.exporter._compat")]
    levels = [q.level for q in quiet]
    for q in quiet:
        q.setLevel(logging.CRITICAL)
    try:
        yield
    finally:
        log.removeFilter(note)
        for q, lv in zip(quiet, levels, strict=True):
            q.setLevel(lv)


def ort_session(path: str | os.PathLike, threads: int | None = None):
    """An onnxruntime ``InferenceSession`` on the CPU provider (``threads`` intra-op)."""
    ort = require("onnxruntime", "torchtof.onnx.ort_session")

    opts = ort.SessionOptions()
    if threads is not None:
        opts.intra_op_num_threads = int(threads)
    return ort.InferenceSession(os.fspath(path), opts, providers=["CPUExecutionProvider"])


#: numpy dtype name -> onnxruntime element type name (``NodeArg.type`` is ``tensor(<name>)``).
_ORT_TYPES = {"float32": "float", "float64": "double", "float16": "float16", "int64": "int64",
              "int32": "int32", "bool": "bool", "uint8": "uint8", "int8": "int8"}


#: How much farther than PyTorch's own float32 result onnxruntime's may lie from the float64
#: one (different summation orders round differently) before an output counts as differing.
ROUNDING_FACTOR = 2.0


def _rounding_judged(module, inputs, got, want, report, bad, rtol, atol) -> list[str]:
    """The outputs of ``bad`` judged against the module run in float64: an output that
    onnxruntime computes no farther from the float64 result than ``ROUNDING_FACTOR`` times
    PyTorch's float32 error (plus the tolerance) is float32 rounding of an ill-conditioned
    output (e.g. a pseudo-inverse with κ ≈ 10⁴), not a wrong export. Its report row gets
    ``float64_err_torch`` / ``float64_err_ort``. Modules that do not run in float64 keep
    the verdict."""
    if not all(t.dtype == torch.float32 for t in inputs):
        return bad
    try:
        m64 = copy.deepcopy(module).double()
        with _eval_mode(m64), torch.no_grad(), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            ref = [t.cpu().numpy() for t in _flat_outputs(m64(*(t.double() for t in inputs)))]
    except Exception:  # noqa: BLE001 - any model that cannot run in float64: keep the verdict
        return bad
    still = []
    for row, g, w, r in zip(report, got, want, ref, strict=False):
        if g.shape != r.shape:
            continue
        e_t = np.abs(w.astype(np.float64) - r)
        e_o = np.abs(g.astype(np.float64) - r)
        peak = max(1.0, float(np.abs(r).max(initial=0)))
        tol = ROUNDING_FACTOR * float(e_t.max(initial=0)) + atol * peak + rtol * np.abs(r)
        row["float64_err_torch"] = float(e_t.max(initial=0))
        row["float64_err_ort"] = float(e_o.max(initial=0))
        if not (np.isfinite(g).all() and float((e_o - tol).max(initial=0)) <= 0):
            still.append(row["name"])
    return [b for b in bad if b.split(":")[0] in still or b.split(":")[0] not in
            {row["name"] for row in report}]


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
    level would test the summation order, not the export. An output outside that bound is
    judged once more against the module run in float64: if onnxruntime's result is no farther
    from it than twice PyTorch's float32 result (plus the tolerance), the difference is float32
    rounding of an ill-conditioned output (a pseudo-inverse with κ ≈ 10⁴ differs by 10⁻³ of
    its peak in both), and the output passes, its row reporting both errors. Use inputs of a
    batch size other than the export's to test the dynamic batch axis.

    Args:
        path: the ``.onnx`` file.
        module: the eager module (run in ``eval`` mode under ``no_grad``; every submodule's
            training flag is restored afterwards).
        inputs: a tensor or a tuple of tensors, float32.
        rtol, atol: tolerances, finite and >= 0 (the formula above).

    Returns:
        ``{"outputs": [{"name", "shape", "peak", "max_abs_err", "max_rel_err"}...],
        "ok": True}`` (rows judged in float64 also ``float64_err_torch``, ``float64_err_ort``).

    Raises:
        TypeError: ``module`` is not an ``nn.Module``, ``inputs`` are not tensors, ``path`` is
            not path-like or a tolerance is not a number.
        ValueError: ``path`` is not an existing file, a tolerance is negative or not finite,
            or the inputs do not match the graph's inputs (count or dtype).
        AssertionError: a shape differs or an output is not within tolerance (the message
            gives the worst error of each output).
    """
    func = "check"
    path = _onnx_file(path, func, must_exist=True)
    if not isinstance(module, nn.Module):
        raise TypeError(f"{func}: expected module to be an nn.Module, got {type(module).__name__}")
    inputs = _as_tuple(inputs, func, "inputs")
    rtol = check_positive(rtol, "rtol", func, strict=False)
    atol = check_positive(atol, "atol", func, strict=False)
    onnx.checker.check_model(onnx.load(path), full_check=True)
    sess = ort_session(path)
    if len(sess.get_inputs()) != len(inputs):
        raise ValueError(
            f"check: {os.fspath(path)} takes {len(sess.get_inputs())} inputs, got {len(inputs)}"
        )
    feeds = {}
    for i, t in zip(sess.get_inputs(), inputs, strict=True):
        a = t.detach().cpu().numpy()
        want_type = f"tensor({_ORT_TYPES.get(a.dtype.name, a.dtype.name)})"
        if i.type != want_type:
            raise ValueError(f"check: input {i.name} of {os.fspath(path)} is {i.type}, got a "
                             f"{t.dtype} tensor")
        feeds[i.name] = a
    # eager first: its input checks name a wrong shape more clearly than onnxruntime does
    with _eval_mode(module), torch.no_grad():
        want = [t.cpu().numpy() for t in _flat_outputs(module(*inputs))]
    got = sess.run(None, feeds)
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
    if bad and len(got) == len(want):
        bad = _rounding_judged(module, inputs, got, want, report, bad, rtol, atol)
    if bad:
        raise AssertionError(
            f"check: {os.fspath(path)} differs from PyTorch "
            f"(rtol={rtol}, atol={atol}): " + "; ".join(bad)
        )
    return {"outputs": report, "ok": True}
