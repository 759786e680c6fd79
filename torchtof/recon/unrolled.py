"""Unrolled (deep-unfolded) TVAL3: K fixed iterations with learned per-iteration scalars.

TVAL3 (Li, Yin, Jiang, Zhang, Comput. Optim. Appl. 56, 2013) solves
``min_u Σ_i ‖D_i u‖ s.t. A u = b`` by the augmented Lagrangian of the split ``w_i = D_i u``

.. math::
    \\mathcal L(w, u) = \\sum_i \\|w_i\\| - σ^T(Du - w) + \\frac{β}{2}\\|Du - w\\|^2
        - δ^T(Au - b) + \\frac{μ}{2}\\|Au - b\\|^2,

alternating a shrinkage w-step, a gradient u-step and multiplier updates. The unrolled
network runs exactly ``K`` iterations of that splitting, each with its own learned
``μ_k, β_k`` (penalties), ``α_k, c_k`` (step factor and preconditioner weight) and ``t_k``
(shrinkage threshold), and no data-dependent control flow (it exports to ONNX). Deep
unfolding after ISTA-Net (Zhang & Ghanem, CVPR 2018) and ADMM-CSNet (Yang et al., TPAMI
2019).

Iteration ``k`` (from ``u_0 = Aᵀb``, ``σ_0 = 0``, ``δ_0 = 0``; as in TVAL3 the u-gradient
is divided by ``β``; ``ρ_k = μ_k/β_k``):

.. math::
    w &= \\operatorname{shrink}(Du - σ/β_k,\\ t_k)\\\\
    d &= Dᵀ(Du - w - σ/β_k) + Aᵀ(ρ_k(Au - b) - δ/β_k)\\\\
    p &= M_k^{-1} d,\\qquad M_k = c_k I + ρ_k AᵀA\\\\
    τ &= \\frac{dᵀp}{\\|Dp\\|^2 + ρ_k\\|Ap\\|^2},\\qquad u \\leftarrow u - α_k τ p\\\\
    σ &\\leftarrow σ - β_k(Du - w),\\qquad δ \\leftarrow δ - μ_k(Au - b)

``τ`` is the exact line search of the quadratic u-subproblem along ``p`` (TVAL3's
first-step length, Li 2009). ``M_k`` is a diagonal-plus-data preconditioner of its Hessian
``DᵀD + ρ_k AᵀA``: with orthonormal rows (``A Aᵀ = I``, so ``AᵀA`` is a projector)
``M_k^{-1} = (I − κ_k AᵀA)/c_k``, ``κ_k = ρ_k/(c_k + ρ_k)`` exactly. With ``Ad = A t + q``
for ``d = t + Aᵀq``, the preconditioned direction costs no more than the plain gradient: one
``A``, one ``Aᵀ`` and two difference operators per iteration (``Du`` and ``Au`` are updated
linearly, ``D(u − s p) = Du − s Dp``). ``c_k → ∞`` gives TVAL3's steepest-descent step.

Initialisation: TVAL3's published defaults ``μ = 2⁸``, ``β = 2⁵``, ``t = 1/β``, ``α = 1``
(``ftvcs_al_opts.m``) and ``c = 4``, the mean eigenvalue of the periodic ``DᵀD``
(:func:`~torchtof.recon.tv.laplacian_eigs`), so the untrained network is K iterations of
TVAL3's splitting with a preconditioned exact-line-search step (at ``n = 64``, 37.5 % SR,
noise-free, it is 0.9 dB closer to converged TVAL3 than the unpreconditioned step, and it
trains 1.6 dB better at 1 % noise).

Scale: ``b = y / s`` with ``s = ‖y‖₂ / 1.5`` per measurement vector, and the result is
multiplied back by ``s``: the network is scale-equivariant (``f(c y) = c f(y)``, ``c ≠ 0``),
so weights trained on ``[0, 1]`` scenes apply to physical bucket units. For Hadamard data of
a scene of one sign the DC coefficient dominates ``‖y‖₂``, so ``b`` has about the range 1.5
that TVAL3's ``Scaleb`` gives it and the defaults keep their meaning. The norm is taken of
``y / max|y|`` (no overflow at 1e30 or underflow at 1e-30 in float32), and an all-zero ``y``
gives an all-zero image (every division is guarded).

Shipped weights (``torchtof/weights/unrolled_n{n}_sr{code}_K{K}.pt``, ``code`` = SR in
hundredths of a percent, e.g. ``2500``) were trained by :func:`torchtof.recon.train_unrolled`
for the Hadamard operator (cake-cutting order) at ``n ∈ {32, 64}`` and the paper's SRs, on
bucket noise of 0–2 % of the measurement spread; regenerate them with
``examples/train_unrolled.py --all``. They favour noisy buckets: on noise-free buckets
converged TVAL3 is better.
"""

