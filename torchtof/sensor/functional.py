"""CW-ToF correlation model: phasors, the four taps, phase, amplitude, depth and camera rules.

A ToF pixel sees a sum of returns; each return of amplitude ``a_j`` from (one-way) distance
``d_j`` is the phasor ``a_j·e^{jθ_j}`` with ``θ_j = 4πf·d_j/c`` (paper Eq. 1 solved for the
phase), so the pixel's phasor is ``P = Σ_j a_j e^{jθ_j}``. The four correlation taps sample
the cross-correlation of Eq. 6 at four delays ``τ_k``:

.. math::

    c_k = B + \\tfrac{|P|}{2}\\cos(θ + τ_k) = B + \\tfrac12\\,\\mathrm{Re}(P e^{jτ_k}),

linear in ``P``, so multipath returns and mixed (flying) pixels are phasor sums. The camera
then computes the phase (Eq. 7), the amplitude (Eq. 8) and the depth (Eq. 1), and applies
its output rules (paper §2.2).

**Tap order.** The paper contradicts itself. Eq. 2 (``φ = atan((Q₄ − Q₃)/(Q₁ − Q₂))``) needs
the control signals at ``C₁ = 0, C₂ = π, C₃ = π/2, C₄ = 3π/2`` (the paper's text on Fig. 1
says only that ``C₁ − C₄`` are π/2 apart; the order is named ``"fig1"`` after the figure that
Eq. 2 describes); the text after Eq. 6 names ``τ₁…τ₄ = 0, π/2, π, 3π/2``. Eq. 7 recovers
``θ`` only for the Eq. 2 order; with the text order ``c₄ − c₃ = c₁ − c₂`` for every ``θ`` and
Eq. 7 degenerates (the ratio is always 1). This module uses the Eq. 2 order
(``order="fig1"``, the default) and keeps ``order="text"``
only to demonstrate the degeneracy.
"""

from __future__ import annotations

import math

import torch

from .._checks import (
    check_broadcast,
    check_finite,
    check_nonnegative,
    check_number,
    check_positive,
    check_shape,
    check_tensor,
)

__all__ = [
    "SPEED_OF_LIGHT",
    "TAP_ORDERS",
    "unambiguous_range",
    "phasor_from_depth",
    "correlation_taps",
    "tap_phase",
    "tap_amplitude",
    "phase_to_depth",
    "camera_rules",
]

from ..constants import SPEED_OF_LIGHT  # noqa: E402  (m/s, exact SI; defined once)

# Tap delays as exact (cos τ_k, sin τ_k) pairs: no rounding from cos(π/2) etc.
TAP_ORDERS: dict[str, tuple[tuple[int, int], ...]] = {
    "fig1": ((1, 0), (-1, 0), (0, 1), (0, -1)),  # τ = 0, π, π/2, 3π/2 (Fig. 1, Eq. 2)
    "text": ((1, 0), (0, 1), (-1, 0), (0, -1)),  # τ = 0, π/2, π, 3π/2 (text after Eq. 6)
}


def check_phasor(phasor: object, func: str, name: str = "phasor") -> torch.Tensor:
    """Raise unless ``phasor`` is a complex tensor of shape ``(B, 1, H, W)``."""
    check_tensor(phasor, name, func)
    if not phasor.is_complex():
        raise TypeError(f"{func}: expected {name} to be a complex tensor, got dtype {phasor.dtype}")
    check_shape(phasor, (None, 1, None, None), name, func, "(B, 1, H, W)")
    check_finite(phasor, name, func)
    return phasor


def check_real(x: object, name: str, func: str) -> torch.Tensor:
    """Raise unless ``x`` is a real floating-point tensor."""
    check_tensor(x, name, func)
    if x.is_complex():
        raise TypeError(f"{func}: expected {name} to be a real tensor, got dtype {x.dtype}")
    return x


def check_rules_config(
    func: str, min_m: object, max_m: object, amp_threshold: object, no_photon_m: object,
    step_m: object,
) -> float | None:
    """The camera-rule parameters of :func:`camera_rules` (also checked by the sensor and
    readout modules at construction): ``0 <= min_m < max_m``, ``no_photon_m >= 0``, all
    finite numbers; ``amp_threshold`` a finite number (NaN would turn the "no photon" rule
    off: no amplitude compares ``<=`` to it); ``step_m`` ``None`` or ``> 0``. Returns the
    step as a float (or ``None``)."""
    for name, v in (("min_m", min_m), ("max_m", max_m), ("no_photon_m", no_photon_m)):
        check_positive(v, name, func, strict=False)
    if not max_m > min_m:
        raise ValueError(f"{func}: expected max_m > min_m, got min_m={min_m}, max_m={max_m}")
    check_number(amp_threshold, "amp_threshold", func)
    return None if step_m is None else check_positive(step_m, "step_m", func)


