"""Regenerate the README's result tables from the JSON the documented commands write.

Every generated table in README.md sits between two markers::

    <!-- generated:NAME -->
    ...
    <!-- /generated:NAME -->

and is rendered from one JSON file by one function below; nothing in a generated block is
typed by hand. ``make docs`` reruns the commands and rewrites the blocks::

    python docs/build.py --run            # rerun every command, then rewrite README.md
    python docs/build.py --run demo       # one section
    python docs/build.py                  # rewrite README.md from the JSON already there
    python docs/build.py --check          # exit 1 if README.md differs from its JSON

``tests/test_readme.py`` runs the ``--check`` logic, so a table that drifts from its JSON
fails the test suite.
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"


@dataclass(frozen=True)
class Section:
    json: str  # relative to the repository root
    render: Callable[[object], str]
    command: tuple[str, ...]  # what regenerates the JSON (run from the repository root)
    note: str = ""


def _f(x: float, digits: int = 2) -> str:
    return f"{x:.{digits}f}"


def render_demo(rows: list[dict]) -> str:
    kinds = {"raw": "raw ToF map", "depth": "depth", "depth_gated": "depth, 3 m gate",
             "taps": "taps I/Q (torchtof)"}
    out = ["| method | buckets | PSNR dB | SSIM | time s |", "|---|---|---|---|---|"]
    for r in rows:
        psnr = _f(r["psnr"]) + (f" ± {_f(r['psnr_std'])}" if r.get("psnr_std") else "")
        t = "–" if r.get("time_s") is None else f"{r['time_s']:.3f}"
        out.append(f"| {r['method']} | {kinds.get(r.get('buckets'), '?')} | {psnr} | "
                   f"{_f(r['ssim'], 3)} | {t} |")
    return "\n".join(out)


def render_stray_light(rows: list[dict]) -> str:
    labels = {"depth": "depth sum (paper Eq. 10, ungated)", "depth_gated": "gated depth (3 m)",
              "intensity": "intensity (Eq. 8 sums)",
              "taps": "taps I/Q (torchtof, Eq. 8 per pixel after reconstruction)"}
    pick = {(r["kind"], r["stray_e"]): r for r in rows if r["noise"] == "default"}
    out = ["| bucket kind | no stray light | default stray light (1000 e⁻) |", "|---|---|---|"]
    for kind, label in labels.items():
        cells = []
        for stray in (0.0, 1000.0):
            r = pick[(kind, stray)]
            iou = f" (IoU {r['iou']:.2f})" if r["iou"] < r["recall"] - 0.1 else ""
            cells.append(f"{r['recall']:.0%}{iou}, {r['psnr_db']:.1f} dB")
        out.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(out)


def render_stability(res: dict) -> str:
    rows, dts = res["rows"], res["dtypes"]
    heads = {"ok": "ok", "error": "clear error", "n/r": "out of range (explained)", "n/a": "n/a",
             "FAIL": "FAIL"}
    out = [f"{len(rows)} rows (module × edge case) × {len(dts)} dtypes, torch {res['torch']}:",
           "", "| dtype | " + " | ".join(heads.values()) + " |", "|---" * (len(heads) + 1) + "|"]
    for d in dts:
        c = res["counts"][d]
        cells = [str(c.get(k, 0)) for k in heads]
        cells[-1] = f"**{cells[-1]}**"
        out.append(f"| {d} | " + " | ".join(cells) + " |")
    return "\n".join(out)


def render_depth(res: dict) -> str:
    labels = {"raw ToF": "raw ToF", "depth-sum": "depth-sum (paper, oracle fit)",
              "depth-sum gate": "depth-sum, 3 m gate (oracle fit)", "I/Q pinv": "I/Q pinv",
              "I/Q TVAL3": "separate, TVAL3 per image", "I/Q vTV-separate":
              "separate, TV per image (`JointTV(joint=False)`)", "I/Q joint": "**joint I/Q**"}
    rows = res["rows"]
    srs = sorted({r["sr"] for r in rows})
    out = ["| multipath | method | " + " | ".join(f"{s:.2%}".replace("0%", "%").rstrip("0")
                                                  .replace(".%", " %") for s in srs) + " |",
           "|---|---|" + "---|" * len(srs)]
    for mp in dict.fromkeys(r["multipath"] for r in rows):
        first = True
        for m in dict.fromkeys(r["method"] for r in rows):
            cells = []
            for sr in srs:
                hit = [r for r in rows if r["multipath"] == mp and r["method"] == m
                       and r["sr"] == sr]
                if not hit:
                    break
                v = f"{hit[0]['rmse_m']:.3f}"
                cells.append(f"**{v}**" if m == "I/Q joint" else v)
            if len(cells) != len(srs):
                continue
            lead = ("on (default)" if mp == "on" else "off") if first else ""
            out.append(f"| {lead} | {labels.get(m, m)} | " + " | ".join(cells) + " |")
            first = False
    return "\n".join(out)


SECTIONS: dict[str, Section] = {
    "demo": Section(
        "docs/demo/demo.json", render_demo,
        (sys.executable, "-m", "torchtof.cli", "demo", "--out", "docs/demo"),
        "the paper's experiment, SR 12.5 %, one noise realisation, seed 0",
    ),
    "stray_light": Section(
        "docs/stray_light/stray_light.json", render_stray_light,
        (sys.executable, "benchmarks/stray_light.py", "--out", "docs/stray_light"),
        "share of 天 recovered per bucket kind, SR 100 %, exact inverse",
    ),
    "depth": Section(
        "docs/depth/depth.json", render_depth,
        (sys.executable, "-c", "import json, pathlib; from torchtof.apps.depth_demo import "
         "depth_curves; r = depth_curves(pathlib.Path('docs/depth'), scenes=('motorcycle',)); "
         "pathlib.Path('docs/depth/depth.json').write_text(json.dumps(r, indent=1))"),
        "depth RMSE of the motorcycle scene vs SR, multipath on and off",
    ),
    "stability": Section(
        "docs/bench/stability.json", render_stability,
        (sys.executable, "-m", "torchtof.cli", "bench", "stability", "--json",
         "docs/bench/stability.json"),
        "the numerical stress matrix",
    ),
}

_BLOCK = re.compile(
    r"(<!-- generated:(?P<name>[\w-]+) -->\n)(?P<body>.*?)(<!-- /generated:(?P=name) -->)", re.S)


def render(name: str) -> str:
    sec = SECTIONS[name]
    data = json.loads((ROOT / sec.json).read_text(encoding="utf-8"))
    return sec.render(data).rstrip("\n") + "\n"


def rewrite(text: str) -> tuple[str, list[str]]:
    """``text`` with every generated block re-rendered, and the names of the blocks found."""
    found: list[str] = []

    def sub(m: re.Match) -> str:
        name = m.group("name")
        if name not in SECTIONS:
            raise SystemExit(f"README.md: unknown generated block {name!r}")
        found.append(name)
        return m.group(1) + render(name) + m.group(4)

    return _BLOCK.sub(sub, text), found


def stale_blocks(text: str | None = None) -> list[str]:
    """Names of the README blocks that differ from what their JSON renders to."""
    text = README.read_text(encoding="utf-8") if text is None else text
    stale = []
    for m in _BLOCK.finditer(text):
        if m.group("body") != render(m.group("name")):
            stale.append(m.group("name"))
    return stale


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description="Regenerate the README's result tables.",
                                formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--run", nargs="*", metavar="NAME", default=None,
                   help=f"rerun the commands of these sections first (none given: all of "
                        f"{', '.join(SECTIONS)})")
    p.add_argument("--check", action="store_true",
                   help="only report blocks that differ from their JSON (exit 1 if any)")
    args = p.parse_args(argv)
    if args.check:
        stale = stale_blocks()
        for name in stale:
            print(f"README.md: generated block {name!r} differs from {SECTIONS[name].json}; "
                  f"run: python docs/build.py", file=sys.stderr)
        return 1 if stale else 0
    if args.run is not None:
        names = args.run or list(SECTIONS)
        for name in names:
            if name not in SECTIONS:
                p.error(f"--run: unknown section {name!r}; choose from {', '.join(SECTIONS)}")
        for name in names:
            cmd = SECTIONS[name].command
            print(f"[docs] {name}: {' '.join(cmd)}", flush=True)
            subprocess.run(cmd, cwd=ROOT, check=True)
    text, found = rewrite(README.read_text(encoding="utf-8"))
    README.write_text(text, encoding="utf-8")
    print(f"[docs] rewrote {len(found)} generated block(s) in README.md: {', '.join(found)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