from __future__ import annotations

import functools
import math
import os
import warnings
from pathlib import Path

import torch
from torch import nn

from .._checks import (
    built_for_cache,
    check_bool,
    check_finite,
    check_real,
    check_shape,
    is_tracing,
    unchecked,
)
from ..operators.base import LinearOperator
from .base import ReconResult, direct_result, renamed_option
from .tv import grad2, grad2_adjoint, shrink

__all__ = [
    "UnrolledTVAL3",
    "unrolled_tval3",
    "WEIGHTS_DIR",
    "DEFAULT_N_LAYERS",
    "DEFAULT_N_ITER",
    "weight_path",
    "check_n_layers",
    "available_weights",
    "sr_code",
    "PARAM_NAMES",
]

#: Folder of the shipped weight files.
WEIGHTS_DIR = Path(__file__).resolve().parent.parent / "weights"
#: Layers (iterations) of the shipped weights (and the default ``n_layers``).
DEFAULT_N_LAYERS = 12
#: Old name of :data:`DEFAULT_N_LAYERS`.
DEFAULT_N_ITER = DEFAULT_N_LAYERS
#: TVAL3 defaults (``ftvcs_al_opts.m``): data penalty μ and TV splitting penalty β.
TVAL3_MU, TVAL3_BETA = 2.0**8, 2.0**5
#: Initial preconditioner weight ``c``: the mean eigenvalue of the periodic ``DᵀD``.
PRECOND_INIT = 4.0
#: ``b = y / s`` with ``s = ‖y‖₂ / B_NORM`` (≈ TVAL3's ``Scaleb`` range 1.5, module docstring).
B_NORM = 1.5


def unrolled_tval3(
    y: torch.Tensor,
    A: LinearOperator,
    mu: torch.Tensor | None = None,
    beta: torch.Tensor | None = None,
    step: torch.Tensor | None = None,
    thresh: torch.Tensor | None = None,
    precond: torch.Tensor | None = None,
    isotropic: bool = True,
    *,
    n_layers: int | None = None,
    pretrained: bool | str | os.PathLike = True,
) -> torch.Tensor:
    """K unrolled TVAL3 iterations with per-iteration scalars (module docstring).

    With none of the five scalar vectors given, the scalars of
    ``UnrolledTVAL3(A, n_layers, pretrained, isotropic)`` (by default the shipped ones for
    ``A``'s ``(n, SR)``; elsewhere TVAL3's defaults, with its warning): the module's
    ``forward``, so the registry's ``function(y, A, **options)`` takes the module's options.

    Args:
        y: measurements ``(B, C, M)``, real floating point.
        A: the measurement operator with orthonormal rows (``A Aᵀ = I``), ``A.m == M``.
        mu: data penalties ``μ_k > 0`` (TVAL3: ``2⁸``).
        beta: TV splitting penalties ``β_k > 0`` (TVAL3: ``2⁵``).
        step: step factors ``α_k > 0`` on the exact line-search step (TVAL3: 1).
        thresh: shrinkage thresholds ``t_k > 0`` (TVAL3: ``1/β_k``).
        precond: preconditioner weights ``c_k > 0`` (``c_k → ∞``: TVAL3's steepest descent).
            Every entry of the five, in the dtype of ``y``, must be finite and ``> 0``
            (checked once here, eager mode).
        isotropic: isotropic TV (TVAL3 ``TVnorm=2``) or anisotropic; a bool.
        n_layers: ``K`` of :class:`UnrolledTVAL3` when no scalars are given (``None``: its
            default); an error with the scalars, whose length is ``K``.
        pretrained: :class:`UnrolledTVAL3`'s weights when no scalars are given (``True``: the
            shipped ones, ``False``: TVAL3's defaults, or a path); an error with the scalars
            unless ``True``.

    Returns:
        The reconstruction ``x`` in the units of the scene (``A x ≈ y``).

    Raises:
        TypeError: if ``y`` or a scalar vector is not a real floating tensor, ``A`` is
            not a :class:`~torchtof.operators.LinearOperator` or ``isotropic`` not a bool.
        ValueError: if ``A`` has no orthonormal rows, ``y`` is not ``(B, C, M)`` with
            ``M = A.m`` or holds NaN/Inf (eager mode), or the five scalar vectors are not
            all of shape ``(K,)``, ``K >= 1``, or some of them are given and others not, or
            an entry of them is not finite and ``> 0`` (eager mode).

    Shape:
        - y: :math:`(B, C, M)`; mu, beta, step, thresh, precond: :math:`(K,)`.
        - Output: :math:`(B, C, n, n)`.

    Example:
        >>> from torchtof.operators import Hadamard
        >>> A = Hadamard(16, sr=0.25)
        >>> k = torch.ones(3)
        >>> unrolled_tval3(A(torch.rand(2, 1, 16, 16)), A, 256 * k, 32 * k, k, k / 32, 4 * k).shape
        torch.Size([2, 1, 16, 16])
    """
    per_iter = (mu, beta, step, thresh, precond)
    if all(v is None for v in per_iter):
        _check_operator(A, "unrolled_tval3")
        check_bool(isotropic, "isotropic", "unrolled_tval3")
        net = UnrolledTVAL3(A, n_layers=DEFAULT_N_LAYERS if n_layers is None else n_layers,
                            pretrained=pretrained, isotropic=isotropic)
        # exp on y's device, as the module moved there computes them (A is never moved)
        dev = y.device if isinstance(y, torch.Tensor) else None
        per_iter = tuple(getattr(net, k).detach().to(device=dev).exp() for k in PARAM_NAMES)
        check_values = False
    else:
        if n_layers is not None or pretrained is not True:
            raise ValueError("unrolled_tval3: n_layers and pretrained choose the module's "
                             "scalars; give them or the five scalar vectors, not both")
        check_values = True
    return _unrolled_tval3(y, A, per_iter, isotropic, check_values=check_values)


