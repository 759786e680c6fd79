"""Noise of a CW-ToF pixel: shot noise per tap, read noise, full well and the ADC.

The taps of :func:`~torchtof.sensor.functional.correlation_taps` are expected in
photo-electrons (e⁻). The chain (Lange & Seitz, IEEE J. Quantum Electron. 37(3), 2001) is

.. math::

    c_k \\xrightarrow{\\text{shot}} \\mathrm{Poisson}(c_k)
        \\xrightarrow{\\text{full well}} \\min(\\cdot, W)
        \\xrightarrow{\\text{read}} {} + σ_r\\,\\mathcal N(0, 1)
        \\xrightarrow{\\text{ADC}} \\mathrm{round}(\\mathrm{clip}(\\cdot / g,\\ 0,\\ 2^{b} − 1)),

``g`` the conversion gain in e⁻/DN and ``b`` the ADC bit depth. The well saturates in the
charge domain, before the readout adds its noise (the linear camera model of EMVA
Standard 1288, Release 4.0, 2021: photo-electrons, then the readout's dark noise, then the
quantiser), so a saturated pixel still reads with the read noise's variance; the ADC's own
clip is the only bound on the digital number. Every random draw takes an
explicit ``torch.Generator`` (on the tensor's device), so a seeded run is reproducible;
with no shot noise, zero read noise, no full well and no ADC the chain is the identity.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from .._checks import check_finite, check_int, check_positive, check_shape, is_tracing
from .functional import check_real

__all__ = ["SHOT_MODES", "shot_noise", "read_noise", "adc_quantize", "tof_noise", "ToFNoise"]

SHOT_MODES = ("poisson", "gaussian")

#: Means (e⁻) above which ``shot_noise(mode="poisson")`` draws the normal approximation
#: ``N(c, c)`` instead of ``torch.poisson`` (2⁴⁰ ≈ 1.1e12: the skewness ``c^{-1/2}`` of
#: the Poisson law is below 1e-6 there, while ``torch.poisson`` stays exact up to ~1e15).
POISSON_MAX_MEAN = float(2**40)


def _check_taps(taps: object, func: str) -> torch.Tensor:
    check_real(taps, "taps", func)
    check_shape(taps, (None, 4, None, None), "taps", func, "(B, 4, H, W)")
    check_finite(taps, "taps", func)
    return taps


def _check_bits(bits: object, name: str, func: str) -> int:
    bits = check_int(bits, name, func)  # numpy integers too, as everywhere
    if not 1 <= bits <= 32:
        raise ValueError(f"{func}: expected {name} in [1, 32], got {bits}")
    return bits


def _check_generator(generator: object, func: str) -> None:
    """``None`` or a ``torch.Generator`` (checked even where no noise is drawn)."""
    if generator is not None and not isinstance(generator, torch.Generator):
        raise TypeError(f"{func}: expected generator to be a torch.Generator or None, got "
                        f"{type(generator).__name__}")


def check_noise_config(
    func: str,
    shot: str | None,
    read_noise_e: float,
    full_well_e: float | None,
    adc_bits: int | None,
    gain_e_per_dn: float,
) -> None:
    """Validate the noise parameters shared by :func:`tof_noise` and the modules."""
    if shot is not None and shot not in SHOT_MODES:
        raise ValueError(f"{func}: expected shot in {SHOT_MODES} or None, got {shot!r}")
    check_positive(read_noise_e, "read_noise_e", func, strict=False)
    if full_well_e is not None:
        check_positive(full_well_e, "full_well_e", func)
    if adc_bits is not None:
        _check_bits(adc_bits, "adc_bits", func)
    check_positive(gain_e_per_dn, "gain_e_per_dn", func)


def _randn_like(x: torch.Tensor, generator: torch.Generator | None) -> torch.Tensor:
    return torch.randn(x.shape, generator=generator, dtype=x.dtype, device=x.device)


def _safe_sqrt(x: torch.Tensor) -> torch.Tensor:
    """``sqrt(max(x, 0))`` with a zero (not infinite) gradient at ``x ≤ 0``."""
    pos = x > 0
    return torch.where(
        pos, torch.sqrt(torch.where(pos, x, torch.ones_like(x))), torch.zeros_like(x)
    )


def shot_noise(
    taps: torch.Tensor, mode: str = "poisson", generator: torch.Generator | None = None
) -> torch.Tensor:
    """Photon shot noise on each tap (Lange & Seitz, 2001).

    ``"poisson"`` draws ``Poisson(c_k)`` exactly with ``torch.poisson`` (above
    :data:`POISSON_MAX_MEAN` e⁻ from its normal approximation, rounded and never negative:
    ``torch.poisson`` overflows near 1e19); its gradient is passed
    straight through (``∂/∂c`` of the mean, i.e. 1). ``"gaussian"`` is the reparameterised
    normal approximation ``c + sqrt(c)·ε``, ``ε ~ N(0, 1)``, whose pathwise gradient is exact
    for the approximation (good above ~10 e⁻). Negative taps are treated as 0 e⁻.

    Args:
        taps: real ``(B, 4, H, W)`` taps in photo-electrons.
        mode: ``"poisson"`` or ``"gaussian"``.
        generator: random generator on the taps' device (``None``: the global one).

    Returns:
        Noisy taps ``(B, 4, H, W)``, same dtype.

    Raises:
        TypeError: if ``taps`` is not a real floating tensor.
        ValueError: on a wrong shape, non-finite taps or an unknown ``mode``.

    Example:
        >>> g = torch.Generator().manual_seed(0)
        >>> shot_noise(torch.full((1, 4, 2, 2), 100.0), generator=g).shape
        torch.Size([1, 4, 2, 2])
    """
    func = "shot_noise"
    _check_taps(taps, func)
    _check_generator(generator, func)
    if mode not in SHOT_MODES:
        raise ValueError(f"{func}: expected mode in {SHOT_MODES}, got {mode!r}")
    rate = taps.clamp_min(0)
    if mode == "poisson":
        r = rate.detach()
        big = r > POISSON_MAX_MEAN
        if is_tracing() or r.is_meta or not bool(big.any()):  # one check per call
            counts = torch.poisson(r, generator=generator)
        else:
            # torch.poisson converts through int64 and wraps to −9.2e18 above ~9e18 (and
            # its spread drifts from 1e17 on): above POISSON_MAX_MEAN draw the normal
            # approximation N(c, c), rounded to counts and never negative
            counts = torch.poisson(torch.where(big, torch.zeros_like(r), r), generator=generator)
            approx = torch.round(r + _safe_sqrt(r) * _randn_like(r, generator)).clamp_min(0)
            counts = torch.where(big, approx, counts)
        return rate + (counts - rate).detach()
    return rate + _safe_sqrt(rate) * _randn_like(rate, generator)


def read_noise(
    taps: torch.Tensor, sigma_e: float, generator: torch.Generator | None = None
) -> torch.Tensor:
    """Additive Gaussian read noise ``c + σ_r·ε``, ``ε ~ N(0, 1)`` (Lange & Seitz, 2001).

    Args:
        taps: real ``(B, 4, H, W)`` taps in photo-electrons.
        sigma_e: read-noise standard deviation in e⁻, ``≥ 0`` (0: identity, no draw).
        generator: random generator on the taps' device (``None``: the global one).

    Returns:
        Taps ``(B, 4, H, W)``, same dtype; the gradient is the identity.

    Raises:
        TypeError: if ``taps`` is not a real floating tensor.
        ValueError: on a wrong shape, non-finite taps or a negative ``sigma_e``.

    Example:
        >>> read_noise(torch.ones(1, 4, 1, 1), 0.0).flatten().tolist()
        [1.0, 1.0, 1.0, 1.0]
    """
    func = "read_noise"
    _check_taps(taps, func)
    _check_generator(generator, func)
    sigma = check_positive(sigma_e, "sigma_e", func, strict=False)
    if sigma == 0.0:
        return taps
    return taps + sigma * _randn_like(taps, generator)


def _digits(dtype: torch.dtype) -> int:
    """Significand bits of a floating dtype (11, 8, 24, 53): it holds every integer up to
    ``2^digits`` exactly."""
    return round(-math.log2(torch.finfo(dtype).eps)) + 1


def _check_bits_dtype(bits: int, dtype: torch.dtype, name: str, func: str) -> None:
    """float16/bfloat16 taps cannot hold the codes of an ADC wider than their significand
    (4095 rounds to 4096 in both, 65535 overflows float16): a ``ValueError`` naming ``name``.
    float32 keeps every depth up to 32 bits (above 24 the top code saturates one step of the
    float32 grid below ``2^b``, :func:`_full_scale`)."""
    if dtype in (torch.float16, torch.bfloat16) and bits > _digits(dtype):
        raise ValueError(
            f"{func}: expected {name} <= {_digits(dtype)} for {dtype} taps (larger codes are "
            f"not all representable: 2^{bits} − 1 = {2**bits - 1}), got {bits}; pass float32 "
            "taps")


def _full_scale(bits: int, dtype: torch.dtype) -> float:
    """The largest value of ``dtype`` that is ``<= 2^bits − 1``: ``2^bits − 1`` itself where
    the dtype holds it (float64; float32 up to 24 bits), else the value below ``2^bits`` on
    the dtype's grid (``2^32 − 1`` rounds up to ``2^32`` in float32)."""
    digits = _digits(dtype)
    top = 2**bits - 1 if bits <= digits else 2**bits - 2 ** (bits - digits)
    return float(min(top, torch.finfo(dtype).max))


