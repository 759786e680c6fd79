"""How long each ONNX exporter takes on the iterative models, for the README's choice of the
TorchScript tracer for them: ``export/export.py`` times each export itself (``export_s`` of its
manifest); this runs it once per exporter and model and records the machine's load.

    OMP_NUM_THREADS=1 python benchmarks/export_time.py --out docs/export_time

writes ``export_time.json`` (the manifests' rows, the load before and after, torch's version).
The ``.onnx`` files go to a temporary folder and are deleted.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch

from torchtof.apps.bench.timing import machine_load

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--models", nargs="+", default=["unrolled_tval3"],
                   help="export/export.py model names")
    p.add_argument("--n", type=int, default=32, help="DMD side")
    p.add_argument("--sr", type=float, default=0.25, help="sampling rate M / n^2")
    p.add_argument("--out", default="docs/export_time", help="folder of export_time.json")
    a = p.parse_args(argv)
    start, rows, t0 = machine_load(), [], time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for model in a.models:
            for exporter in ("torchscript", "dynamo"):
                out = Path(tmp) / f"{model}_{exporter}"
                print(f"[export_time] {model} with {exporter} ...", file=sys.stderr, flush=True)
                subprocess.run([sys.executable, str(ROOT / "export" / "export.py"), model,
                                "--n", str(a.n), "--sr", str(a.sr), "--exporter", exporter,
                                "--no-check", "--out", str(out)], check=True,
                               stdout=subprocess.DEVNULL)
                rows += json.loads((out / "manifest.json").read_text(encoding="utf-8"))
    res = {"rows": [{k: r[k] for k in ("model", "n", "sr", "n_iter", "exporter", "export_s")}
                    for r in rows],
           "machine": {"start": start, "end": machine_load()}, "torch": torch.__version__,
           "total_s": round(time.perf_counter() - t0, 1),
           "command": "python benchmarks/export_time.py " + " ".join(argv or sys.argv[1:])}
    Path(a.out).mkdir(parents=True, exist_ok=True)
    path = Path(a.out) / "export_time.json"
    path.write_text(json.dumps(res, indent=1) + "\n", encoding="utf-8")
    print(f"[export_time] {len(rows)} exports in {res['total_s']:.0f} s; wrote {path}",
          file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
