"""Total-variation building blocks shared by TVAL3, unrolled TVAL3 and the DIP loss.

Periodic forward differences as in TVAL3's ``defDDt`` (Li, Yin, Zhang 2013):
``D_x u = u[:, j+1] − u[:, j]`` and ``D_y u = u[i+1, :] − u[i, :]`` with wrap-around;
``Dᵀ`` is the negative periodic backward difference (minus the divergence), so
``⟨Du, w⟩ = ⟨u, Dᵀw⟩`` exactly. ``DᵀD`` is the periodic Laplacian, diagonal in the
2-D DFT (used by exact u-steps).
"""

from __future__ import annotations

import math

import torch

__all__ = ["grad2", "grad2_adjoint", "tv_norm", "shrink", "laplacian_eigs"]


def grad2(u: torch.Tensor) -> torch.Tensor:
    """Periodic forward differences ``(B, C, H, W) -> (B, C, 2, H, W)`` (``[D_x u, D_y u]``)."""
    dx = torch.roll(u, -1, dims=-1) - u
    dy = torch.roll(u, -1, dims=-2) - u
    return torch.stack((dx, dy), dim=-3)


def grad2_adjoint(w: torch.Tensor) -> torch.Tensor:
    """``Dᵀ w`` for ``w (B, C, 2, H, W) -> (B, C, H, W)``: exact adjoint of :func:`grad2`."""
    wx, wy = w[..., 0, :, :], w[..., 1, :, :]
    return (torch.roll(wx, 1, dims=-1) - wx) + (torch.roll(wy, 1, dims=-2) - wy)


def tv_norm(u: torch.Tensor, isotropic: bool = True, eps: float = 0.0) -> torch.Tensor:
    """``Σ_i ‖D_i u‖`` per image ``(B, C, H, W) -> (B,)``.

    Isotropic: ``Σ sqrt(D_x² + D_y² + eps)``; anisotropic: ``Σ |D_x| + |D_y|``.
    """
    g = grad2(u)
    if isotropic:
        mag = torch.sqrt((g * g).sum(dim=-3) + eps)
    else:
        mag = g.abs().sum(dim=-3)
    return mag.flatten(1).sum(dim=1)


def shrink(
    v: torch.Tensor, threshold: torch.Tensor | float, isotropic: bool = True
) -> torch.Tensor:
    """Proximal map of ``threshold·‖·‖`` on the gradient field ``v (…, 2, H, W)``.

    Isotropic (TVAL3 ``TVnorm=2``): ``max(‖v‖₂ − t, 0) · v / ‖v‖₂`` per pixel over the
    two components; anisotropic: soft threshold ``sign(v) max(|v| − t, 0)``.
    The isotropic form avoids 0/0 (a zero vector stays zero with a zero gradient).
    """
    if not isotropic:
        return torch.sign(v) * torch.clamp(v.abs() - threshold, min=0)
    tiny = torch.finfo(v.dtype).tiny
    norm = torch.sqrt((v * v).sum(dim=-3, keepdim=True) + tiny)
    return v * (torch.clamp(norm - threshold, min=0) / norm)


def laplacian_eigs(h: int, w: int, dtype=torch.float64, device=None) -> torch.Tensor:
    """Eigenvalues of ``DᵀD`` (periodic) on the 2-D DFT grid, shape ``(h, w)``:
    ``4 sin²(π k/h) + 4 sin²(π l/w)``."""
    ky = torch.arange(h, dtype=dtype, device=device)
    kx = torch.arange(w, dtype=dtype, device=device)
    sy = 4 * torch.sin(math.pi * ky / h) ** 2
    sx = 4 * torch.sin(math.pi * kx / w) ** 2
    return sy[:, None] + sx[None, :]
