"""Join the ``--out`` files of ``benchmarks/eval_learned.py`` into ``docs/learned/eval.json``,
the JSON the README's learned-reconstructor block is rendered from (``docs/build.py``).

    sh docs/learned/run.sh            # the evaluation (about 80 min here), then this script
    python docs/learned/merge.py DIR  # only the join, from the part files in DIR

Part files (all written by ``eval_learned.py --out``): ``main_*.json`` (learned against TVAL3's
defaults, one row per (n, SR, noise, class)), ``auto_*.json`` (the automatic TV reconstructor
on the same cells), ``speed.json``, ``onnx.json``, ``paper.json``.
"""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
WEIGHTS = ROOT / "torchtof" / "weights" / "learned" / "learned.pt"


def _rows(path: Path) -> list:
    data = json.loads(path.read_text(encoding="utf-8"))
    return data["rows"] if isinstance(data, dict) else data


def merge(parts: Path) -> dict:
    return {
        "what": "benchmarks/eval_learned.py on held-out scenes: learned (the weights whose "
                "sha256 is weights_sha256; every part run with them) against TVAL3's defaults "
                "and the automatic TV reconstructor (auto rows: the cells its part file covers)",
        "parts": sorted(f.name for f in parts.glob("*.json")),
        "weights_sha256": hashlib.sha256(WEIGHTS.read_bytes()).hexdigest(),
        "rows": [r for f in sorted(parts.glob("main_*.json")) for r in _rows(f)],
        "auto_rows": [r for f in sorted(parts.glob("auto_*.json")) for r in _rows(f)],
        "speed": _rows(parts / "speed.json"),
        "onnx": _rows(parts / "onnx.json"),
        "paper": _rows(parts / "paper.json"),
        "command": "sh docs/learned/run.sh",
    }


if __name__ == "__main__":
    parts = Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "docs" / "learned" / "parts"
    out = ROOT / "docs" / "learned" / "eval.json"
    out.write_text(json.dumps(merge(parts), indent=0) + "\n", encoding="utf-8")
    print(f"wrote {out}")