def check_order(order: str, func: str) -> tuple[tuple[int, int], ...]:
    if order not in TAP_ORDERS:
        raise ValueError(f"{func}: expected order in {tuple(TAP_ORDERS)}, got {order!r}")
    return TAP_ORDERS[order]


def unambiguous_range(freq_hz: float) -> float:
    """Unambiguous range of a CW-ToF camera, ``R = c / (2f)`` (paper Eq. 1 at ``θ = 2π``).

    Args:
        freq_hz: modulation frequency in Hz, ``> 0``.

    Returns:
        The range in metres; a return from ``d ≥ R`` wraps to ``d − R``.

    Raises:
        ValueError: if ``freq_hz`` is not positive and finite.

    Example:
        >>> round(unambiguous_range(30e6), 3)
        4.997
    """
    f = check_positive(freq_hz, "freq_hz", "unambiguous_range")
    return SPEED_OF_LIGHT / (2.0 * f)


def phasor_from_depth(
    amplitude: torch.Tensor | float, depth_m: torch.Tensor, freq_hz: float
) -> torch.Tensor:
    """Phasor of a single return: ``a·e^{jθ}`` with ``θ = 4πf·d/c`` (paper Eq. 1).

    Args:
        amplitude: return amplitude ``a`` (photo-electrons; real tensor broadcastable to
            ``depth_m``, or a number).
        depth_m: one-way distance ``d`` in metres (real tensor, any shape, usually
            ``(B, 1, H, W)``). Depths beyond :func:`unambiguous_range` wrap naturally.
        freq_hz: modulation frequency in Hz, ``> 0``.

    Returns:
        Complex tensor of the broadcast shape; ``complex64`` for ``float32`` input,
        ``complex128`` for ``float64``.

    Raises:
        TypeError: if ``depth_m`` (or a tensor ``amplitude``) is not a real floating tensor.
        ValueError: if ``freq_hz`` is not positive, ``depth_m``/``amplitude`` hold NaN/Inf, or
            ``amplitude`` is negative.

    Example:
        >>> p = phasor_from_depth(2.0, torch.zeros(1, 1, 2, 2), 30e6)
        >>> p.dtype, p[0, 0, 0, 0].real.item()
        (torch.complex64, 2.0)
    """
    func = "phasor_from_depth"
    check_real(depth_m, "depth_m", func)
    f = check_positive(freq_hz, "freq_hz", func)
    if depth_m.dtype not in (torch.float32, torch.float64):
        raise TypeError(
            f"{func}: expected depth_m of dtype float32 or float64 (complex64/complex128 "
            f"phasors), got {depth_m.dtype}"
        )
    check_finite(depth_m, "depth_m", func)
    if isinstance(amplitude, torch.Tensor):
        check_real(amplitude, "amplitude", func)
        check_finite(amplitude, "amplitude", func)
        # a magnitude: a negative one would be a phase shift of π, i.e. c/(4f) of depth
        check_nonnegative(amplitude, "amplitude", func)
    else:
        if isinstance(amplitude, bool) or not isinstance(amplitude, (int, float)):
            raise TypeError(
                f"{func}: expected amplitude to be a real tensor or a number, "
                f"got {type(amplitude).__name__}"
            )
        if not math.isfinite(amplitude):
            raise ValueError(f"{func}: expected a finite amplitude, got {amplitude}")
        if amplitude < 0:
            raise ValueError(f"{func}: expected amplitude >= 0 (a magnitude; a negative one "
                             f"moves the depth by c/(4f)), got {amplitude}")
        amplitude = torch.as_tensor(float(amplitude), dtype=depth_m.dtype, device=depth_m.device)
    theta = depth_m * (4.0 * math.pi * f / SPEED_OF_LIGHT)
    amplitude, theta = torch.broadcast_tensors(amplitude.to(depth_m.dtype), theta)
    return torch.polar(amplitude, theta)


