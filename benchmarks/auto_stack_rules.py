"""How ``auto`` should weight the learned network it stacks with its TV/TGV choice. (Offline study.)

For each peers cell (``benchmarks/peers_scenes.py``: same image, Hadamard rows, noise draw and
PSNR as ``benchmarks/peers.py``), ``auto(y, A, learned=False)`` runs once; its chosen
candidate and the shipped learned network are then fitted on the same tail folds as ``auto``
uses (the network on the first ``k`` rows, a plain ``Hadamard(n, m=k)``), and the weight
``w`` of the convex combination ``(1 − w) x̂_auto + w x̂_learned`` of the two full-row
reconstructions is set by several rules from the held-out predictions (no ground truth):

- ``pooled``: the least-squares weight over all folds' held-out rows together;
- ``relative``: the same with each fold's rows divided by the TV/TGV choice's error there;
- ``latest``: the least-squares weight of the fold trained on the most rows (7/8);
- ``min``: the smallest of the folds' least-squares weights;
- ``median``: the median of the folds' weights; ``mean``: their mean;
- ``latest∧pooled``, ``latest∧relative``: the smaller of the latest fold's weight and the
  pooled (relative) one; ``latest∧relative`` is ``auto``'s rule
  (:func:`torchtof.recon.auto.stack_weight`).

``--far``: also the far-fold rules of :data:`FAR_RULES` (the choice and the network fitted on
the first M/2 or M/4 rows and scored on the last quarter or half: a gap between the rows fitted
and the rows scored; tried, not adopted: ``docs/auto.md``, "Tried, not adopted: far folds").

``--auto-eval``: the cells of ``benchmarks/auto_eval.py`` instead (6 scenes incl. the smooth
``moon``, cake-cutting rows, noise of ``--noise`` × the bucket spread; no peers there, so only
the change against ``auto`` without the network is reported): a check of a rule chosen on the
peers cells on cells it was not chosen on.

Prints, per rule, the mean gap to the best oracle-tuned peer of ``docs/peers.json``, the
cells at ≥ 0, the mean and worst change against ``auto`` without the network; and the fixed
weights ``w ∈ {0.25, 0.5, 1}`` and the per-cell oracle weight for reference.

    OMP_NUM_THREADS=1 python benchmarks/auto_stack_rules.py --n 32 --orders cake_cutting \\
        sequency
    OMP_NUM_THREADS=1 python benchmarks/auto_stack_rules.py --n 32 --noise 0.05 --sr 0.125 0.375
    OMP_NUM_THREADS=1 python benchmarks/auto_stack_rules.py --n 64 --sr 0.125 0.25 0.375
    python benchmarks/auto_stack_rules.py --table "n = 32::p32.json" "n = 64::p64.json"

(``--out FILE`` keeps the per-cell rows; ``--table LABEL::FILE ...`` prints one table of the
rules over several such files, as in ``docs/auto.md``.)
"""

from __future__ import annotations

import importlib
import json
import statistics
import time
from pathlib import Path

import peers_scenes as ps  # benchmarks/ is the script's directory
import torch

from torchtof.operators import Hadamard
from torchtof.recon import auto, learned

ROOT = Path(__file__).resolve().parents[1]
RULES = ("pooled", "relative", "latest", "min", "median", "mean", "latest∧pooled",
         "latest∧relative")
FIXED = (0.25, 0.5, 1.0)


def fold_predictions(y, A, choice, am):
    """``(pa, pl, held)``: the chosen candidate's and the network's predictions ``A x̂`` fitted
    on each of ``auto``'s default tail folds ``(1, F, M)`` (``auto``'s own
    :func:`~torchtof.recon.auto.stack_predictions`), and the held-out rows ``(F, M)``."""
    held, train = am.cv_folds(A, y, None, 0, "tail")
    pa, pl = am.stack_predictions(y, A, [choice], train, 100)
    return pa, pl, held


#: The far folds (``--far``): (fraction of the rows trained on, first held-out fraction): the
#: models fitted on the first M/2 rows and scored on the last quarter, and on the first M/4 and
#: scored on the last half, so that a gap separates the rows fitted from the rows scored.
FAR = ((0.5, 0.75), (0.25, 0.5))
FAR_RULES = ("far½", "far¼", "far½∨auto", "far¼∨auto", "mean(far½, auto)")


def far_predictions(y, A, choice, am):
    """``(pa, pl, held)`` of the :data:`FAR` folds: the chosen candidate and the network fitted
    on each fold's prefix of the rows, scored on its far held-out rows."""
    m = y.shape[-1]
    train = torch.zeros(len(FAR), m, dtype=torch.bool, device=y.device)
    held = torch.zeros_like(train)
    for i, (ft, fh) in enumerate(FAR):
        train[i, : max(int(ft * m), 1)] = True
        held[i, int(fh * m):] = True
    pa, pl = am.stack_predictions(y, A, [choice], train, 100)
    return pa, pl, held


