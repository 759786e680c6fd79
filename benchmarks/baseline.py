"""Plain ADMM-TV baseline (Boyd et al. 2011, consensus splitting), float64:

    min_x lam * sum_i ||D_i x|| + 1/2 ||A x - y||^2      (isotropic TV, periodic D)

split as z = D x, w = x:  x-step (D^T D + I) x = D^T(z - u) + (w - v) by FFT (periodic Laplacian),
w-step (A^T A + rho I) w = A^T y + rho (x + v) in closed form for orthonormal rows
((A^T A + rho I)^-1 = (I - A^T A / (1 + rho)) / rho), z-step isotropic shrinkage.
Stops when the primal and dual residuals (Boyd §3.3) fall below tol (relative)."""

import math

import torch

from torchtof.recon.tv import grad2, grad2_adjoint, laplacian_eigs, shrink


def admm_tv(y, A, lam, rho=None, iters=20000, tol=1e-6):
    assert A.orthonormal_rows
    n = A.n
    y = y.double()
    rho = 1.0 if rho is None else rho
    eig = laplacian_eigs(n, n, dtype=torch.float64)[:, : n // 2 + 1] + 1.0
    aty = A.adjoint(y)
    x = aty.clone()
    w = x.clone()
    v = torch.zeros_like(x)
    z = grad2(x)
    u = torch.zeros_like(z)
    for k in range(iters):
        rhs = grad2_adjoint(z - u) + (w - v)
        x = torch.fft.irfft2(torch.fft.rfft2(rhs) / eig, s=(n, n))
        t = aty + rho * (x + v)
        w_old, z_old = w, z
        w = (t - A.adjoint(A(t)) / (1 + rho)) / rho
        dx = grad2(x)
        z = shrink(dx + u, lam / rho, True)
        u = u + dx - z
        v = v + x - w
        if k % 10 == 0:
            r = math.sqrt(float(((dx - z) ** 2).sum() + ((x - w) ** 2).sum()))
            s = rho * float((grad2_adjoint(z - z_old) + (w - w_old)).norm())
            scale = max(float(x.norm()), 1e-30)
            if k > 20 and r < tol * scale and s < tol * scale:
                break
    return w, k + 1
