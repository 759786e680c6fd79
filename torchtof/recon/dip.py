r"""Deep image prior (DIP) reconstruction: an untrained U-Net fitted to the buckets (paper Eq. 12).

GIDC design (Wang et al. 2022, Light Sci. Appl. 11, 1): the network input is the normalised
correlation image, the network output passes through the measurement operator, and the
weights are fitted so that the predicted buckets match the measured ones:

.. math::

    \theta^* = \arg\min_\theta \; \tfrac{1}{M}\big\| z(A R_\theta(x_0)) - z(y) \big\|^2
    + \zeta\, \frac{\mathrm{TV}(R_\theta(x_0))}{\operatorname{std}(R_\theta(x_0))},
    \qquad z(v) = \frac{v - \bar v}{\operatorname{std}(v)}

This is paper Eq. 12 with GIDC's measurement normalisation ``z`` and a scale-invariant TV
(``TV`` is the mean isotropic total variation per pixel). The fitting loop lives in
:func:`fit_dip`, never in a ``forward`` that export would trace; the fitted
:class:`~torchtof.recon.unet.UNet` is the exportable part.
"""

from __future__ import annotations

import copy
import inspect
import itertools
import math
import warnings
from typing import NamedTuple

import torch
from torch import nn

from .._checks import (
    check_finite,
    check_int,
    check_positive,
    check_shape,
    check_tensor,
    unchecked,
)
from ..constants import DISCREPANCY_TAU
from ..operators.base import LinearOperator
from .base import ReconResult, pow2_scale, relative_residual, renamed_option
from .noise import tail_noise_sigma
from .tv import tv_norm
from .unet import UNet

__all__ = ["DIP", "DIPResult", "auto_zeta", "default_unet", "dip", "dip_input", "fit_dip"]

#: ``zeta="auto"``: ``ζ = clip(κ σ/std(y), ζ_min, ζ_max)`` (see :func:`auto_zeta`).
ZETA_KAPPA = 1.5
ZETA_MIN = 0.03
ZETA_MAX = 1.0
_EARLY_STOP = ("wmv", "discrepancy", None)
_OUTPUTS = ("calibrated", "unit")


class DIPResult(NamedTuple):
    """Output of :func:`fit_dip`.

    Attributes:
        x: the fitted image min-max normalised to ``[0, 1]``, ``(1, 1, n, n)``.
        x_cal: the affine-calibrated image ``a·x̂ + b`` in the units of ``y`` (the two scalars
            minimise ``‖A(a x̂ + b·1) − y‖²``), ``(1, 1, n, n)``; ``a < 0`` for a negative image.
        unet: the fitted :class:`UNet` in eval mode with the batch statistics of ``x0`` folded
            into its batch norms: ``unet(x0)`` reproduces the fitted sigmoid output ``x̂``
            (``x`` is its min-max normalisation), and it exports to ONNX.
        x0: the network input ``(1, C0, n, n)``.
        n_iter: number of iterations run (Adam steps + 1 for the last evaluated output).
        best_iter: 0-based iteration whose network is returned (the ES-WMV minimum, the
            discrepancy stop, or ``n_iter − 1``).
        loss_history: ``(n_iter,)`` loss of Eq. 12 at every iteration.
        stop_reason: ``"wmv"`` (ES-WMV), ``"discrepancy"`` or ``"max_iter"``.
    """

    x: torch.Tensor
    x_cal: torch.Tensor
    unet: UNet
    x0: torch.Tensor
    n_iter: int
    best_iter: int
    loss_history: torch.Tensor
    stop_reason: str = "max_iter"


def _swap_legacy(y, A, func: str):
    """``(y, A)``; the old order ``(A, y)`` still works for one release (DeprecationWarning)."""
    if isinstance(y, LinearOperator) and isinstance(A, torch.Tensor):
        warnings.warn(f"{func}: the argument order is now ({func}(y, A, ...)); "
                      f"{func}(A, y) will stop working in the next release",
                      DeprecationWarning, stacklevel=3)
        return A, y
    return y, A


def _zscore(v: torch.Tensor, rescale: bool = False) -> torch.Tensor:
    """Standardise over the last axis (GIDC's normalisation of buckets). ``rescale``: first
    multiply each slice by the power of two of :func:`~torchtof.recon.base.pow2_scale`
    (exact, and 1 at ordinary scales; the result is scale-free anyway), so that the variance
    of data at any scale the dtype holds neither overflows nor underflows."""
    if rescale:
        v = v * pow2_scale(v)
    mean = v.mean(dim=-1, keepdim=True)
    std = v.std(dim=-1, keepdim=True, unbiased=False)
    return (v - mean) / std.clamp_min(torch.finfo(v.dtype).tiny)


def _minmax(x: torch.Tensor) -> torch.Tensor:
    lo = x.amin(dim=(-2, -1), keepdim=True)
    span = x.amax(dim=(-2, -1), keepdim=True) - lo
    return (x - lo) / torch.where(span > 0, span, torch.ones_like(span))