def fold_terms(pa, pl, y, held):
    """Per fold, from the held-out rows: ``(num, den, per_fold, r)``, the least-squares
    weight's numerator ``⟨d, r⟩`` and denominator ``‖d‖²`` (``d = p^l − p^a``, ``r = y − p^a``),
    the weight clipped to [0, 1], and the residuals ``r`` ``(F, M)``."""
    h = held.to(y.dtype)
    d, r = ((pl - pa) * h)[0], ((y - pa) * h)[0]  # (F, M)
    num, den = (d * r).sum(-1), (d * d).sum(-1)
    per_fold = torch.where(den > 0, num / den.clamp_min(1e-300), torch.zeros_like(num))
    return num, den, per_fold.clamp(0, 1), r


def far_weights(pa, pl, y, held, auto_w: float) -> dict:
    wf = fold_terms(pa, pl, y, held)[2]
    w = {"far½": float(wf[0]), "far¼": float(wf[1])}
    w["far½∨auto"] = max(w["far½"], auto_w)
    w["far¼∨auto"] = max(w["far¼"], auto_w)
    w["mean(far½, auto)"] = (w["far½"] + auto_w) / 2
    return w


def rule_weights(pa, pl, y, held, am) -> dict:
    num, den, per_fold, r = fold_terms(pa, pl, y, held)
    rel = 1 / r.square().sum(-1).clamp_min(1e-300)

    def pooled(wf):
        return float(((num * wf).sum() / (den * wf).sum().clamp_min(1e-300)).clamp(0, 1))

    w = {"pooled": pooled(torch.ones_like(num)), "relative": pooled(rel),
         "latest": float(per_fold[0]), "min": float(per_fold.min()),
         "median": float(per_fold.median()), "mean": float(per_fold.mean())}
    w["latest∧pooled"] = min(w["latest"], w["pooled"])
    w["latest∧relative"] = min(w["latest"], w["relative"])
    own = float(am.stack_weight(pa, pl, y, held)[0])  # auto's rule, computed by auto
    assert abs(own - w["latest∧relative"]) <= 1e-9 + 1e-6 * own, (own, w)
    return w


