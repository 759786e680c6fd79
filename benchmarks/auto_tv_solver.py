"""``auto``'s TV-L2 solver: ``tv_solver="split"`` against ``"tval3"`` (the default: TVAL3 for
every TV fit), interleaved in one process, one thread.

For each cell (``benchmarks/peers_scenes.py``: scene, n, SR, order, 1 % noise by default) the
plain ``auto(y, A)`` call runs with each solver in turn, ``--repeats`` rounds, alternating
which goes first; the PSNR (as the peers benchmark scores it), the choice and the median wall
time of each are printed, then the mean PSNR difference and the median time ratio of the
second solver given to the first (default ``--solvers tval3 split``: split / tval3). ``--cells`` takes ``scene:n:sr:order`` items.

    OMP_NUM_THREADS=1 python benchmarks/auto_tv_solver.py --out docs/auto/tv_solver.json

``--variants`` runs any ``solver[:fit_iter]`` settings the same way (every one is timed and
printed per cell; the summary compares the second with the first, as ``--solvers`` does in
the order given), e.g. the TV-L2/TGV-L2 fits' own budget ``fit_iter`` against the default:

    OMP_NUM_THREADS=1 python benchmarks/auto_tv_solver.py --variants tval3 tval3:300 \
        --out docs/auto/fit_iter.json

``--peers-compare F`` instead compares a peers-benchmark JSON of ``auto`` run with
``benchmarks/peers.py --auto-tv-solver split`` (``docs/auto/tv_solver_peers.json``; with
``--auto-cv-iter 300`` as well: ``docs/auto/tv_solver_cv300_peers.json``) with the
stored one-call results of ``docs/peers.json``, cell by cell: the mean gap to the best tuned
peer with each solver, the cells at or above it, and every cell that changed.

    python benchmarks/auto_tv_solver.py --peers-compare docs/auto/tv_solver_peers.json
"""

from __future__ import annotations

import json
import math
import statistics
import sys
import time
from pathlib import Path

CELLS = ("planes:64:0.0625:cake_cutting", "planes:64:0.125:cake_cutting",
         "sky:64:0.375:cake_cutting", "coins:64:0.125:cake_cutting",
         "camera:32:0.375:sequency", "horse:32:0.125:sequency", "coins:32:0.0625:sequency",
         "planes:32:0.125:cake_cutting", "sky:32:0.25:cake_cutting",
         "planes:128:0.0625:cake_cutting", "camera:128:0.125:cake_cutting")


def parse(argv=None):
    from torchtof.apps.args import OneLineParser  # a mistake: one line, exit 2

    p = OneLineParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--cells", nargs="+", default=list(CELLS))
    p.add_argument("--noise", type=float, default=0.01)
    p.add_argument("--repeats", type=int, default=1)
    p.add_argument("--solvers", nargs="+", default=["tval3", "split"], choices=("tval3", "split"))
    p.add_argument("--cv-iter", type=int, default=100, help="auto's cv_iter (every solver)")
    p.add_argument("--variants", nargs="+", default=None, metavar="SOLVER[:FIT_ITER]",
                   help="settings to compare instead of --solvers: tv_solver and optionally "
                        "fit_iter, e.g. tval3 tval3:300 (the first is the reference)")
    p.add_argument("--out", type=Path, default=None)
    p.add_argument("--peers-compare", type=Path, default=None, metavar="SPLIT_JSON")
    a = p.parse_args(argv)
    if a.repeats < 1 or a.cv_iter < 1:
        p.error("expected --repeats, --cv-iter >= 1")
    if a.variants is None:
        a.variants = list(a.solvers)
    for v in a.variants:
        s, _, it = v.partition(":")
        if s not in ("tval3", "split") or (it and not (it.isdigit() and int(it) >= 1)):
            p.error(f"expected --variants items tval3|split[:FIT_ITER >= 1], got {v!r}")
    for c in a.cells:
        parts = c.split(":")
        if len(parts) != 4:
            p.error(f"expected --cells items scene:n:sr:order, got {c!r}")
    return a


def _choice(ch: dict) -> str:
    mu = "c" if ch.get("mu") is None else f"2^{round(math.log2(ch['mu']))}"
    return f"{ch['prior']} {ch.get('tv')} {ch.get('bounds')} {mu}"