#: The per-layer scalar arguments of :func:`unrolled_tval3`, in order.
_SCALAR_NAMES = ("mu", "beta", "step", "thresh", "precond")


def _unrolled_tval3(y: torch.Tensor, A: LinearOperator, per_iter: tuple, isotropic: bool,
                    check_values: bool) -> torch.Tensor:
    """:func:`unrolled_tval3`; ``check_values=False`` (the module's positive-by-construction
    scalars) skips the host read of the scalars' values."""
    func = "unrolled_tval3"
    _check_operator(A, func)
    check_bool(isotropic, "isotropic", func)
    check_real(y, "y", func)
    check_shape(y, (None, None, A.m), "y", func, "(B, C, M)")
    check_finite(y, "y", func)
    names = _SCALAR_NAMES
    missing = [k for k, v in zip(names, per_iter, strict=True) if v is None]
    if missing:
        raise ValueError(f"{func}: expected mu, beta, step, thresh and precond all given or "
                         f"all None (the shipped scalars), got None for {', '.join(missing)}")
    mu = per_iter[0]
    for name, v in zip(names, per_iter, strict=True):
        check_real(v, name, func)
        if not is_tracing() and (v.ndim != 1 or v.shape[0] < 1 or v.shape != mu.shape):
            raise ValueError(
                f"{func}: expected {name} of shape (K,) with K >= 1, the same for mu, beta, "
                f"step, thresh and precond, got {tuple(v.shape)} (mu {tuple(mu.shape)})"
            )
    mu, beta, step, thresh, precond = (v.to(dtype=y.dtype, device=y.device) for v in per_iter)
    if check_values and not is_tracing() and y.device.type != "meta":
        vals = torch.stack((mu, beta, step, thresh, precond)).detach()
        ok = ((vals > 0) & vals.isfinite()).all(dim=1).tolist()  # one host read, at entry
        for name, good, v in zip(names, ok, vals, strict=True):
            if not good:
                raise ValueError(f"{func}: expected every entry of {name} > 0 and finite (in "
                                 f"{y.dtype}), got {v.tolist()}")
    fwd, adj = A.loop_pair(y)
    tiny = torch.finfo(y.dtype).tiny

    peak = y.abs().amax(dim=-1, keepdim=True).clamp_min(tiny)  # ‖y‖ without over/underflow
    s = peak * (y / peak).norm(dim=-1, keepdim=True) / B_NORM  # (B, C, 1)
    b = y / s.clamp_min(tiny)
    u = adj(b)
    au = fwd(u)
    du = grad2(u)
    sigma = torch.zeros_like(du)
    delta = torch.zeros_like(b)
    rho = mu / beta
    kappa = rho / (precond + rho)
    scalars = (mu, beta, 1.0 / beta, rho, kappa, 1.0 / precond, step, thresh)
    with unchecked():  # y checked above: the operator calls of the loop do no host sync
        for mu_k, beta_k, ib_k, rho_k, ka_k, ic_k, step_k, t_k in zip(
            *(v.unbind() for v in scalars), strict=True
        ):
            v = du - sigma * ib_k  # Du − σ/β
            w = shrink(v, t_k, isotropic=isotropic)
            t = grad2_adjoint(v - w)  # d = t + Aᵀq
            q = rho_k * (au - b) - delta * ib_k
            at = fwd(t)
            p = (t + adj((1 - ka_k) * q - ka_k * at)) * ic_k  # M⁻¹ d
            ap = (1 - ka_k) * ic_k * (at + q)  # A p = (1 − κ) A d / c
            dp = grad2(p)
            num = (t * p).sum(dim=(-2, -1))[..., None] + (q * ap).sum(dim=-1, keepdim=True)  # dᵀp
            den = (dp * dp).sum(dim=(-3, -2, -1))[..., None] + rho_k * (ap * ap).sum(
                -1, keepdim=True)
            tau = step_k * num / (den + tiny)  # (B, C, 1)
            u = u - tau[..., None] * p
            du = du - tau[..., None, None] * dp
            au = au - tau * ap
            sigma = sigma - beta_k * (du - w)
            delta = delta - mu_k * (au - b)
    return u * s[..., None]


