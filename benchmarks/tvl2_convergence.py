"""How far TVAL3's TV-L2 solve is from the TV-L2 minimiser, and what the minimiser scores, on
a peers-benchmark cell where ``auto`` loses to pylops' tuned split-Bregman TV.

The peers cell (``benchmarks/peers_scenes.py``: the piecewise-planar map, cake-cutting rows,
1 % noise) is solved for each norm and weight μ of ``--mus`` three ways:

- ``default``: ``tval3(y, A, mu=μ, tvl2=True, boundary="neumann")`` with TVAL3's published
  stopping rule (``tol_inner=1e-3``, ``max_outer=10``: the fits ``auto`` scores and refits);
- ``further``: the same solve with the tolerances and budget of ``--tol``, ``--tol-inner``,
  ``--max-outer``, ``--max-iter``;
- ``minimiser``: the ADMM of :func:`torchtof.recon.tv.admm_tv` with the exact u-step (Wang,
  Yang, Yin & Zhang 2008; every step solved exactly, so its fixed point is the minimiser) at
  the penalty ``--beta``, run until the relative change of ``u`` is below ``--admm-tol`` or
  ``--admm-iter`` iterations.

Each row reports the objective ``F(u) = TV(u) + μ/2‖Au − b‖²`` in TVAL3's scaled units
(``b = y·1.5/spread``, ``u = x·1.5/spread``; Hadamard rows are orthonormal, so ``A`` is not
scaled): a solve with a larger ``F`` is not at the minimiser, whatever its PSNR. ``--sweep``
adds the minimiser's PSNR for every μ = 2^k of the given exponents (the best weight the model
has, tuned against the truth; a row with ``n_iter == --admm-iter`` stopped at the cap). PSNR as the peers benchmark scores it; one thread.

usage: python benchmarks/tvl2_convergence.py [--scene planes] [--n 64] [--sr 0.0625]
       [--mus 1024 4096] [--tol 1e-6] [--tol-inner 1e-5] [--max-outer 50] [--max-iter 20000]
       [--beta 256] [--admm-iter 3000] [--admm-tol 1e-8] [--sweep 8 10 12 14 16] [--out F.json]
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
    p.add_argument("--beta", type=float, default=256.0)
    p.add_argument("--admm-iter", type=int, default=3000)
    p.add_argument("--admm-tol", type=float, default=1e-8)
    p.add_argument("--sweep", type=int, nargs="*", default=[])
    p.add_argument("--out", type=Path, default=None)
    a = p.parse_args(argv)
    if a.max_iter < 1 or a.max_outer < 1 or not a.tol_inner > 0 or not a.tol > 0:
        p.error("expected --max-iter, --max-outer >= 1 and --tol, --tol-inner > 0")
    if a.admm_iter < 1 or not a.admm_tol > 0 or not a.beta > 0:
        p.error("expected --admm-iter >= 1 and --admm-tol, --beta > 0")
    return a


def scaled(y):
    """TVAL3's ``Scaleb`` gain for orthonormal rows: the bucket spread mapped to 1.5."""
    from torchtof.recon.tv import bucket_spread

    return 1.5 / bucket_spread(y)


def objective(x, y, A, mu: float, tv: str) -> float:
    """``TV(u) + μ/2‖Au − b‖²`` with Neumann differences, in TVAL3's scaled units."""
    from torchtof.recon.tv import tv_norm

    g = scaled(y)
    u, b = x * g[..., None, None], y * g[..., None]
    return float(tv_norm(u, tv == "isotropic", boundary="neumann").sum()
                 + 0.5 * mu * (A(u) - b).square().sum())


def minimiser(y, A, mu: float, tv: str, a):
    """The TV-L2 minimiser by exact-step ADMM: ``(x, iterations)``."""
    import torch

    from torchtof.recon.tv import admm_tv

    g = scaled(y)
    one = torch.ones(y.shape[:2], dtype=y.dtype)
    out = admm_tv(y * g[..., None], A, mu * one, a.beta * one,
                  torch.zeros(y.shape[:2], dtype=torch.bool), tv=tv, boundary="neumann",
                  max_iter=a.admm_iter, tol=a.admm_tol)
    return out.u / g[..., None, None], int(out.n_iter)


def main(argv=None) -> int:
    a = parse(argv)
    import torch

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import peers_scenes as ps

    from torchtof.recon.tval3 import tval3

    torch.set_num_threads(1)
    x, A, y, _ = ps.make_problem(a.scene, a.n, a.sr, a.order, a.noise)
    y = y.double()  # the objective compared to 1e-4 needs double precision
    rows = []

    def record(tv, mu, label, xh, n_iter, t0):
        row = dict(tv=tv, mu=mu, stop=label, n_iter=n_iter, psnr=ps.score(xh, x),
                   objective=objective(xh, y, A, mu, tv), time_s=time.perf_counter() - t0)
        rows.append(row)
        print(f"{tv:11s} mu={mu:<8g} {label:9s} {n_iter:6d} iterations {row['psnr']:6.2f} dB "
              f"F = {row['objective']:.4f} {row['time_s']:6.1f} s", flush=True)

    for tv in a.norms:
        for mu in a.mus:
            for label, kw in (("default", {}),
                              ("further", dict(tol=a.tol, tol_inner=a.tol_inner,
                                               max_outer=a.max_outer, max_iter=a.max_iter))):
                t0 = time.perf_counter()
                r = tval3(y, A, mu=mu, tvl2=True, tv=tv, boundary="neumann",
                          return_result=True, **kw)
                record(tv, mu, label, r.x, int(r.n_iter), t0)
            t0 = time.perf_counter()
            record(tv, mu, "minimiser", *minimiser(y, A, mu, tv, a), t0)
        for k in a.sweep:
            t0 = time.perf_counter()
            record(tv, 2.0 ** k, "sweep", *minimiser(y, A, 2.0 ** k, tv, a), t0)
    if a.out is not None:
        a.out.write_text(json.dumps({"args": {k: str(v) if isinstance(v, Path) else v
                                              for k, v in vars(a).items()}, "rows": rows},
                                    indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
