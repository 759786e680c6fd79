"""Run time of the iterative reconstructors against a previous revision, interleaved.

A git worktree of ``--rev`` is made in a temporary folder; then, round after round, one process
imports ``torchtof`` from that tree and one from this one, and each times the same calls on the
same buckets (``benchmarks/peers_scenes.make_problem``: the peers benchmark's scenes, Hadamard
rows, 1 % noise, float64, one thread). Each process also saves its outputs, and the script
reports whether the two revisions' outputs are equal bit for bit (``torch.equal``), so a
speed-up that changes a result shows as one.

Prints, per call, the best time of each revision over the rounds (the best of ``--repeats``
calls within a process, one call for ``auto``) and their ratio (previous / this: > 1 is faster
now). The machine's 1-minute load before and after is printed with them.

    OMP_NUM_THREADS=1 python benchmarks/versus_rev.py --rev HEAD~1 --rounds 2
    python benchmarks/versus_rev.py --rev v0.1 --calls "tval3 n=32" "auto n=32" --out cmp.json
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import torch

from torchtof.apps.args import OneLineParser

ROOT = Path(__file__).resolve().parents[1]

#: name -> (function, n, SR, row order, options). ``auto`` is timed once per process.
CALLS = {
    "tval3 n=8": ("tval3", 8, 0.5, "cake_cutting", {}),
    "tval3 n=32": ("tval3", 32, 0.125, "cake_cutting", {}),
    "tval3 n=64": ("tval3", 64, 0.125, "cake_cutting", {}),
    "tval3 n=128": ("tval3", 128, 0.125, "cake_cutting", {}),
    "tgv n=32": ("tgv", 32, 0.25, "cake_cutting", {}),
    "bp n=32": ("basis_pursuit", 32, 0.25, "cake_cutting", {}),
    "joint_tv n=32": ("joint_tv", 32, 0.25, "cake_cutting", {}),
    "auto n=32": ("auto", 32, 0.125, "cake_cutting", {}),
    "auto n=64": ("auto", 64, 0.125, "cake_cutting", {}),
}

# the child: times CALLS[name] for each name in argv, torchtof imported from sys.path[0]
CHILD = r"""
import json, sys, time, warnings
warnings.simplefilter("ignore")
import torch
torch.set_num_threads(1)
sys.path.insert(0, sys.argv[1])
import torchtof
assert torchtof.__file__.startswith(sys.argv[1]), torchtof.__file__
sys.path.insert(0, sys.argv[2])
import peers_scenes
from torchtof import recon
calls, repeats, save = json.loads(sys.argv[3]), int(sys.argv[4]), sys.argv[5]
times, outs = {}, {}
for name, (fn, n, sr, order, kw) in calls.items():
    _, A, y, _ = peers_scenes.make_problem("camera", n, sr, order, 0.01, 0)
    y = y.double()
    f = getattr(recon, fn)
    best = float("inf")
    for _ in range(1 if fn == "auto" else repeats):
        t = time.perf_counter()
        x = f(y, A, **kw)
        best = min(best, time.perf_counter() - t)
    times[name], outs[name] = best, x
torch.save(outs, save)
print(json.dumps(times))
"""


def load() -> float:
    return os.getloadavg()[0]


def main(argv: list[str] | None = None) -> int:
    p = OneLineParser(description=__doc__.splitlines()[0])
    p.add_argument("--rev", default="HEAD~1", help="the previous revision (default HEAD~1)")
    p.add_argument("--rounds", type=int, default=2, help="alternating rounds (default 2)")
    p.add_argument("--repeats", type=int, default=3, help="calls per process, best kept")
    p.add_argument("--calls", nargs="+", choices=sorted(CALLS), default=list(CALLS),
                   help="which calls (default: all)")
    p.add_argument("--out", help="JSON of the times, ratios and the load")
    a = p.parse_args(argv)
    if a.rounds < 1 or a.repeats < 1:
        p.error("--rounds and --repeats must be >= 1")
    calls = {k: CALLS[k] for k in a.calls}
    commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", a.rev], check=True,
                            capture_output=True, text=True).stdout.strip()
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    with tempfile.TemporaryDirectory() as tmp:
        old = Path(tmp) / "rev"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "-q", "--detach", str(old),
                        commit], check=True)
        try:
            best = {"previous": {}, "this": {}}
            outs = {}
            load0 = load()
            for r in range(a.rounds):
                for label, tree in (("previous", old), ("this", ROOT)):
                    save = Path(tmp) / f"{label}.pt"
                    res = subprocess.run(
                        [sys.executable, "-c", CHILD, str(tree), str(ROOT / "benchmarks"),
                         json.dumps(calls), str(a.repeats), str(save)],
                        check=True, capture_output=True, text=True, env=env)
                    t = json.loads(res.stdout.strip().splitlines()[-1])
                    for k, v in t.items():
                        best[label][k] = min(best[label].get(k, float("inf")), v)
                    outs[label] = torch.load(save)
                print(f"round {r + 1}/{a.rounds} done", file=sys.stderr)
            load1 = load()
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(old)],
                           check=False)
    rows = []
    print(f"{a.rev} against the working tree (best of {a.rounds} rounds; load {load0:.1f} "
          f"-> {load1:.1f})")
    print(f"{'call':<12} {'previous s':>11} {'this s':>9} {'ratio':>6}  equal")
    for k in calls:
        po, th = best["previous"][k], best["this"][k]
        eq = bool(torch.equal(outs["previous"][k], outs["this"][k]))
        rows.append({"call": k, "previous_s": po, "this_s": th, "ratio": po / th, "equal": eq})
        print(f"{k:<12} {po:>11.3f} {th:>9.3f} {po / th:>6.2f}  {eq}")
    if a.out:
        Path(a.out).write_text(json.dumps({"rev": a.rev, "rev_commit": commit,
                                           "rounds": a.rounds, "repeats": a.repeats,
                                           "load_1min": [load0, load1], "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
