"""Multipath interference: a delayed, attenuated second return added as a phasor.

A pixel that also receives light over a longer, indirect path (inter-reflection, the prism
and DMD optics) sees the phasor sum (each return's phase: paper Eq. 1)

.. math::

    P' = P + s\\, e^{j 4π f Δ / c}\\, (G_σ * P),

``s`` the relative strength of the indirect return, ``Δ`` its extra path expressed as an
apparent extra distance (the indirect return alone would read depth ``d + Δ``; its total
optical path is ``2Δ`` longer), and ``G_σ`` an optional Gaussian spread of the indirect
light over neighbouring pixels. The camera then measures ``arg(P')`` — a depth between
the two returns, biased towards the stronger one.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from .._checks import check_broadcast, check_finite, check_nonnegative, check_positive
from .functional import SPEED_OF_LIGHT, check_phasor, check_real
from .mixing import blur_phasor

__all__ = ["add_multipath", "Multipath"]


def _check_scalar_or_real(
    value: object, name: str, func: str, phasor: torch.Tensor
) -> torch.Tensor | float:
    """A number ``>= 0``, or a real tensor ``>= 0``, finite, broadcastable to the phasor
    without growing its batch (the same rules for both forms)."""
    if isinstance(value, torch.Tensor):
        check_real(value, name, func)
        check_broadcast(value, phasor.shape, name, func, "(B, 1, H, W)")
        check_finite(value, name, func)
        check_nonnegative(value, name, func)
        return value
    return check_positive(value, name, func, strict=False)


def add_multipath(
    phasor: torch.Tensor,
    strength: torch.Tensor | float,
    extra_path_m: torch.Tensor | float,
    freq_hz: float = 30e6,
    blur_sigma: float | None = None,
) -> torch.Tensor:
    """Add a second, delayed and attenuated copy of the phasor (two-path multipath).

    .. math::

        P' = P + s\\, e^{j 4π f Δ / c}\\, (G_σ * P)

    (phase of a return at distance ``Δ``: paper Eq. 1; the returns add as phasors).

    Args:
        phasor: complex ``(B, 1, H, W)`` direct phasor.
        strength: relative amplitude ``s ≥ 0`` of the indirect return (number or real
            tensor broadcastable to the phasor, e.g. a per-pixel map). ``0`` is the identity.
        extra_path_m: apparent extra distance ``Δ`` in metres (number ``≥ 0`` or real tensor
            ``≥ 0`` broadcastable to the phasor).
        freq_hz: modulation frequency in Hz, ``> 0``.
        blur_sigma: Gaussian spread of the indirect light in pixels (``None``: no spread).

    Returns:
        Complex ``(B, 1, H, W)`` phasor, same dtype.

    Raises:
        TypeError: if ``phasor`` is not complex or a tensor argument is not real.
        ValueError: on a wrong shape, a ``strength``/``extra_path_m`` tensor that does not
            broadcast to the phasor (or would grow its batch), NaN/Inf or negative values
            (numbers or tensors), or a non-positive ``freq_hz``/``blur_sigma``.

    Tensor ``strength``/``extra_path_m`` are moved to the phasor's device and real dtype.

    Shape:
        - phasor: :math:`(B, 1, H, W)`; output: :math:`(B, 1, H, W)`

    Example:
        >>> p = torch.ones(1, 1, 2, 2, dtype=torch.complex64)
        >>> torch.equal(add_multipath(p, 0.0, 1.0), p)
        True
    """
    func = "add_multipath"
    check_phasor(phasor, func)
    strength = _check_scalar_or_real(strength, "strength", func, phasor)
    extra_path_m = _check_scalar_or_real(extra_path_m, "extra_path_m", func, phasor)
    f = check_positive(freq_hz, "freq_hz", func)
    if blur_sigma is not None:
        check_positive(blur_sigma, "blur_sigma", func)
    indirect = phasor if blur_sigma is None else blur_phasor(phasor, blur_sigma)
    if isinstance(extra_path_m, torch.Tensor):  # the maps follow the phasor's device
        extra_path_m = extra_path_m.to(device=phasor.device)
    theta = extra_path_m * (4.0 * math.pi * f / SPEED_OF_LIGHT)
    if isinstance(theta, torch.Tensor):
        theta = theta.to(phasor.real.dtype)
        delay = torch.polar(torch.ones_like(theta), theta)
    else:
        delay = complex(math.cos(theta), math.sin(theta))
    if isinstance(strength, torch.Tensor):
        strength = strength.to(dtype=phasor.real.dtype, device=phasor.device)
    return phasor + strength * delay * indirect


class Multipath(nn.Module):
    """Module wrapper of :func:`add_multipath` with fixed scalar parameters.

    Example:
        >>> mp = Multipath(strength=0.3, extra_path_m=0.5, freq_hz=30e6, blur_sigma=1.0)
        >>> mp(torch.ones(2, 1, 8, 8, dtype=torch.complex64)).shape
        torch.Size([2, 1, 8, 8])
    """

    def __init__(
        self,
        strength: float,
        extra_path_m: float,
        freq_hz: float = 30e6,
        blur_sigma: float | None = None,
    ) -> None:
        super().__init__()
        func = "Multipath"
        self.strength = check_positive(strength, "strength", func, strict=False)
        self.extra_path_m = check_positive(extra_path_m, "extra_path_m", func, strict=False)
        self.freq_hz = check_positive(freq_hz, "freq_hz", func)
        self.blur_sigma = (
            None if blur_sigma is None else check_positive(blur_sigma, "blur_sigma", func)
        )

    def forward(self, phasor: torch.Tensor) -> torch.Tensor:
        return add_multipath(
            phasor, self.strength, self.extra_path_m, self.freq_hz, self.blur_sigma
        )

    def extra_repr(self) -> str:
        return (
            f"strength={self.strength}, extra_path_m={self.extra_path_m}, "
            f"freq_hz={self.freq_hz}, blur_sigma={self.blur_sigma}"
        )
