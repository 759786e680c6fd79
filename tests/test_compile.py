"""``torch.compile(fullgraph=True)``: the Hadamard operator, the unrolled TVAL3, the U-Net and
the fixed-iteration TGV and basis pursuit trace into one graph each (no graph break: no host
sync, no data-dependent Python branch) and compute what eager mode computes.

The default run compiles with dynamo's ``"eager"`` backend (the graph capture that
``fullgraph=True`` checks, without code generation); the slow tests also generate code with
inductor.
"""

from __future__ import annotations

import pytest
import torch
import torch._dynamo

from torchtof.operators import Hadamard
from torchtof.recon import TGV, BasisPursuit, UNet, UnrolledTVAL3


def _models(device):
    A = Hadamard(16, sr=0.5).to(device)
    x = torch.rand(2, 1, 16, 16, generator=torch.Generator().manual_seed(0)).to(device)
    unrolled = UnrolledTVAL3(A, n_layers=3, pretrained=False).to(device)
    unet = UNet(base=4, depth=2).to(device).eval()
    tgv = TGV(A, max_iter=5, adaptive=False).to(device)
    bp = BasisPursuit(A, n_iter=5, adaptive=False).to(device)
    return {"hadamard": (A, x), "adjoint": (A.adjoint, A(x)), "unrolled": (unrolled, A(x)),
            "unet": (unet, x), "tgv": (tgv, A(x)), "bp": (bp, A(x))}


def _check(name, backend, device):
    fn, inp = _models(device)[name]
    torch._dynamo.reset()
    compiled = torch.compile(fn, fullgraph=True, backend=backend)
    # float32: on CUDA, cuDNN convolutions run in TF32 by default (10-bit mantissa), and the
    # compiled and eager graphs may pick different algorithms: the U-Net differed by 7e-6
    # (1.4e-5 relative) on an H200, within TF32's 1e-3
    tol = dict(rtol=1e-5, atol=1e-6) if device.type == "cpu" else dict(rtol=1e-3, atol=1e-4)
    with torch.no_grad():
        torch.testing.assert_close(compiled(inp), fn(inp), **tol)


def test_hadamard_compiles_fullgraph(device):
    _check("hadamard", "eager", device)


@pytest.mark.parametrize("name", ["tgv", "bp"])
def test_solvers_compile_fullgraph(name, device):
    # their fixed-iteration loops, through the inference-mode switch that an eager call
    # without gradients takes (it must stay out of the traced graph): 2 s together
    _check(name, "eager", device)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["adjoint", "unrolled", "unet"])
def test_compiles_fullgraph(name, device):
    _check(name, "eager", device)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["hadamard", "unrolled", "unet"])
def test_compiles_with_inductor(name, device):
    _check(name, "inductor", device)
