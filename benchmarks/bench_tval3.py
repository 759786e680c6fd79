"""TVAL3 benchmark: horse 64x64, Hadamard SR 25 %, 1 % Gaussian noise; TVAL3 defaults vs a plain
ADMM-TV baseline with its weight tuned (oracle grid), run to convergence.
Usage: .venv/bin/python benchmarks/bench_tval3.py [threads] [--no-baseline]"""

import statistics
import sys
import time

import numpy as np
import torch
from skimage import data, transform

sys.path.insert(0, str(__import__("pathlib").Path(__file__).parent))
from torchtof.operators import Hadamard
from torchtof.recon.tval3 import tval3

threads = int(sys.argv[1]) if len(sys.argv) > 1 else 2
torch.set_num_threads(threads)
n = 64
img = data.horse().astype(np.float64)
x = torch.tensor(transform.resize(img, (n, n), anti_aliasing=True) < 0.5, dtype=torch.float32)[
    None, None
]
A = Hadamard(n, sr=0.25)
y0 = A(x)
sigma = 0.01 * float(y0.max() - y0.min())
y = y0 + sigma * torch.randn(y0.shape, generator=torch.Generator().manual_seed(0))


def psnr(a, b):
    return float(10 * torch.log10(1.0 / ((a.double() - b.double()) ** 2).mean()))


for u_step in ("bb", "exact"):
    tval3(y, A, u_step=u_step)  # warm-up (and exact-step factor cache)
    ts = []
    for _ in range(9):
        t = time.perf_counter()
        r = tval3(y, A, u_step=u_step)
        ts.append(time.perf_counter() - t)
    print(
        f"TVAL3 defaults u_step={u_step}: median {statistics.median(ts):.3f} s, min {min(ts):.3f} s "
        f"({threads} threads), n_iter={int(r.n_iter)}, converged={bool(r.converged)}, "
        f"PSNR={psnr(r.x, x):.2f} dB, residual={float(r.residual):.4f}"
    )
r = tval3(y.double(), A, noise_sigma=sigma)
print(f"TVAL3 with the true sigma (float64): PSNR={psnr(r.x, x):.2f} dB")
if "--no-baseline" not in sys.argv:
    from baseline import admm_tv

    best = (-1, None, None)
    for k in range(-16, 9):
        lam = 2.0 ** (k / 4) * sigma
        xb, it = admm_tv(y.double(), A, lam, tol=1e-6)
        p = psnr(xb, x)
        print(
            f"  ADMM-TV lam={lam:.4g} ({k / 4:+.2f} log2 sigma): PSNR={p:.2f} dB, {it} iterations",
            flush=True,
        )
        if p > best[0]:
            best = (p, lam, it)
    print(f"ADMM-TV tuned: best PSNR={best[0]:.2f} dB at lam={best[1]:.4g} ({best[2]} iterations)")
