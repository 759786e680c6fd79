"""PSNR of the learned reconstructor's two starting estimates on the held-out scenes.

``Aᵀb`` (``x0="adjoint"``) against the Gaussian–Markov completion (``x0="markov"``,
:func:`torchtof.recon.gauss.markov_completion`), each exactly as :class:`Learned` forms it
(the noise-corrected scale, the ``"auto"`` noise estimate): a one-layer network with its
prior and step switched off returns its start. Scenes, buckets and score of
``benchmarks/eval_learned.py``.

usage: OMP_NUM_THREADS=1 python benchmarks/markov_start.py [--sizes 32 64 128]
       [--srs 0.0625 0.125] [--levels 0 0.01]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from eval_learned import CLASSES, buckets, scenes, score  # noqa: E402

from torchtof.operators import Hadamard  # noqa: E402
from torchtof.recon.learned import Learned  # noqa: E402


def start(A: Hadamard, y: torch.Tensor, x0: str) -> torch.Tensor:
    net = Learned(A, n_layers=1, width=4, pretrained=False, x0=x0)
    with torch.no_grad():
        net.prior.out.weight.zero_()
        net.prior.out.bias.zero_()
        net.step_raw.fill_(-1e4)  # γ = 2·sigmoid(−10⁴) = 0: no data step
        net.final_dc = False
        return net(y)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[32, 64, 128])
    p.add_argument("--srs", type=float, nargs="+", default=[0.0625, 0.125])
    p.add_argument("--levels", type=float, nargs="+", default=[0.0, 0.01])
    a = p.parse_args()
    torch.set_num_threads(1)
    print("| n | SR % | noise % | class | Aᵀb dB | markov dB | Δ dB |")
    print("|---|---|---|---|---|---|---|")
    deltas = []
    for n in a.sizes:
        for sr in a.srs:
            A = Hadamard(n, sr=sr, order="cake_cutting")
            for level in a.levels:
                for cls in CLASSES:
                    x = scenes(cls, n)
                    y = buckets(A, x, level, salt=n + int(sr * 1e4) + int(level * 1e4))
                    pa, pm = (score(start(A, y, s), x)[0] for s in ("adjoint", "markov"))
                    deltas.append(pm - pa)
                    print(f"| {n} | {100 * sr:g} | {100 * level:g} | {cls} | {pa:.2f} | {pm:.2f} "
                          f"| {pm - pa:+.2f} |", flush=True)
    print(f"Δ: mean {sum(deltas) / len(deltas):+.2f} dB, min {min(deltas):+.2f}, "
          f"max {max(deltas):+.2f} ({len(deltas)} cells)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
