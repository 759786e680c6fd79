"""The separable first-order Markov (exponential) image covariance and its Wiener estimate.

A zero-mean Gaussian image prior with covariance ``Σ = S ⊗ S``, ``S_ij = exp(−|i − j| / ℓ)``
``= ρ^|i−j|`` (``ρ = e^{−1/ℓ}``), the separable AR(1) model of images (Jain, *Fundamentals
of Digital Image Processing*, 1989, §2.9). For the Sylvester Hadamard operator row
``r = a·n + b`` is the pattern ``H[a, i] H[b, j] / n``, so with ``Ĥ = H / √n`` and
``T = Ĥ S Ĥᵀ`` the bucket covariance separates, ``(A Σ Aᵀ)[r, r'] = T[a, a'] T[b, b']``.

Used by :func:`torchtof.recon.auto.auto` (its Gaussian-prior stage, dense on ``M ≤ 1024``
rows) and by :class:`torchtof.recon.learned.Learned` (``x0="markov"``: the network's
starting estimate, matrix-free, any size).
"""

from __future__ import annotations

import math

import torch

from .._checks import check_positive, check_power_of_two
from ..operators.base import LinearOperator
from ..operators.fwht import sylvester
from ..operators.hadamard import Hadamard

__all__ = ["markov_covariance", "markov_completion", "MARKOV_RHO", "MARKOV_ITERS"]

#: Correlation ``ρ`` of neighbouring pixels in :func:`markov_completion`'s default model.
MARKOV_RHO = 0.95
#: Preconditioned CG steps of :func:`markov_completion`.
MARKOV_ITERS = 20


def markov_covariance(n: int, ell: float, dtype: torch.dtype = torch.float64,
                      device=None) -> tuple[torch.Tensor, torch.Tensor]:
    """``(S, T)``, both ``(n, n)``: the one-axis covariance ``S_ij = exp(−|i − j| / ℓ)`` and
    its image ``T = Ĥ S Ĥᵀ`` in the normalised Sylvester basis (module docstring); ``n`` a
    power of two, ``ℓ > 0`` finite."""
    check_power_of_two(n, "n", "markov_covariance")
    check_positive(ell, "ell", "markov_covariance")  # > 0 and finite
    s = _exp_kernel(n, ell, dtype, device)
    h = sylvester(n, dtype, device) / math.sqrt(n)
    return s, h @ s @ h.T


def _exp_kernel(n: int, ell: float, dtype: torch.dtype, device) -> torch.Tensor:
    t = torch.arange(n, dtype=dtype, device=device)
    return torch.exp(-(t[:, None] - t[None, :]).abs() / float(ell))


def markov_completion(
    b: torch.Tensor,
    op: LinearOperator,
    lam: torch.Tensor,
    rho: float = MARKOV_RHO,
    iters: int = MARKOV_ITERS,
) -> torch.Tensor:
    """Linear MMSE (Wiener) estimate ``x = Σ Aᵀ (A Σ Aᵀ + λ I)⁻¹ b`` under the zero-mean
    Markov prior ``Σ = S ⊗ S``, ``S_ij = ρ^|i−j|`` (module docstring): the unmeasured
    coefficients filled from the measured ones, the "completion" of Lorente Mur et al.,
    Opt. Express 29, 17097 (2021), with this analytic covariance.

    ``Σ v = S V S`` costs two ``n × n`` matrix products per image; the ``M × M`` system is
    solved by ``iters`` steps of conjugate gradients preconditioned by its diagonal (for a
    :class:`~torchtof.operators.Hadamard` operator ``T[a, a] T[b, b]`` for row ``a·n + b``;
    other operators: no preconditioner). A fixed number of steps and no data-dependent branch,
    so it traces into ONNX.

    Args:
        b: buckets ``(B, C, M)`` of an operator with orthonormal rows.
        op: the operator.
        lam: ``(B, C, 1)`` noise variance over the prior's pixel variance (``> 0``; not
            checked here, the function runs inside a network's forward pass).
        rho, iters: the Markov correlation in ``(0, 1)`` and the CG steps (``>= 1``).

    Returns:
        ``(B, C, n, n)`` in the dtype of ``b``, computed in float64: with ``λ`` near
        ``10⁻³`` the system's condition number reaches 10⁵–10⁶, and float32 CG drifted by up to
        1 % of the image's peak between two runtimes (PyTorch and onnxruntime); in float64 they
        agree to float32 rounding. (On GPUs with slow float64 this step costs more than the
        network's own float32 work.)

    Raises:
        ValueError: if ``rho`` is not in ``(0, 1)`` or ``iters`` is not an int ``>= 1``.
    """
    if isinstance(rho, bool) or not isinstance(rho, (int, float)) or not 0 < rho < 1:
        raise ValueError(f"markov_completion: expected rho in (0, 1), got {rho!r}")
    if isinstance(iters, bool) or not isinstance(iters, int) or iters < 1:
        raise ValueError(f"markov_completion: expected iters to be an int >= 1, got {iters!r}")
    out_dtype = b.dtype
    b = b.to(torch.float64)
    lam = lam.to(torch.float64)
    fwd, adj = op.loop_pair(b)
    n, ell = op.n, -1.0 / math.log(rho)
    if isinstance(op, Hadamard):
        s, t = markov_covariance(n, ell, b.dtype, b.device)
        d = t.diagonal()
        index = op.index.to(b.device)
        diag = d[index // n] * d[index % n]  # (M,)
    else:  # no Sylvester structure (n need not be a power of two): no preconditioner
        s = _exp_kernel(n, ell, b.dtype, b.device)
        diag = torch.ones(op.m, device=b.device, dtype=b.dtype)

    def sig(v: torch.Tensor) -> torch.Tensor:
        return s @ adj(v) @ s

    pre = 1 / (diag + lam)  # (B, C, M)
    tiny = torch.finfo(b.dtype).tiny
    v = torch.zeros_like(b)
    r = b
    z = pre * r
    p = z
    rz = (r * z).sum(-1, keepdim=True)
    for _ in range(iters):
        gp = fwd(sig(p)) + lam * p
        alpha = rz / (p * gp).sum(-1, keepdim=True).clamp_min(tiny)
        v = v + alpha * p
        r = r - alpha * gp
        z = pre * r
        rz_new = (r * z).sum(-1, keepdim=True)
        p = z + rz_new / rz.clamp_min(tiny) * p
        rz = rz_new
    return sig(v).to(out_dtype)
