"""Export the registered torchtof models to ONNX and check them against PyTorch.

Usage (from the repository root)::

    python export/export.py                      # every model, n=32, SR 25 %, into export/onnx/
    python export/export.py g2 unrolled_tval3 --n 32 --sr 0.25 --out /tmp/onnx
    python export/export.py bp --n-iter 200      # iterations of an iterative model
    python export/export.py --readme             # print the model table of export/README.md

Each model is written as ``{out}/{name}.onnx`` (batch axis dynamic, opset 18, validated by
``onnx.checker``), compared with eager PyTorch under onnxruntime at batch 1 and 3 (skip with
``--no-check``), and described in ``{out}/manifest.json`` (inputs, outputs and their shapes,
opset and exporter, all as stored in the file). ``.onnx`` files are build outputs, never committed.
The same export is ``torchtof export MODEL --n 32 --sr 0.25 -o out.onnx``.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import onnx

from torchtof.apps.args import OneLineParser, positive_int, power_of_two, sampling_rate
from torchtof.apps.onnx_models import MODELS, export_model
from torchtof.onnx import DEFAULT_OPSET, EXPORTER_KEY, OPSETS, check, model_opset


def readme_table() -> str:
    """The Markdown table of ``export/README.md``, generated from the registry."""
    lines = [
        "| model | inputs | outputs | exporter | iterations | what |",
        "|---|---|---|---|---|---|",
    ]
    for name, spec in MODELS.items():
        ins = "<br>".join(f"`{i}` {spec.shapes[i]}" for i in spec.inputs)
        outs = "<br>".join(f"`{o}` {spec.shapes[o]}" for o in spec.outputs)
        iters = "–" if spec.n_iter is None else str(spec.n_iter)
        lines.append(f"| `{name}` | {ins} | {outs} | {spec.exporter} | {iters} | {spec.doc} |")
    return "\n".join(lines)


def _dims(value: onnx.ValueInfoProto) -> list[str | int]:
    return [d.dim_param or d.dim_value for d in value.type.tensor_type.shape.dim]


def main(argv: list[str] | None = None) -> list[dict]:
    p = OneLineParser(description=__doc__.splitlines()[0])
    p.add_argument("models", nargs="*", metavar="MODEL",
                   help=f"models (default: all of {list(MODELS)})")
    p.add_argument("--n", type=power_of_two, default=32, help="DMD side")
    p.add_argument("--sr", type=sampling_rate, default=0.25, help="sampling rate M / n^2")
    p.add_argument("--n-iter", type=positive_int, default=None,
                   help="iterations of iterative models")
    p.add_argument("--opset", type=int, choices=OPSETS, default=DEFAULT_OPSET)
    p.add_argument(
        "--exporter",
        choices=["dynamo", "torchscript"],
        default=None,
        help="override the registry's exporter",
    )
    p.add_argument("--out", default=str(Path(__file__).resolve().parent / "onnx"))
    p.add_argument("--no-check", action="store_true", help="skip the onnxruntime comparison")
    p.add_argument("--readme", action="store_true", help="print the README model table, exit")
    args = p.parse_args(argv)
    unknown = [m for m in args.models if m not in MODELS]
    if unknown:
        p.error(f"argument MODEL: unknown model {unknown[0]!r}; choose from "
                f"{', '.join(MODELS)}")
    if args.readme:
        print(readme_table())
        return []
    names = args.models or list(MODELS)
    out = Path(args.out)
    manifest = []
    for name in names:
        spec = MODELS[name] if name in MODELS else None
        if spec is None:
            p.error(f"unknown model {name!r}; choose from {list(MODELS)}")
        n_iter = args.n_iter if spec.n_iter is not None else None
        t0 = time.perf_counter()
        path = export_model(
            name,
            n=args.n,
            sr=args.sr,
            path=out / f"{name}.onnx",
            opset=args.opset,
            n_iter=n_iter,
            exporter=args.exporter,
        )
        entry = {
            "model": name,
            "file": path.name,
            "n": args.n,
            "sr": args.sr,
            "n_iter": n_iter or spec.n_iter,
            "opset": args.opset,
            "exporter": args.exporter or spec.exporter,
            "export_s": round(time.perf_counter() - t0, 2),
        }
        model = onnx.load(path)
        # as stored in the file: an opset-17 export the dynamo exporter cannot down-convert
        # is written by the tracer (torchtof.onnx.export)
        entry["opset"] = model_opset(model)
        meta = {p.key: p.value for p in model.metadata_props}
        entry["exporter"] = meta.get(EXPORTER_KEY, entry["exporter"])
        graph = model.graph
        entry["inputs"] = {v.name: _dims(v) for v in graph.input}
        entry["outputs"] = {v.name: _dims(v) for v in graph.output}
        if not args.no_check:
            module, _ = spec(args.n, args.sr, n_iter=n_iter)
            for batch in (1, 3):
                _, inputs = spec(args.n, args.sr, batch=batch, seed=1, n_iter=n_iter)
                rep = check(path, module, inputs)
                entry[f"max_abs_err_batch{batch}"] = max(o["max_abs_err"] for o in rep["outputs"])
        print(json.dumps(entry))
        manifest.append(entry)
    out.mkdir(parents=True, exist_ok=True)
    (out / "manifest.json").write_text(json.dumps(manifest, indent=2) + "\n")
    return manifest


if __name__ == "__main__":
    main()
