"""Unrolled TVAL3 (shipped weights) vs converged TVAL3 on held-out scenes.

usage: python benchmarks/compare_unrolled.py [--n 32 64] [--sr ...] [--noise 0.01] [--train STEPS]
                                            [--out DIR]

With ``--out DIR`` the rows, the machine's load and the run time go to ``DIR/unrolled.json``
(the README table is generated from it by ``docs/build.py``).
"""

import argparse
import json
import statistics
import time
from pathlib import Path

import torch

from torchtof.operators import Hadamard
from torchtof.recon.synthetic import synthetic_scenes
from torchtof.recon.train import PAPER_SRS, noisy_measurements, train_unrolled
from torchtof.recon.tval3 import TVAL3
from torchtof.recon.unrolled import DEFAULT_N_ITER, UnrolledTVAL3
from torchtof.scenes import binary_scene, depth_steps, motorcycle_depth, sky_character

HELD_OUT_SEED = 10**6  # training uses seed 0


def held_out(n, n_syn=16):
    fixed = [sky_character(n)] + [
        binary_scene(k, n) for k in ("horse", "camera", "coins", "rocket")
    ]
    fixed += [depth_steps(n, seed=3).depth_m / 3.0, motorcycle_depth(n) / 4.0]
    return torch.cat([synthetic_scenes(n, HELD_OUT_SEED, 0, range(n_syn))] + fixed)


def psnr(a, b):
    return 10 * torch.log10(1.0 / ((a - b) ** 2).mean(dim=(1, 2, 3)))


def per_scene(rec, y, repeats=1, time_scenes=None):
    """Each scene alone (batch 1): outputs and the medians over scenes of the best-of-repeats
    wall time and process CPU time (``time.process_time``; on a loaded machine the wall time
    of a long call grows with the load, its CPU time much less).

    With ``time_scenes=K`` only the first K scenes are timed alone and the outputs come from
    one batched call, at a fraction of the wall time (TVAL3 stops per sample: its batched
    images equalled the batch-1 ones bit for bit on these scenes at n = 32, SR 6.25 %)."""
    outs, ts, cs = [], [], []
    with torch.no_grad():
        rec(y[:1])  # warm-up
        if time_scenes is not None:
            _, t, c = per_scene(rec, y[:time_scenes], repeats)
            return rec(y), t, c
        for i in range(len(y)):
            best, best_cpu = float("inf"), float("inf")
            for _ in range(repeats):
                t, c = time.perf_counter(), time.process_time()
                o = rec(y[i : i + 1])
                best = min(best, time.perf_counter() - t)
                best_cpu = min(best_cpu, time.process_time() - c)
            outs.append(o)
            ts.append(best)
            cs.append(best_cpu)
    return torch.cat(outs), statistics.median(ts), statistics.median(cs)


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--n", type=int, nargs="+", default=[32, 64])
    p.add_argument("--sr", type=float, nargs="+", default=list(PAPER_SRS))
    p.add_argument("--noise", type=float, nargs="+", default=[0.01])
    p.add_argument("--K", type=int, default=DEFAULT_N_ITER)
    p.add_argument(
        "--train",
        type=int,
        default=0,
        help="train in-process with this many steps instead of shipped weights",
    )
    p.add_argument("--out", type=Path, default=None, help="write DIR/unrolled.json")
    p.add_argument("--time-scenes", type=int, default=None,
                   help="time only the first K scenes alone; PSNR from one batched call")
    p.add_argument("--repeats", type=int, default=None,
                   help="best-of-R timing for the unrolled network and TVAL3 alike (default: "
                        "5 for the network, 1 for TVAL3; equal counts keep the time ratio fair "
                        "on a loaded machine)")
    a = p.parse_args()
    torch.set_num_threads(1)
    from torchtof.apps.bench.timing import machine_load

    t0, start, rows = time.perf_counter(), machine_load(), []
    print(
        "| n | SR % | noise % | unrolled dB | TVAL3 auto dB | TVAL3 mu=2^8 dB | diff vs best | unrolled ms | TVAL3 auto ms | TVAL3 2^8 ms | time ratio (vs best) |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for n in a.n:
        x = held_out(n)
        for sr in a.sr:
            A = Hadamard(n, sr=sr)
            if a.train:
                net = train_unrolled(n=n, sr=sr, n_layers=a.K, steps=a.train).model.eval()
            else:
                net = UnrolledTVAL3(A, n_layers=a.K).eval()
            recs = {"auto": TVAL3(A), "mu256": TVAL3(A, mu=2**8)}
            for lvl in a.noise:
                y = noisy_measurements(A, x, 777, 0, range(len(x)), (lvl, lvl))
                xu, tu, cu = per_scene(net, y, repeats=a.repeats or 5,
                                       time_scenes=a.time_scenes)
                pu = psnr(xu, x).mean().item()
                res = {}
                for k, r in recs.items():
                    xt, tt_, ct = per_scene(r, y, repeats=a.repeats or 1,
                                            time_scenes=a.time_scenes)
                    res[k] = (psnr(xt, x).mean().item(), tt_, ct)
                best = max(res, key=lambda k: res[k][0])
                rows.append({"n": n, "sr": sr, "noise": lvl, "unrolled_db": pu,
                             "tval3_auto_db": res["auto"][0], "tval3_mu256_db": res["mu256"][0],
                             "best_tval3": best, "best_tval3_db": res[best][0],
                             "unrolled_s": tu, "tval3_auto_s": res["auto"][1],
                             "tval3_mu256_s": res["mu256"][1],
                             "time_ratio": res[best][1] / tu,
                             "unrolled_cpu_s": cu, "tval3_auto_cpu_s": res["auto"][2],
                             "tval3_mu256_cpu_s": res["mu256"][2],
                             "cpu_time_ratio": res[best][2] / cu})
                print(
                    f"| {n} | {sr * 100:g} | {lvl * 100:g} | {pu:.2f} | {res['auto'][0]:.2f} | {res['mu256'][0]:.2f} | "
                    f"{pu - res[best][0]:+.2f} | {tu * 1e3:.2f} | {res['auto'][1] * 1e3:.1f} | {res['mu256'][1] * 1e3:.1f} | "
                    f"{res[best][1] / tu:.0f}x |",
                    flush=True,
                )
    if a.out is not None:
        a.out.mkdir(parents=True, exist_ok=True)
        out = {"benchmark": "unrolled", "K": a.K, "trained_steps": a.train,
               "scenes": len(held_out(8)), "timed_scenes": a.time_scenes or len(held_out(8)),
               "repeats": {"unrolled": a.repeats or 5, "tval3": a.repeats or 1},
               "threads": 1, "torch": torch.__version__,
               "rows": rows, "total_s": time.perf_counter() - t0,
               "machine": {"start": start, "end": machine_load()}}
        (a.out / "unrolled.json").write_text(json.dumps(out, indent=1))
        print(f"wrote {a.out / 'unrolled.json'} ({out['total_s']:.0f} s)")


if __name__ == "__main__":
    main()
