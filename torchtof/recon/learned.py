"""Learned proximal-gradient reconstructor: one small CNN prior for every size, SR and order.

An unrolled proximal-gradient iteration (deep unfolding: ISTA-Net, Zhang & Ghanem, CVPR
2018; learned proximal gradient descent, Mardani et al., NeurIPS 2018) with the exact
operator at every step and one convolutional prior shared by all ``K`` steps. From
``x_0 = Aᵀ b`` (the pseudo-inverse for orthonormal rows, ``A Aᵀ = I``; Gong 2015), or with
``x0="markov"`` from the Gaussian–Markov completion of ``b``
(:func:`torchtof.recon.gauss.markov_completion`):

.. math::
    z_k &= x_{k-1} - γ_k\\, Aᵀ(A x_{k-1} - b) \\\\
    x_k &= z_k + R_θ(z_k;\\ c_k), \\qquad k = 1 … K

followed by one noise-weighted data-consistency step

.. math::
    x = x_K + w\\, Aᵀ(b - A x_K), \\qquad w = \\frac{1}{1 + (σ_n / τ)^2},

the exact projection onto ``{A x = b}`` for noise-free buckets (``w = 1``) and a Wiener-like
shrinkage of it as the noise grows (``τ``: one scalar, set by
:func:`~torchtof.recon.learned_train.calibrate_tau` on training data).
``γ_k = 2 sigmoid(g_k) ∈ (0, 2)`` are learned step sizes (``A Aᵀ = I`` makes ``AᵀA`` a
projector, so any ``γ`` in that interval is a contraction of the data term). ``R_θ`` is a
residual two-scale CNN (a small U-Net, Ronneberger et al. 2015; ``scales=S`` deepens it to
``S`` resolutions) whose weights are the same at every step; it is told what varies by a
FiLM conditioning (Perez et al., AAAI 2018):
``c_k = (log σ_n, log SR, k/K)`` goes through a two-layer MLP into a per-channel scale and
shift of every hidden layer. ``σ_n`` is the bucket noise std in the normalised units below
(``noise_sigma``: given, or estimated from the high-order tail of ``y`` by
:func:`~torchtof.recon.tval3.bucket_noise_sigma`).

Only convolutions, a stride-2 down- and a transposed up-sampling, and the fast operator act
on the image, so one set of weights applies to every ``n`` divisible by 2 (by
``2^(S-1)·r`` for a prior of ``S`` scales with pixel unshuffle ``r``; the package's Hadamard
sizes 32–256) and every
``(SR, order)``; the work per step is bounded
(``O(n²)`` convolutions plus one ``A`` and one ``Aᵀ``) and there is no data-dependent control
flow (it exports to ONNX).

Scale: ``b = y / s`` with ``s = ν / n`` and the sign of ``⟨1, Aᵀy⟩`` folded into ``s``, where
``ν`` is the noise-corrected norm of the buckets

.. math::
    ν = \\sqrt{\\max(‖y‖_2^2 - M σ^2,\\ ε ‖y‖_2^2)}, \\qquad ε = 10^{-2},

with ``σ`` the bucket noise std (``noise_sigma`` or its estimate). Under the square root is
the method-of-moments estimate of ``‖A x‖²`` (Kay, *Fundamentals of Statistical Signal
Processing: Estimation Theory*, 1993, Ch. 9), unbiased for the true ``σ``: for
``y = A x + e`` with zero-mean noise of covariance ``σ² I_M``,
``E‖y‖² = ‖A x‖² + 2⟨A x, E e⟩ + E‖e‖² = ‖A x‖² + M σ²``; ``ε`` keeps it positive when ``σ``
is over-estimated. So
``s`` is the RMS of the clean ``Aᵀ A x`` over the ``n²`` pixels and ``σ_n = σ / |s|`` the noise
relative to the *signal* at every size. (Weights files before this rule, ``meta["scale"]``
absent, used ``ν = ‖y‖₂``, under which ``σ_n·√SR = σ√M/‖y‖ < 1`` saturates at ``1/√SR`` once
the noise dominates the buckets; they load with that rule.) The output is multiplied back by
``s``: the
reconstructor is equivariant to any non-zero scale, ``f(c y) = c f(y)`` (trained on scenes
in ``[0, 1]``, it applies to physical bucket units and to negative images alike). An
all-zero ``y`` gives an all-zero image.

:class:`~torchtof.operators.DMDSplit` buckets (``2M`` 0/1 frames) are first combined into
the ±1 measurements ``(y⁺ − y⁻)/n`` of the underlying Hadamard operator
(:func:`~torchtof.operators.combine_split`).

Shipped weights: ``torchtof/weights/learned/learned.pt`` with ``recipe.json`` beside it
(command, seed, data recipe, torch version, wall time); trained by
:mod:`torchtof.recon.learned_train` on the procedural scenes of :mod:`torchtof.data`.
"""

from __future__ import annotations

import functools
import math
import os
from pathlib import Path
from typing import NamedTuple

import torch
import torch.nn.functional as F
from torch import nn