def adc_quantize(taps: torch.Tensor, bits: int = 12, gain_e_per_dn: float = 1.0) -> torch.Tensor:
    """Analogue-to-digital conversion: gain, saturation and rounding.

    .. math::

        \\mathrm{DN} = \\mathrm{round}\\big(\\mathrm{clip}(c / g,\\ 0,\\ 2^{b} − 1)\\big)

    The rounding passes its gradient straight through (Bengio et al., 2013), so the
    output has gradient ``1/g`` where the ADC is not saturated and 0 where it clips.
    float16 and bfloat16 taps take at most 11 and 8 bits (the integers they hold exactly);
    in float32 above 24 bits the output saturates at the largest float32 below ``2^b``
    (``2^32 − 1`` itself rounds up to ``2^32``), never above ``2^b − 1``.

    Args:
        taps: real ``(B, 4, H, W)`` taps in photo-electrons.
        bits: ADC bit depth ``b`` (the OPT8241 delivers 12 bits), in ``[1, 32]``.
        gain_e_per_dn: conversion gain ``g`` in e⁻ per digital number, ``> 0``.

    Returns:
        Taps in digital numbers ``(B, 4, H, W)``, integer-valued, same dtype.

    Raises:
        TypeError: if ``taps`` is not a real floating tensor or ``bits`` not an int.
        ValueError: on a wrong shape, non-finite taps, ``bits`` outside ``[1, 32]`` (or
            above 11 for float16, 8 for bfloat16 taps) or a non-positive gain.

    Example:
        >>> adc_quantize(torch.tensor([-3.0, 2.4, 2.6, 9e9]).view(1, 4, 1, 1)).flatten().tolist()
        [0.0, 2.0, 3.0, 4095.0]
    """
    func = "adc_quantize"
    _check_taps(taps, func)
    _check_bits(bits, "bits", func)
    _check_bits_dtype(bits, taps.dtype, "bits", func)
    gain = check_positive(gain_e_per_dn, "gain_e_per_dn", func)
    dn = (taps / gain).clamp(0.0, _full_scale(bits, taps.dtype))
    return dn + (torch.round(dn) - dn).detach()


