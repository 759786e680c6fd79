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

A target whose rerun takes far longer than ``make docs`` may (the fault sweep, the learned
reconstructor's held-out evaluation) is render-only: ``--run NAME`` prints its command and
measured duration instead of running it, and its block is still rendered from the JSON.

``--run`` prints how long each command took and records its seconds and the machine's load
in ``docs/build_times.json``; every command writes its JSON under ``docs/`` with ``--out DIR``
(and records the load itself where it reports seconds), so a rendered time always comes with
the load it ran under. A block inside a list item keeps the item's indentation.

``tests/test_readme.py`` runs the ``--check`` logic for every block (and that every target has
exactly one block), so a table that drifts from its JSON fails the test suite.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
#: seconds and machine load of each ``--run NAME``, written by ``--run``
TIMES = ROOT / "docs" / "build_times.json"


@dataclass(frozen=True)
class Section:
    json: str  # relative to the repository root
    render: Callable[[object], str]
    command: tuple[str, ...]  # what regenerates the JSON (run from the repository root)
    note: str = ""
    #: a rerun far longer than ``make docs`` may take: ``--run NAME`` prints the command and
    #: this measured duration instead of running it (the block still renders from the JSON)
    render_only: str = ""


def _f(x: float, digits: int = 2) -> str:
    return f"{x:.{digits}f}"


def _load(res: dict) -> str:
    """"load 0.4–1.2 on 2 CPUs, 1 thread": the machine's 1-minute load average at the start
    and end of the run (``machine`` of the JSON), which every stated time needs."""
    m = res.get("machine") or {}
    start, end = m.get("start") or {}, m.get("end") or {}
    loads = sorted(x for x in (start.get("load_1min"), end.get("load_1min")) if x is not None)
    if not loads:
        return "load not recorded"
    span = f"{loads[0]:.1f}" if f"{loads[0]:.1f}" == f"{loads[-1]:.1f}" else \
        f"{loads[0]:.1f}–{loads[-1]:.1f}"
    th = start.get("threads")
    return (f"load {span} on {start.get('cpus')} CPUs"
            + (f", {th} thread{'s' * (th != 1)}" if th else ""))


def _ms(s: float) -> str:
    """Seconds as milliseconds with 3 significant digits."""
    ms = 1e3 * s
    return f"{ms:.3f}" if ms < 1 else f"{ms:.2f}" if ms < 10 else f"{ms:.1f}" if ms < 100 \
        else f"{ms:.0f}"


def _run_load(name: str) -> str:
    """How long the last ``--run NAME`` took and under what load (for commands whose JSON
    does not record it)."""
    try:
        rec = json.loads(TIMES.read_text(encoding="utf-8"))[name]
    except (OSError, KeyError, ValueError):
        return "load not recorded"
    return (f"the whole command {rec['seconds']:.0f} s, "
            + _load({"machine": {"start": rec["start"], "end": rec["end"]}}))


def render_demo(rows: list[dict]) -> str:
    kinds = {"raw": "raw ToF map", "depth": "depth", "depth_gated": "depth, 3 m gate",
             "taps": "taps I/Q (torchtof)"}
    out = ["| method | buckets | PSNR dB | SSIM | time s |", "|---|---|---|---|---|"]
    for r in rows:
        psnr = _f(r["psnr"]) + (f" ± {_f(r['psnr_std'])}" if r.get("psnr_std") else "")
        t = "–" if r.get("time_s") is None else f"{r['time_s']:.3f}"
        out.append(f"| {r['method']} | {kinds.get(r.get('buckets'), '?')} | {psnr} | "
                   f"{_f(r['ssim'], 3)} | {t} |")
    out += ["", f"Times: one wall-clock run each, {_run_load('demo')}."]
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


def render_operators(res: dict) -> str:
    rows = res["rows"]
    out = [f"One run, forward + adjoint, batch {res['batch']}, SR {res['sr']:.0%}, "
           f"{_load(res)}, torch {res['torch']} (median of {res.get('repeat', 5)} samples):",
           "", "| n | Hadamard (auto) | dense `(M, N)` matmul | `PatternOperator` | speed-up vs "
           "dense | time growth kron / butterflies / N log N |", "|---|---|---|---|---|---|"]
    for r in rows:
        auto = r[f"hadamard_{r['hadamard_auto']}_s"]
        dense = (f"{_ms(r['dense_s'])} ms" if r.get("dense_s") else
                 f"not built ({r.get('dense_skipped', '').split('need ')[-1]})")
        pat = f"{_ms(r['pattern_operator_s'])} ms" if r.get("pattern_operator_s") else "not built"
        speed = f"{r['dense_s'] / auto:.1f}×" if r.get("dense_s") else "–"
        growth = (f"{r['kron_growth']:.2f} / {r['fwht_growth']:.2f} / {r['NlogN_growth']:.2f}"
                  if "kron_growth" in r else "–")
        out.append(f"| {r['n']} | {_ms(auto)} ms ({r['hadamard_auto']}) | {dense} | {pat} | "
                   f"{speed} | {growth} |")
    big = [r for r in rows if r["n"] >= 64]
    if big:
        ns = " / ".join(str(r["n"]) for r in big)
        out += ["", f"In the same run the separable matmul took "
                f"{' / '.join(_ms(r['hadamard_matmul_s']) for r in big)} ms at n = {ns}, the "
                f"Kronecker transform {' / '.join(_ms(r['hadamard_kron_s']) for r in big)} ms "
                f"and the butterflies {' / '.join(_ms(r['hadamard_fwht_s']) for r in big)} ms."]
        fast = [r for r in rows
                if min(("matmul", "kron", "fwht"), key=lambda k: r[f"hadamard_{k}_s"])
                != r["hadamard_auto"]]
        if fast:
            out[-1] += " Where `auto` was not the fastest here: " + "; ".join(
                f"n = {r['n']}: " + min(("matmul", "kron", "fwht"),
                                        key=lambda k: r[f"hadamard_{k}_s"])
                + f" {r['hadamard_' + r['hadamard_auto'] + '_s'] / r['best_hadamard_s']:.2f}× "
                  f"faster" for r in fast) + "."
        if len(big) > 1:
            a, b = big[0], big[-1]
            nl = (b["N"] * math.log2(b["N"])) / (a["N"] * math.log2(a["N"]))
            out[-1] += (f" From n = {a['n']} to {b['n']} the Kronecker transform's time grew "
                        f"{b['hadamard_kron_s'] / a['hadamard_kron_s']:.0f}× against "
                        f"{nl:.0f}× for N log N.")
    return "\n".join(out)


def _label(lab: str) -> str:
    """A sweep label (``TVAL3@80``, ``DIP@100``, ``Unrolled``) in words."""
    names = {"PINV": "PINV / g2", "Unrolled": "unrolled TVAL3", "TVAL3": "TVAL3 defaults",
             "BP": "BP, noise-aware `eps`", "DIP": "DIP"}
    method, _, budget = lab.partition("@")
    if not budget:
        return names.get(method, method)
    unit = "steps" if method == "DIP" else "iterations"
    return f"{method}, {budget} {unit}"


def _sec(s: float) -> str:
    return f"{1e6 * s:.0f} µs" if s < 1e-3 else f"{_ms(s)} ms" if s < 1 else f"{s:.1f} s"


def render_tradeoff(res: dict) -> str:
    rec = res["recommend"]
    ns = sorted({r["n"] for r in rec})
    budgets = sorted({r["budget_s"] for r in rec})
    out = [f"`torchtof bench tradeoff{' --quick' if res.get('quick') else ''}`: "
           f"{len(res['scenes'])} scenes ({', '.join(res['scenes'])}), SR "
           f"{', '.join(f'{s:.2%}' for s in sorted({p['sr'] for p in res['points']}))}, "
           f"{res['noise']:.0%} noise; one run of {res['total_s']:.0f} s, {_load(res)}, "
           f"torch {res['torch']}. Best PSNR averaged over scenes and SRs within each budget "
           "per image:", "", "| budget per image | " + " | ".join(f"n = {n}" for n in ns) + " |",
           "|---|" + "---|" * len(ns)]
    for b in budgets:
        cells = []
        for n in ns:
            r = next(x for x in rec if x["n"] == n and x["budget_s"] == b)
            cells.append("–" if r["psnr"] is None else
                         f"{_label(r['method'])} ({r['psnr']:.1f} dB, {_sec(r['time_s'])})")
        out.append(f"| {f'{1e3 * b:g} ms' if b < 1 else f'{b:g} s'} | " + " | ".join(cells)
                   + " |")
    pts = res["points"]
    cells = sorted({(p["n"], p["sr"]) for p in pts})
    best = [max((p for p in pts if (p["n"], p["sr"]) == c), key=lambda p: p["psnr"])
            for c in cells]
    winners = sorted({_label(p["label"]) for p in best})
    out += ["", f"Most accurate point of each of the {len(cells)} (n, SR) cells: "
            + ", ".join(f"{w} in {sum(_label(p['label']) == w for p in best)}" for w in winners)
            + f" ({min(p['psnr'] for p in best):.1f}–{max(p['psnr'] for p in best):.1f} dB at "
            f"{_sec(min(p['time_s'] for p in best))}–{_sec(max(p['time_s'] for p in best))} per "
            "image)."]
    bp = [p for p in pts if p["method"] == "BP" and p["pareto"]]
    out[-1] += (" BP on the Pareto front: " + ("; ".join(
        f"n = {p['n']}, SR {p['sr']:.2%} ({_label(p['label'])})" for p in bp) if bp else "nowhere")
        + ".")
    return "\n".join(out)


def render_reproduce(res: dict) -> str:
    """The claims table of ``torchtof reproduce`` and the numbers behind the verdicts."""
    from torchtof.experiment import PAPER_PSNR

    table, raw = res["table"], res["raw"]
    srs = sorted({r["sr"] for rows in table.values() for r in rows})
    methods = list(dict.fromkeys(r["method"] for rows in table.values() for r in rows))

    def psnr(case, m, sr):
        return next(r["psnr"] for r in table[case] if r["method"] == m and abs(r["sr"] - sr)
                    < 1e-9)

    dip = res["options"].get("DIP", {}).get("max_iter")
    out = [f"{'`--quick`' if res['quick'] else 'Full run'}: {res['realisations']} noise "
           f"realisations, DIP {f'{dip} steps' if dip else 'default schedule'}, seed 0; one "
           f"run of {res['total_s']:.0f} s, {_load(res)}.", "",
           "| claim | held | evidence |", "|---|---|---|"]
    verdict = {True: "held", False: "not held", None: "not evaluated"}
    out += [f"| {c['claim']} | {verdict[c['held']]} | {c['evidence']} |" for c in res["claims"]]
    out += [""]
    if "DIP" in methods and "TVAL3" in methods:
        low = [s for s in srs if s <= 0.125]
        above = sum(psnr(c, "DIP", s) > psnr(c, "TVAL3", s) for c in table for s in low)
        air = ", ".join(f"{psnr('air', 'DIP', s):.2f} vs {psnr('air', 'TVAL3', s):.2f} dB at "
                        f"{s:.2%}" for s in low)
        best: dict[str, int] = {}
        for c in table:
            for s in srs:
                w = max(methods, key=lambda m, c=c, s=s: psnr(c, m, s))
                best[w] = best.get(w, 0) + 1
        cells = len(table) * len(srs)
        others = ", ".join(f"{m} {k}" for m, k in sorted(best.items(), key=lambda t: -t[1])
                           if m != "DIP")
        out.append(f"- **DIP against TVAL3** at SR ≤ 12.5 %: above in {above} of "
                   f"{len(table) * len(low)} (case, SR) cells (air without gate: {air}); "
                   f"best of all methods in {best.get('DIP', 0)} of {cells} cells"
                   + (f" (the others: {others})." if others else "."))
    if {"TVAL3", "CGI", "BP"} <= set(methods):
        low = [s for s in srs if s <= 0.125]
        held = sum(psnr(c, "TVAL3", s) >= max(psnr(c, "CGI", s), psnr(c, "BP", s))
                   for c in table for s in low)
        out.append(f"- **TVAL3 ≥ CGI and BP at SR ≤ 12.5 %** in {held} of "
                   f"{len(table) * len(low)} cells.")
    if "CGI" in methods:
        cgi = [(s, psnr("air", "CGI", s), PAPER_PSNR.get(("air", s), {}).get("CGI"))
               for s in srs if PAPER_PSNR.get(("air", s), {}).get("CGI") is not None]
        out.append("- **Absolute values in air:** CGI " + ", ".join(
            f"{v:.2f} dB at {s:.1%} (paper {p:.2f})" for s, v, p in cgi)
            + f"; the raw ToF image {raw['air']['psnr']:.2f} dB (paper "
              f"{PAPER_PSNR[('air', 0.125)]['raw ToF']:.2f}).")
    return "\n".join(out)


def _repeats(res: dict) -> str:
    rep = res.get("repeats") or {"unrolled": 5, "tval3": 1}
    if rep["unrolled"] == rep["tval3"]:
        return str(rep["tval3"])
    return f"{rep['unrolled']} (network) and {rep['tval3']} (TVAL3)"


def render_unrolled(res: dict) -> str:
    rows = res["rows"]
    noise = ", ".join(sorted({f"{r['noise']:.0%}" for r in rows}))
    timed = res.get("timed_scenes", res["scenes"])
    out = [f"One run of {res['total_s']:.0f} s, {_load(res)}, torch {res['torch']}; "
           f"{res['scenes']} held-out scenes, {noise} "
           f"noise, PSNR on [0, 1], time per image at batch 1 (median over "
           f"{'the' if timed == res['scenes'] else 'the first'} {timed} scenes of the best "
           f"of {_repeats(res)} runs). Best "
           "converged TVAL3: the better of `mu=\"auto\"` and the published μ = 2⁸ per row.", "",
           "| n | SR | unrolled dB | best converged TVAL3 dB | Δ dB | time ratio wall / CPU |",
           "|---|---|---|---|---|---|"]
    for r in rows:
        d = r["unrolled_db"] - r["best_tval3_db"]
        sign = "−" if d < 0 else "+"
        mu = "auto" if r["best_tval3"] == "auto" else "2⁸"
        out.append(f"| {r['n']} | {100 * r['sr']:g} % | {r['unrolled_db']:.2f} | "
                   f"{r['best_tval3_db']:.2f} (μ {mu}) | {sign}{abs(d):.2f} | "
                   f"{r['time_ratio']:.0f}× / "
                   + (f"{r['cpu_time_ratio']:.0f}×" if "cpu_time_ratio" in r else "–") + " |")
    worst = min(rows, key=lambda r: r["unrolled_db"] - r["best_tval3_db"])
    key = "cpu_time_ratio" if all("cpu_time_ratio" in r for r in rows) else "time_ratio"
    slow = min(rows, key=lambda r: r[key])
    within = sum(r["unrolled_db"] - r["best_tval3_db"] >= -0.5 for r in rows)
    out += ["", f"{within} of {len(rows)} rows are within 0.5 dB of converged TVAL3 or better "
            f"(worst {worst['unrolled_db'] - worst['best_tval3_db']:+.2f} dB at n = "
            f"{worst['n']}, SR {100 * worst['sr']:g} %); the unrolled network takes "
            f"{slow[key]:.0f}× to {max(r[key] for r in rows):.0f}× less "
            f"{'CPU' if key == 'cpu_time_ratio' else 'wall-clock'} time per image than the "
            "best TVAL3."]
    return "\n".join(out)


def _int(k: int) -> str:
    """12656 as "12 656"."""
    return f"{k:,}".replace(",", " ")


def render_bad_inputs(res: dict) -> str:
    """The bad-input matrix of ``tests/reliability/`` summed over the modules it covers."""
    tot = {c: sum(res["counts"][m][c] for m in res["modules"]) for c in res["classes"]}
    return (f"`tests/reliability/` misuses {res['calls']} public calls of these modules as a "
            "user would (a list, int64, NaN, Inf, wrong rank, float16/bfloat16/complex, B = 0, "
            f"meta tensors, bad sizes and rates): of {_int(sum(tot.values()))} cases, "
            f"{_int(tot['clear'])} are refused clearly and {_int(tot['correct'])} answered "
            f"correctly — {tot['silent-wrong']} silent-wrong, {tot['cryptic']} cryptic, "
            f"{tot['crash']} crash (torch {res['torch']}; `{res['command']}` prints the table "
            "per module and writes this JSON).")


FAULT_KINDS = {"drop": "lost", "extra": "spurious", "duplicate": "duplicated",
               "frame_timeout": "missed-trigger", "corrupt": "short", "split": "split",
               "stall": "stalled"}


def render_fault_sweep(res: dict) -> str:
    """The full fault sweep of ``benchmarks/fault_sweep.py``: counts, time and load."""
    setup, modes = res["setup"], res["modes"]
    kinds = setup["kinds"]
    one = next(iter(modes.values()))
    loads = (res["load_avg_start"][0], res["load_avg_end"][0])
    return (f"Every single frame fault ({', '.join(FAULT_KINDS.get(k, k) for k in kinds)}: "
            f"{len(kinds)} kinds × {setup['positions']} frames of one sequence) and every "
            f"unordered pair of them ({_int(one['doubles'])}) on the simulated bench, with device "
            f"frame numbers and with host counting: **{_int(res['runs'])} runs, "
            f"{res['wrong_buckets']} wrong buckets, {res['failed_runs']} failed runs**, each "
            "run's buckets read back from its own store and compared bit for bit with the clean "
            "run's (`docs/reliability/fault_sweep.json`). To reproduce: `OMP_NUM_THREADS=1 "
            f"{res['command']}` ({res['workers']} worker processes; one run of "
            f"{res['wall_s'] / 60:.0f} min wall, {res['cpu_s'] / 60:.0f} min CPU on a shared "
            f"{res['cores']}-core machine, 1-minute load average {min(loads):.0f}–"
            f"{max(loads):.0f}, torch {res['torch']}, {res['date_utc'][:10]}).")


def _sr(sr: float) -> str:
    return f"{100 * sr:g} %"


def render_learned(res: dict) -> str:
    """The learned reconstructor on held-out scenes (``benchmarks/eval_learned.py``):
    Δ = PSNR(learned) − PSNR(TVAL3 defaults) per noise level and n, its times, onnxruntime,
    the automatic TV reconstructor and the paper's experiment."""
    rows = [r for r in res["rows"] if "learned" in r and "tval3" in r
            and not r.get("generalisation")]

    def delta(r, ref="tval3"):
        return r["learned"][0] - r[ref][0]

    ns = sorted({r["n"] for r in rows})
    levels = sorted({r["level"] for r in rows})
    srs = {n: sorted({r["sr"] for r in rows if r["n"] == n}) for n in ns}
    full = max(len(v) for v in srs.values())
    head = [f"n = {n}" + ("" if len(srs[n]) == full else
                          f" (SR ≤ {_sr(max(srs[n]))} only)") for n in ns]
    out = ["| noise | " + " | ".join(head) + " |", "|---|" + "---|" * len(ns)]
    for lev in levels:
        cells = []
        for n in ns:
            d = [delta(r) for r in rows if r["n"] == n and r["level"] == lev]
            cells.append(f"{sum(d) / len(d):+.2f} (min {min(d):+.2f})" if d else "-")
        out.append(f"| {100 * lev:g} % | " + " | ".join(cells) + " |")
    sp = {r["n"]: r for r in res["speed"]}
    out.append("| time TVAL3 / learned (min of 3 interleaved, SR 12.5 %, 1 %) | " + " | ".join(
        f"{sp[n]['ratio']:.1f}× ({sp[n]['tval3_ms']:.0f} / {sp[n]['learned_ms']:.0f} ms)"
        if n in sp else "-" for n in ns) + " |")
    loads = sorted({f"{r['load_avg']:.0f}" for r in res["speed"]}, key=float)
    load = loads[0] if len(loads) == 1 else f"{loads[0]}–{loads[-1]}"
    ox = res["onnx"]
    text = (f"Times on the shared machine at 1-minute load {load}. "
            f"onnxruntime (1 thread, batch {ox[0]['batch']}, SR 12.5 %): "
            + ", ".join(f"{o['ort_ms']:.1f} ms per image at n = {o['n']}" for o in ox)
            + " (eager PyTorch " + " / ".join(f"{o['torch_ms']:.1f}" for o in ox)
            + " ms under the same load); max abs difference to PyTorch "
            + " / ".join(f"{o['max_abs_err']:.1e}" for o in ox) + ".")
    key = ("n", "sr", "level", "class")
    auto = {tuple(r[k] for k in key): r for r in res["auto_rows"]}
    low = [r for r in rows if r["sr"] <= 0.125 + 1e-9 and abs(r["level"] - 0.01) < 1e-9]
    both = [(r, auto[tuple(r[k] for k in key)]) for r in low if tuple(r[k] for k in key) in auto]
    da = [r["learned"][0] - a["auto"][0] for r, a in both]
    if da:
        # the auto rows' own TVAL3 time where their run measured one (same run, same load)
        ta = sorted(a["t_auto"] / a.get("t_tval3", r["t_tval3"]) for r, a in both)
        text += (" Against `auto` (`torchtof.recon.auto`, its defaults; "
                 f"{ta[0]:.0f}–{ta[-1]:.0f}× a default TVAL3 solve per image on these cells): "
                 f"{sum(da) / len(da):+.2f} dB at SR ≤ 12.5 %, 1 % noise "
                 f"({len(da)} cells, n ≤ {max(r['n'] for r, _ in both)}, min {min(da):+.2f}).")
    pp = res["paper"]
    wins = sum(r["learned"][0] > r["tval3"][0] and r["learned"][1] > r["tval3"][1] for r in pp)
    text += (" On the paper's experiment it scores a higher PSNR and SSIM than TVAL3's defaults "
             + ("at every SR, with and without the 3 m gate" if wins == len(pp) else
                f"in {wins} of {len(pp)} (SR, gate) cases") + ".")
    small = [r for r in rows if r["n"] <= 128]
    worse = sorted((r for r in small if delta(r) < -0.5), key=delta)
    dl = [delta(r) for r in low]
    w0 = worse[0] if worse else min(small, key=delta)

    def ratio(r):
        return r["t_tval3"] / r["t_learned"]

    def median(xs):
        xs = sorted(xs)
        return (xs[(len(xs) - 1) // 2] + xs[len(xs) // 2]) / 2

    med = {n: median([ratio(r) for r in rows if r["n"] == n]) for n in ns}
    clean = [r for r in small if r["level"] == 0]
    slow = [r for r in clean if ratio(r) < 10]
    big = [r for r in rows if r["n"] > 128 and r["level"] == 0]
    fmt = lambda r: (f"n = {r['n']}, SR {_sr(r['sr'])}, "  # noqa: E731
                     + ("noise-free" if r["level"] == 0 else f"{100 * r['level']:g} % noise")
                     + f" {r['class']}")
    dl = [delta(r) for r in low if r["n"] <= 128]
    text2 = (f"Measured against its targets: at SR ≤ 12.5 %, 1 % noise and n ≤ 128 it is "
             f"{sum(dl) / len(dl):+.2f} dB from TVAL3's defaults on average ({len(dl)} cells; "
             f"the target was +2 dB); it is more than 0.5 dB worse in {len(worse)} of "
             f"{len(small)} (class, n, SR, noise) cells at n ≤ 128 (worst {delta(w0):+.2f} dB: "
             f"{fmt(w0)}"
             + (f"; then {delta(worse[1]):+.2f} dB: {fmt(worse[1])}" if len(worse) > 1 else "")
             + "). Time TVAL3 / learned, median over each n's cells (target ≥ 10×): "
             + ", ".join(f"{med[n]:.1f}× at n = {n}" for n in ns)
             + f"; below 10× on {len(slow)} of {len(clean)} noise-free cells at n ≤ 128"
             + (f" (down to {min(ratio(r) for r in slow):.1f}×)" if slow else "")
             + (f", {min(ratio(r) for r in big):.1f}–{max(ratio(r) for r in big):.1f}× on the "
                "noise-free cells above n = 128" if big else "") + ".")
    return "\n".join(out + ["", text, "", text2])


def render_export_time(res: dict) -> str:
    """Seconds each exporter took per model (``export/export.py``'s own timer)."""
    out = []
    for model in dict.fromkeys(r["model"] for r in res["rows"]):
        by = {r["exporter"]: r for r in res["rows"] if r["model"] == model}
        r = next(iter(by.values()))
        lab = ONNX_LABELS.get(model, f"`{model}`")
        if "torchscript" in by and "dynamo" in by:
            t, d = by["torchscript"]["export_s"], by["dynamo"]["export_s"]
            out.append(f"{lab} at n = {r['n']}, SR {_sr(r['sr'])}: {d:.1f} s to export with "
                       f"dynamo against {t:.1f} s with the TorchScript tracer ({d / t:.0f}×)")
    return ("Export time, one run each (`" + res["command"] + "`, " + _load(res) + ", torch "
            + res["torch"] + "): " + "; ".join(out) + ".")


def render_learned_recipe(rec: dict) -> str:
    """How the shipped learned weights were trained, from the ``recipe.json`` beside them."""
    load = (rec.get("load_avg_end") or [None])[0]
    ws = rec.get("world_size", 1)
    return (f"The shipped weights took {rec['steps_run']} steps in {rec['wall_s'] / 60:.1f} min "
            f"(`{rec['command']}`, {ws} process{'es' * (ws != 1)}, {rec['threads']} "
            f"thread{'s' * (rec['threads'] != 1)}, 1-minute load "
            + (f"{load:.0f} at the end" if load is not None else "not recorded")
            + f", torch {rec['torch_version']}), plus {rec['calibration_wall_s']:.0f} s to "
            "calibrate the final step " + (f"(`{rec['calibration_command']}`)."
                                           if rec.get("calibration_command") else
                                           "at the end of the same command."))


ONNX_LABELS = {"unrolled_tval3": "unrolled TVAL3 (K = 12)", "g2": "g2", "bp": "basis pursuit",
               "tval3": "TVAL3, fixed iterations", "dip": "DIP U-Net"}


def render_onnx(res: dict) -> str:
    its = res.get("n_iter") or {}
    out = [f"One run, n = {res['n']}, SR {res['sr']:.0%}, medians, {_load(res)}, torch "
           f"{res['torch']}, onnxruntime {res['onnxruntime']}:", "",
           "| model | batch | eager PyTorch | onnxruntime | onnxruntime speed-up |",
           "|---|---|---|---|---|"]
    for r in res["rows"]:
        lab = ONNX_LABELS.get(r["model"], f"`{r['model']}`")
        if r["model"] in its:
            lab += (f" (fitted {its['dip']} steps)" if r["model"] == "dip"
                    else f" ({its[r['model']]} it.)")
        out.append(f"| {lab} | {r['batch']} | {_ms(r['eager_s'])} ms | {_ms(r['ort_s'])} ms | "
                   f"{r['ort_speedup']:.1f}× |")
    return "\n".join(out)


def render_tval3(res: dict) -> str:
    t, rows = res["timing"]["bb"], res["rows"]
    gaps = [r["default"] - r["oracle"] for r in rows if "oracle" in r]
    ps = [r["default"] for r in rows]
    cpu = f", {t['cpu_median_s']:.3f} s CPU time" if "cpu_median_s" in t else ""
    text = (f"The defaults take **{t['median_s']:.3f} s** median of 9{cpu} ({t['n_iter']} "
            f"iterations, {_load(res)}) and score {min(ps):.2f}–{max(ps):.2f} dB over "
            f"{len(ps)} noise draws")
    if gaps:
        lo, hi = min(gaps), max(gaps)
        where = (f"{-hi:.2f}–{-lo:.2f} dB below" if hi <= 0 else f"{lo:+.2f} to {hi:+.2f} dB from")
        text += (f", {where} a plain ADMM-TV whose weight is tuned per noise draw with "
                 f"the ground truth (an oracle bound no fixed rule can beat; {len(gaps)} noise "
                 "draws)")
    return text + "."


def _cm(x: float) -> str:
    return f"{x:.3f}"


def render_depth_joint(res: dict) -> str:
    rows, summ = res["rows"], res["summary"]
    low = [r for r in rows if r["sr"] <= 0.125]
    wins, paired = sum(r["wins"] for r in low), sum(r["realisations"] for r in low)

    def cell(scene, mp, sr):
        return next(r for r in rows if r["scene"] == scene and r["multipath"] == mp
                    and r["sr"] == sr)

    sky = cell("sky", "off", 0.0625)
    sl = cell("slanted", "off", 0.125)
    steps = [r for r in rows if r["scene"] == "steps" and r["TVAL3"] < r["joint"]]
    where = "; ".join(f"{_sr(r['sr'])} with multipath {r['multipath']} ({_cm(r['TVAL3'])} vs "
                      f"{_cm(r['joint'])} m)" for r in steps) or "nowhere"
    return (f"Joint vs separate (`{res['command']} --out docs/depth`; generated from "
            f"`docs/depth/depth_joint.json`; "
            f"{res['realisations']} realisations, {', '.join(res['scenes'])}, SR ≤ 12.5 %, "
            f"{_load(res)}): joint beats the same solver with TV per image in {wins} of "
            f"{paired} paired realisations; mean RMSE ratio {summ['on']['ratio']:.3f} with "
            f"multipath, {summ['off']['ratio']:.3f} without. On the sky character at 6.25 % "
            f"without multipath: joint {_cm(sky['joint'])} vs separate {_cm(sky['vTV-sep'])} m. "
            f"Slanted plane, 12.5 %, no multipath: I/Q pseudo-inverse {_cm(sl['pinv'])} vs "
            f"joint {_cm(sl['joint'])} m. Steps: the package's TVAL3 per "
            f"image beats joint at {where}.")


def render_dip_time(res: dict) -> str:
    rows = res["rows"]
    meds = [r["median_s"] for r in rows]
    walls = [w for r in rows for w in r["walls_s"]]
    span = (f"{min(meds):.2f}–{max(meds):.2f} s" if f"{min(meds):.2f}" != f"{max(meds):.2f}"
            else f"{meds[0]:.2f} s")
    return (f"{res['iters']} steps at {res['n']}×{res['n']} take {span} (median of "
            f"{res['repeats']} per SR, {', '.join(_sr(r['sr']) for r in rows)}; range "
            f"{min(walls):.2f}–{max(walls):.2f} s; {_load(res)}) with `early_stop=None` "
            f"(`{res['command']} --out docs/bench`; generated from `docs/bench/time_dip.json`).")


def render_dip_quality(res: dict) -> str:
    cells = res["cells"]
    lvls = sorted({c["level"] for c in cells})
    srs = sorted({c["sr"] for c in cells})
    scenes = list(dict.fromkeys(c["scene"] for c in cells))

    def versus(other: str) -> str:
        d = [c["dip"] - c[other] for c in cells]
        wins = sum(v > 0 for v in d)
        return (f"{wins} of {len(d)} cells (mean {statistics.mean(d):+.2f} dB, from "
                f"{min(d):+.2f} to {max(d):+.2f})")

    sky = [c for c in cells if c["scene"] == "sky" and c["level"] == lvls[0]]
    pairs = "; ".join(f"{c['dip']:.2f} vs {c['tval3']:.2f} dB at {_sr(c['sr'])}" for c in sky)
    t = {m: statistics.median(c[f"t_{m}"] for c in cells) for m in ("dip", "tval3", "auto")}
    return (f"On the {res['n']}×{res['n']} proxy ({', '.join(scenes)}; cake-cutting Hadamard, "
            f"SR {', '.join(_sr(s) for s in srs)}; Gaussian noise "
            f"{', '.join(f'{100 * v:g} %' for v in lvls)} of the bucket spread; "
            f"{res['repeats']} noise draws per cell, mean PSNR) DIP beats TVAL3's defaults in "
            f"{versus('tval3')} and `auto` in {versus('auto')}; on 天 at {100 * lvls[0]:g} % "
            f"noise DIP vs TVAL3: {pairs}. Median time per image: DIP {t['dip']:.1f} s, TVAL3 "
            f"{t['tval3']:.2f} s, `auto` {t['auto']:.2f} s ({_load(res)}; "
            f"`{res['command'].strip()}`, generated from "
            f"`docs/bench/dip_vs_tval3.json`).")


def render_peers(res: dict) -> str:
    """torchtof's one-call reconstructors against the best oracle-tuned peer of each cell
    (``benchmarks/peers.py``, merged runs in ``docs/peers.json``)."""
    cells = [c for c in res["cells"] if c["headline"]["best_peer"]]
    ours = sorted({k for c in cells for k, v in c["results"].items() if v["peer"] == "torchtof"
                   and k != "torchtof pinv"})
    names = sorted({k for c in cells for k in c["results"]})

    def gaps(k: str, sub=None) -> list[float]:
        return [c["results"][k]["psnr"] - c["headline"]["best_peer_psnr"] for c in cells
                if k in c["results"] and (sub is None or sub(c))]

    parts = []
    for k in sorted(ours, key=lambda k: -statistics.mean(gaps(k))):
        g = gaps(k)
        parts.append(f"`{k.replace('torchtof ', '')}` {statistics.mean(g):+.2f} dB (≥ 0 in "
                     f"{sum(v >= 0 for v in g)} of {len(g)})")
    mean = {k: statistics.mean(c["results"][k]["psnr"] for c in cells) for k in names
            if all(k in c["results"] for c in cells)}
    top = sorted(mean, key=mean.get, reverse=True)[:5]
    small = [c for c in cells if c["n"] == 32]
    best32 = max(ours, key=lambda k: statistics.mean(gaps(k, lambda c: c["n"] == 32)))
    lose = sorted((c for c in cells if c["results"]["torchtof auto"]["psnr"]
                   - c["headline"]["best_peer_psnr"] < -1.0), key=lambda c: (
        c["results"]["torchtof auto"]["psnr"] - c["headline"]["best_peer_psnr"]))
    worst = "; ".join(
        f"{c['scene']} n = {c['n']} SR {_sr(c['sr'])} {c['order'].replace('_', '-')} "
        f"{100 * c['level']:g} %: "
        f"{c['results']['torchtof auto']['psnr'] - c['headline']['best_peer_psnr']:+.1f} dB "
        f"({c['headline']['best_peer']})" for c in lose[:8])
    more = f" and {len(lose) - 8} more" if len(lose) > 8 else ""
    w = min(cells, key=lambda c: c["results"]["torchtof auto"]["psnr"]
            - c["headline"]["best_peer_psnr"])
    gap_w = w["results"]["torchtof auto"]["psnr"] - w["headline"]["best_peer_psnr"]
    worst_any = (f"{w['scene']} n = {w['n']} SR {_sr(w['sr'])} {w['order'].replace('_', '-')} "
                 f"{100 * w['level']:g} %, {gap_w:+.2f} dB, {w['headline']['best_peer']}")
    ranked = ", ".join(f"{k} {mean[k]:.2f}" for k in top)
    return (f"Over the {len(cells)} stored cells, the mean gap to the best tuned peer of the "
            f"same cell: {', '.join(parts)}. Mean PSNR, the five best: {ranked} dB. "
            f"At n = 32 ({len(small)} cells) the best torchtof call on average is "
            f"`{best32.replace('torchtof ', '')}`, "
            f"{statistics.mean(gaps(best32, lambda c: c['n'] == 32)):+.2f} dB. "
            + (f"`auto` loses by more than 1 dB in {len(lose)} cells: {worst}{more} "
               if lose else
               f"`auto` loses by more than 1 dB in no cell (its worst: {worst_any}) ")
            + "(generated from `docs/peers.json`; `python benchmarks/peers.py --report "
            "docs/peers.json`).")


#: Classes of the held-out peers scenes (``benchmarks/peers_scenes.py``, ``HELD_OUT_SCENES``).
HELD_OUT_CLASSES = {"binary": ("glyph", "blobs"), "grey": ("astronaut", "phantom"),
                    "depth": ("objects", "smooth")}


def render_peers_heldout(res: dict) -> str:
    """The same comparison on scenes that chose none of ``auto``'s rules and trained no
    network (``docs/peers_heldout.json``): the mean gaps overall and per class, and every
    cell ``auto`` loses by more than 0.5 dB."""
    cells = [c for c in res["cells"] if c["headline"]["best_peer"]]

    def gap(c, k="torchtof auto"):
        return c["results"][k]["psnr"] - c["headline"]["best_peer_psnr"]

    ours = [k for k in ("torchtof auto", "torchtof auto [0,1]", "torchtof learned",
                        "torchtof tval3") if all(k in c["results"] for c in cells)]
    overall = ", ".join(
        f"`{k.replace('torchtof ', '')}` {statistics.mean(gap(c, k) for c in cells):+.2f} dB "
        f"(≥ 0 in {sum(gap(c, k) >= 0 for c in cells)})" for k in ours)
    by_class = []
    for cls, names in HELD_OUT_CLASSES.items():
        sub = [c for c in cells if c["scene"] in names]
        if sub:
            by_class.append(f"{cls} ({', '.join(names)}) {statistics.mean(map(gap, sub)):+.2f} dB, "
                            f"{sum(gap(c) >= 0 for c in sub)} of {len(sub)}")
    def run_of(c):
        return c["n"], c["order"].replace("_", "-"), c["level"]

    runs = sorted({run_of(c) for c in cells})
    spans = "; ".join(f"n = {n}, {o}, {100 * lv:g} % noise: "
                      f"{sum(run_of(c) == (n, o, lv) for c in cells)} cells" for n, o, lv in runs)
    lose = sorted((c for c in cells if gap(c) < -0.5), key=gap)
    worst = "; ".join(f"{c['scene']} n = {c['n']} SR {_sr(c['sr'])} "
                      f"{c['order'].replace('_', '-')} {100 * c['level']:g} %: {gap(c):+.2f} dB "
                      f"({c['headline']['best_peer']})" for c in lose)
    best_peer = {}
    for c in cells:
        best_peer[c["headline"]["best_peer"]] = best_peer.get(c["headline"]["best_peer"], 0) + 1
    peers = ", ".join(f"{k} {v}" for k, v in sorted(best_peer.items(), key=lambda kv: -kv[1]))
    return (f"On {len(cells)} held-out cells ({spans}), the mean gap to the best tuned peer of "
            f"the same cell: {overall} of {len(cells)}. `auto` by class: {'; '.join(by_class)}. "
            f"Best tuned peer per cell: {peers}. "
            + (f"`auto` loses by more than 0.5 dB in {len(lose)} cells: {worst} " if lose else
               "`auto` loses by more than 0.5 dB in no cell ")
            + "(generated from `docs/peers_heldout.json`; `python benchmarks/peers.py --report "
            "docs/peers_heldout.json`).")


def render_memory(res: dict) -> str:
    """Peak memory (growth of the maximum resident set) and time of the dense entry points,
    each in a fresh process (``tests/reliability/measure_memory.py``)."""
    c = res["cases"]

    def mib(k: str) -> str:
        return f"+{c[k]['peak_mib']:.0f} MiB"

    def gib(k: str) -> str:
        return f"+{c[k]['peak_mib'] / 1024:.2f} GiB"

    est = ", ".join(f"{b / 2**30:.2g} GiB at n = {n}"
                    for n, b in res["exact_factors_estimate_bytes_sr25"].items())

    return (f"Measured peaks (growth of the maximum resident set over `import torchtof`, each "
            f"case in a fresh process; {_load(res)}): `DMDSplit(Hadamard(128, sr=0.25))` "
            f"{mib('split_stream_128')} streamed with `iter_patterns(256)`, "
            f"{mib('split_patterns_128')} for the whole stack; the exact u-step's factors "
            f"(estimated {est}) {mib('exact_factors_64')} at n = 64 and "
            f"{gib('exact_factors_128')} at n = 128 (SR 25 %); the paper's experiment at "
            f"n = 64 with a 128-pixel region "
            f"{mib('experiment_64_roi128_c64')} in chunks of 64 frames, "
            f"{mib('experiment_64_roi128_c256')} in chunks of 256. Times at n = 64, SR 25 %, "
            f"the sky character: `tval3(u_step=\"exact\")` {c['exact_tval3_64']['time_s']:.1f} s, "
            f"`JointTV` (two channels) {c['jointtv_64']['time_s']:.1f} s (factors included; "
            f"`{res['command']} --out docs/reliability/memory.json`; generated from "
            f"`docs/reliability/memory.json`).")


#: TVAL3's defaults timed with 1 and 2 torch threads (two runs of ``time_call`` each, median
#: of 5): sky character 32×32, Hadamard SR 25 %, Gaussian noise 1 % of the measurement spread
THREADS_CMD = (
    "import json, pathlib, torch; from torchtof.apps.bench.timing import machine_load, "
    "time_call; from torchtof.operators import Hadamard; from torchtof.recon.tval3 import "
    "tval3; from torchtof.scenes import sky_character; A = Hadamard(32, sr=0.25); "
    "y0 = A(sky_character(32)); g = torch.Generator().manual_seed(0); "
    "y = y0 + 0.01 * (y0.max() - y0.min()) * torch.randn(y0.shape, generator=g); "
    "start = machine_load(); runs = {}\n"
    "for t in (1, 2):\n"
    "    torch.set_num_threads(t); runs[t] = [time_call(lambda: tval3(y, A), repeat=5) "
    "for _ in range(2)]\n"
    "torch.set_num_threads(1); out = pathlib.Path('docs/bench'); "
    "out.mkdir(parents=True, exist_ok=True); (out / 'threads.json').write_text(json.dumps("
    "{'n': 32, 'sr': 0.25, 'noise': 0.01, 'repeat': 5, 'runs_s': {str(k): v for k, v in "
    "runs.items()}, 'machine': {'start': start, 'end': machine_load()}}, indent=1) + '\\n')")


def _span_s(xs: list[float]) -> str:
    """"190–240 ms" below a second, "2.1–13.6 s" above."""
    lo, hi = min(xs), max(xs)
    if hi < 1:
        a, b, unit = _ms(lo), _ms(hi), "ms"
    else:
        a, b, unit = f"{lo:.2f}" if lo < 1 else f"{lo:.1f}", f"{hi:.1f}", "s"
    return f"{a}–{b} {unit}" if a != b else f"{a} {unit}"


def render_threads(res: dict) -> str:
    m = res["machine"]
    loads = sorted(x for x in (m["start"]["load_1min"], m["end"]["load_1min"]) if x is not None)
    if not loads:
        load = "load not recorded"
    else:
        lo, hi = f"{loads[0]:.1f}", f"{loads[-1]:.1f}"
        load = f"load {lo}" if lo == hi else f"load {lo}–{hi}"
    r = res["runs_s"]
    return (f"Measured on the {m['start']['cpus']}-core machine at {load}, TVAL3 defaults on "
            f"n = {res['n']}, SR {_sr(res['sr'])}, median of {res['repeat']}: "
            f"**{_span_s(r['1'])} with one thread, {_span_s(r['2'])} with two** "
            f"({len(r['1'])} runs each, `torch.set_num_threads(t)`, "
            "`torchtof.apps.bench.timing.time_call`; generated from `docs/bench/threads.json`, "
            "`python docs/build.py --run threads`).")


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
    "depth_joint": Section(
        "docs/depth/depth_joint.json", render_depth_joint,
        (sys.executable, "benchmarks/depth_joint_vs_separate.py", "--realisations", "5",
         "--out", "docs/depth"),
        "joint (vectorial-TV) vs separate I/Q reconstruction: depth RMSE, paired wins",
    ),
    "operators": Section(
        "docs/bench/bench_operators.json", render_operators,
        (sys.executable, "-m", "torchtof.cli", "bench", "operators", "--out", "docs/bench"),
        "forward + adjoint time of the Hadamard operator against dense baselines",
    ),
    "tradeoff": Section(
        "docs/bench/tradeoff.json", render_tradeoff,
        (sys.executable, "-m", "torchtof.cli", "bench", "tradeoff", "--quick", "--out",
         "docs/bench"),
        "which reconstructor for which time budget (quick grid)",
    ),
    "reproduce": Section(
        "docs/reproduce/reproduce.json", render_reproduce,
        (sys.executable, "-m", "torchtof.cli", "reproduce", "--quick", "--out",
         "docs/reproduce"),
        "the paper's claims against the quick run",
    ),
    "unrolled": Section(
        "docs/bench/unrolled.json", render_unrolled,
        (sys.executable, "benchmarks/compare_unrolled.py", "--noise", "0.01", "--time-scenes",
         "5", "--repeats", "3", "--out", "docs/bench"),
        "the unrolled TVAL3 against converged TVAL3 on held-out scenes",
    ),
    "onnx": Section(
        "docs/bench/bench_onnx.json", render_onnx,
        (sys.executable, "-m", "torchtof.cli", "bench", "onnx", "--models",
         "unrolled_tval3,g2,bp,tval3,dip", "--no-compile", "--out", "docs/bench"),
        "onnxruntime against eager PyTorch for the reconstructors",
    ),
    "export_time": Section(
        "docs/export_time/export_time.json", render_export_time,
        (sys.executable, "benchmarks/export_time.py", "--out", "docs/export_time"),
        "seconds each ONNX exporter takes on the unrolled TVAL3",
    ),
    "tval3": Section(
        "docs/bench/tval3.json", render_tval3,
        (sys.executable, "benchmarks/bench_tval3.py", "--threads", "1", "--seeds", "0-5",
         "--no-baseline", "--out", "docs/bench"),
        "TVAL3's defaults against an oracle-tuned ADMM-TV",
    ),
    "dip_time": Section(
        "docs/bench/time_dip.json", render_dip_time,
        (sys.executable, "benchmarks/time_dip.py", "--out", "docs/bench"),
        "wall time of 300 DIP iterations at 32×32 without early stopping",
    ),
    "dip_quality": Section(
        "docs/bench/dip_vs_tval3.json", render_dip_quality,
        (sys.executable, "benchmarks/dip_vs_tval3.py", "--out", "docs/bench"),
        "DIP against TVAL3's defaults and auto at 32×32 (PSNR, time per image)",
    ),
    "peers": Section(
        "docs/peers.json", render_peers,
        (sys.executable, "benchmarks/peers.py", "--out", "docs/peers_run.json"),
        "torchtof's one-call reconstructors against the oracle-tuned peer libraries",
        render_only="hours: the runs listed in docs/peers.md, merged with --report",
    ),
    "peers_heldout": Section(
        "docs/peers_heldout.json", render_peers_heldout,
        (sys.executable, "benchmarks/peers.py", "--scenes", "astronaut", "phantom", "glyph",
         "blobs", "objects", "smooth", "--seed", "1", "--out", "docs/peers_heldout_run.json"),
        "the peers comparison on held-out scenes (new images, seeds and noise draw)",
        render_only="hours: the runs listed in docs/peers.md, merged with --report",
    ),
    "memory": Section(
        "docs/reliability/memory.json", render_memory,
        (sys.executable, "tests/reliability/measure_memory.py", "--out",
         "docs/reliability/memory.json"),
        "peak memory and time of the dense entry points, each in a fresh process",
    ),
    "threads": Section(
        "docs/bench/threads.json", render_threads,
        (sys.executable, "-c", THREADS_CMD),
        "TVAL3's defaults with one and two threads, and the load they ran under",
    ),
    "stability": Section(
        "docs/bench/bench_stability.json", render_stability,
        (sys.executable, "-m", "torchtof.cli", "bench", "stability", "--out", "docs/bench"),
        "the numerical stress matrix",
    ),
    "learned": Section(
        "docs/learned/eval.json", render_learned,
        ("sh", "docs/learned/run.sh"),
        "the learned reconstructor on held-out scenes against TVAL3's defaults",
        render_only="about 11 min at load 1–2 (80 min at load 12–16)",
    ),
    "learned_recipe": Section(
        "torchtof/weights/learned/recipe.json", render_learned_recipe,
        ("torchtof", "train", "--model", "learned", "--seed", "0", "--out", "/tmp/learned_run"),
        "the shipped learned weights' training run",
        render_only="a 35-min training run and its calibration; it rewrites the weights",
    ),
    "bad_inputs": Section(
        "docs/reliability/bad_inputs.json", render_bad_inputs,
        (sys.executable, "-m", "tests.reliability.matrix", "--out",
         "docs/reliability/bad_inputs.json"),
        "the bad-input matrix: every misuse of the public calls, classified",
    ),
    "fault_sweep": Section(
        "docs/reliability/fault_sweep.json", render_fault_sweep,
        (sys.executable, "benchmarks/fault_sweep.py", "--workers", "2"),
        "every single and double frame fault on the simulated bench",
        render_only="38 min wall on 2 workers at load 1–2",
    ),
}

_BLOCK = re.compile(
    r"^(?P<ind>[ \t]*)(?P<open><!-- generated:(?P<name>[\w-]+) -->\n)(?P<body>.*?)"
    r"^(?P=ind)(?P<close><!-- /generated:(?P=name) -->)", re.S | re.M)


def render(name: str, indent: str = "") -> str:
    """The block ``name`` rendered from its JSON, each line indented by ``indent`` (a block
    inside a list item keeps the item's indentation)."""
    sec = SECTIONS[name]
    if not (ROOT / sec.json).exists():
        raise SystemExit(f"README.md block {name!r}: {sec.json} is missing; run: python "
                         f"docs/build.py --run {name}")
    data = json.loads((ROOT / sec.json).read_text(encoding="utf-8"))
    body = sec.render(data).rstrip("\n") + "\n"
    return "".join(indent + line if line.strip() else line
                   for line in body.splitlines(keepends=True))


def rewrite(text: str) -> tuple[str, list[str]]:
    """``text`` with every generated block re-rendered, and the names of the blocks found."""
    found: list[str] = []

    def sub(m: re.Match) -> str:
        name = m.group("name")
        if name not in SECTIONS:
            raise SystemExit(f"README.md: unknown generated block {name!r}")
        found.append(name)
        ind = m.group("ind")
        return ind + m.group("open") + render(name, ind) + ind + m.group("close")

    return _BLOCK.sub(sub, text), found


def stale_blocks(text: str | None = None) -> list[str]:
    """Names of the README blocks that differ from what their JSON renders to."""
    text = README.read_text(encoding="utf-8") if text is None else text
    stale = []
    for m in _BLOCK.finditer(text):
        if m.group("body") != render(m.group("name"), m.group("ind")):
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
        took, failed = {}, []
        sys.path.insert(0, str(ROOT))
        # the commands import this checkout's torchtof, whatever is installed
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(
            [str(ROOT)] + ([os.environ["PYTHONPATH"]] if os.environ.get("PYTHONPATH") else []))}
        from torchtof.apps.bench.timing import machine_load

        for name in names:
            cmd = SECTIONS[name].command
            if SECTIONS[name].render_only:
                shown = " ".join(["python" if cmd[0] == sys.executable else cmd[0], *cmd[1:]])
                print(f"[docs] {name}: not rerun here ({SECTIONS[name].render_only}); to "
                      f"regenerate {SECTIONS[name].json}: OMP_NUM_THREADS=1 {shown}",
                      flush=True)
                continue
            print(f"[docs] {name}: {' '.join(cmd)}", flush=True)
            t0, start = time.perf_counter(), machine_load()
            start.pop("threads")  # this process's, not the command's
            rc = subprocess.run(cmd, cwd=ROOT, env=env).returncode
            if rc != 0:  # unattended: the other targets still run, the status says it failed
                failed.append(name)
                print(f"[docs] {name}: FAILED with exit status {rc}; its block keeps the "
                      "previous JSON", file=sys.stderr, flush=True)
                continue
            took[name] = time.perf_counter() - t0
            times = json.loads(TIMES.read_text(encoding="utf-8")) if TIMES.exists() else {}
            end = machine_load()
            end.pop("threads")
            times[name] = {"seconds": round(took[name], 3), "start": start, "end": end,
                           "command": " ".join(["python", *cmd[1:]])}
            TIMES.write_text(json.dumps(times, indent=1, sort_keys=True) + "\n", encoding="utf-8")
            print(f"[docs] {name}: {took[name]:.0f} s", flush=True)
        print("[docs] time per target: " + ", ".join(f"{k} {v:.0f} s" for k, v in took.items())
              + (f"; FAILED: {', '.join(failed)}" if failed else ""), flush=True)
    else:
        failed = []
    text, found = rewrite(README.read_text(encoding="utf-8"))
    README.write_text(text, encoding="utf-8")
    print(f"[docs] rewrote {len(found)} generated block(s) in README.md: {', '.join(found)}")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