from .._checks import (
    built_for_cache,
    check_finite,
    check_real,
    check_shape,
    check_tensor,
    is_tracing,
)
from ..operators.base import LinearOperator
from ..operators.hadamard import Hadamard
from ..operators.split import DMDSplit, combine_split
from .base import pow2_scale, relative_residual
from .gauss import markov_completion
from .tval3 import bucket_noise_sigma
from .unrolled import check_n_layers

__all__ = [
    "Learned",
    "LearnedResult",
    "LearnedPrior",
    "learned",
    "WEIGHTS_FILE",
    "DEFAULT_N_LAYERS",
    "DEFAULT_WIDTH",
    "DEFAULT_SHUFFLE",
    "DEFAULT_SCALES",
    "STOP_REASON",
    "FLIPS",
    "check_weights_file",
]

#: The shipped weights (with ``recipe.json`` in the same folder).
WEIGHTS_FILE = Path(__file__).resolve().parent.parent / "weights" / "learned" / "learned.pt"
#: Unrolled steps ``K`` of the shipped weights.
DEFAULT_N_LAYERS = 6
#: Prior channels and pixel-unshuffle factor without a weights file (:class:`LearnedPrior`).
DEFAULT_WIDTH = 16
DEFAULT_SHUFFLE = 1
#: Resolutions of the prior without a weights file (:class:`LearnedPrior`; files without the
#: key: 2).
DEFAULT_SCALES = 2
#: ``LearnedResult.stop_reason``: the fixed depth ran out (there is no convergence test).
STOP_REASON = "n_layers"
#: Floor of ``σ_n`` inside the log of the conditioning (noise-free buckets).
SIGMA_FLOOR = 1e-3
#: Initial ``τ`` of the final data-consistency weight (module docstring).
TAU_INIT = 0.1
#: ``ε`` of the noise-corrected norm ``ν`` (module docstring).
CLEAN_FLOOR = 1e-2
#: ``meta["scale"]`` of the two normalisations: ``ν`` noise-corrected (this module's) or the
#: noisy ``‖y‖`` (weights files without the key).
SCALE_CLEAN, SCALE_NOISY = "clean", "noisy"
#: The network's starting estimates ``x₀`` (:class:`Learned`, ``x0``): the adjoint ``Aᵀb``
#: (the shipped weights') or the Gaussian–Markov completion (:func:`markov_completion`).
X0_CHOICES = ("adjoint", "markov")
#: Floor added to the noise variance of the Markov start (conditioning; units of the
#: normalised buckets, whose image has unit RMS).
MARKOV_FLOOR = 1e-3


class LearnedResult(NamedTuple):
    """Output of :meth:`Learned.solve`.

    Attributes:
        x: reconstruction ``(B, C, n, n)``.
        n_iter: ``(B, C)`` int64, the unrolled steps run (``n_layers`` for every sample).
        residual: ``‖A x − y‖ / ‖y‖`` per sample ``(B, C)`` (0 for an all-zero ``y``), in the
            measurement space of the operator given (``2M`` frames for a DMD split).
        converged: ``(B, C)`` bool, always ``True``: a fixed-depth network has no stopping
            test, every sample ran its ``n_layers`` steps.
        stop_reason: ``"n_layers"`` per sample, a tuple of tuples ``[b][c]``.
    """

    x: torch.Tensor
    n_iter: torch.Tensor
    residual: torch.Tensor
    converged: torch.Tensor
    stop_reason: tuple


# -- the prior network ----------------------------------------------------------------------


def prior_multiple(scales: int, shuffle: int) -> int:
    """The image sides a prior of ``scales`` resolutions after a pixel unshuffle by
    ``shuffle`` accepts are the multiples of ``2^(scales-1)·shuffle``."""
    return 2 ** (scales - 1) * shuffle


def check_prior_sizes(func: str, width, shuffle, scales, optional: bool = False) -> None:
    """``width`` and ``shuffle`` ints ``>= 1``, ``scales`` an int ``>= 2`` (each may be
    ``None`` if ``optional``: read from a weights file later)."""
    for name, v, lo in (("width", width, 1), ("shuffle", shuffle, 1), ("scales", scales, 2)):
        if optional and v is None:
            continue
        if isinstance(v, bool) or not isinstance(v, int) or v < lo:
            raise ValueError(f"{func}: expected {name} to be an int >= {lo}, got {v!r}")