def tof_noise(
    taps: torch.Tensor,
    shot: str | None = "poisson",
    read_noise_e: float = 0.0,
    full_well_e: float | None = None,
    adc_bits: int | None = 12,
    gain_e_per_dn: float = 1.0,
    generator: torch.Generator | None = None,
) -> torch.Tensor:
    """The full noise chain of a ToF pixel: shot → full well → read → ADC.

    See the module docstring for the model (Lange & Seitz, 2001; EMVA 1288). Shot noise is
    drawn before read noise from the same ``generator``; the full well clips the collected
    electrons at ``full_well_e`` (pixel saturation, in the charge domain, before the readout
    adds its noise); the ADC (:func:`adc_quantize`) converts to digital
    numbers. With ``shot=None``, ``read_noise_e=0``, ``full_well_e=None`` and
    ``adc_bits=None`` the taps are returned unchanged (in e⁻).

    Args:
        taps: real ``(B, 4, H, W)`` taps in photo-electrons.
        shot: ``"poisson"``, ``"gaussian"`` (see :func:`shot_noise`) or ``None``.
        read_noise_e: read-noise standard deviation in e⁻, ``≥ 0``.
        full_well_e: full-well capacity in e⁻ (``None``: unlimited).
        adc_bits: ADC bit depth, or ``None`` to skip the ADC (output stays in e⁻).
        gain_e_per_dn: ADC conversion gain in e⁻/DN (used only with an ADC).
        generator: random generator on the taps' device (``None``: the global one).

    Returns:
        Noisy taps ``(B, 4, H, W)``: digital numbers with an ADC, e⁻ without.

    Raises:
        TypeError, ValueError: as the stages they come from.

    Example:
        >>> x = torch.rand(2, 4, 3, 3) * 100
        >>> torch.equal(tof_noise(x, shot=None, adc_bits=None), x)
        True
    """
    func = "tof_noise"
    _check_taps(taps, func)
    _check_generator(generator, func)
    check_noise_config(func, shot, read_noise_e, full_well_e, adc_bits, gain_e_per_dn)
    if adc_bits is not None:  # before drawing any noise
        _check_bits_dtype(adc_bits, taps.dtype, "adc_bits", func)
    if shot is not None:
        taps = shot_noise(taps, shot, generator)
    if full_well_e is not None:
        taps = taps.clamp_max(float(full_well_e))
    taps = read_noise(taps, read_noise_e, generator)
    if adc_bits is not None:
        taps = adc_quantize(taps, adc_bits, gain_e_per_dn)
    return taps


