"""Where the learned network's gain over TVAL3 goes: its own training families against the
held-out classes, on the same sizes, sampling rates and noise.

For each ``(n, SR)`` (cake-cutting rows, Gaussian noise of ``level × (max y − min y)``, the
convention of ``eval_learned.py``), the mean PSNR of the learned network and of TVAL3's
defaults on three scene sets:

- ``seen``: the scene seeds of the weights' own training run (its first two steps,
  ``scene_seed(seed, step, i)``, drawn at this ``n``: those steps trained at n = 32, so at
  larger ``n`` they are the same scenes rendered at another size);
- ``fresh <family>``: each training family (``torchtof.data.FAMILIES``) drawn from seeds no
  training run uses (``EVAL_SEED_BASE + 5000`` and up; the natural family crops the training
  photographs anew);
- ``held-out <class>``: the three classes of ``eval_learned.py`` (held-out seeds and images).

Each set is scored over ``draws`` noise draws (the first draw of a held-out class is
``eval_learned.py``'s own, so that draw reproduces its cell); the mean over scenes and draws.

If the network's gain on fresh draws of its own families is far above its gain on the
held-out classes, the acceptance's shortfall is a distribution shift, not the network's or
the problem's limit.

usage: OMP_NUM_THREADS=1 python benchmarks/learned_gap.py [--sizes 32 64 128]
           [--srs 0.0625 0.125] [--level 0.01] [--per-family 6] [--draws 3] [--weights W]
           [--out gap.json]
       python benchmarks/learned_gap.py --table gap.json
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
import eval_learned as ev  # noqa: E402

from torchtof.data import EVAL_SEED_BASE, FAMILIES, draw_scene  # noqa: E402
from torchtof.operators import Hadamard  # noqa: E402
from torchtof.recon.learned import WEIGHTS_FILE, Learned  # noqa: E402
from torchtof.recon.synthetic import scene_seed  # noqa: E402
from torchtof.recon.tval3 import tval3  # noqa: E402


def scene_sets(n: int, per_family: int, recipe_seed: int) -> dict[str, torch.Tensor]:
    sets = {"seen": torch.cat([draw_scene(n, scene_seed(recipe_seed, step, i))
                               for step in range(2) for i in range(per_family // 2)])}
    for k, fam in enumerate(f for f, p in FAMILIES.items() if p > 0):
        sets[f"fresh {fam}"] = torch.cat([
            draw_scene(n, EVAL_SEED_BASE + 5000 + 100 * k + j, fam) for j in range(per_family)])
    for cls in ev.CLASSES:
        sets[f"held-out {cls}"] = ev.scenes(cls, n)
    return {k: v.float() for k, v in sets.items()}


def run(sizes, srs, level, per_family, weights, draws) -> list[dict]:
    torch.set_num_threads(1)
    seed = torch.load(weights, weights_only=True)["meta"]["seed"]  # the run's seed
    rows = []
    for n in sizes:
        sets = scene_sets(n, per_family, seed)
        for sr in srs:
            A = Hadamard(n, sr=sr, order="cake_cutting")
            net = Learned(A, pretrained=weights)
            for j, (name, x) in enumerate(sets.items()):
                t = time.perf_counter()
                pl, pt = [], []
                for d in range(draws):
                    # draw 0 of a held-out class: the noise of eval_learned.py's cell
                    salt = (n + int(sr * 1e4) + int(level * 1e4) if name.startswith("held")
                            and d == 0 else 100_000 + 1000 * d + 7 * n + int(sr * 1e4) + j)
                    y = ev.buckets(A, x, level, salt=salt)
                    with torch.no_grad():
                        xl = net(y)
                        xt = tval3(y, A)
                    pl += [ev.score(xl[i:i + 1], x[i:i + 1])[0] for i in range(x.shape[0])]
                    pt += [ev.score(xt[i:i + 1], x[i:i + 1])[0] for i in range(x.shape[0])]
                rows.append({"n": n, "sr": sr, "level": level, "set": name,
                             "scenes": x.shape[0], "draws": draws, "learned": float(np.mean(pl)),
                             "tval3": float(np.mean(pt)),
                             "delta": float(np.mean(np.subtract(pl, pt)))})
                print(f"n={n:3d} sr={sr:.4f} {name:22s} learned {rows[-1]['learned']:6.2f}  "
                      f"TVAL3 {rows[-1]['tval3']:6.2f}  Δ {rows[-1]['delta']:+.2f} dB  "
                      f"({time.perf_counter() - t:.1f} s)", flush=True)
    return rows


def table(rows: list[dict]) -> str:
    names = list(dict.fromkeys(r["set"] for r in rows))
    keys = list(dict.fromkeys((r["n"], r["sr"]) for r in rows))
    out = ["| scene set | " + " | ".join(f"n = {n}, {sr * 100:g} %" for n, sr in keys)
           + " | mean Δ |", "|---" * (len(keys) + 2) + "|"]
    for name in names:
        d = {(r["n"], r["sr"]): r["delta"] for r in rows if r["set"] == name}
        out.append(f"| {name} | " + " | ".join(f"{d[k]:+.2f}" for k in keys)
                   + f" | {np.mean(list(d.values())):+.2f} |")
    return "\n".join(out)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[32, 64, 128])
    p.add_argument("--srs", type=float, nargs="+", default=[0.0625, 0.125])
    p.add_argument("--level", type=float, default=0.01)
    p.add_argument("--per-family", type=int, default=6,
                   help="scenes per family, an even number >= 2 (the seen set takes half from "
                   "each of two training steps)")
    p.add_argument("--draws", type=int, default=3, help="noise draws per scene set")
    p.add_argument("--weights", default=str(WEIGHTS_FILE))
    p.add_argument("--out", default=None)
    p.add_argument("--table", default=None, help="print the table of a stored --out file")
    a = p.parse_args()
    if a.per_family < 2 or a.per_family % 2:
        p.error(f"argument --per-family: expected an even number >= 2, got {a.per_family}")
    if a.table:
        print(table(json.loads(Path(a.table).read_text())["rows"]))
        return
    rows = run(a.sizes, a.srs, a.level, a.per_family, a.weights, a.draws)
    if a.out:
        Path(a.out).write_text(json.dumps({"weights": a.weights, "rows": rows}, indent=1))
    print(table(rows))


if __name__ == "__main__":
    main()
