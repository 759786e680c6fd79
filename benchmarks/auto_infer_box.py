"""What ``auto``'s inferred box is worth, and what it costs, on the peers' cells.

For every peers cell given (``benchmarks/peers_scenes.py``: same image, rows, noise draw and
PSNR as ``benchmarks/peers.py``), ``auto(y, A, infer_box=False)`` and ``auto(y, A)`` (the
default, ``infer_box=True``) run one after the other, ``--repeats`` rounds interleaved, one
thread; the PSNR of each, the inferred box, the choice, and the median time of each.

    OMP_NUM_THREADS=1 python benchmarks/auto_infer_box.py --n 32 --orders sequency cake_cutting \\
        --scenes sky horse --out docs/auto/infer_box32.json
    OMP_NUM_THREADS=1 python benchmarks/auto_infer_box.py --n 64 --sr 0.125 0.25 0.375 \\
        --scenes sky horse --out docs/auto/infer_box64.json

Prints one line per cell and the mean PSNR change and the median time ratio over the cells
whose image was found two-level (the others run the same code path and cost nothing more).
"""

from __future__ import annotations

import json
import os
import statistics
import time

import peers_scenes as ps  # benchmarks/ is the script's directory
import torch

from torchtof.recon import auto


def main(argv: list[str] | None = None) -> dict:
    p = ps.cell_parser(__doc__.splitlines()[0])
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--out", default=None)
    a = p.parse_args(argv)
    torch.set_num_threads(1)
    rows = []
    for order in a.orders:
        for sr in a.sr:
            for scene in a.scenes:
                x, A, y, _ = ps.make_problem(scene, a.n, sr, order, a.noise)
                t = {False: [], True: []}
                for _ in range(a.repeats):
                    for flag in (False, True):
                        t0 = time.perf_counter()
                        r = auto(y, A, infer_box=flag, return_result=True)
                        t[flag].append(time.perf_counter() - t0)
                        if flag:
                            on = r
                        else:
                            off = r
                ch = on.choice[0][0]
                row = dict(scene=scene, n=a.n, sr=sr, order=order, level=a.noise,
                           psnr_off=ps.score(off.x, x), psnr_on=ps.score(on.x, x),
                           inferred=ch["inferred"], choice={k: ch[k] for k in
                                                            ("prior", "tv", "bounds", "mu")},
                           time_off_s=statistics.median(t[False]),
                           time_on_s=statistics.median(t[True]))
                rows.append(row)
                print(f"n={a.n} {order} {scene} SR={sr}: {row['psnr_off']:.2f} -> "
                      f"{row['psnr_on']:.2f} dB (two-level {ch['inferred']}, bounds "
                      f"{ch['bounds']}), time x{row['time_on_s'] / row['time_off_s']:.2f}",
                      flush=True)
    two = [r for r in rows if r["inferred"]]
    summary = dict(cells=len(rows), two_level=len(two))
    if two:
        summary.update(
            mean_gain_db=statistics.mean(r["psnr_on"] - r["psnr_off"] for r in two),
            median_time_ratio=statistics.median(r["time_on_s"] / r["time_off_s"] for r in two))
        print(f"{len(two)} of {len(rows)} cells two-level: mean {summary['mean_gain_db']:+.2f} dB,"
              f" median time x{summary['median_time_ratio']:.2f}")
    res = dict(args=vars(a), loadavg=list(os.getloadavg()), rows=rows, summary=summary)
    if a.out:
        with open(a.out, "w") as f:
            json.dump(res, f, indent=1)
    return res


if __name__ == "__main__":
    main()