def correlation_taps(
    phasor: torch.Tensor, offset: torch.Tensor | float = 0.0, order: str = "fig1"
) -> torch.Tensor:
    """The four correlation taps of a CW-ToF pixel (paper Eq. 6, sampled at four delays).

    .. math::

        c_k = B + \\tfrac12\\,\\mathrm{Re}(P e^{jτ_k}) = B + \\tfrac{|P|}{2}\\cos(θ + τ_k).

    The taps are linear in the phasor, so a pixel that sees several returns (multipath,
    mixed pixels) gets the taps of the phasor sum. The delays are applied as exact
    ``(cos τ_k, sin τ_k) ∈ {0, ±1}`` pairs, so a zero phase gives exactly ``c₃ = c₄``.

    Args:
        phasor: complex ``(B, 1, H, W)`` phasor ``P = Σ a_j e^{jθ_j}`` (photo-electrons).
        offset: the offset ``B`` of every tap (ambient light plus the unmodulated part of the
            signal), a number or a real tensor broadcastable to ``(B, 1, H, W)``.
        order: ``"fig1"`` (default): ``τ = (0, π, π/2, 3π/2)``, the order of Fig. 1 / Eq. 2
            for which Eq. 7 holds. ``"text"``: ``τ = (0, π/2, π, 3π/2)``, the order named in
            the text after Eq. 6; Eq. 7 degenerates for it (``c₄ − c₃ = c₁ − c₂`` always),
            kept only to demonstrate the paper's contradiction.

    Returns:
        Real taps ``(B, 4, H, W)`` (``float32`` for ``complex64``, ``float64`` for ``complex128``)
        in the order given.

    Raises:
        TypeError: if ``phasor`` is not complex, or ``offset`` is neither a number nor a real
            floating tensor.
        ValueError: on a wrong shape, an ``offset`` that holds NaN/Inf or does not broadcast
            to ``(B, 1, H, W)`` (it may not grow the batch), or an unknown ``order``.

    Shape:
        - phasor: :math:`(B, 1, H, W)` complex
        - output: :math:`(B, 4, H, W)` real

    Example:
        >>> p = torch.full((1, 1, 1, 1), 2.0 + 0j)
        >>> correlation_taps(p, offset=1.0).flatten().tolist()
        [2.0, 0.0, 1.0, 1.0]
    """
    func = "correlation_taps"
    check_phasor(phasor, func)
    table = check_order(order, func)
    re, im = phasor.real, phasor.imag
    if isinstance(offset, torch.Tensor):
        check_real(offset, "offset", func)
        check_broadcast(offset, phasor.shape, "offset", func, "(B, 1, H, W)")
        check_finite(offset, "offset", func)
        offset = offset.to(re.dtype)  # the taps follow the phasor's real dtype
    else:
        check_number(offset, "offset", func)
    # Re(P e^{jτ}) = Re P cos τ − Im P sin τ, with cos τ, sin τ ∈ {0, ±1} (loop over 4 taps)
    return offset + 0.5 * torch.cat([c * re - s * im for c, s in table], dim=1)