def _affine_coeffs(ax: torch.Tensor, a1: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """``(a, b)`` minimising ``‖a·Ax̂ + b·A1 − y‖²`` (2×2 normal equations, minimum norm when
    ``A1`` and ``Ax̂`` are dependent). Inputs ``(M,)``; returns ``(2,)``."""
    basis = torch.stack((ax, a1), dim=-1)  # (M, 2)
    gram = basis.T @ basis
    return torch.linalg.pinv(gram, hermitian=True) @ (basis.T @ y)


def dip_input(y: torch.Tensor, A: LinearOperator) -> torch.Tensor:
    r"""The default network input: the z-scored pseudo-inverse image.

    .. math::

        x_0 = \frac{A^+ y - \overline{A^+ y}}{\operatorname{std}(A^+ y)}

    For orthonormal rows (Hadamard) ``A⁺y = Aᵀy``, which is (up to an affine map) the g2/DGI
    correlation image of the ±1 DMD pair acquisition (paper Eq. 9–10; GIDC feeds the
    z-scored DGI image, Wang et al. 2022).

    Args:
        y: buckets ``(B, C, M)``.
        A: measurement operator.

    Returns:
        ``(B, C, n, n)``, zero mean and unit standard deviation per image (all zeros if
        ``A⁺y`` is constant).

    Raises:
        TypeError: if ``A`` is not a :class:`LinearOperator` or ``y`` not a float tensor.
        ValueError: if ``y`` is not ``(B, C, M)`` or holds NaN/Inf.

    Shape:
        - y: :math:`(B, C, M)`.
        - Output: :math:`(B, C, n, n)`.

    Example:
        >>> from torchtof.operators import Hadamard
        >>> A = Hadamard(16, sr=0.25)
        >>> x0 = dip_input(A(torch.rand(1, 1, 16, 16)), A)
        >>> x0.shape, abs(float(x0.mean())) < 1e-5
        (torch.Size([1, 1, 16, 16]), True)
    """
    y, A = _swap_legacy(y, A, "dip_input")
    _check_a_y(A, y, "dip_input")
    img = A.pinv(y)
    flat = _zscore(img.flatten(-2), rescale=True)
    return flat.reshape(img.shape)


def default_unet(n: int, in_ch: int = 1, generator: torch.Generator | None = None) -> UNet:
    """The U-Net that :func:`fit_dip` builds when none is given.

    ``UNet(in_ch, 1, base=16, depth=3, kernel=3)`` for ``n <= 32`` (4×4 bottleneck at 32×32)
    and ``depth=4`` for larger images (GIDC's 4 down-samplings, 4×4 bottleneck at 64×64),
    capped so that the bottleneck keeps at least 2×2 pixels. 3×3 kernels instead of GIDC's
    5×5: on the 32×32 proxy they are as accurate and several times faster on CPU.

    Args:
        n: image side.
        in_ch: input channels.
        generator: CPU generator of the weight initialisation (``None``: the global RNG);
            :func:`fit_dip` passes its own, seeded one.

    Returns:
        A freshly initialised :class:`UNet` on the CPU, float32.
    """
    depth = 3 if n <= 32 else 4
    while depth > 1 and n // 2**depth < 2:
        depth -= 1
    if generator is None:
        return UNet(in_ch=in_ch, out_ch=1, base=16, depth=depth, kernel=3)
    with torch.device("meta"):  # no draw from the global RNG
        net = UNet(in_ch=in_ch, out_ch=1, base=16, depth=depth, kernel=3)
    net = net.to_empty(device="cpu")
    net.reset_parameters(generator)
    return net


def _check_a_y(A: LinearOperator, y: torch.Tensor, func: str) -> None:
    if not isinstance(A, LinearOperator):
        raise TypeError(f"{func}: expected A to be a LinearOperator, got {type(A).__name__}")
    check_tensor(y, "y", func)
    check_shape(y, (None, None, A.m), "y", func, "(B, C, M)")
    if y.dtype not in (torch.float32, torch.float64):
        raise TypeError(f"{func}: expected y of dtype float32 or float64, got {y.dtype}")
    check_finite(y, "y", func)


def _check_options(func, max_iter, lr, betas, zeta, early_stop, window, patience, noise_sigma,
                   seed, unet, lr_step, lr_gamma) -> tuple:
    """The checks of :func:`fit_dip`'s options, shared by :func:`dip` and :class:`DIP` (which
    run them once, before any fit): ``(max_iter, lr, zeta, window, patience, noise_sigma,
    seed, lr_step, lr_gamma)`` as numbers (``zeta`` and ``noise_sigma`` may stay ``"auto"``,
    which needs ``y``)."""
    max_iter = check_int(max_iter, "max_iter", func, 1)
    window = check_int(window, "window", func, 2)
    patience = check_int(patience, "patience", func, 1)
    lr_step = check_int(lr_step, "lr_step", func, 1)
    seed = check_int(seed, "seed", func, 0, 2**64 - 1)  # torch.Generator.manual_seed's range
    lr = check_positive(lr, "lr", func)
    if zeta != "auto":
        if isinstance(zeta, str):
            raise ValueError(f"{func}: expected zeta >= 0 or 'auto', got {zeta!r}")
        zeta = check_positive(zeta, "zeta", func, strict=False)
    lr_gamma = check_positive(lr_gamma, "lr_gamma", func)
    if lr_gamma > 1:
        raise ValueError(f"{func}: expected lr_gamma in (0, 1], got {lr_gamma}")
    try:
        ok = len(betas) == 2 and all(0 <= float(b) < 1 for b in betas)
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise ValueError(f"{func}: expected betas as two numbers in [0, 1), got {betas!r}")
    if early_stop not in _EARLY_STOP:
        raise ValueError(f"{func}: expected early_stop in {_EARLY_STOP}, got {early_stop!r}")
    if isinstance(noise_sigma, str):
        if noise_sigma != "auto":
            raise ValueError(f"{func}: expected noise_sigma > 0, None or 'auto', got "
                             f"{noise_sigma!r}")
    elif noise_sigma is not None:
        noise_sigma = check_positive(noise_sigma, "noise_sigma", func)
    if early_stop == "discrepancy" and noise_sigma is None:
        raise ValueError(f"{func}: early_stop='discrepancy' needs noise_sigma")
    if unet is not None and not isinstance(unet, UNet):
        raise TypeError(f"{func}: expected unet to be a UNet, got {type(unet).__name__}")
    return max_iter, lr, zeta, window, patience, noise_sigma, seed, lr_step, lr_gamma


class _WindowedVariance:
    r"""ES-WMV early stopping (Wang, Li, Zhuang et al. 2021, "Early stopping for deep image
    prior", arXiv:2112.06074): the running variance of the last ``window`` outputs,

    .. math:: \mathrm{VAR}_t = \frac{1}{W}\sum_{w=0}^{W-1}\|x_{t-w} - \bar x_t\|^2,

    its minimum is tracked and the fit stops after ``patience`` consecutive iterations
    without a new minimum; the output at the minimum is returned.
    """

    def __init__(self, window: int, patience: int) -> None:
        self.window, self.patience = window, patience
        self.buffer: list[torch.Tensor] = []
        self.best = math.inf
        self.wait = 0

    def update(self, x: torch.Tensor) -> tuple[bool, bool]:
        """Add output ``x``; return ``(improved, stop)``."""
        self.buffer.append(x)
        if len(self.buffer) > self.window:
            self.buffer.pop(0)
        if len(self.buffer) < self.window:
            return False, False
        stack = torch.stack(self.buffer)
        var = float(((stack - stack.mean(dim=0)) ** 2).sum() / self.window)
        if var < self.best:
            self.best, self.wait = var, 0
            return True, False
        self.wait += 1
        return False, self.wait >= self.patience


def auto_zeta(y: torch.Tensor, noise_sigma: float | None = None) -> float:
    r"""The TV weight of ``zeta="auto"``: proportional to the noise-to-signal ratio of the buckets.

    .. math::

        \zeta = \operatorname{clip}\Big(\kappa\,\frac{\sigma}{\operatorname{std}(y)},
        \ \zeta_{\min},\ \zeta_{\max}\Big)

    with :data:`ZETA_KAPPA` ``κ = 1.5``, :data:`ZETA_MIN` ``= 0.03``, :data:`ZETA_MAX` ``= 1``;
    ``σ`` is ``noise_sigma`` or, when it is ``None``, the estimate of
    :func:`~torchtof.recon.noise.tail_noise_sigma` (high-order tail of ``y``; meant for
    Hadamard orders that put low sequencies first, as TVAL3's ``mu="auto"``). The TV term of
    :func:`fit_dip` is scale invariant and the data term is the squared residual over the bucket
    variance, so ``ζ`` relative to the data term scales like ``σ/std(y)`` (TV is 1-homogeneous;
    the same argument gives TVAL3's ``μ ∝ 1/σ``, see :func:`~torchtof.recon.tval3.tval3`). The
    constants were chosen on binary 32×32 scenes (the character 天, scikit-image horse and camera
    silhouettes), cake-cutting Hadamard at SR 6.25 % and 12.5 %, noise 1–5 % of the bucket range.

    Args:
        y: buckets of one image ``(1, 1, M)``.
        noise_sigma: bucket noise std in the units of ``y``, or ``None`` to estimate it.

    Returns:
        ``ζ`` as a Python float.
    """
    y = y.detach()
    sigma = float(tail_noise_sigma(y)) if noise_sigma is None else float(noise_sigma)
    u = float(pow2_scale(y.reshape(1, -1)))  # exact power of two (1 at ordinary scales): the
    # variance of y at any scale neither overflows nor underflows, the ratio is unchanged
    ratio = sigma * u / max(float((y * u).std(unbiased=False)), torch.finfo(y.dtype).tiny)
    return min(max(ZETA_KAPPA * ratio, ZETA_MIN), ZETA_MAX)


@torch.inference_mode(False)
@torch.enable_grad()
def fit_dip(
    y: torch.Tensor,
    A: LinearOperator,
    x0: torch.Tensor | None = None,
    max_iter: int = 300,
    lr: float = 0.05,
    betas: tuple[float, float] = (0.5, 0.9),
    zeta: float | str = "auto",
    early_stop: str | None = "wmv",
    window: int = 20,
    patience: int = 50,
    noise_sigma: float | str | None = None,
    seed: int = 0,
    unet: UNet | None = None,
    progress: bool = False,
    lr_step: int = 100,
    lr_gamma: float = 0.9,
    n_iter: int | None = None,
) -> DIPResult:
    r"""Fit an untrained U-Net to one bucket vector (deep image prior, paper Eq. 12).

    Minimises, over the weights ``θ`` of ``R_θ`` with its single input ``x0`` fixed
    (``x̂ = R_θ(x0)``),

    .. math::

        L(\theta) = \tfrac{1}{M}\| z(A \hat x) - z(y) \|^2
        + \zeta \, \frac{\tfrac{1}{n^2}\sum_i \|D_i \hat x\|}{\operatorname{std}(\hat x)}

    (paper Eq. 12). ``z`` standardises a bucket vector over its ``M`` entries, as GIDC does
    (Wang et al. 2022), so the data term ignores the scale of the data and a constant offset
    of the buckets. ``D_i`` are TVAL3's periodic differences (isotropic TV). The TV term is
    divided by ``std(x̂)`` so that it is scale invariant like the data term: with a plain
    ``TV(x̂)``, the network could lower the penalty by shrinking the contrast of ``x̂`` at no
    cost to the data term, and the weight would do nothing. ``zeta="auto"`` (default) sets
    ``ζ`` from the noise-to-signal ratio of ``y`` (:func:`auto_zeta`). The optimiser is Adam
    (Kingma & Ba 2015) with ``lr`` and ``betas``, and ``lr ← lr_gamma · lr`` every
    ``lr_step`` iterations (GIDC's decay). Batch norm stays in training mode throughout.

    Early stopping:

    - ``"wmv"`` (default): ES-WMV (Wang et al. 2021). It tracks the running variance of the
      last ``window`` outputs, stops after ``patience`` iterations without a new minimum,
      and returns the output at the minimum;
    - ``"discrepancy"``: Morozov's discrepancy principle on the calibrated residual. It stops
      at the first ``min_{a,b} ‖A(a x̂ + b) − y‖² ≤ τ M σ²`` (``σ = noise_sigma``,
      ``τ =`` :data:`DISCREPANCY_TAU`). With Hadamard buckets at low SR a blurred early
      output already meets the bound, so this rule tends to stop too early;
    - ``None``: runs ``max_iter`` iterations and returns the last output.

    Host syncs: the inputs are checked once at entry; a step of the loop reads nothing back
    to the host except the early-stopping test itself, one value per step (the ES-WMV window
    variance once the window is full, or the calibrated residual for ``"discrepancy"``);
    ``early_stop=None`` makes none.

    Defaults (``base=16, depth=3, kernel=3`` at 32×32, ``lr=0.05``, ``betas=(0.5, 0.9)``,
    ``zeta="auto"``, ES-WMV with ``W=20, P=50``, 300 iterations) were chosen on binary 32×32
    scenes: the character 天 and the scikit-image horse and camera silhouettes, cake-cutting
    Hadamard at SR 6.25 % and 12.5 %, Gaussian bucket noise of 1–5 % of the bucket range.
    The choice was one configuration for all scenes, not a per-image tuning.

    Output scale: the loss is scale invariant, so the sigmoid output ``x̂ ∈ [0, 1]`` is known
    only up to an affine map. ``x`` is ``x̂`` min-max normalised to ``[0, 1]``. ``x_cal`` is
    ``a x̂ + b`` with ``(a, b) = argmin ‖A(a x̂ + b·1) − y‖²``, in the physical units of
    ``y``; a negative image gives ``a < 0``, but the sigmoid prior favours a bright object on
    a dark background, so flip the sign of negative-polarity buckets before fitting.

    Export: after the fit, the batch statistics of ``x0`` are folded into the batch-norm
    running buffers (:meth:`UNet.fold_batch_stats`) and the network is put in eval mode. The
    returned ``unet(x0)`` and its ONNX export then compute the fitted ``x̂`` exactly (up to
    rounding), with no momentum-averaged running statistics involved.

    Determinism: the network is initialised from its own ``torch.Generator`` seeded with
    ``seed`` (the weights equal those drawn after ``torch.manual_seed(seed)``), so the global
    RNG is neither read nor changed and fits in parallel threads do not interfere. On CPU, two
    runs with the same arguments are bitwise equal. The fit enables autograd itself and
    detaches ``y``, so it also runs under ``torch.no_grad()`` or ``torch.inference_mode()``
    and on a ``y`` that requires grad (no gradient flows back to ``y``).

    Args:
        y: buckets of one image, ``(1, 1, M)``; ``M == A.m``, finite, not constant.
        A: measurement operator with ``n`` divisible by ``2^depth`` of the U-Net.
        x0: network input ``(1, C0, n, n)``; default :func:`dip_input` (z-scored ``A⁺y``).
        max_iter: maximal number of iterations, ``>= 1``.
        lr: Adam learning rate (GIDC: 0.05).
        betas: Adam betas (GIDC: (0.5, 0.9)).
        zeta: TV weight ``ζ >= 0`` or ``"auto"`` (:func:`auto_zeta`; for operators without a
            low-to-high measurement order pass ``noise_sigma`` or a number).
        early_stop: ``"wmv"`` (default), ``"discrepancy"`` or ``None``.
        window: ES-WMV window ``W >= 2``.
        patience: ES-WMV patience ``P >= 1``.
        noise_sigma: standard deviation of the bucket noise (units of ``y``). Required by
            ``"discrepancy"``; used by ``zeta="auto"`` when given (else estimated). ``"auto"``:
            the tail estimate of :func:`~torchtof.recon.noise.tail_noise_sigma` (for
            low-to-high orders such as cake-cutting).
        seed: seed of the weight initialisation, an int in ``[0, 2⁶⁴)`` (ignored when ``unet``
            is given).
        unet: network to start from (copied, not modified); default :func:`default_unet`.
        progress: show a tqdm progress bar.
        lr_step: iterations between learning-rate decays, ``>= 1``.
        lr_gamma: learning-rate decay factor in ``(0, 1]``.
        n_iter: old name of ``max_iter`` (``DeprecationWarning``; removed in the next release).

    Returns:
        :class:`DIPResult` ``(x, x_cal, unet, x0, n_iter, best_iter, loss_history,
        stop_reason)``.

    Raises:
        TypeError: if ``A``, ``y``, ``x0`` or ``unet`` have the wrong type.
        ValueError: if ``y`` is not ``(1, 1, A.m)``, holds NaN/Inf or is constant; if ``x0``
            has the wrong shape; if ``n`` does not fit the U-Net depth (``n`` divisible by
            ``2^depth`` with a bottleneck of at least 2×2); if an option is out of range or
            ``early_stop="discrepancy"`` lacks ``noise_sigma``.

    Shape:
        - y: :math:`(1, 1, M)`.
        - x, x_cal: :math:`(1, 1, n, n)`.

    Example:
        >>> from torchtof.operators import Hadamard
        >>> A = Hadamard(16, sr=0.25)
        >>> x = torch.zeros(1, 1, 16, 16); x[..., 4:12, 6:10] = 1
        >>> res = fit_dip(A(x), A, max_iter=20)
        >>> res.x.shape, res.n_iter
        (torch.Size([1, 1, 16, 16]), 20)
    """
    func = "fit_dip"
    y, A = _swap_legacy(y, A, func)
    max_iter = renamed_option(func, "n_iter", "max_iter", n_iter, max_iter, 300)
    _check_a_y(A, y, func)
    if y.shape[:2] != (1, 1):
        raise ValueError(
            f"{func}: expected y of shape (1, 1, {A.m}) (one image; use dip() for batches), "
            f"got {tuple(y.shape)}"
        )
    if bool(y.amax() == y.amin()):
        raise ValueError(f"{func}: y is constant (zero spread), nothing to fit")
    max_iter, lr, zeta, window, patience, noise_sigma, seed, lr_step, lr_gamma = _check_options(
        func, max_iter, lr, betas, zeta, early_stop, window, patience, noise_sigma, seed, unet,
        lr_step, lr_gamma)
    if noise_sigma == "auto":
        noise_sigma = float(tail_noise_sigma(y.detach())[0, 0])
        if noise_sigma <= 0:
            raise ValueError(f"{func}: noise_sigma='auto' estimated 0 (noise-free tail); "
                             "pass a noise level")
    if zeta == "auto":
        zeta = auto_zeta(y, noise_sigma)

    n = A.n
    # a normal tensor even under torch.inference_mode, and no graph back to the caller's y
    y = y.detach().clone()
    if x0 is None:
        x0 = dip_input(y, A)
    else:
        check_tensor(x0, "x0", func)
        check_shape(x0, (1, None, n, n), "x0", func, "(1, C0, n, n)")
        check_finite(x0, "x0", func)
        x0 = x0.detach().to(dtype=y.dtype, device=y.device).clone()
    if unet is None:  # own generator: the global RNG is not touched (thread-safe)
        net = default_unet(n, in_ch=x0.shape[1],
                           generator=torch.Generator().manual_seed(seed))
    else:
        net = copy.deepcopy(unet)
    f = 2**net.depth
    if n % f or n // f < 2 or x0.shape[1] != net.in_ch or net.out_ch != 1:
        raise ValueError(
            f"{func}: expected n divisible by 2^depth = {f} with a bottleneck of at least 2x2 "
            f"and x0 with {net.in_ch} channel(s) for a 1-channel UNet, got n={n}, "
            f"x0 {tuple(x0.shape)}, UNet(in_ch={net.in_ch}, out_ch={net.out_ch}, "
            f"depth={net.depth})"
        )
    net = net.to(dtype=y.dtype, device=y.device).train()

    zy = _zscore(y, rescale=True)
    a1 = A(torch.ones_like(x0[:, :1])).flatten()
    yf = y.flatten()
    # the discrepancy test on (A x - y)·unit: an exact power of two, 1 at ordinary scales, so
    # that its squares neither overflow nor underflow at any scale of y
    unit = float(pow2_scale(yf))
    fused = y.device.type in ("cpu", "cuda")  # one kernel per step: ~15 % faster on CPU
    opt = torch.optim.Adam(
        net.parameters(), lr=lr, betas=(float(betas[0]), float(betas[1])), fused=fused
    )
    sched = torch.optim.lr_scheduler.StepLR(opt, step_size=lr_step, gamma=lr_gamma)
    wmv = _WindowedVariance(window, patience) if early_stop == "wmv" else None
    bound = (DISCREPANCY_TAU * A.m * (noise_sigma * unit)**2 if early_stop == "discrepancy"
             else None)
    best_state, best_iter = None, 0
    losses = []
    steps = range(max_iter)
    if progress:
        from .._optional import progress_bar as tqdm

        steps = tqdm(steps, desc=func)
    t, reason = 0, "max_iter"
    # inputs checked above: no NaN/Inf host sync in the loop's operator calls. cuDNN's
    # deterministic convolution algorithms, so that a seeded fit repeats bit for bit on CUDA too
    # (PyTorch notes, "Reproducibility": the default ones may accumulate with atomics)
    with unchecked(), torch.backends.cudnn.flags(enabled=torch.backends.cudnn.enabled,
                                                 benchmark=False, deterministic=True):
        for t in steps:
            out = net(x0)
            ax = A(out)
            loss = (_zscore(ax) - zy).pow(2).mean()
            if zeta > 0:
                scale = out.std(unbiased=False).clamp_min(torch.finfo(out.dtype).eps)
                loss = loss + zeta * tv_norm(out, eps=1e-12).sum() / (n * n * scale)
            losses.append(loss.detach())
            if wmv is not None:
                improved, stop = wmv.update(out.detach())
                if improved:
                    best_iter = t
                    best_state = [p.detach().clone() for p in net.parameters()]
                if stop:
                    reason = "wmv"
                    break
            if bound is not None:
                with torch.no_grad():
                    ab = _affine_coeffs(ax.flatten(), a1, yf)
                    res = ((ab[0] * ax.flatten() + ab[1] * a1 - yf) * unit).pow(2).sum()
                if float(res) <= bound:  # one host sync per convergence check
                    reason = "discrepancy"
                    break
            if t == max_iter - 1:
                break  # the last output is evaluated, not stepped past
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            sched.step()
    if best_state is not None:
        with torch.no_grad():
            for p, best in zip(net.parameters(), best_state):
                p.copy_(best)
    else:
        best_iter = t
    net.fold_batch_stats(x0)
    with torch.no_grad():
        x_hat = net(x0)
        ab = _affine_coeffs(A(x_hat).flatten(), a1, yf)
    x_cal = ab[0] * x_hat + ab[1]
    return DIPResult(
        x=_minmax(x_hat),
        x_cal=x_cal,
        unet=net,
        x0=x0,
        n_iter=t + 1,
        best_iter=best_iter,
        loss_history=torch.stack(losses),
        stop_reason=reason,
    )


#: The options of :func:`fit_dip` that :func:`dip` and :class:`DIP` pass on, with defaults.
_FIT_DEFAULTS = {k: p.default for k, p in inspect.signature(fit_dip).parameters.items()
                 if k not in ("y", "A", "x0")}


def _check_fit_kwargs(func: str, fit_kwargs: dict) -> None:
    """``TypeError`` for a name that is no option of :func:`fit_dip`, and the option checks of
    :func:`fit_dip` (:func:`_check_options`), once, before any fit."""
    unknown = sorted(set(fit_kwargs) - set(_FIT_DEFAULTS))
    if unknown:
        raise TypeError(f"{func}: unexpected options {unknown} (the options of fit_dip: "
                        f"{sorted(_FIT_DEFAULTS)})")
    o = {**_FIT_DEFAULTS, **fit_kwargs}
    if o["n_iter"] is not None and "max_iter" not in fit_kwargs:  # the old name
        o["max_iter"] = o["n_iter"]
    _check_options(func, o["max_iter"], o["lr"], o["betas"], o["zeta"], o["early_stop"],
                   o["window"], o["patience"], o["noise_sigma"], o["seed"], o["unet"],
                   o["lr_step"], o["lr_gamma"])


def _dip_batch(y, A, x0, output, func, fit_kwargs):
    """Fit every ``(b, c)`` sample: ``(x, n_iter (B, C), stop reasons [b][c])``. A sample with
    constant buckets is not fitted (:func:`dip`): its image is the constant of the affine
    calibration, 0 for zero buckets (``n_iter`` 0, ``"direct"``)."""
    y, A = _swap_legacy(y, A, func)
    _check_a_y(A, y, func)
    if output not in _OUTPUTS:
        raise ValueError(f"{func}: expected output in {_OUTPUTS}, got {output!r}")
    _check_fit_kwargs(func, fit_kwargs)
    b, c, _ = y.shape
    if x0 is not None:
        check_tensor(x0, "x0", func)
        check_shape(x0, (b, c, A.n, A.n), "x0", func, "(B, C, n, n)")
        check_finite(x0, "x0", func)
    key = "x_cal" if output == "calibrated" else "x"
    x = y.new_zeros(b, c, A.n, A.n)
    iters = torch.zeros(b, c, dtype=torch.int64)
    reasons = []
    yd = y.detach()
    const = (yd.amax(-1) == yd.amin(-1)).tolist()  # one host read: the samples with no contrast
    # (constant buckets, zero spread: the z-scored fit has nothing to fit)
    if isinstance(fit_kwargs.get("noise_sigma"), str):  # "auto": every estimate before any fit
        for i, j in itertools.product(range(b), range(c)):
            # the estimate fit_dip makes of the sample (the same slice: the same number)
            if not const[i][j] and float(tail_noise_sigma(yd[i : i + 1, j : j + 1])[0, 0]) <= 0:
                raise ValueError(f"{func}: noise_sigma='auto' estimated 0 for sample ({i}, {j}) "
                                 "(noise-free tail); pass a noise level")
    # an exact power of two per sample (1 at ordinary scales: bit for bit the same) keeps the
    # calibration's sums finite for buckets near the dtype's ends (1e38 in float32 gave NaN);
    # the network sees z-scored buckets, so only the calibrated image and σ scale with it
    scale = pow2_scale(yd)[..., 0].tolist()  # (B, C), one host read
    for i in range(b):
        row = []
        for j in range(c):
            k = scale[i][j]
            if const[i][j]:
                x[i, j] = _constant_image(yd[i, j] * k, A) / k if key == "x_cal" else 0.0
                row.append("direct")
                continue
            x0_ij = None if x0 is None else x0[i : i + 1, j : j + 1]
            kw = dict(fit_kwargs)
            if not isinstance(kw.get("noise_sigma"), (str, type(None))):
                kw["noise_sigma"] = kw["noise_sigma"] * k
            res = fit_dip(y[i : i + 1, j : j + 1] * k, A, x0=x0_ij, **kw)
            x[i, j] = getattr(res, key)[0, 0].detach() / (k if key == "x_cal" else 1.0)
            iters[i, j] = res.n_iter
            row.append(res.stop_reason)
        reasons.append(tuple(row))
    return x, iters.to(y.device), tuple(reasons)


def _constant_image(y: torch.Tensor, A: LinearOperator) -> torch.Tensor:
    """``(n, n)`` the constant image ``b·1`` with ``b = argmin ‖b·A1 − y‖²`` for the buckets
    ``y (M,)`` of one sample: :func:`fit_dip`'s calibration ``a·x̂ + b`` of a fit that saw no
    contrast (``a = 0``). 0 for zero buckets; the determined image where one measurement of a
    constant image is all there is."""
    with torch.no_grad():
        a1 = A(y.new_ones(1, 1, A.n, A.n)).flatten()
        ab = _affine_coeffs(torch.zeros_like(a1), a1, y)
    return ab[1].expand(A.n, A.n)


def dip(
    y: torch.Tensor,
    A: LinearOperator,
    x0: torch.Tensor | None = None,
    output: str = "calibrated",
    **fit_kwargs,
) -> torch.Tensor:
    """Deep-image-prior reconstruction of a batch: :func:`fit_dip` on every ``(b, c)`` sample.

    Every sample is fitted independently with the same options and seed (a Python loop over
    samples: a DIP fits one network per image), so a batch equals the stacked single fits;
    an empty batch (``B = 0``) gives an empty result. A sample whose buckets are constant
    (zero spread, e.g. all zero, or a single measurement) gives the z-scored fit nothing to
    fit: it is not fitted, and its image is the constant ``b`` minimising ``‖b·A1 − y‖²``
    (the calibration of ``x_cal`` without a fitted image; 0 for zero buckets, the exact
    image for one measurement of a constant scene; ``"unit"``: 0), without affecting the
    other samples. With ±1 patterns, non-zero constant buckets do describe a non-constant
    image (``A⁺y``), which this constant does not fit (relative residual near 1, reported as
    ``"direct"``): reconstruct such buckets with :func:`~torchtof.recon.pseudo_inverse`.

    Args:
        y: buckets ``(B, C, M)``.
        A: measurement operator.
        x0: optional network inputs ``(B, C, n, n)`` (one channel per sample); default
            :func:`dip_input`.
        output: ``"calibrated"`` (default): ``x_cal``, the image in the units of ``y``
            (comparable with :func:`~torchtof.recon.pinv.pseudo_inverse` and TVAL3);
            ``"unit"``: ``x``, min-max normalised to ``[0, 1]``.
        **fit_kwargs: options of :func:`fit_dip` (``max_iter``, ``lr``, ``zeta``,
            ``early_stop``, ``seed`` …), checked once before any fit.

    Returns:
        ``(B, C, n, n)`` images, dtype and device of ``y`` (detached: no gradient to ``y``).

    Raises:
        TypeError, ValueError: as :func:`fit_dip` (but constant buckets are no error);
            ``TypeError`` for a name that is no option of :func:`fit_dip`; ``ValueError`` for
            an unknown ``output`` or ``x0`` of the wrong shape, or with ``noise_sigma="auto"``
            for a sample whose estimate is 0 (every sample is estimated before any fit).

    Shape:
        - y: :math:`(B, C, M)`.
        - Output: :math:`(B, C, n, n)`.

    Example:
        >>> from torchtof.operators import Hadamard
        >>> A = Hadamard(16, sr=0.25)
        >>> dip(A(torch.rand(2, 1, 16, 16)), A, max_iter=5).shape
        torch.Size([2, 1, 16, 16])
    """
    return _dip_batch(y, A, x0, output, "dip", fit_kwargs)[0]


class DIP(nn.Module):
    """Module of :func:`dip`: ``forward(y (B, C, M)) -> (B, C, n, n)``.

    The fit runs inside ``forward`` of this wrapper (it is not meant for export: export the
    fitted :class:`UNet` of :func:`fit_dip` instead). :meth:`solve` also returns the
    iterations and stop reason of every sample (``"direct"`` for a sample with constant
    buckets, see :func:`dip`).

    Args:
        A: measurement operator (a submodule).
        output: ``"calibrated"`` (default, units of ``y``) or ``"unit"`` (``[0, 1]``).
        **fit_kwargs: options of :func:`fit_dip` (``max_iter``, ``seed``, ``zeta`` …),
            checked here (``TypeError`` for a name that is no option of :func:`fit_dip`,
            ``TypeError``/``ValueError`` for a bad value, as :func:`fit_dip`).

    Example:
        >>> from torchtof.operators import Hadamard
        >>> A = Hadamard(16, sr=0.25)
        >>> DIP(A, max_iter=5)(A(torch.rand(1, 1, 16, 16))).shape
        torch.Size([1, 1, 16, 16])
    """

    def __init__(self, A: LinearOperator, output: str = "calibrated", **fit_kwargs) -> None:
        super().__init__()
        if not isinstance(A, LinearOperator):
            raise TypeError(f"DIP: expected A to be a LinearOperator, got {type(A).__name__}")
        if output not in _OUTPUTS:
            raise ValueError(f"DIP: expected output in {_OUTPUTS}, got {output!r}")
        if "n_iter" in fit_kwargs:
            fit_kwargs["max_iter"] = renamed_option(
                "DIP", "n_iter", "max_iter", fit_kwargs.pop("n_iter"),
                fit_kwargs.get("max_iter", 300), 300)
        _check_fit_kwargs("DIP", fit_kwargs)
        self.A = A
        self.output = output
        self.fit_kwargs = dict(fit_kwargs)

    def solve(self, y: torch.Tensor) -> ReconResult:
        """:class:`~torchtof.recon.base.ReconResult`: ``n_iter`` per sample, ``converged``
        where the early stop ended the fit before ``max_iter``, ``stop_reason[b][c]`` in
        ``"wmv"``, ``"discrepancy"``, ``"max_iter"`` (``"direct"``: constant buckets, not
        fitted, :func:`dip`)."""
        x, iters, reasons = _dip_batch(y, self.A, None, self.output, "DIP", self.fit_kwargs)
        with torch.no_grad():
            res = relative_residual(x, y.detach(), self.A)
        conv = torch.tensor([[r != "max_iter" for r in row] for row in reasons],
                            dtype=torch.bool).reshape(iters.shape).to(y.device)
        return ReconResult(x, iters, res, conv, reasons)

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        return dip(y, self.A, output=self.output, **self.fit_kwargs)