def peers_compare(path: Path, stored: Path) -> dict:
    """Per-method summary of ``path`` (``auto`` with the split solver) against ``stored``."""
    key = lambda c: (c["scene"], c["n"], c["sr"], c["order"], c["level"])  # noqa: E731
    old = {key(c): c for c in json.loads(stored.read_text())["cells"]}
    new = {key(c): c for c in json.loads(path.read_text())["cells"]}
    out = {}
    for m in ("torchtof auto", "torchtof auto [0,1]"):
        rows = []
        for k, c in new.items():
            if k not in old or m not in c["results"]:
                continue
            peer = old[k]["headline"]["best_peer_psnr"]
            rows.append((k, old[k]["results"][m]["psnr"] - peer, c["results"][m]["psnr"] - peer))
        if not rows:
            continue
        gaps_t, gaps_s = [r[1] for r in rows], [r[2] for r in rows]
        changed = sorted((r[2] - r[1], r[0]) for r in rows if abs(r[2] - r[1]) > 0.005)
        out[m] = dict(cells=len(rows), mean_gap_tval3=statistics.mean(gaps_t),
                      mean_gap_split=statistics.mean(gaps_s),
                      at_or_above_tval3=sum(g >= 0 for g in gaps_t),
                      at_or_above_split=sum(g >= 0 for g in gaps_s),
                      changed=[dict(cell=list(k), db=d) for d, k in changed])
        print(f"{m}: {len(rows)} cells, mean gap to the best tuned peer: docs/peers.json "
              f"{out[m]['mean_gap_tval3']:+.2f} dB ({out[m]['at_or_above_tval3']} >= 0), {path.name} "
              f"{out[m]['mean_gap_split']:+.2f} dB ({out[m]['at_or_above_split']} >= 0); "
              f"{len(changed)} cells changed")
        for d, k in changed:
            print(f"  {d:+6.2f} dB  {k[0]} n={k[1]} SR={k[2]:g} {k[3]} noise={k[4]:g}")
    return out


def main(argv=None) -> int:
    a = parse(argv)
    if a.peers_compare is not None:
        peers_compare(a.peers_compare, Path(__file__).resolve().parents[1] / "docs" / "peers.json")
        return 0
    import torch

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import peers_scenes as ps

    from torchtof.recon.auto import auto

    torch.set_num_threads(1)
    rows = []
    for cell in a.cells:
        scene, n, sr, order = cell.split(":")
        x, A, y, _ = ps.make_problem(scene, int(n), float(sr), order, a.noise)
        res = {s: dict(times=[]) for s in a.variants}
        for k in range(a.repeats):
            for s in (a.variants if k % 2 == 0 else a.variants[::-1]):
                solver, _, it = s.partition(":")
                t0 = time.perf_counter()
                r = auto(y, A, tv_solver=solver, cv_iter=a.cv_iter,
                         fit_iter=int(it) if it else None, return_result=True)
                res[s]["times"].append(time.perf_counter() - t0)
                res[s].update(psnr=ps.score(r.x, x), choice=_choice(r.choice[0][0]))
        row = dict(cell=cell, noise=a.noise, cv_iter=a.cv_iter,
                   **{s: dict(v, time_s=statistics.median(v["times"])) for s, v in res.items()})
        rows.append(row)
        print(f"{cell:34s} " + "  ".join(f"{s} {row[s]['psnr']:6.2f} dB {row[s]['time_s']:6.1f} s "
                                         f"[{row[s]['choice']}]" for s in a.variants), flush=True)
    summary = {}
    if len(set(a.variants)) < 2:
        if a.out is not None:
            a.out.write_text(json.dumps({"args": {k: str(v) if isinstance(v, Path) else v
                                                  for k, v in vars(a).items()},
                                         "rows": rows}, indent=1))
        return 0
    ref, new = a.variants[0], a.variants[1]
    d = [r[new]["psnr"] - r[ref]["psnr"] for r in rows]
    ratio = [r[new]["time_s"] / r[ref]["time_s"] for r in rows]
    summary.update(reference=ref, variant=new, mean_db=statistics.mean(d), min_db=min(d),
                   max_db=max(d), median_time_ratio=statistics.median(ratio))
    print(f"{new} - {ref}: mean {summary['mean_db']:+.2f} dB (min {summary['min_db']:+.2f}, max "
          f"{summary['max_db']:+.2f}); time {new} / {ref}: median "
          f"{summary['median_time_ratio']:.2f}")
    if a.out is not None:
        a.out.write_text(json.dumps({"args": {k: str(v) if isinstance(v, Path) else v
                                              for k, v in vars(a).items()},
                                     "rows": rows, "summary": summary}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
