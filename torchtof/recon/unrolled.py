"""Unrolled (deep-unfolded) TVAL3: K fixed iterations with learned per-iteration scalars.

TVAL3 (Li, Yin, Jiang, Zhang, Comput. Optim. Appl. 56, 2013; domain-notes §1) solves
``min_u Σ_i ‖D_i u‖ s.t. A u = b`` by the augmented Lagrangian of the split ``w_i = D_i u``

.. math::
    \\mathcal L(w, u) = \\sum_i \\|w_i\\| - σ^T(Du - w) + \\frac{β}{2}\\|Du - w\\|^2
        - δ^T(Au - b) + \\frac{μ}{2}\\|Au - b\\|^2,

alternating a shrinkage w-step, a gradient u-step and multiplier updates. The unrolled
network runs exactly ``K`` iterations of that splitting, each with its own learned
``μ_k, β_k`` (penalties), ``α_k`` (step factor) and ``t_k`` (shrinkage threshold), and
no data-dependent control flow (it exports to ONNX). Deep unfolding after ISTA-Net (Zhang
& Ghanem, CVPR 2018) and ADMM-CSNet (Yang et al., TPAMI 2019); domain-notes §1.6.

Iteration ``k`` (from ``u_0 = Aᵀb``, ``σ_0 = 0``, ``δ_0 = 0``; TVAL3's gradients are
divided by ``β``, domain-notes §1.2):

.. math::
    w &= \\operatorname{shrink}(Du - σ/β_k,\\ t_k)\\\\
    d &= Dᵀ(Du - w - σ/β_k) + Aᵀ(μ_k(Au - b) - δ)/β_k\\\\
    τ &= \\frac{dᵀd}{\\|Dd\\|^2 + (μ_k/β_k)\\|Ad\\|^2}\\qquad\\text{(exact steepest descent)}\\\\
    u &\\leftarrow u - α_k τ d\\\\
    σ &\\leftarrow σ - β_k(Du - w),\\qquad δ \\leftarrow δ - μ_k(Au - b)

Initialised at TVAL3's published defaults ``μ = 2⁸``, ``β = 2⁵``, ``t = 1/β``, ``α = 1``
(``ftvcs_al_opts.m``), so the untrained network is K iterations of TVAL3 with its
first-step (steepest-descent) step length. ``Du`` and ``Au`` are updated linearly
(``D(u − s d) = Du − s Dd``), so one iteration costs one ``A``, one ``Aᵀ`` and two
difference operators.

Scale: ``b = y / s`` with ``s = max|y| / 1.5`` per measurement vector (TVAL3's ``Scaleb``
brings ``b`` to a range of 1.5; for Hadamard data of a scene of one sign the DC
coefficient is ``max|y|``), and the result is multiplied back by ``s``: the network is
scale-equivariant, so weights trained on ``[0, 1]`` scenes apply to physical bucket units.
An all-zero ``y`` gives an all-zero image (every division is guarded).

Shipped weights (``torchtof/weights/unrolled_n{n}_sr{code}_K{K}.pt``, ``code`` = SR in
hundredths of a percent, e.g. ``2500``) were trained by :func:`torchtof.recon.train_unrolled`
for the Hadamard operator (cake-cutting order) at ``n ∈ {32, 64}`` and the paper's SRs;
regenerate them with ``examples/train_unrolled.py --all``.
"""

from __future__ import annotations

import math
import os
import warnings
from pathlib import Path

import torch
from torch import nn

from .._checks import check_finite, check_shape, check_tensor
from ..operators.base import LinearOperator
from ._tv import grad2, grad2_adjoint, shrink

__all__ = [
    "UnrolledTVAL3",
    "unrolled_tval3",
    "WEIGHTS_DIR",
    "DEFAULT_N_ITER",
    "weight_path",
    "available_weights",
    "sr_code",
]

#: Folder of the shipped weight files.
WEIGHTS_DIR = Path(__file__).resolve().parent.parent / "weights"
#: Iterations of the shipped weights (and the default ``n_iter``).
DEFAULT_N_ITER = 12
#: TVAL3 defaults (``ftvcs_al_opts.m``): data penalty μ and TV splitting penalty β.
TVAL3_MU, TVAL3_BETA = 2.0**8, 2.0**5
#: ``b = y / s`` with ``s = max|y| / B_RANGE`` (TVAL3's ``Scaleb`` target range).
B_RANGE = 1.5