def _safe_iq(
    taps: torch.Tensor, func: str, half: bool = False
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``q = c₄ − c₃``, ``i = c₁ − c₂`` (each halved if ``half``) and the mask ``(q, i) ≠ 0``
    (Eq. 7/8 operands)."""
    check_real(taps, "taps", func)
    check_shape(taps, (None, 4, None, None), "taps", func, "(B, 4, H, W)")
    check_finite(taps, "taps", func)
    c1, c2, c3, c4 = (0.5 * taps if half else taps).unbind(dim=1)
    q = (c4 - c3).unsqueeze(1)
    i = (c1 - c2).unsqueeze(1)
    nonzero = (q != 0) | (i != 0)  # not q² + i² > 0: it underflows at 1e-30 (float32)
    return q, i, nonzero


def _pow2_rescale(q: torch.Tensor, i: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``(q·s, i·s)`` with ``s`` a power of two per pixel that brings ``m = max(|q|, |i|)``
    into ``[2^-e, 2^e]``, ``e = maxexp/2 − 2`` (``2^±62`` in float32, ``2^±510`` in float64),
    and ``s = 1`` where ``m`` already lies there.

    ``atan2(q, i)`` is invariant to a common positive scale, and a power of two scales
    exactly, so the phase does not change (bit for bit wherever nothing over- or underflows);
    but the backward of ``atan2`` divides by ``q² + i²``, which underflows to 0 in float32 for
    ``m`` below about 1e-19 (an infinite or NaN gradient for a finite true one, ``1/|P|``) and
    overflows above 1e19. The factor is chosen by comparisons (no ``log2``/``exp2`` rounding,
    exports to ONNX) and is a constant per pixel (no gradient of its own)."""
    e = math.frexp(torch.finfo(q.dtype).max)[1] // 2 - 2  # max < 2^maxexp
    hi, k = 2.0**e, 2.0 ** (2 * e)
    m = torch.maximum(q.abs(), i.abs())
    s = torch.where(m > hi, torch.full_like(m, 1.0 / k),
                    torch.where(m < 1.0 / hi, torch.full_like(m, k), torch.ones_like(m)))
    return q * s, i * s


def tap_phase(taps: torch.Tensor) -> torch.Tensor:
    """Phase from the four taps, paper Eq. 7, wrapped to ``[0, 2π)``.

    .. math::

        θ = \\operatorname{atan2}(c_4 − c_3,\\; c_1 − c_2) \\bmod 2π.

    Eq. 7 assumes the Fig. 1 tap order (``τ = 0, π, π/2, 3π/2``, see
    :func:`correlation_taps`); for taps in the text order it returns ``π/4`` or ``5π/4``
    whatever the true phase. A pixel with ``c₁ = c₂`` and ``c₃ = c₄`` (no modulated light)
    gets phase 0 with a zero gradient (no NaN: ``atan2(0, 0)`` has no derivative, so both
    operands are replaced there before the call). Operands far from 1 (the larger of
    ``|c₄ − c₃|``, ``|c₁ − c₂|`` below ``2^-62`` or above ``2^62`` in float32) are first
    scaled by a power of two: the phase is scale-invariant and unchanged, and the gradient
    stays finite where ``q² + i²`` in ``atan2``'s backward would underflow (it is
    ``1/|P|``-sized, e.g. ``1e20`` at ``|P| = 1e-20``).

    Args:
        taps: real ``(B, 4, H, W)`` taps in the Fig. 1 order.

    Returns:
        Phase ``(B, 1, H, W)`` in radians, in ``[0, 2π)``, same dtype as ``taps``.

    Raises:
        TypeError: if ``taps`` is not a real floating tensor.
        ValueError: if ``taps`` is not ``(B, 4, H, W)``.

    Example:
        >>> taps = torch.tensor([1.0, 1.0, 0.0, 2.0]).view(1, 4, 1, 1)
        >>> round(tap_phase(taps).item(), 4)  # atan2(2, 0) = π/2
        1.5708
    """
    q, i, nonzero = _safe_iq(taps, "tap_phase")
    q, i = _pow2_rescale(q, i)
    q_safe = torch.where(nonzero, q, torch.zeros_like(q))
    i_safe = torch.where(nonzero, i, torch.ones_like(i))
    theta = torch.where(nonzero, torch.atan2(q_safe, i_safe), torch.zeros_like(q))
    two_pi = 2.0 * math.pi
    theta = torch.where(theta < 0, theta + two_pi, theta)
    # −tiny + 2π rounds to 2π: keep the half-open interval [0, 2π)
    return torch.where(theta >= two_pi, theta - two_pi, theta)


def tap_amplitude(taps: torch.Tensor) -> torch.Tensor:
    """Amplitude from the four taps, paper Eq. 8.

    .. math::

        A = \\tfrac12\\sqrt{(c_4 − c_3)^2 + (c_1 − c_2)^2}.

    For taps of :func:`correlation_taps` (Fig. 1 order) ``c₄ − c₃ = |P| sin θ`` and
    ``c₁ − c₂ = |P| cos θ``, so Eq. 8 returns ``|P|/2`` — the *correlation amplitude*
    ``a/2`` of Eq. 6, half the phasor amplitude. The square root is guarded so that a zero
    amplitude has a zero (not NaN) gradient.

    Args:
        taps: real ``(B, 4, H, W)`` taps in the Fig. 1 order.

    Returns:
        Amplitude ``(B, 1, H, W)``, same dtype and units as ``taps``.

    Raises:
        TypeError: if ``taps`` is not a real floating tensor.
        ValueError: if ``taps`` is not ``(B, 4, H, W)``.

    Example:
        >>> taps = correlation_taps(torch.full((1, 1, 1, 1), 3.0 + 4.0j), offset=5.0)
        >>> tap_amplitude(taps).item()  # |P| / 2
        2.5
    """
    q, i, nonzero = _safe_iq(taps, "tap_amplitude", half=True)
    # hypot(q/2, i/2) as m·sqrt((q/m)² + (i/m)²), m = max(|q|, |i|): no q², i² to over- or
    # underflow at 1e±30 (float32), exports to ONNX (aten.hypot does not), and the guarded
    # operands keep the gradient finite at q = i = 0. The halves are taken before the
    # differences (exact: a power-of-two scaling), so taps of ±3e38 do not overflow.
    q_safe = torch.where(nonzero, q, torch.ones_like(q))
    i_safe = torch.where(nonzero, i, torch.ones_like(i))
    m = torch.maximum(q_safe.abs(), i_safe.abs())
    amp = m * torch.sqrt((q_safe / m) ** 2 + (i_safe / m) ** 2)
    return torch.where(nonzero, amp, torch.zeros_like(amp))


def phase_to_depth(phase: torch.Tensor, freq_hz: float) -> torch.Tensor:
    """Depth from phase, paper Eq. 1: ``d = c·θ / (4πf)``.

    Args:
        phase: real tensor of phases in radians (any shape, usually ``(B, 1, H, W)``).
        freq_hz: modulation frequency in Hz, ``> 0``.

    Returns:
        Depth in metres, same shape and dtype; ``θ ∈ [0, 2π)`` maps to ``[0, c/(2f))``.

    Raises:
        TypeError: if ``phase`` is not a real floating tensor.
        ValueError: if ``freq_hz`` is not positive.

    Example:
        >>> round(phase_to_depth(torch.tensor([math.pi]), 30e6).item(), 4)
        2.4983
    """
    func = "phase_to_depth"
    check_real(phase, "phase", func)
    f = check_positive(freq_hz, "freq_hz", func)
    check_finite(phase, "phase", func)
    return phase * (SPEED_OF_LIGHT / (4.0 * math.pi * f))


def camera_rules(
    depth: torch.Tensor,
    amplitude: torch.Tensor,
    min_m: float = 1.0,
    max_m: float = 5.0,
    amp_threshold: float = 0.0,
    no_photon_m: float = 5.0,
    step_m: float | None = None,
) -> torch.Tensor:
    """Output rules of the ToF camera (paper §2.2).

    In order: the depth is clipped to ``[min_m, max_m]`` ("values less than 1 or larger than
    5 would be automatically set to be 1 or 5"); optionally quantised to the grid
    ``min_m + k·step_m`` ("from 1 to 5 m with a step of 0.25 m"), rounding to the nearest
    step with a straight-through gradient; finally pixels with
    ``amplitude ≤ amp_threshold`` ("pixels without receiving any photon") are set to
    ``no_photon_m``. With the default threshold 0 only pixels with exactly zero amplitude
    count as dark; raise it (in the units of ``amplitude``) to model the camera's
    confidence cut. Vectorised with ``torch.where``: no Python branch on tensor values.

    Args:
        depth: real ``(B, 1, H, W)`` depth in metres.
        amplitude: real ``(B, 1, H, W)`` amplitude (e.g. :func:`tap_amplitude`).
        min_m: lower clip in metres.
        max_m: upper clip in metres, ``> min_m``.
        amp_threshold: pixels with ``amplitude ≤ amp_threshold`` report ``no_photon_m``.
        no_photon_m: depth reported by dark pixels, in metres.
        step_m: output quantisation step in metres (paper: 0.25), or ``None`` for none.

    Returns:
        Depth ``(B, 1, H, W)`` in metres, same dtype as ``depth``. Gradients: 1 inside the
        clip range (straight through the rounding), 0 where clipped or dark.

    Raises:
        TypeError: if ``depth``/``amplitude`` are not real floating tensors or a parameter
            is not a number.
        ValueError: on mismatched shapes, ``max_m ≤ min_m``, a negative ``min_m`` or
            ``no_photon_m``, a non-positive ``step_m`` or non-finite parameters (a NaN
            ``amp_threshold`` would switch the "no photon" rule off).

    Shape:
        - depth, amplitude: :math:`(B, 1, H, W)`
        - output: :math:`(B, 1, H, W)`

    Example:
        >>> d = torch.tensor([0.3, 2.1, 7.0, 3.0]).view(1, 1, 2, 2)
        >>> a = torch.tensor([1.0, 1.0, 1.0, 0.0]).view(1, 1, 2, 2)
        >>> camera_rules(d, a, step_m=0.25).flatten().tolist()
        [1.0, 2.0, 5.0, 5.0]
    """
    func = "camera_rules"
    check_real(depth, "depth", func)
    check_real(amplitude, "amplitude", func)
    check_shape(depth, (None, 1, None, None), "depth", func, "(B, 1, H, W)")
    if amplitude.shape != depth.shape:
        raise ValueError(
            f"{func}: expected amplitude of shape {tuple(depth.shape)} (as depth), "
            f"got {tuple(amplitude.shape)}"
        )
    check_finite(depth, "depth", func)
    check_finite(amplitude, "amplitude", func)
    step = check_rules_config(func, min_m, max_m, amp_threshold, no_photon_m, step_m)
    d = depth.clamp(min_m, max_m)
    if step is not None:
        k = (d - min_m) / step
        d = min_m + step * (k + (torch.round(k) - k).detach())
        d = d.clamp(min_m, max_m)  # a step that does not divide the range rounds past max_m
    dark = amplitude <= amp_threshold
    return torch.where(dark, torch.full_like(d, float(no_photon_m)), d)
