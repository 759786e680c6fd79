"""``torchtof bench onnx``: latency of onnxruntime (CPU) against eager PyTorch and
``torch.compile`` for every model of :data:`torchtof.apps.onnx_models.MODELS`, as ratios
from one run.

Each model is exported once (batch 2, dynamic batch axis, the registry's exporter) into a
temporary folder and run at every batch size on the same inputs by the three back ends,
with the same number of intra-op threads (``torch.get_num_threads()``). ``torch.compile``
(inductor) needs a C++ toolchain and can fail or take minutes on the long unrolled solver
graphs: a failure is caught per model and its reason recorded in the result, and its
compile time (the first call) is reported apart from the latency.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import torch

from ... import onnx as tt_onnx
from ..._optional import progress_bar
from ...report import print_table
from ..onnx_models import MODELS
from .timing import time_call

#: Iterations of the iterative models in the benchmark (latency grows linearly with them;
#: the registry's defaults make graphs of 10⁴–10⁵ nodes that take minutes to compile).
BENCH_N_ITER = {"bp": 50, "tval3": 20, "dip": 50}
#: Models not given to ``torch.compile`` by default (the reason is recorded): with them the
#: whole benchmark had not finished after 30 minutes on 2 cores, without them it takes ~10;
#: their fixed-iteration graphs are the largest (every branch of every iteration).
COMPILE_SKIP = ("bp", "tval3")


def _first_call(fn, inputs: tuple[torch.Tensor, ...]) -> tuple[float | None, str | None]:
    """``(seconds, None)`` of the first (compiling) call of ``fn``, or ``(None, reason)``."""
    try:
        t0 = time.perf_counter()
        with torch.no_grad():
            fn(*inputs)
        return time.perf_counter() - t0, None
    except Exception as exc:  # noqa: BLE001 - a benchmark records why compile failed
        lines = str(exc).strip().splitlines() or [""]
        return None, f"{type(exc).__name__}: {lines[0][:200]}"


def bench_onnx(
    models=None,
    batches=(1, 16),
    n: int = 32,
    sr: float = 0.25,
    compile: bool = True,
    repeat: int = 5,
    n_iter: dict | None = None,
    progress: bool = False,
    compile_skip=COMPILE_SKIP,
) -> dict:
    """Median latency (s) of onnxruntime, eager PyTorch and ``torch.compile`` per model/batch.

    Args:
        models: names of :data:`torchtof.apps.onnx_models.MODELS` (default: all).
        batches: batch sizes to time.
        n, sr: DMD side and sampling rate of every model.
        compile: also time ``torch.compile`` (inductor).
        repeat: timing samples (median) per measurement.
        n_iter: ``{name: n_iter}`` for iterative models (default :data:`BENCH_N_ITER`; the
            unrolled TVAL3 keeps the K of its shipped weights).
        progress: a progress bar over the models (stderr), each row written as measured.
        compile_skip: models not compiled (default :data:`COMPILE_SKIP`), reason recorded.

    Returns:
        ``{"benchmark": "onnx", "rows": [...]}``; one row per (model, batch) with
        ``eager_s``, ``ort_s``, ``compile_s`` (``None`` when it failed), the ratios
        ``ort_speedup = eager_s / ort_s`` and ``compile_speedup = eager_s / compile_s``, the
        export and compile times, and ``compile_error`` where ``torch.compile`` failed.
    """
    names = list(MODELS) if models is None else list(models)
    unknown = [m for m in names if m not in MODELS]
    if unknown:
        raise ValueError(f"bench_onnx: unknown models {unknown}; known: {sorted(MODELS)}")
    n_iter = dict(BENCH_N_ITER if n_iter is None else n_iter)
    threads = torch.get_num_threads()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        bar = progress_bar(names, desc="bench onnx", disable=not progress, leave=False)
        for name in bar:
            bar.set_postfix_str(name)
            spec = MODELS[name]
            module, example = spec(n, sr, n_iter=n_iter.get(name))
            path = Path(tmp) / f"{name}.onnx"
            t0 = time.perf_counter()
            tt_onnx.export(
                module,
                example,
                path,
                input_names=spec.inputs,
                output_names=spec.outputs,
                exporter=spec.exporter,
            )
            export_s = time.perf_counter() - t0
            sess = tt_onnx.ort_session(path, threads=threads)
            module.eval()
            compiled = torch.compile(module) if compile and name not in compile_skip else None
            for batch in batches:
                _, inputs = spec(n, sr, batch=batch, seed=1, n_iter=n_iter.get(name))
                feeds = {i.name: t.numpy() for i, t in zip(sess.get_inputs(), inputs, strict=True)}
                row = {
                    "model": name,
                    "batch": batch,
                    "exporter": spec.exporter,
                    "export_s": export_s,
                }
                with torch.no_grad():
                    row["eager_s"] = time_call(lambda m=module, i=inputs: m(*i), repeat=repeat)
                row["ort_s"] = time_call(lambda s=sess, f=feeds: s.run(None, f), repeat=repeat)
                row["ort_speedup"] = row["eager_s"] / row["ort_s"]
                row["compile_s"] = None
                if compile and compiled is None:
                    row["compile_error"] = "skipped: inductor compile too slow (COMPILE_SKIP)"
                if compiled is not None:
                    first_s, err = _first_call(compiled, inputs)
                    row["compile_first_call_s"] = first_s
                    if err is not None:
                        row["compile_error"] = err
                    else:
                        with torch.no_grad():
                            row["compile_s"] = time_call(
                                lambda c=compiled, i=inputs: c(*i), repeat=repeat
                            )
                        row["compile_speedup"] = row["eager_s"] / row["compile_s"]
                rows.append(row)
                if progress:
                    bar.write(progress_line(row))
    return {
        "benchmark": "onnx",
        "n": n,
        "sr": sr,
        "threads": threads,
        "torch": torch.__version__,
        "onnxruntime": __import__("onnxruntime").__version__,
        "n_iter": {k: v for k, v in n_iter.items() if k in names},
        "rows": rows,
    }


def _seconds(v) -> str:
    return f"{v:.3g} s" if isinstance(v, (int, float)) else "-"


def progress_line(row: dict) -> str:
    """One model's times as printed while the benchmark runs (3 significant digits).

    Example:
        >>> progress_line({"model": "pinv", "batch": 1, "eager_s": 0.0009510731546395187,
        ...                "ort_s": 0.00042, "compile_s": None})
        'pinv batch 1: eager 0.000951 s, onnxruntime 0.00042 s, compile -'
    """
    return (f"{row['model']} batch {row['batch']}: eager {_seconds(row.get('eager_s'))}, "
            f"onnxruntime {_seconds(row.get('ort_s'))}, compile {_seconds(row.get('compile_s'))}")


def print_onnx(result: dict) -> None:
    """Print :func:`bench_onnx`'s result as a table (ratios > 1: faster than eager)."""
    cols = [
        "model",
        "batch",
        "exporter",
        "eager_s",
        "ort_s",
        "compile_s",
        "ort_speedup",
        "compile_speedup",
        "export_s",
        "compile_first_call_s",
    ]
    print(
        f"n={result['n']}, SR {result['sr']:.0%}, {result['threads']} "
        f"thread{'s' * (result['threads'] != 1)}, torch "
        f"{result['torch']}, onnxruntime {result['onnxruntime']}"
    )
    print_table(result["rows"], cols)
    for r in result["rows"]:
        if r.get("compile_error"):
            print(f"{r['model']} (batch {r['batch']}): torch.compile failed: {r['compile_error']}")