def _check_operator(op: object, func: str) -> None:
    if not isinstance(op, LinearOperator):
        raise TypeError(f"{func}: expected A to be a LinearOperator, got {type(op).__name__}")
    if not op.orthonormal_rows:
        raise ValueError(
            f"{func}: expected an operator with orthonormal rows (A Aᵀ = I, e.g. Hadamard), "
            f"got {type(op).__name__} with orthonormal_rows=False"
        )


def sr_code(sr: float) -> str:
    """File-name code of a sampling rate: hundredths of a percent, 4 digits (0.25 → ``"2500"``)."""
    return f"{round(sr * 10000):04d}"


def check_n_layers(n_layers: object, func: str) -> None:
    """``TypeError`` unless ``n_layers`` is an int (not a bool), ``ValueError`` if ``< 1`` (the
    unrolled networks' depth: :class:`UnrolledTVAL3` and
    :class:`~torchtof.recon.learned.Learned`)."""
    if isinstance(n_layers, bool) or not isinstance(n_layers, int):
        raise TypeError(f"{func}: expected n_layers to be an int, got {type(n_layers).__name__}")
    if n_layers < 1:
        raise ValueError(f"{func}: expected n_layers >= 1, got {n_layers}")


def weight_path(n: int, m: int, n_layers: int) -> Path:
    """Path of the shipped weight file for ``(n, SR = m/n², K)`` (it may not exist)."""
    return WEIGHTS_DIR / f"unrolled_n{n}_sr{sr_code(m / (n * n))}_K{n_layers}.pt"


def available_weights() -> list[str]:
    """Names of the shipped weight files."""
    return sorted(p.name for p in WEIGHTS_DIR.glob("unrolled_n*_sr*_K*.pt"))


#: Raw parameter names, in the order of :func:`unrolled_tval3`'s scalar arguments.
PARAM_NAMES = ("log_mu", "log_beta", "log_step", "log_thresh", "log_precond")


def _raw_init(n_layers: int) -> dict[str, torch.Tensor]:
    """The initialisation (module docstring) as raw (log) parameters of shape ``(K,)``."""
    values = (TVAL3_MU, TVAL3_BETA, 1.0, 1.0 / TVAL3_BETA, PRECOND_INIT)
    return {k: torch.full((n_layers,), math.log(v))
            for k, v in zip(PARAM_NAMES, values, strict=True)}


@functools.lru_cache(maxsize=16)
@built_for_cache
def _read_cached(path: str, mtime_ns: int, size: int) -> dict:
    return torch.load(path, weights_only=True)