class ToFNoise(nn.Module):
    """Module wrapper of :func:`tof_noise`; ``forward(taps, generator=None)``.

    Example:
        >>> noise = ToFNoise(shot="gaussian", read_noise_e=2.0)
        >>> noise(torch.full((1, 4, 2, 2), 50.0), torch.Generator().manual_seed(0)).shape
        torch.Size([1, 4, 2, 2])
    """

    def __init__(
        self,
        shot: str | None = "poisson",
        read_noise_e: float = 0.0,
        full_well_e: float | None = None,
        adc_bits: int | None = 12,
        gain_e_per_dn: float = 1.0,
    ) -> None:
        super().__init__()
        check_noise_config("ToFNoise", shot, read_noise_e, full_well_e, adc_bits, gain_e_per_dn)
        self.shot = shot
        self.read_noise_e = float(read_noise_e)
        self.full_well_e = full_well_e
        self.adc_bits = adc_bits
        self.gain_e_per_dn = float(gain_e_per_dn)

    def forward(self, taps: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
        return tof_noise(
            taps,
            self.shot,
            self.read_noise_e,
            self.full_well_e,
            self.adc_bits,
            self.gain_e_per_dn,
            generator,
        )

    def extra_repr(self) -> str:
        return (
            f"shot={self.shot!r}, read_noise_e={self.read_noise_e}, "
            f"full_well_e={self.full_well_e}, adc_bits={self.adc_bits}, "
            f"gain_e_per_dn={self.gain_e_per_dn}"
        )