class LearnedPrior(nn.Module):
    """Residual multi-scale CNN ``R_θ(z; c)`` with FiLM conditioning (module docstring).

    Args:
        width: channels at the first scale (``2^(k-1)·width`` at scale ``k``).
        cond_dim: size of the conditioning vector ``c``.
        hidden: hidden units of the FiLM MLP.
        shuffle: ``r``: the image is first rearranged into ``r²`` channels at ``1/r`` of its
            side (pixel unshuffle, Shi et al., CVPR 2016) and the output rearranged back, so
            the first two scales of the network are ``1/r`` and ``1/(2r)`` of the side
            (``r = 1``: full and half resolution).
        scales: ``S >= 2``, the U-Net's resolutions: ``1/r, 1/(2r), …, 1/(2^(S-1) r)`` of the
            side (``S = 2``: the shipped network). Each scale more about doubles the
            receptive field of one pass (19, 43, 87 pixels for ``S = 2, 3, 4``) and adds
            about 0.8× the multiply-adds of the two-scale prior.

    Raises:
        ValueError: if ``width``, ``shuffle`` are not ints ``>= 1`` or ``scales`` not an int
            ``>= 2``.

    Shape:
        - z: ``(N, 1, H, W)`` with ``H, W`` divisible by ``2^(S-1)·r``; c: ``(N, cond_dim)``.
        - Output: ``(N, 1, H, W)``, the correction added to ``z``.

    Parameters are stored in float32; :meth:`forward` casts them to the input's dtype (a no-op
    for float32), so float64 inputs are computed in float64.
    """

    def __init__(
        self, width: int = 16, cond_dim: int = 3, hidden: int = 32, shuffle: int = 1,
        scales: int = 2,
    ) -> None:
        super().__init__()
        check_prior_sizes("LearnedPrior", width, shuffle, scales)
        w, r, S = width, shuffle, scales
        self.width, self.shuffle, self.scales = w, r, S
        self.inc = nn.Conv2d(r * r, w, 3, padding=1)
        self.enc = nn.Conv2d(w, w, 3, padding=1)
        self.down = nn.Conv2d(w, 2 * w, 3, stride=2, padding=1)
        self.mid1 = nn.Conv2d(2 * w, 2 * w, 3, padding=1)
        self.mid2 = nn.Conv2d(2 * w, 2 * w, 3, padding=1)
        self.up = nn.ConvTranspose2d(2 * w, w, 2, stride=2)
        self.dec = nn.Conv2d(2 * w, w, 3, padding=1)
        self.out = nn.Conv2d(w, r * r, 3, padding=1)
        # FiLM scale and shift for the six hidden activations (inc, enc, down, mid1, mid2, dec)
        sizes = [w, w, 2 * w, 2 * w, 2 * w, w]
        # scales > 2: each further scale k halves the side again and doubles the channels
        # (c = 2^(k-1)·w in, 2c inside), nested between ``mid1`` and ``mid2`` of the scale
        # above it (a U-Net, Ronneberger et al., MICCAI 2015); empty for the shipped S = 2,
        # whose parameter names are unchanged
        self.deeper = nn.ModuleList()
        for k in range(2, S):
            c = 2 ** (k - 1) * w
            self.deeper.append(nn.ModuleDict({
                "down": nn.Conv2d(c, 2 * c, 3, stride=2, padding=1),
                "mid1": nn.Conv2d(2 * c, 2 * c, 3, padding=1),
                "mid2": nn.Conv2d(2 * c, 2 * c, 3, padding=1),
                "up": nn.ConvTranspose2d(2 * c, c, 2, stride=2),
                "dec": nn.Conv2d(2 * c, c, 3, padding=1),
            }))
            sizes += [2 * c, 2 * c, 2 * c, c]
        self.film_sizes = tuple(sizes)
        self.film = nn.Sequential(
            nn.Linear(cond_dim, hidden), nn.SiLU(), nn.Linear(hidden, 2 * sum(self.film_sizes))
        )
        with torch.no_grad():  # start near the identity modulation and a zero correction
            self.film[-1].weight.mul_(0.1)
            self.film[-1].bias.zero_()
            self.out.weight.mul_(0.1)
            self.out.bias.zero_()

    @staticmethod
    def _conv(layer: nn.Module, x: torch.Tensor, **kw) -> torch.Tensor:
        w, b = layer.weight.to(x), layer.bias.to(x)  # dtype and device of the input
        if isinstance(layer, nn.ConvTranspose2d):
            return F.conv_transpose2d(x, w, b, stride=layer.stride)
        return F.conv2d(x, w, b, stride=layer.stride, padding=layer.padding)

    def forward(self, z: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
        lin1, lin2 = self.film[0], self.film[2]
        h = F.silu(F.linear(c, lin1.weight.to(z), lin1.bias.to(z)))
        mod = F.linear(h, lin2.weight.to(z), lin2.bias.to(z))
        gains, shifts = mod.split(sum(self.film_sizes), dim=-1)
        sc = gains.split(self.film_sizes, dim=-1)
        sh = shifts.split(self.film_sizes, dim=-1)

        def act(x: torch.Tensor, i: int) -> torch.Tensor:
            return F.silu(x * (1 + sc[i][..., None, None]) + sh[i][..., None, None])

        r = self.shuffle
        if r > 1:
            z = F.pixel_unshuffle(z, r)
        h0 = act(self._conv(self.inc, z), 0)
        h1 = act(self._conv(self.enc, h0), 1)
        d = act(self._conv(self.down, h1), 2)
        d = act(self._conv(self.mid1, d), 3)
        d = self._deeper(d, 0, act)
        d = act(self._conv(self.mid2, d), 4)
        u = self._conv(self.up, d)
        u = act(self._conv(self.dec, torch.cat((u, h1), dim=1)), 5)
        out = self._conv(self.out, u)
        return F.pixel_shuffle(out, r) if r > 1 else out

    def _deeper(self, x: torch.Tensor, k: int, act) -> torch.Tensor:
        """Scales ``k + 3, …, S`` nested around ``x`` (identity for ``S = 2``)."""
        if k == len(self.deeper):
            return x
        m, i = self.deeper[k], 6 + 4 * k  # FiLM indices of this scale's four activations
        e = act(self._conv(m["down"], x), i)
        e = act(self._conv(m["mid1"], e), i + 1)
        e = self._deeper(e, k + 1, act)
        e = act(self._conv(m["mid2"], e), i + 2)
        u = self._conv(m["up"], e)
        return act(self._conv(m["dec"], torch.cat((u, x), dim=1)), i + 3)


# -- operator plumbing ------------------------------------------------------------------------


def _check_operator(A: object, func: str) -> None:
    if not isinstance(A, LinearOperator):
        raise TypeError(f"{func}: expected A to be a LinearOperator, got {type(A).__name__}")
    if not (isinstance(A, DMDSplit) or A.orthonormal_rows):
        raise ValueError(
            f"{func}: expected A with orthonormal rows (A Aᵀ = I, e.g. Hadamard) or a DMDSplit, "
            f"got {type(A).__name__} with orthonormal_rows=False"
        )
    if A.n % 2:
        raise ValueError(f"{func}: expected A.n divisible by 2, got n={A.n}")


def _base_operator(A: LinearOperator) -> LinearOperator:
    """The orthonormal operator the iteration runs on (a DMD split's Hadamard)."""
    return A.hadamard if isinstance(A, DMDSplit) else A


#: The image flips of the self-ensemble, in order: ``(flip rows, flip columns)``.
FLIPS = ((False, False), (False, True), (True, False), (True, True))


def _flip_signs(op: Hadamard, flips: int, like: torch.Tensor) -> torch.Tensor:
    """``(flips, M)`` ±1: the measurements of each flipped image (:data:`FLIPS`) are the
    measurements of the image times these signs. Row ``a·n + b`` of ``A`` is the Sylvester
    pattern ``H[a, i] H[b, j]`` with ``H[k, j] = (−1)^{popcount(k ∧ j)}``; reversing ``j``
    (``j → n − 1 − j = j ⊕ (n − 1)``) multiplies it by ``(−1)^{popcount(b)}``, reversing
    ``i`` by ``(−1)^{popcount(a)}``."""
    n = op.n
    a, b = op.index // n, op.index % n
    pa, pb = torch.zeros_like(a), torch.zeros_like(b)
    for bit in range(max(1, n.bit_length())):  # parity of the set bits
        pa = pa ^ ((a >> bit) & 1)
        pb = pb ^ ((b >> bit) & 1)
    sa, sb = (1 - 2 * pa).to(like.dtype), (1 - 2 * pb).to(like.dtype)
    one = torch.ones_like(sa)
    return torch.stack([(sa if fi else one) * (sb if fj else one) for fi, fj in FLIPS[:flips]])


def check_flips(flips, A: LinearOperator, func: str) -> None:
    """``flips`` in ``{1, 2, 4}``; above 1 only for a Hadamard operator (or its DMD split)."""
    if isinstance(flips, bool) or not isinstance(flips, int):
        raise TypeError(f"{func}: expected flips to be an int, got {type(flips).__name__}")
    if flips not in (1, 2, 4):
        raise ValueError(f"{func}: expected flips in (1, 2, 4), got {flips}")
    if flips > 1 and not isinstance(_base_operator(A), Hadamard):
        raise ValueError(f"{func}: flips > 1 needs a Hadamard operator (or its DMD split): the "
                         f"sign rule of a flipped image holds for its rows; got "
                         f"{type(A).__name__}")


def check_x0(x0, func: str, optional: bool = True) -> None:
    """``x0`` is one of :data:`X0_CHOICES` (or ``None`` if ``optional``)."""
    if optional and x0 is None:
        return
    if not isinstance(x0, str) or x0 not in X0_CHOICES:
        none = "None or " if optional else ""
        raise ValueError(f"{func}: expected x0 to be {none}one of {X0_CHOICES}, got {x0!r}")


def _sigma_of(noise_sigma, y: torch.Tensor, func: str) -> torch.Tensor:
    """``(B, C)`` noise std in the units of ``y`` (orthonormal measurements)."""
    if isinstance(noise_sigma, str):
        if noise_sigma not in ("auto", "tail"):
            raise ValueError(
                f"{func}: expected noise_sigma to be a number, a tensor or 'auto', "
                f"got {noise_sigma!r}"
            )
        return bucket_noise_sigma(y)
    if isinstance(noise_sigma, torch.Tensor):
        check_tensor(noise_sigma, "noise_sigma", func)
        s = noise_sigma.to(dtype=y.dtype, device=y.device)
        if s.ndim == 1:
            s = s[:, None]
        return s.expand(y.shape[:-1])
    if isinstance(noise_sigma, bool) or not isinstance(noise_sigma, (int, float)):
        raise TypeError(
            f"{func}: expected noise_sigma to be a float, a tensor or 'auto', "
            f"got {type(noise_sigma).__name__}"
        )
    if not math.isfinite(noise_sigma) or noise_sigma < 0:
        raise ValueError(f"{func}: expected noise_sigma >= 0 and finite, got {noise_sigma}")
    return y.new_full(y.shape[:-1], float(noise_sigma))


def _check_noise_tensor(noise_sigma, y: torch.Tensor, func: str) -> None:
    if isinstance(noise_sigma, torch.Tensor) and not is_tracing():
        s = noise_sigma
        ok = s.ndim == 0 or (s.ndim == 1 and s.shape[0] == y.shape[0]) or (
            s.ndim == 2 and tuple(s.shape) == tuple(y.shape[:2])
        )
        if not ok:
            raise ValueError(
                f"{func}: expected noise_sigma of shape (), (B,) or (B, C) = "
                f"{tuple(y.shape[:2])}, got {tuple(s.shape)}"
            )
        check_real(s, "noise_sigma", func)
        if s.numel() and s.device.type != "meta":
            neg, bad = torch.stack(((s < 0).any(), ~s.isfinite().all())).tolist()  # one read
            if bad:
                raise ValueError(f"{func}: expected noise_sigma finite, got a NaN or Inf entry")
            if neg:
                raise ValueError(f"{func}: expected noise_sigma >= 0, got a negative entry")


def _unrolled(
    y: torch.Tensor,
    A: LinearOperator,
    prior: LearnedPrior,
    step_raw: torch.Tensor,
    log_tau: torch.Tensor | None,
    noise_sigma,
    func: str,
    clean_scale: bool = True,
    flips: int = 1,
    x0: str = "adjoint",
) -> torch.Tensor:
    """The iteration of the module docstring; ``y`` already checked. ``clean_scale=False``: the
    normalisation of weights files before the noise-corrected norm (``ν = ‖y‖``). ``flips > 1``:
    the self-ensemble over image flips (:class:`Learned`), run as one batch."""
    if isinstance(A, DMDSplit):
        if noise_sigma is not None and not isinstance(noise_sigma, str):
            # σ of each frame → σ of (y⁺ − y⁻)/n: √2 σ / n
            noise_sigma = noise_sigma * (math.sqrt(2.0) / A.n)
        y = combine_split(y, A.n)
    op = _base_operator(A)
    n, m = op.n, op.m
    fwd, adj = op.loop_pair(y)
    tiny = torch.finfo(y.dtype).tiny
    B, C = y.shape[0], y.shape[1]

    sigma = _sigma_of("auto" if noise_sigma is None else noise_sigma, y, func)  # (B, C)
    # f(c·y) = c·f(y): an exact power of two per sample (1 at ordinary scales, bit for bit
    # the same) keeps the norms below finite for buckets near the dtype's ends (1e38)
    # (eager only: the factor is built from IEEE bits, which the exporters cannot trace; an
    # exported graph keeps the plain normalisation, finite for ordinary buckets)
    p2 = None if is_tracing() else pow2_scale(y)  # (B, C, 1)
    if p2 is not None:
        y, sigma = y * p2, sigma * p2[..., 0]
    B0 = B
    if flips > 1:  # every flipped image's buckets, stacked along the batch
        d = _flip_signs(op, flips, y)  # (F, M)
        y = (y[None] * d[:, None, None, :]).reshape(flips * B, C, m)
        sigma = sigma.repeat(flips, 1)
        B = flips * B
    peak = y.abs().amax(dim=-1, keepdim=True).clamp_min(tiny)  # ‖y‖ without over/underflow
    norm = peak * (y / peak).norm(dim=-1, keepdim=True)  # (B, C, 1)
    xu = adj(y / norm.clamp_min(tiny))  # unit-norm Aᵀ b
    sign = torch.where(xu.sum(dim=(-2, -1)) >= 0, 1.0, -1.0).to(y.dtype)[..., None]  # (B, C, 1)
    if clean_scale:  # ν = √max(‖y‖² − Mσ², ε‖y‖²), in units of the peak (no overflow)
        rel = (norm / peak) ** 2 - m * (sigma[..., None] / peak) ** 2
        norm = peak * torch.maximum(rel, CLEAN_FLOOR * (norm / peak) ** 2).sqrt()
    s = sign * norm / n  # signed RMS scale of Aᵀ y
    b = y / torch.where(s >= 0, s.clamp_min(tiny), s.clamp_max(-tiny))
    sigma_n = sigma / norm[..., 0].clamp_min(tiny) * n  # σ / |s|: the noise std of b
    if x0 == "markov":
        x = markov_completion(b, op, sigma_n[..., None] ** 2 + MARKOV_FLOOR)
    else:
        x = adj(b)
    log_sigma = torch.log(sigma_n.clamp_min(0) + SIGMA_FLOOR)
    log_sr = torch.full_like(log_sigma, math.log(m / (n * n)))
    K = step_raw.shape[0]
    steps = 2 * torch.sigmoid(step_raw.to(y))

    flat = (B * C, 1, n, n)
    bf = b
    x = x.reshape(flat)
    base = torch.stack((log_sigma, log_sr), dim=-1).reshape(B * C, 2)
    for k, g in enumerate(steps.unbind()):
        xi = x.reshape(B, C, n, n)
        z = (xi - g * adj(fwd(xi) - bf)).reshape(flat)
        tk = torch.full_like(base[:, :1], (k + 1) / K)
        x = z + prior(z, torch.cat((base, tk), dim=-1))
    x = x.reshape(B, C, n, n)
    if log_tau is not None:  # final noise-weighted data consistency
        w = 1 / (1 + (sigma_n / torch.exp(log_tau.to(y))) ** 2)  # (B, C)
        x = x + w[..., None, None] * adj(bf - fwd(x))
    x = x * s[..., None]
    if flips > 1:  # flip every estimate back and average them
        xs = x.reshape(flips, B0, C, n, n).unbind(0)
        back = [torch.flip(xf, [d for d, f in zip((-2, -1), fl, strict=True) if f])
                if any(fl) else xf for xf, fl in zip(xs, FLIPS, strict=False)]
        x = torch.stack(back).mean(0)
    return x if p2 is None else x / p2[..., None]


# -- weights -------------------------------------------------------------------------------


@functools.lru_cache(maxsize=4)
@built_for_cache
def _read_blob(path: str) -> dict:
    return torch.load(path, weights_only=True, map_location="cpu")


def _load_blob(path: str, func: str = "Learned") -> dict:
    """The contents of a :meth:`Learned.save_weights` file; a ``ValueError`` naming the file
    when it is something else (a training checkpoint, a log, another format)."""
    try:
        blob = _read_blob(path)
    except Exception as exc:  # noqa: BLE001 - every unpickling failure means "not one"
        raise ValueError(f"{func}: {path!r} is not a learned weights file (Learned.save_weights, "
                         f"a torchtof train run's learned.pt): {type(exc).__name__}") from None
    if not isinstance(blob, dict) or not isinstance(blob.get("prior"), dict):
        raise ValueError(f"{func}: {path!r} is not a learned weights file (Learned.save_weights, "
                         "a torchtof train run's learned.pt): no 'prior' weights in it")
    return blob


def check_weights_file(path: str | os.PathLike, func: str = "check_weights_file") -> dict:
    """The metadata (``n_layers``, ``width``, …; ``{}`` for the oldest files) of a learned
    weights file, read once here; a ``ValueError`` naming the file when it is missing or not
    one (what the command line checks ``--weights`` with before any work)."""
    if not Path(path).is_file():
        raise ValueError(f"{func}: no such weights file: {os.fspath(path)!r}")
    return _load_blob(os.fspath(Path(path).resolve()), func).get("meta", {})


class Learned(nn.Module):
    """Learned proximal-gradient reconstructor with a shared CNN prior (module docstring).

    Args:
        A: :class:`~torchtof.operators.Hadamard` (any ``n`` divisible by 2, any SR and
            order), another operator with orthonormal rows, or a
            :class:`~torchtof.operators.DMDSplit` of a Hadamard operator; held inside.
        n_layers: unrolled steps ``K``; ``None``: the weights file's (:data:`DEFAULT_N_LAYERS`,
            the shipped weights', without one); given, it must match it.
        noise_sigma: bucket noise std in the units of ``y`` (float, ``(B,)`` or ``(B, C)``
            tensor; for a DMD split the std of one frame) or ``"auto"`` (estimated from the
            high-order tail of ``y``, :func:`~torchtof.recon.tval3.bucket_noise_sigma`; meant
            for low-to-high orders such as cake-cutting). The shipped weights were trained with
            the estimate on every sample, the noise-free ones too (it is never 0): keep
            ``"auto"`` for noise-free buckets (``0`` scored 1.2–2.8 dB lower on the held-out
            evaluation, ``docs/learned.md``).
        pretrained: ``True`` loads the shipped weights (:data:`WEIGHTS_FILE`), ``False``
            keeps the random initialisation, a path loads that file.
        width, shuffle, scales: the prior's channels, pixel-unshuffle factor and number of
            resolutions (:class:`LearnedPrior`); ``None``: the weights file's
            (:data:`DEFAULT_WIDTH`, :data:`DEFAULT_SHUFFLE`, :data:`DEFAULT_SCALES` without
            one); given, they must match it.
        flips: ``1`` (default), ``2`` or ``4``: average the reconstructions of the image and
            of its flips (left–right; then up–down and both), a self-ensemble (test-time
            augmentation; Timofte, Rothe & Van Gool, CVPR 2016, "Seven ways to improve
            example-based single image super resolution"). A flipped image's Hadamard
            buckets are the buckets times a sign per row (:data:`FLIPS`), so no new
            measurement is needed; the network is not flip-invariant, so the estimates
            differ and their mean is better on average (measured in ``docs/learned.md``),
            for ``flips`` times the work (one batched call). Hadamard operators and their DMD
            split only.
        x0: the iteration's starting estimate: ``"adjoint"`` (``Aᵀb``, the pseudo-inverse) or
            ``"markov"`` (the Gaussian–Markov completion :func:`markov_completion`, which
            fills the unmeasured coefficients from the measured ones); ``None``: the weights
            file's (``"adjoint"`` for files without it, the shipped weights included). A
            network works best with the estimate it was trained on.

    Raises:
        TypeError: if ``A`` is not a :class:`~torchtof.operators.LinearOperator` or
            ``n_layers`` not an int.
        ValueError: if ``A`` has no orthonormal rows (and is not a DMD split), ``A.n`` is
            not divisible by ``2^(scales-1)·shuffle``, ``scales < 2``, ``n_layers < 1``, the
            weights file does not match, ``flips`` is not 1, 2 or 4 (or above 1 for a
            non-Hadamard operator), or ``x0`` is not one of :data:`X0_CHOICES`.
        FileNotFoundError: if ``pretrained=True`` and the shipped file is missing.

    Shape:
        ``(B, C, M) -> (B, C, n, n)`` (``M = A.m``; ``2M`` frames for a DMD split).

    Example:
        >>> from torchtof.operators import Hadamard
        >>> A = Hadamard(32, sr=0.125)
        >>> net = Learned(A, pretrained=False)
        >>> net(A(torch.rand(2, 1, 32, 32))).shape
        torch.Size([2, 1, 32, 32])
    """

    def __init__(
        self,
        A: LinearOperator,
        n_layers: int | None = None,
        noise_sigma: float | torch.Tensor | str = "auto",
        pretrained: bool | str | os.PathLike = True,
        width: int | None = None,
        shuffle: int | None = None,
        flips: int = 1,
        x0: str | None = None,
        scales: int | None = None,
    ) -> None:
        super().__init__()
        func = "Learned"
        _check_operator(A, func)
        check_x0(x0, func)
        if n_layers is not None:
            check_n_layers(n_layers, func)
        check_flips(flips, A, func)
        check_prior_sizes(func, width, shuffle, scales, optional=True)
        if not isinstance(noise_sigma, torch.Tensor):
            _sigma_of(noise_sigma, torch.zeros(1, 1, 1), func)  # validate once here
        if not isinstance(pretrained, (bool, str, os.PathLike)):
            raise TypeError(f"{func}: expected pretrained to be a bool or a weights file path, "
                            f"got {type(pretrained).__name__}")
        path = None
        if pretrained is True:
            if not WEIGHTS_FILE.is_file():
                raise FileNotFoundError(
                    f"{func}: shipped weights {os.fspath(WEIGHTS_FILE)!r} are missing; "
                    "pass pretrained=False or train them with `torchtof train --model learned`"
                )
            path = WEIGHTS_FILE
        elif pretrained is not False:
            path = pretrained
        # the architecture: the weights file's unless given (a mismatch raises in load_weights)
        file_meta = _load_blob(os.fspath(Path(path).resolve())).get("meta", {}) if path else {}
        if n_layers is None:
            n_layers = int(file_meta.get("n_layers", DEFAULT_N_LAYERS))
        if width is None:
            width = int(file_meta.get("width", DEFAULT_WIDTH))
        if shuffle is None:
            shuffle = int(file_meta.get("shuffle", 1 if file_meta else DEFAULT_SHUFFLE))
        if scales is None:
            scales = int(file_meta.get("scales", 2 if file_meta else DEFAULT_SCALES))
        if A.n % (f := prior_multiple(scales, shuffle)):
            raise ValueError(
                f"{func}: expected A.n divisible by 2^(scales-1)·shuffle = {f}, got n={A.n}")
        self.A = A
        self.n_layers = n_layers
        self.noise_sigma = noise_sigma
        self.flips = flips
        self.prior = LearnedPrior(width=width, shuffle=shuffle, scales=scales)
        self.step_raw = nn.Parameter(torch.zeros(n_layers))
        self.log_tau = nn.Parameter(torch.tensor(math.log(TAU_INIT)))
        #: apply the final data-consistency step (training of the prior switches it off)
        self.final_dc = True
        #: normalise by the noise-corrected norm (module docstring); ``False`` for weights
        #: files written before it (``meta["scale"]`` absent)
        self.clean_scale = True
        self.weights_file: str | None = None
        #: the starting estimate (:data:`X0_CHOICES`): the weights file's unless given
        self.x0 = "adjoint"
        if path is not None:
            self.load_weights(path)
        if x0 is not None:
            self.x0 = x0

    def meta(self) -> dict:
        """What a weights file must match: ``n_layers``, ``width``, ``shuffle``, ``scales``."""
        return {"model": "learned", "n_layers": self.n_layers, "width": self.prior.width,
                "shuffle": self.prior.shuffle, "scales": self.prior.scales}

    def load_weights(self, path: str | os.PathLike) -> None:
        """Load a file written by :meth:`save_weights` (``torch.load(weights_only=True)``).

        Raises:
            ValueError: if its ``n_layers``/``width``/``shuffle``/``scales`` differ from this
                module's.
        """
        blob = _load_blob(os.fspath(Path(path).resolve()))
        # files before ``shuffle``/``scales``: r = 1, S = 2
        meta = {"shuffle": 1, "scales": 2, **blob.get("meta", {})}
        want = self.meta()
        if any(meta.get(k) != v for k, v in want.items()):
            raise ValueError(
                f"Learned.load_weights: weights file {os.fspath(path)!r} holds "
                f"{ {k: meta.get(k) for k in want} }, expected {want}"
            )
        self.clean_scale = meta.get("scale", SCALE_NOISY) == SCALE_CLEAN
        self.x0 = meta.get("x0", "adjoint")
        self.prior.load_state_dict(blob["prior"])
        with torch.no_grad():
            self.step_raw.copy_(blob["step_raw"])
            self.log_tau.copy_(blob["log_tau"])
        self.weights_file = os.fspath(path)

    def save_weights(self, path: str | os.PathLike, **meta: object) -> None:
        """Save the prior, the step sizes and metadata (``meta`` adds training details)."""
        blob = {
            "prior": {k: v.detach().clone() for k, v in self.prior.state_dict().items()},
            "step_raw": self.step_raw.detach().clone(),
            "log_tau": self.log_tau.detach().clone(),
            "meta": {**self.meta(), "scale": SCALE_CLEAN if self.clean_scale else SCALE_NOISY,
                     "x0": self.x0,
                     **meta},
        }
        torch.save(blob, Path(path))
        _read_blob.cache_clear()  # a file rewritten in place is read afresh

    def steps(self) -> torch.Tensor:
        """The step sizes ``γ_k ∈ (0, 2)``, shape ``(K,)``."""
        return 2 * torch.sigmoid(self.step_raw)

    def _check_y(self, y: torch.Tensor, func: str) -> None:
        check_real(y, "y", func)
        check_shape(y, (None, None, self.A.m), "y", func, "(B, C, M)")
        check_finite(y, "y", func)
        _check_noise_tensor(self.noise_sigma, y, func)

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        func = "Learned.forward"
        self._check_y(y, func)
        if y.shape[0] == 0 and not is_tracing():
            return y.new_zeros(0, y.shape[1], self.A.n, self.A.n)
        log_tau = self.log_tau if self.final_dc else None
        return _unrolled(y, self.A, self.prior, self.step_raw, log_tau, self.noise_sigma, func,
                         self.clean_scale, self.flips, self.x0)

    def solve(self, y: torch.Tensor) -> LearnedResult:
        """:meth:`forward` plus the per-sample residual ``‖A x − y‖ / ‖y‖`` and the fields of
        the reconstructor contract (:class:`LearnedResult`)."""
        x = self.forward(y)
        B, C = y.shape[0], y.shape[1]
        with torch.no_grad():
            residual = relative_residual(x, y, self.A) if B else y.new_zeros(B, C)
        return LearnedResult(
            x=x,
            n_iter=torch.full((B, C), self.n_layers, dtype=torch.int64, device=y.device),
            residual=residual,
            converged=torch.ones(B, C, dtype=torch.bool, device=y.device),
            stop_reason=tuple(tuple(STOP_REASON for _ in range(C)) for _ in range(B)),
        )

    def extra_repr(self) -> str:
        return (
            f"n_layers={self.n_layers}, noise_sigma={self.noise_sigma!r}, flips={self.flips}, "
            f"x0={self.x0!r}, "
            f"clean_scale={self.clean_scale}, weights_file={self.weights_file!r}"
        )


def learned(
    y: torch.Tensor,
    A: LinearOperator,
    n_layers: int | None = None,
    noise_sigma: float | torch.Tensor | str = "auto",
    pretrained: bool | str | os.PathLike = True,
    width: int | None = None,
    shuffle: int | None = None,
    flips: int = 1,
    x0: str | None = None,
    scales: int | None = None,
) -> torch.Tensor:
    """Reconstruct ``y = A x`` with the learned proximal-gradient network (:class:`Learned`).

    Args:
        y: buckets ``(B, C, M)``, ``M = A.m`` (``2M`` DMD frames for a DMD split).
        A: the operator (see :class:`Learned`).
        n_layers, noise_sigma, pretrained, width, shuffle, flips, x0, scales: as in
            :class:`Learned`.

    Returns:
        ``(B, C, n, n)`` reconstruction, dtype and device of ``y``; differentiable with
        respect to ``y`` (the network's weights are held fixed: train :class:`Learned`).

    Example:
        >>> from torchtof.operators import Hadamard
        >>> A = Hadamard(32, sr=0.25)
        >>> learned(A(torch.rand(1, 1, 32, 32)), A, pretrained=False).shape
        torch.Size([1, 1, 32, 32])
    """
    check_real(y, "y", "learned")  # before y.device below (Learned.forward checks the rest)
    net = Learned(A, n_layers=n_layers, noise_sigma=noise_sigma, pretrained=pretrained,
                  width=width, shuffle=shuffle, flips=flips, x0=x0, scales=scales)
    # the weights are constants here: the output carries a graph only through ``y``
    return net.requires_grad_(False).to(y.device)(y)