def _read_weights(path: str | os.PathLike) -> dict:
    """The contents of a weights file, read once per version of the file (keyed by its path,
    modification time and size: a file rewritten in place is read again); callers copy the
    tensors out, never keep or change them."""
    p = Path(path).resolve()
    st = p.stat()
    return _read_cached(os.fspath(p), st.st_mtime_ns, st.st_size)


def _read_weights_file(path: str | os.PathLike, func: str, name: str) -> dict:
    """:func:`_read_weights` of a given file, a ``ValueError`` naming argument ``name`` when
    the file is missing, unreadable or no :meth:`UnrolledTVAL3.save_weights` file."""
    if not Path(path).is_file():
        raise ValueError(f"{func}: expected {name} to be an existing weights file, got "
                         f"{os.fspath(path)!r} (no such file)")
    try:
        blob = _read_weights(path)
    except Exception as exc:  # noqa: BLE001 - every read or unpickling failure means "not one"
        raise ValueError(f"{func}: expected {name} to be an UnrolledTVAL3 weights file "
                         f"(UnrolledTVAL3.save_weights), got {os.fspath(path)!r}: "
                         f"{type(exc).__name__}") from None
    if not isinstance(blob, dict):
        raise ValueError(f"{func}: expected {name} to be an UnrolledTVAL3 weights file "
                         f"(UnrolledTVAL3.save_weights), got {os.fspath(path)!r}: it holds a "
                         f"{type(blob).__name__}, not a dict")
    return blob


