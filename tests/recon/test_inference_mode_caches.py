"""Caches filled inside ``torch.inference_mode()`` must still serve calls that need gradients.

A common workflow evaluates under ``inference_mode`` first, then trains or differentiates.
Every cache the package keeps behind an operator or in the process (the Kronecker factors of
a Hadamard operator, the Sylvester matrices, the DCT matrix, the row orders, the exact
u-step's factors, a dense operator's pseudo-inverse, weights read from a file) must hold
ordinary tensors, or PyTorch refuses the later backward pass ("Inference tensors cannot be
saved for backward"). Each case runs in a fresh interpreter, so the process-wide caches start
empty and the first use really is the one under ``inference_mode``.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

PRELUDE = """
import torch, warnings
warnings.simplefilter("ignore")
torch.manual_seed(0)
import torchtof.recon as recon
from torchtof.operators import Hadamard, PatternOperator
"""

CASES = {
    # the Kronecker factors of Hadamard(n >= 64) and the row order / Sylvester caches
    "pinv_kron": """
A = Hadamard(64, sr=0.25); x = torch.rand(1, 1, 64, 64)
with torch.inference_mode():
    recon.pseudo_inverse(A(x), A)
y = A(x).detach().requires_grad_()
recon.get("pinv").build(A)(y).sum().backward()
assert y.grad is not None and torch.isfinite(y.grad).all()
""",
    # a new operator of another size, the process-wide caches filled by the first one
    "pinv_new_operator": """
with torch.inference_mode():
    A0 = Hadamard(64, sr=0.25)
    recon.pseudo_inverse(A0(torch.rand(1, 1, 64, 64)), A0)
A = Hadamard(64, sr=0.125)
y = A(torch.rand(1, 1, 64, 64)).requires_grad_()
recon.pseudo_inverse(y, A).sum().backward()
assert torch.isfinite(y.grad).all()
""",
    # the DCT matrix, cached per (n, dtype, device) for every operator
    "basis_pursuit_dct": """
A = Hadamard(16, sr=0.25)
with torch.inference_mode():
    recon.basis_pursuit(A(torch.rand(1, 1, 16, 16)), A, n_iter=10)
A2 = Hadamard(16, sr=0.5)
y = A2(torch.rand(1, 1, 16, 16)).requires_grad_()
recon.basis_pursuit(y, A2, n_iter=10).sum().backward()
assert torch.isfinite(y.grad).all()
""",
    # the exact u-step's eigendecomposition, cached per operator
    "tval3_exact": """
A = Hadamard(16, sr=0.25); x = torch.rand(1, 1, 16, 16)
with torch.inference_mode():
    recon.tval3(A(x), A, u_step="exact", max_iter=5)
y = A(x).detach().requires_grad_()
recon.tval3(y, A, u_step="exact", max_iter=5).sum().backward()
assert torch.isfinite(y.grad).all()
""",
    # a dense operator's pseudo-inverse, cached per dtype/device
    "pattern_pinv": """
P = PatternOperator(torch.rand(20, 8, 8)); x = torch.rand(1, 1, 8, 8)
with torch.inference_mode():
    recon.pseudo_inverse(P(x), P)
y = P(x).detach().requires_grad_()
recon.pseudo_inverse(y, P).sum().backward()
assert torch.isfinite(y.grad).all()
""",
    # the area-overlap matrices of the DMD-to-sensor mapping, cached per size pair
    "dmd_to_sensor": """
from torchtof.sensor.mixing import dmd_to_sensor
with torch.inference_mode():
    dmd_to_sensor(torch.rand(1, 1, 8, 8), (12, 12))
x = torch.rand(1, 1, 8, 8, requires_grad=True)
dmd_to_sensor(x, (12, 12)).sum().backward()
assert torch.isfinite(x.grad).all()
""",
    # the shipped weights, read once per process
    "learned": """
A = Hadamard(32, sr=0.125); x = torch.rand(1, 1, 32, 32)
with torch.inference_mode():
    recon.Learned(A)(A(x))
y = A(x).detach().requires_grad_()
recon.Learned(A)(y).sum().backward()
assert torch.isfinite(y.grad).all()
""",
    "unrolled": """
A = Hadamard(32, sr=0.125); x = torch.rand(1, 1, 32, 32)
with torch.inference_mode():
    recon.get("unrolled").build(A)(A(x))
y = A(x).detach().requires_grad_()
recon.get("unrolled").build(A)(y).sum().backward()
assert torch.isfinite(y.grad).all()
""",
    # an ordinary call without a graph runs its loop in inference mode itself (autograd_free):
    # the caches it fills (exact u-step factors, ScaleA's s2, the network's weights) and what
    # it returns stay ordinary tensors
    "ordinary_calls_then_gradients": """
A = Hadamard(32, sr=0.25); x = torch.rand(1, 1, 32, 32)
P = PatternOperator(torch.rand(128, 16, 16)); xp = torch.rand(1, 1, 16, 16)
outs = [recon.tval3(A(x), A, u_step="exact"), recon.tval3(P(xp), P, mu=2**6),
        recon.auto(A(x), A, priors=("tv",), cv_iter=10, max_iter=40, return_result=True).x,
        recon.tgv(A(x), A, max_iter=30), recon.basis_pursuit(P(xp), P, n_iter=30)]
for res in (recon.tgv(A(x), A, max_iter=30, return_result=True),
            recon.joint_tv(A(x.expand(1, 2, 32, 32)), A, n_iter=30, return_result=True)):
    outs += [t for t in res if isinstance(t, torch.Tensor)]
for out in outs:
    assert not out.is_inference()
    out.copy_(out.clone())  # in place, outside inference mode: an inference tensor refuses
for yy, op, kw in ((A(x), A, dict(u_step="exact", mu=2**6)), (P(xp), P, dict(mu=2**6))):
    yy = yy.detach().requires_grad_()
    recon.tval3(yy, op, max_iter=5, adaptive=False, **kw).sum().backward()
    assert yy.grad is not None and torch.isfinite(yy.grad).all() and yy.grad.abs().sum() > 0
y = A(x).detach().requires_grad_()
recon.get("learned").build(A)(y).sum().backward()
assert torch.isfinite(y.grad).all()
for f in (recon.tgv, recon.basis_pursuit):
    y = A(x).detach().requires_grad_()
    f(y, A, **({"max_iter": 10} if f is recon.tgv else {"n_iter": 10})).sum().backward()
    assert torch.isfinite(y.grad).all() and y.grad.abs().sum() > 0
""",
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_cache_filled_under_inference_mode_serves_autograd(case):
    code = PRELUDE + textwrap.dedent(CASES[case]) + "\nprint('ok')\n"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=240)
    assert out.returncode == 0 and out.stdout.strip().endswith("ok"), out.stderr[-2000:]
