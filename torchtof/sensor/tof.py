"""The CW-ToF camera: phasors in, the four taps, amplitude, phase and depth out.

One call runs the whole pixel model of the paper's §2.1–2.2: correlation taps (Eq. 6, Fig. 1
tap order), shot/read noise, full well and ADC (Lange & Seitz 2001), phase (Eq. 7),
amplitude (Eq. 8), depth (Eq. 1) and the camera's output rules (§2.2).

**Frames.** A sequence of ``M`` frames (one per DMD pattern) is passed as the batch
dimension: ``(M, 1, H, W)`` for one scene, ``(B·M, 1, H, W)`` for ``B`` scenes (reshape the
outputs back with ``.view(B, M, ...)``). Ranks are strict: a single frame is
``(1, 1, H, W)``. Noise is drawn for the whole batch from one generator, so a seeded batch is
reproducible but differs from the same frames drawn one by one.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import nn

from .._checks import check_finite, check_positive, check_rank
from .functional import (
    check_order,
    check_phasor,
    check_real,
    check_rules_config,
    correlation_taps,
)
from .noise import check_noise_config, tof_noise
from .readout import camera_readout

__all__ = ["ToFFrame", "cw_tof_sensor", "CWToFSensor"]

_CONFIG_KEYS = (
    "freq_hz",
    "order",
    "ambient_e",
    "shot",
    "read_noise_e",
    "full_well_e",
    "adc_bits",
    "gain_e_per_dn",
    "min_m",
    "max_m",
    "amp_threshold",
    "no_photon_m",
    "step_m",
)


class ToFFrame(NamedTuple):
    """Output of the ToF sensor, one entry per frame of the batch.

    Attributes:
        taps: ``(B, 4, H, W)`` noisy taps in the Fig. 1 order (``τ = 0, π, π/2, 3π/2``);
            digital numbers with an ADC, photo-electrons without.
        amplitude: ``(B, 1, H, W)`` Eq. 8 amplitude (``|P|/2`` noise-free), units of ``taps``.
        phase: ``(B, 1, H, W)`` Eq. 7 phase in ``[0, 2π)`` radians.
        depth: ``(B, 1, H, W)`` depth in metres after the camera rules.
    """

    taps: torch.Tensor
    amplitude: torch.Tensor
    phase: torch.Tensor
    depth: torch.Tensor


def _check_camera_config(
    func: str, freq_hz: float, ambient_e: float, min_m: float, max_m: float,
    amp_threshold: float, no_photon_m: float, step_m: float | None,
) -> None:
    check_positive(freq_hz, "freq_hz", func)
    check_positive(ambient_e, "ambient_e", func, strict=False)
    check_rules_config(func, min_m, max_m, amp_threshold, no_photon_m, step_m)


def cw_tof_sensor(
    phasor: torch.Tensor,
    intensity: torch.Tensor | None = None,
    *,
    freq_hz: float = 30e6,
    order: str = "fig1",
    ambient_e: float = 0.0,
    shot: str | None = "poisson",
    read_noise_e: float = 0.0,
    full_well_e: float | None = None,
    adc_bits: int | None = 12,
    gain_e_per_dn: float = 1.0,
    min_m: float = 1.0,
    max_m: float = 5.0,
    amp_threshold: float = 0.0,
    no_photon_m: float = 5.0,
    step_m: float | None = None,
    generator: torch.Generator | None = None,
) -> ToFFrame:
    """Simulate a CW-ToF camera frame from the phasor each pixel receives (paper §2.1–2.2).

    .. math::

        c_k &= B + \\tfrac12\\mathrm{Re}(P e^{jτ_k}), \\quad B = B_{amb} + I
            &&\\text{(Eq. 6)}\\\\
        \\tilde c_k &= \\mathrm{ADC}(\\min(\\mathrm{Poisson}(c_k) + σ_r ε, W))
            &&\\text{(Lange \\& Seitz, 2001)}\\\\
        θ &= \\operatorname{atan2}(\\tilde c_4 − \\tilde c_3, \\tilde c_1 − \\tilde c_2)
            &&\\text{(Eq. 7)}\\\\
        A &= \\tfrac12\\sqrt{(\\tilde c_4 − \\tilde c_3)^2 + (\\tilde c_1 − \\tilde c_2)^2}
            &&\\text{(Eq. 8)}\\\\
        d &= \\mathrm{rules}(cθ/(4πf), A) &&\\text{(Eq. 1, §2.2)}

    The tap offset ``B`` is the ambient light plus ``I``, the unmodulated part of the
    returned light per tap. ``I`` defaults to ``|P|/2`` (one fully modulated return: taps in
    ``[0, |P|]``); pass ``intensity`` for mixed or multipath pixels, where the unmodulated
    light is ``Σ_j a_j/2 ≥ |P|/2``. Noise-free (``shot=None``, ``read_noise_e=0``,
    ``full_well_e=None``, ``adc_bits=None``) the phase, amplitude ``|P|/2`` and depth are
    recovered exactly up to the wrap at ``c/(2f)`` and the camera rules.

    Frames of a sequence go in the batch dimension (see the module docstring).

    Args:
        phasor: complex ``(B, 1, H, W)`` phasor per pixel, in photo-electrons.
        intensity: real ``(B, 1, H, W)`` unmodulated signal per tap in e⁻, ``≥ |P|/2``
            (default ``|P|/2``).
        freq_hz: modulation frequency in Hz (30 MHz: range 4.997 m).
        order: tap order, ``"fig1"`` or ``"text"`` (see
            :func:`~torchtof.sensor.functional.correlation_taps`; Eq. 7 needs ``"fig1"``).
        ambient_e: ambient-light offset per tap in e⁻, ``≥ 0``.
        shot: shot noise, ``"poisson"``, ``"gaussian"`` or ``None``.
        read_noise_e: read-noise standard deviation in e⁻.
        full_well_e: full-well capacity in e⁻ (``None``: unlimited).
        adc_bits: ADC bit depth (12 for the OPT8241) or ``None`` for no ADC.
        gain_e_per_dn: ADC conversion gain in e⁻/DN.
        min_m, max_m: depth clip range of the camera in metres (paper: 1 and 5).
        amp_threshold: "no photon" threshold on the Eq. 8 amplitude (units of the taps).
        no_photon_m: depth of dark pixels in metres (paper: 5).
        step_m: output depth step in metres (paper: 0.25) or ``None``.
        generator: random generator on the phasor's device (``None``: the global one).

    Returns:
        :class:`ToFFrame` ``(taps, amplitude, phase, depth)``, real tensors of the phasor's
        real dtype (``float32`` for ``complex64``).

    Raises:
        TypeError: if ``phasor`` is not complex or ``intensity`` is not real.
        ValueError: on wrong shapes, non-finite input or invalid parameters.

    Shape:
        - phasor, intensity: :math:`(B, 1, H, W)`
        - taps: :math:`(B, 4, H, W)`; amplitude, phase, depth: :math:`(B, 1, H, W)`

    Example:
        >>> from torchtof.sensor.functional import phasor_from_depth
        >>> p = phasor_from_depth(100.0, torch.full((1, 1, 2, 2), 2.0), 30e6)
        >>> frame = cw_tof_sensor(p, shot=None, adc_bits=None)
        >>> round(frame.depth[0, 0, 0, 0].item(), 4), round(frame.amplitude[0, 0, 0, 0].item(), 3)
        (2.0, 50.0)
    """
    func = "cw_tof_sensor"
    check_phasor(phasor, func)
    check_order(order, func)
    _check_camera_config(func, freq_hz, ambient_e, min_m, max_m, amp_threshold, no_photon_m,
                         step_m)
    check_noise_config(func, shot, read_noise_e, full_well_e, adc_bits, gain_e_per_dn)
    if intensity is None:
        intensity = 0.5 * phasor.abs()
    else:
        check_real(intensity, "intensity", func)
        check_rank(intensity, 4, "intensity", func, "(B, 1, H, W)")
        if intensity.shape != phasor.shape:
            raise ValueError(
                f"{func}: expected intensity of shape {tuple(phasor.shape)} (as phasor), "
                f"got {tuple(intensity.shape)}"
            )
        check_finite(intensity, "intensity", func)
        # Each return of amplitude a_j brings a_j/2 of unmodulated light per tap, and
        # |Σ a_j e^{jφ_j}| ≤ Σ a_j (triangle inequality), so I ≥ |P|/2; below it a tap
        # c = B + ½Re(P e^{jτ}) would be negative for zero ambient light. The relative slack
        # 1e-4 absorbs the rounding of an I computed by the same optics as P.
        half = 0.5 * phasor.abs()
        short = intensity < half * (1.0 - 1e-4)
        if bool(short.any()):
            k = int(short.flatten().nonzero()[0])
            raise ValueError(
                f"{func}: expected intensity >= |phasor|/2 (the unmodulated light of a "
                f"return is at least half its modulated amplitude), got "
                f"{float(intensity.flatten()[k]):.6g} < {float(half.flatten()[k]):.6g} at "
                f"flat index {k}"
            )
    taps = correlation_taps(phasor, float(ambient_e) + intensity, order)
    taps = tof_noise(taps, shot, read_noise_e, full_well_e, adc_bits, gain_e_per_dn, generator)
    amplitude, phase, depth = camera_readout(
        taps, freq_hz=freq_hz, min_m=min_m, max_m=max_m, amp_threshold=amp_threshold,
        no_photon_m=no_photon_m, step_m=step_m,
    )
    return ToFFrame(taps, amplitude, phase, depth)


class CWToFSensor(nn.Module):
    """Module wrapper of :func:`cw_tof_sensor`; ``forward(phasor, intensity=None, generator=None)``.

    Holds the camera configuration (the keyword arguments of :func:`cw_tof_sensor`, as plain
    attributes, validated here; :attr:`config` returns them as a dict); no buffers or
    parameters.

    Example:
        >>> sensor = CWToFSensor(freq_hz=30e6, shot=None, adc_bits=None, step_m=0.25)
        >>> p = torch.full((3, 1, 4, 4), 50.0 + 0j)  # zero phase: depth 0 -> clipped to 1 m
        >>> sensor(p).depth.unique().tolist()
        [1.0]
    """

    def __init__(
        self,
        freq_hz: float = 30e6,
        order: str = "fig1",
        ambient_e: float = 0.0,
        shot: str | None = "poisson",
        read_noise_e: float = 0.0,
        full_well_e: float | None = None,
        adc_bits: int | None = 12,
        gain_e_per_dn: float = 1.0,
        min_m: float = 1.0,
        max_m: float = 5.0,
        amp_threshold: float = 0.0,
        no_photon_m: float = 5.0,
        step_m: float | None = None,
    ) -> None:
        super().__init__()
        func = "CWToFSensor"
        check_order(order, func)
        _check_camera_config(func, freq_hz, ambient_e, min_m, max_m, amp_threshold, no_photon_m,
                             step_m)
        check_noise_config(func, shot, read_noise_e, full_well_e, adc_bits, gain_e_per_dn)
        config = dict(
            freq_hz=float(freq_hz),
            order=order,
            ambient_e=float(ambient_e),
            shot=shot,
            read_noise_e=float(read_noise_e),
            full_well_e=full_well_e,
            adc_bits=adc_bits,
            gain_e_per_dn=float(gain_e_per_dn),
            min_m=float(min_m),
            max_m=float(max_m),
            amp_threshold=float(amp_threshold),
            no_photon_m=float(no_photon_m),
            step_m=step_m,
        )
        for key, value in config.items():
            setattr(self, key, value)

    def forward(
        self,
        phasor: torch.Tensor,
        intensity: torch.Tensor | None = None,
        generator: torch.Generator | None = None,
    ) -> ToFFrame:
        return cw_tof_sensor(phasor, intensity, generator=generator, **self.config)

    @property
    def config(self) -> dict:
        """The keyword arguments passed to :func:`cw_tof_sensor`."""
        return {key: getattr(self, key) for key in _CONFIG_KEYS}

    def extra_repr(self) -> str:
        return ", ".join(f"{k}={v!r}" for k, v in self.config.items())