def table(groups: list[str]) -> str:
    """Markdown: per rule, the mean (worst) change against ``auto`` without the network in each
    ``LABEL::FILE`` group of ``--out`` rows, over all of them, and the gap to the best tuned
    peer where the rows have one."""
    data = []
    for g in groups:
        label, path = g.split("::")
        data.append((label, json.loads(Path(path).read_text())))
    everything = [r for _, rows in data for r in rows]

    def val(r, k):
        return {"no network (w = 0)": r["auto"], "oracle w (ground truth)": r["oracle"]}.get(
            k, r["fixed"].get(k[len("fixed w = "):], r["rules"].get(k)))

    keys = (["no network (w = 0)", *everything[0]["rules"]]
            + [f"fixed w = {w}" for w in everything[0]["fixed"]] + ["oracle w (ground truth)"])
    out = ["| rule | " + " | ".join(f"{lab} ({len(rows)})" for lab, rows in data)
           + " | all: mean change | worst change | gap to the best tuned peer | cells ≥ 0 |",
           "|---" * (len(data) + 5) + "|"]
    peers = [r for r in everything if r["peer"] == r["peer"]]  # not nan
    for k in keys:
        cells = []
        for _, rows in data:
            d = [val(r, k) - r["auto"] for r in rows]
            cells.append(f"{statistics.mean(d):+.2f} ({min(d):+.2f})")
        d = [val(r, k) - r["auto"] for r in everything]
        gap = (f"{statistics.mean(val(r, k) - r['peer'] for r in peers):+.2f} | "
               f"{sum(val(r, k) >= r['peer'] for r in peers)} of {len(peers)}" if peers
               else "– | –")
        name = f"**{k}** (`auto`)" if k == "latest∧relative" else k
        out.append(f"| {name} | " + " | ".join(cells)
                   + f" | {statistics.mean(d):+.2f} | {min(d):+.2f} | {gap} |")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> dict:
    p = ps.cell_parser(__doc__.splitlines()[0])
    p.add_argument("--peers", default=str(ROOT / "docs" / "peers.json"))
    p.add_argument("--auto-eval", action="store_true",
                   help="the cells of benchmarks/auto_eval.py (--n, --sr; its six scenes, "
                        "cake-cutting rows, --noise × the bucket spread) instead of the peers'")
    p.add_argument("--out", default=None, help="JSON file of the per-cell rows")
    p.add_argument("--table", nargs="+", default=None, metavar="LABEL::FILE",
                   help="print the rules table of these --out files and exit")
    p.add_argument("--far", action="store_true",
                   help="also the far-fold rules (FAR_RULES: models fitted on a prefix of the "
                        "rows, scored on rows separated from it by a gap)")
    a = p.parse_args(argv)
    if a.table:
        print(table(a.table))
        return {}
    if a.auto_eval:
        import auto_eval as ae

        problems = [(name, a.n, sr, "cake_cutting") for sr in a.sr for name in ae.SCENES]

        def make(name, n, sr, order):
            A = Hadamard(n, sr=sr).double()
            x, y = ae.noisy(name, A, a.noise)
            return x, A, y
    else:
        problems = [(scene, a.n, sr, order) for order in a.orders for sr in a.sr
                    for scene in a.scenes]

        def make(name, n, sr, order):
            return ps.make_problem(name, n, sr, order, a.noise)[:3]
    am = importlib.import_module("torchtof.recon.auto")
    torch.set_num_threads(1)
    stored = {(c["scene"], c["n"], c["sr"], c["order"], c["level"]): c
              for c in json.loads(Path(a.peers).read_text())["cells"]}
    rows = []
    for scene, n, sr, order in problems:
        key = (scene, n, sr, order, a.noise)
        if key not in stored and not a.auto_eval:
            continue
        x, A, y = make(scene, n, sr, order)
        t0 = time.perf_counter()
        r = auto(y, A, learned=False, return_result=True)
        t_off = time.perf_counter() - t0
        t0 = time.perf_counter()  # the stacking stage alone, as auto(y, A) runs it
        opts = am.auto_options()  # auto's defaults, every key its stages read
        stacked = am._with_learned(r, y, A, None, opts)
        t_stack = time.perf_counter() - t0
        ch = r.choice[0][0]
        with torch.no_grad():
            x_l = learned(y, A)
            if ch["prior"] == "box":
                ws = dict.fromkeys(RULES + (FAR_RULES if a.far else ()), 0.0)
            else:
                pa, pl, held = fold_predictions(y, A, ch, am)
                ws = rule_weights(pa, pl, y, held, am)
                if a.far:
                    fa, fl, fh = far_predictions(y, A, ch, am)
                    ws.update(far_weights(fa, fl, y, fh, ws["latest∧relative"]))
        if a.auto_eval:
            peer = float("nan")
        else:
            res = stored[key]["results"]
            peer = max(v["psnr"] for v in res.values()
                       if v.get("peer") != "torchtof" and v["psnr"] is not None)
        blend = {w: ps.score(r.x + w * (x_l - r.x), x) for w in (0.0, *FIXED)}
        grid = [ps.score(r.x + (i / 20) * (x_l - r.x), x) for i in range(21)]
        row = dict(scene=scene, n=n, sr=sr, order=order, peer=peer, auto=blend[0.0],
                   weights=ws, fixed={str(w): blend[w] for w in FIXED},
                   oracle=max(grid),
                   rules={k: ps.score(r.x + w * (x_l - r.x), x) for k, w in ws.items()},
                   stacked=ps.score(stacked.x, x), cost=(t_off + t_stack) / t_off)
        rows.append(row)
        print(f"{order} SR={sr} {scene}: auto {row['auto']:.2f}, "
              + ", ".join(f"{k} {row['rules'][k] - row['auto']:+.2f} (w {w:.2f})"
                          for k, w in ws.items()), flush=True)
    print(f"{len(rows)} cells: gap to the best tuned peer (mean, cells >= 0, worst) and change "
          "against auto without the network (mean, worst)")

    def line(name, f):
        g = [f(r) - r["peer"] for r in rows]
        d = [f(r) - r["auto"] for r in rows]
        gap = ("– | – | –" if a.auto_eval else
               f"{statistics.mean(g):+.2f} | {sum(v >= 0 for v in g)} | {min(g):+.2f}")
        print(f"| {name} | {gap} | {statistics.mean(d):+.2f} | {min(d):+.2f} |")

    print("| rule | mean gap dB | cells ≥ 0 | worst gap | mean change | worst change |")
    print("|---|---|---|---|---|---|")
    line("no network (w = 0)", lambda r: r["auto"])
    for k in RULES + (FAR_RULES if a.far else ()):
        line(k, lambda r, k=k: r["rules"][k])
    for w in FIXED:
        line(f"fixed w = {w:g}", lambda r, w=w: r["fixed"][str(w)])
    line("oracle w (ground truth)", lambda r: r["oracle"])
    line("auto(y, A) (stacked: latest∧relative)", lambda r: r["stacked"])
    cost = sorted(r["cost"] for r in rows)
    print(f"cost of auto(y, A) against auto(y, A, learned=False), same buckets: median "
          f"{statistics.median(cost):.2f}× ({cost[0]:.2f}–{cost[-1]:.2f}×)")
    if a.out:
        Path(a.out).write_text(json.dumps(rows, indent=0))
    return dict(rows=rows)


if __name__ == "__main__":
    main()