def unrolled_tval3(
    y: torch.Tensor,
    op: LinearOperator,
    mu: torch.Tensor,
    beta: torch.Tensor,
    step: torch.Tensor,
    thresh: torch.Tensor,
    isotropic: bool = True,
) -> torch.Tensor:
    """K unrolled TVAL3 iterations with per-iteration scalars (module docstring).

    Args:
        y: measurements.
        op: the measurement operator ``A`` (``op.m == M``).
        mu: data penalties ``μ_k > 0``.
        beta: TV splitting penalties ``β_k > 0``.
        step: step factors ``α_k > 0`` on the exact steepest-descent step.
        thresh: shrinkage thresholds ``t_k > 0`` (TVAL3: ``1/β_k``).
        isotropic: isotropic TV (TVAL3 ``TVnorm=2``) or anisotropic.

    Returns:
        The reconstruction in the units of ``y``'s scene (``A x ≈ y``).

    Raises:
        TypeError: if ``y`` or a scalar vector is not a floating tensor.
        ValueError: if ``y`` is not ``(B, C, M)`` with ``M = op.m``, holds NaN/Inf (eager
            mode), or the four scalar vectors are not all of shape ``(K,)``, ``K >= 1``.

    Shape:
        - y: :math:`(B, C, M)`; mu, beta, step, thresh: :math:`(K,)`.
        - Output: :math:`(B, C, n, n)`.

    Example:
        >>> from torchtof.operators import Hadamard
        >>> A = Hadamard(16, sr=0.25)
        >>> k = torch.ones(3)
        >>> unrolled_tval3(A(torch.rand(2, 1, 16, 16)), A, 256 * k, 32 * k, k, k / 32).shape
        torch.Size([2, 1, 16, 16])
    """
    func = "unrolled_tval3"
    check_tensor(y, "y", func)
    check_shape(y, (None, None, op.m), "y", func, "(B, C, M)")
    check_finite(y, "y", func)
    for name, v in (("mu", mu), ("beta", beta), ("step", step), ("thresh", thresh)):
        check_tensor(v, name, func)
        if v.ndim != 1 or v.shape[0] < 1 or v.shape != mu.shape:
            raise ValueError(
                f"{func}: expected {name} of shape (K,) with K >= 1 equal for mu, beta, step, "
                f"thresh, got {tuple(v.shape)} (mu {tuple(mu.shape)})"
            )
    mu, beta, step, thresh = (
        v.to(dtype=y.dtype, device=y.device) for v in (mu, beta, step, thresh)
    )
    tiny = torch.finfo(y.dtype).tiny

    s = y.abs().amax(dim=-1, keepdim=True) / B_RANGE  # (B, C, 1)
    b = y / s.clamp_min(tiny)
    u = op.adjoint(b)
    au = op(u)
    du = grad2(u)
    sigma = torch.zeros_like(du)
    delta = torch.zeros_like(b)
    for k in range(mu.shape[0]):
        mu_k, beta_k = mu[k], beta[k]
        w = shrink(du - sigma / beta_k, thresh[k], isotropic=isotropic)
        d = grad2_adjoint(du - w - sigma / beta_k) + op.adjoint(mu_k * (au - b) - delta) / beta_k
        dd, ad = grad2(d), op(d)
        num = (d * d).sum(dim=(-2, -1))[..., None]  # (B, C, 1)
        den = (dd * dd).sum(dim=(-3, -2, -1))[..., None] + (mu_k / beta_k) * (ad * ad).sum(
            dim=-1, keepdim=True
        )
        tau = step[k] * num / (den + tiny)
        u = u - tau[..., None] * d
        du = du - tau[..., None, None] * dd
        au = au - tau * ad
        sigma = sigma - beta_k * (du - w)
        delta = delta - mu_k * (au - b)
    return u * s[..., None]


def sr_code(sr: float) -> str:
    """File-name code of a sampling rate: hundredths of a percent, 4 digits (0.25 → ``"2500"``)."""
    return f"{round(sr * 10000):04d}"


def weight_path(n: int, m: int, n_iter: int) -> Path:
    """Path of the shipped weight file for ``(n, SR = m/n², K)`` (it may not exist)."""
    return WEIGHTS_DIR / f"unrolled_n{n}_sr{sr_code(m / (n * n))}_K{n_iter}.pt"


def available_weights() -> list[str]:
    """Names of the shipped weight files."""
    return sorted(p.name for p in WEIGHTS_DIR.glob("unrolled_n*_sr*_K*.pt"))


def _raw_init(n_iter: int) -> dict[str, torch.Tensor]:
    """TVAL3 defaults as raw (log) parameters of shape ``(K,)``."""
    full = lambda v: torch.full((n_iter,), math.log(v))  # noqa: E731
    return {
        "log_mu": full(TVAL3_MU),
        "log_beta": full(TVAL3_BETA),
        "log_step": full(1.0),
        "log_thresh": full(1.0 / TVAL3_BETA),
    }


