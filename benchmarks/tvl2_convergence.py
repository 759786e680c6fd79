"""How far TVAL3's TV-L2 solve at its published stopping rule is from the TV-L2 minimiser, on
a peers-benchmark cell where ``auto`` loses to pylops' tuned split-Bregman TV.

The peers cell (``benchmarks/peers_scenes.py``: the piecewise-planar map, cake-cutting rows,
1 % noise) is solved by ``tval3(y, A, mu=μ, tvl2=True, boundary="neumann")`` for each norm and
weight, once with TVAL3's default tolerances (``tol_inner=1e-3``, ``max_outer=10``: the fits
``auto`` scores and refits) and once run further (``tol_inner``/``max_outer``/``max_iter`` below).
PSNR as the peers benchmark scores it; one thread.

usage: python benchmarks/tvl2_convergence.py [--n 64] [--sr 0.0625] [--mus 1024 4096]
       [--tol 1e-6] [--tol-inner 1e-5] [--max-outer 50] [--max-iter 20000] [--out F.json]
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path


def parse(argv=None):
    from torchtof.apps.args import OneLineParser  # a mistake: one line, exit 2

    p = OneLineParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scene", default="planes")
    p.add_argument("--n", type=int, default=64)
    p.add_argument("--sr", type=float, default=0.0625)
    p.add_argument("--order", default="cake_cutting")
    p.add_argument("--noise", type=float, default=0.01)
    p.add_argument("--mus", type=float, nargs="+", default=[1024.0, 4096.0])
    p.add_argument("--norms", nargs="+", default=["isotropic", "anisotropic"])
    p.add_argument("--tol", type=float, default=1e-6)
    p.add_argument("--tol-inner", type=float, default=1e-5)
    p.add_argument("--max-outer", type=int, default=50)
    p.add_argument("--max-iter", type=int, default=20000)
    p.add_argument("--out", type=Path, default=None)
    a = p.parse_args(argv)
    if a.max_iter < 1 or a.max_outer < 1 or not a.tol_inner > 0 or not a.tol > 0:
        p.error("expected --max-iter, --max-outer >= 1 and --tol, --tol-inner > 0")
    return a


def main(argv=None) -> int:
    a = parse(argv)
    import torch

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import peers_scenes as ps

    from torchtof.recon.tval3 import tval3

    torch.set_num_threads(1)
    x, A, y, _ = ps.make_problem(a.scene, a.n, a.sr, a.order, a.noise)
    rows = []
    for tv in a.norms:
        for mu in a.mus:
            for label, kw in (("default", {}),
                              ("further", dict(tol=a.tol, tol_inner=a.tol_inner, max_outer=a.max_outer,
                                               max_iter=a.max_iter))):
                t0 = time.perf_counter()
                r = tval3(y, A, mu=mu, tvl2=True, tv=tv, boundary="neumann",
                          return_result=True, **kw)
                row = dict(tv=tv, mu=mu, stop=label, n_iter=int(r.n_iter),
                           psnr=ps.score(r.x, x), time_s=time.perf_counter() - t0)
                rows.append(row)
                print(f"{tv:11s} mu={mu:<6g} {label:8s} {row['n_iter']:6d} iterations "
                      f"{row['psnr']:6.2f} dB {row['time_s']:6.1f} s", flush=True)
    if a.out is not None:
        a.out.write_text(json.dumps({"args": {k: str(v) if isinstance(v, Path) else v
                                              for k, v in vars(a).items()}, "rows": rows},
                                    indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