class UnrolledTVAL3(nn.Module):
    """Unrolled TVAL3 with learned per-iteration scalars (:func:`unrolled_tval3`).

    The scalars are positive by parametrisation: ``μ_k = exp(log_mu[k])``, and likewise
    ``β_k, α_k, t_k, c_k`` from the raw ``nn.Parameter`` vectors ``log_beta``, ``log_step``,
    ``log_thresh``, ``log_precond``, each of shape ``(K,)``.

    Args:
        A: measurement operator with orthonormal rows (e.g.
            :class:`~torchtof.operators.Hadamard`); held inside, so ``forward`` takes only ``y``.
        n_layers: number of unrolled iterations ``K >= 1`` (shipped:
            :data:`DEFAULT_N_LAYERS`).
        pretrained: ``True`` loads the shipped file for ``(A.n, SR, order, K)`` when there is
            one and otherwise falls back to the untrained initialisation (TVAL3's defaults)
            with a ``UserWarning``; ``False`` starts from the initialisation silently; a path
            loads that file (its metadata must match ``A``, ``n_layers`` and ``isotropic``).
        isotropic: isotropic TV (TVAL3's default) or anisotropic; a bool.
        n_iter: old name of ``n_layers`` (``DeprecationWarning``; removed in the next release).

    The operator's patterns and the scalars are in the ``state_dict``; :meth:`solve` returns a
    :class:`~torchtof.recon.base.ReconResult` (``n_iter = K`` for every sample, stop reason
    ``"fixed"``).

    Attributes:
        weights_file: the file the weights came from, or ``None``.

    Raises:
        TypeError: if ``A`` is not a :class:`~torchtof.operators.LinearOperator`,
            ``n_layers`` not an int, ``isotropic`` not a bool or ``pretrained`` neither a bool
            nor a path (``str``, ``os.PathLike``).
        ValueError: if ``A`` has no orthonormal rows, ``n_layers < 1``, or a given weight file
            is missing, unreadable or does not match.

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
        n_layers: int = DEFAULT_N_LAYERS,
        pretrained: bool | str | os.PathLike = True,
        isotropic: bool = True,
        n_iter: int | None = None,
    ) -> None:
        super().__init__()
        func = "UnrolledTVAL3"
        n_layers = renamed_option(func, "n_iter", "n_layers", n_iter, n_layers, DEFAULT_N_LAYERS)
        _check_operator(A, func)
        check_n_layers(n_layers, func)
        self.A = A
        self.n_layers = n_layers
        self.isotropic = check_bool(isotropic, "isotropic", func)
        if not isinstance(pretrained, (bool, str, os.PathLike)):
            raise TypeError(f"{func}: expected pretrained to be a bool or a weights file path "
                            f"(str or os.PathLike), got {type(pretrained).__name__}")
        for name, v in _raw_init(n_layers).items():
            setattr(self, name, nn.Parameter(v))
        self.weights_file: str | None = None
        if pretrained is True:
            path = weight_path(A.n, A.m, n_layers)
            if path.is_file() and self._meta_matches(_read_weights(path).get("meta", {})):
                self.load_weights(path)
            else:
                warnings.warn(
                    f"{func}: no shipped weights for {self._describe()}; using the untrained "
                    f"initialisation (TVAL3 defaults). Shipped: {available_weights()}",
                    UserWarning,
                    stacklevel=2,
                )
        elif pretrained is not False:
            self._load(pretrained, func, "pretrained")  # missing/unreadable: names it

    def _describe(self) -> str:
        A = self.A
        return (
            f"{type(A).__name__}(n={A.n}, m={A.m}, SR {A.m / A.n**2:.4g}, "
            f"order={getattr(A, 'order', None)!r}), n_layers={self.n_layers}, "
            f"isotropic={self.isotropic}"
        )

    def _meta(self) -> dict:
        return {
            "operator": type(self.A).__name__,
            "n": self.A.n,
            "m": self.A.m,
            "order": getattr(self.A, "order", None),
            "n_iter": self.n_layers,  # the files' key (shipped weights)
            "isotropic": self.isotropic,
        }

    def _meta_matches(self, meta: dict) -> bool:
        return all(meta.get(k) == v for k, v in self._meta().items())

    def load_weights(self, path: str | os.PathLike) -> None:
        """Load a file written by :meth:`save_weights` (read with ``weights_only=True``).

        Raises:
            ValueError: if the file is missing or unreadable, or its metadata (operator, n, m,
                order, K, TV norm) or its parameter shapes do not match this network.
        """
        self._load(path, "UnrolledTVAL3.load_weights", "path")

    def _load(self, path: str | os.PathLike, read_func: str, name: str) -> None:
        """:meth:`load_weights`; a missing or unreadable file is an error of ``read_func``'s
        argument ``name`` (the constructor's ``pretrained``)."""
        func = "UnrolledTVAL3.load_weights"
        blob = _read_weights_file(path, read_func, name)
        meta, state = blob.get("meta", {}), blob.get("state_dict", {})
        meta = meta if isinstance(meta, dict) else {}
        state = state if isinstance(state, dict) and all(
            isinstance(v, torch.Tensor) for v in state.values()) else {}
        if not self._meta_matches(meta):
            raise ValueError(
                f"{func}: weights file {os.fspath(path)!r} was trained for {meta}, "
                f"not for {self._describe()}"
            )
        shape = (self.n_layers,)
        if set(state) != set(PARAM_NAMES) or any(v.shape != shape for v in state.values()):
            raise ValueError(
                f"{func}: expected parameters {PARAM_NAMES} of shape {shape} in "
                f"{os.fspath(path)!r}, got { {k: tuple(v.shape) for k, v in state.items()} }"
            )
        with torch.no_grad():
            for k in PARAM_NAMES:
                getattr(self, k).copy_(state[k])
        self.weights_file = os.fspath(path)

    def save_weights(self, path: str | os.PathLike, **meta: object) -> None:
        """Save the raw parameters and metadata (``meta`` adds training details); the file
        loads with ``torch.load(weights_only=True)``."""
        state = {k: getattr(self, k).detach().clone() for k in PARAM_NAMES}
        torch.save({"state_dict": state, "meta": {**self._meta(), **meta}}, Path(path))

    def scalars(self) -> tuple[torch.Tensor, ...]:
        """The positive per-iteration ``(μ, β, α, t, c)``, each of shape ``(K,)``."""
        return tuple(getattr(self, k).exp() for k in PARAM_NAMES)

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        # the scalars are exp() of the parameters: positive by construction, no value check
        return _unrolled_tval3(y, self.A, self.scalars(), self.isotropic, check_values=False)

    def solve(self, y: torch.Tensor) -> ReconResult:
        """``forward`` with its :class:`~torchtof.recon.base.ReconResult` (``K`` iterations
        for every sample, ``"fixed"``; ``residual = ‖A x − y‖ / ‖y‖``)."""
        return direct_result(self(y), y, self.A, self.n_layers, "fixed")

    def extra_repr(self) -> str:
        return (
            f"n_layers={self.n_layers}, isotropic={self.isotropic}, "
            f"weights_file={self.weights_file!r}"
        )