class UnrolledTVAL3(nn.Module):
    """Unrolled TVAL3 with learned per-iteration ``μ_k, β_k, α_k, t_k`` (:func:`unrolled_tval3`).

    The scalars are positive by parametrisation: ``μ_k = exp(log_mu[k])`` etc., with the
    raw ``nn.Parameter`` vectors ``log_mu, log_beta, log_step, log_thresh`` of shape
    ``(K,)``.

    Args:
        A: measurement operator (held inside, so ``forward`` takes only ``y``).
        n_iter: number of unrolled iterations ``K >= 1`` (shipped: :data:`DEFAULT_N_ITER`).
        pretrained: ``True`` loads the shipped file for ``(A.n, SR, order, K)`` when there is
            one and otherwise falls back to the untrained initialisation (TVAL3's defaults)
            with a ``UserWarning``; ``False`` starts from TVAL3's defaults; a path loads that
            file (its metadata must match ``A`` and ``n_iter``).
        isotropic: isotropic TV (TVAL3's default) or anisotropic.

    Attributes:
        weights_file: the file the weights came from, or ``None``.

    Raises:
        TypeError: if ``A`` is not a :class:`~torchtof.operators.LinearOperator` or
            ``n_iter`` not an int.
        ValueError: if ``n_iter < 1`` or a given weight file does not match ``A``/``n_iter``.

    Shape:
        ``(B, C, M) -> (B, C, n, n)``.

    Example:
        >>> from torchtof.operators import Hadamard
        >>> A = Hadamard(32, sr=0.25)
        >>> net = UnrolledTVAL3(A)  # loads weights/unrolled_n32_sr2500_K12.pt
        >>> net(A(torch.rand(1, 1, 32, 32))).shape
        torch.Size([1, 1, 32, 32])
    """

    def __init__(
        self,
        A: LinearOperator,
        n_iter: int = DEFAULT_N_ITER,
        pretrained: bool | str | os.PathLike = True,
        isotropic: bool = True,
    ) -> None:
        super().__init__()
        func = "UnrolledTVAL3"
        if not isinstance(A, LinearOperator):
            raise TypeError(f"{func}: expected A to be a LinearOperator, got {type(A).__name__}")
        if isinstance(n_iter, bool) or not isinstance(n_iter, int):
            raise TypeError(f"{func}: expected n_iter to be an int, got {type(n_iter).__name__}")
        if n_iter < 1:
            raise ValueError(f"{func}: expected n_iter >= 1, got {n_iter}")
        self.A = A
        self.n_iter = n_iter
        self.isotropic = bool(isotropic)
        for name, v in _raw_init(n_iter).items():
            setattr(self, name, nn.Parameter(v))
        self.weights_file: str | None = None
        if pretrained is True:
            path = weight_path(A.n, A.m, n_iter)
            if path.is_file() and self._meta_matches(torch.load(path, weights_only=True)["meta"]):
                self.load_weights(path)
            else:
                warnings.warn(
                    f"{func}: no shipped weights for n={A.n}, m={A.m} (SR {A.m / A.n**2:.4g}), "
                    f"order={getattr(A, 'order', None)!r}, K={n_iter}; using the untrained "
                    f"initialisation (TVAL3 defaults). Shipped: {available_weights()}",
                    UserWarning,
                    stacklevel=2,
                )
        elif pretrained is not False:
            self.load_weights(pretrained)

    def _meta_matches(self, meta: dict) -> bool:
        return (
            meta.get("n") == self.A.n
            and meta.get("m") == self.A.m
            and meta.get("n_iter") == self.n_iter
            and meta.get("order") == getattr(self.A, "order", None)
            and meta.get("operator") == type(self.A).__name__
            and meta.get("isotropic", True) == self.isotropic
        )

    def load_weights(self, path: str | os.PathLike) -> None:
        """Load a weight file written by :meth:`save_weights` (``torch.load(weights_only=True)``).

        Raises:
            ValueError: if its metadata (operator, n, m, order, K, TV norm) does not match.
        """
        blob = torch.load(Path(path), weights_only=True)
        if not self._meta_matches(blob["meta"]):
            raise ValueError(
                f"UnrolledTVAL3.load_weights: weights file {os.fspath(path)!r} was trained for "
                f"{blob['meta']}, not for {type(self.A).__name__}(n={self.A.n}, m={self.A.m}, "
                f"order={getattr(self.A, 'order', None)!r}) with n_iter={self.n_iter}"
            )
        self.load_state_dict(blob["state_dict"], strict=False)
        self.weights_file = os.fspath(path)

    def save_weights(self, path: str | os.PathLike, **meta: object) -> None:
        """Save the raw parameters and metadata (loadable with ``weights_only=True``)."""
        info = {
            "operator": type(self.A).__name__,
            "n": self.A.n,
            "m": self.A.m,
            "order": getattr(self.A, "order", None),
            "n_iter": self.n_iter,
            "isotropic": self.isotropic,
            **meta,
        }
        state = {k: v.detach().clone() for k, v in self.named_parameters() if k.startswith("log_")}
        torch.save({"state_dict": state, "meta": info}, Path(path))

    def scalars(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """The positive per-iteration ``(μ, β, α, t)``, each of shape ``(K,)``."""
        return self.log_mu.exp(), self.log_beta.exp(), self.log_step.exp(), self.log_thresh.exp()

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        return unrolled_tval3(y, self.A, *self.scalars(), isotropic=self.isotropic)

    def extra_repr(self) -> str:
        return (
            f"n_iter={self.n_iter}, isotropic={self.isotropic}, weights_file={self.weights_file!r}"
        )
