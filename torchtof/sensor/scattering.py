"""A scattering medium (the paper's dusty plastic sheet) in the depth or the phasor domain.

**Depth domain** (paper Eq. 15, the model that reproduces the paper): the camera's depth map
becomes

.. math::

    D'(x) = α D(x) + D^s(x), \\qquad 0 < α ≤ 1,

``α`` the transmittance ratio and ``Dˢ`` the scattered-light term (a number, a given map, or a
smooth dust map, see :func:`dust_map`).

**Phasor domain** (Muraji et al., Opt. Express 27(13), 2019): the sheet
attenuates and blurs the direct light (forward scatter) and adds a backscatter phasor from
the sheet's own distance ``d_s``,

.. math::

    P' = α\\,(G_{σ_f} * P) + b(x)\\, e^{j 4π f d_s / c},

``b`` a smooth backscatter amplitude map (dust); the camera then measures ``arg P'``. Both
forms are linear in their input; ``α = 1`` with no blur and no backscatter is the identity.
"""

from __future__ import annotations

import math
import numbers

import torch
from torch import nn

from .._checks import (
    check_finite,
    check_float_dtype,
    check_in_range,
    check_int,
    check_nonnegative,
    check_positive,
    check_rank,
    check_tensor,
)
from .._memory import check_memory
from .functional import SPEED_OF_LIGHT, check_phasor, check_real
from .mixing import blur_phasor, size_pair

__all__ = [
    "SCATTER_MODES",
    "dust_map",
    "scatter_depth",
    "scatter_phasor",
    "scattering_medium",
    "ScatteringMedium",
]

SCATTER_MODES = ("depth", "phasor")


def _check_alpha(alpha: float, func: str) -> float:
    return check_in_range(alpha, 0.0, 1.0, "alpha", func, lo_open=True)


def _check_term(value: object, x: torch.Tensor, name: str, func: str) -> torch.Tensor | float:
    """A non-negative number or a real, finite, non-negative tensor that broadcasts to ``x``
    (cast to its real dtype and device): the same rules for both forms."""
    if not isinstance(value, torch.Tensor):
        return check_positive(value, name, func, strict=False)
    check_real(value, name, func)
    try:
        shape = torch.broadcast_shapes(value.shape, x.shape)
    except RuntimeError:
        shape = None
    if shape != x.shape:
        raise ValueError(
            f"{func}: expected {name} broadcastable to {tuple(x.shape)}, got {tuple(value.shape)}"
        )
    check_finite(value, name, func)
    check_nonnegative(value, name, func)
    return value.to(dtype=x.real.dtype, device=x.device)


def dust_map(
    size: int | tuple[int, int],
    sigma_px: float = 4.0,
    generator: torch.Generator | None = None,
    dtype: torch.dtype | None = None,
    device: torch.device | str | None = None,
) -> torch.Tensor:
    """A smooth random map in ``[0, 1]``: low-pass filtered white noise (dust on the sheet).

    White Gaussian noise (drawn on the CPU in float64 from ``generator``, so a seed gives the
    same map on every device and dtype) is blurred with a Gaussian of ``sigma_px`` pixels
    (:func:`~torchtof.sensor.mixing.blur_phasor`) and rescaled to ``[0, 1]`` (min–max).

    Args:
        size: ``(H, W)`` or one int.
        sigma_px: correlation length of the dust in pixels, ``> 0``.
        generator: a CPU ``torch.Generator`` (``None``: the global one).
        dtype: dtype of the result (default: ``torch.get_default_dtype()``).
        device: device of the result.

    Returns:
        ``(1, 1, H, W)`` map with minimum 0 and maximum 1 (all zeros if ``H = W = 1``).

    Raises:
        TypeError, ValueError: on a bad ``size`` or a non-positive ``sigma_px``.

    Example:
        >>> m = dust_map((16, 16), generator=torch.Generator().manual_seed(0))
        >>> m.shape, float(m.min()), float(m.max())
        (torch.Size([1, 1, 16, 16]), 0.0, 1.0)
    """
    func = "dust_map"
    h, w = size_pair(size, "size", func)
    check_memory(4 * h * w * 8, f"a {h}x{w} dust map", func)
    sigma = check_positive(sigma_px, "sigma_px", func)
    noise = torch.randn((1, 1, h, w), generator=generator, dtype=torch.float64)
    if min(h, w) > 1:
        noise = blur_phasor(noise, sigma)
    lo, hi = noise.amin(), noise.amax()
    m = (noise - lo) / (hi - lo).clamp_min(torch.finfo(torch.float64).tiny)
    dtype = torch.get_default_dtype() if dtype is None else check_float_dtype(dtype, "dtype", func)
    return m.to(dtype=dtype, device=device)


def scatter_depth(
    depth: torch.Tensor, alpha: float = 0.6, depth_s: torch.Tensor | float = 0.0
) -> torch.Tensor:
    """Depth-domain scattering, paper Eq. 15: ``D' = α·D + Dˢ``.

    Args:
        depth: real ``(B, C, H, W)`` depth maps in metres (usually ``C = 1``).
        alpha: transmittance ratio ``α ∈ (0, 1]`` (paper: ``0 < α < 1``; 1 = clear).
        depth_s: scattered-light term ``Dˢ`` in metres, ``≥ 0``: a number or a real tensor
            broadcastable to ``depth`` (e.g. ``dust_m · dust_map(...)``, shape ``(1, 1, H, W)``).

    Returns:
        ``(B, C, H, W)`` depth, same dtype.

    Raises:
        TypeError: if ``depth``/``depth_s`` are not real tensors.
        ValueError: if ``alpha ∉ (0, 1]``, on a wrong rank, non-finite input, a negative
            ``depth_s`` or one that does not broadcast.

    The result is not clipped or quantised: applied to a camera's output (clipped to
    ``[1, 5]`` m, 0.25 m steps, 5 m for pixels without photons) it leaves that domain (a dark
    pixel's 5 m becomes ``5α + Dˢ``). To model a camera behind the sheet, apply it to the
    Eq. 1 depth and the camera rules after it, as
    :class:`~torchtof.experiment.PaperExperiment` does with ``scattering_model="depth"``.

    Example:
        >>> scatter_depth(torch.full((1, 1, 2, 2), 2.0), alpha=0.5, depth_s=1.0).unique().tolist()
        [2.0]
    """
    func = "scatter_depth"
    check_real(depth, "depth", func)
    check_rank(depth, 4, "depth", func, "(B, C, H, W)")
    check_finite(depth, "depth", func)
    a = _check_alpha(alpha, func)
    return a * depth + _check_term(depth_s, depth, "depth_s", func)


def scatter_phasor(
    phasor: torch.Tensor,
    alpha: float = 0.6,
    blur_sigma: float | None = None,
    backscatter: torch.Tensor | float = 0.0,
    sheet_m: float = 0.5,
    freq_hz: float = 30e6,
) -> torch.Tensor:
    """Phasor-domain scattering: ``P' = α·(G_σ * P) + b·e^{j4πf d_s/c}`` (Muraji et al. 2019).

    Args:
        phasor: complex ``(B, 1, H, W)`` phasor reaching the sheet.
        alpha: transmittance ``α ∈ (0, 1]`` of the direct light.
        blur_sigma: forward-scatter Gaussian blur in pixels (``None``: none).
        backscatter: backscatter amplitude ``b ≥ 0`` in the phasor's units (e⁻), a number or
            a real map broadcastable to the phasor (e.g. ``b₀ · dust_map(...)``).
        sheet_m: distance of the sheet ``d_s`` in metres (the backscatter's phase, Eq. 1).
        freq_hz: modulation frequency in Hz, ``> 0``.

    Returns:
        Complex ``(B, 1, H, W)`` phasor, same dtype.

    Raises:
        TypeError: if ``phasor`` is not complex or ``backscatter`` is not real.
        ValueError: if ``alpha ∉ (0, 1]``, on a wrong shape, non-finite input, a negative
            ``backscatter`` or invalid parameters.

    Shape:
        - phasor: :math:`(B, 1, H, W)`; output: :math:`(B, 1, H, W)`

    Example:
        >>> p = torch.ones(1, 1, 4, 4, dtype=torch.complex64)
        >>> torch.equal(scatter_phasor(p, alpha=1.0), p)
        True
    """
    func = "scatter_phasor"
    check_phasor(phasor, func)
    a = _check_alpha(alpha, func)
    b = _check_term(backscatter, phasor, "backscatter", func)
    d_s = check_positive(sheet_m, "sheet_m", func, strict=False)
    f = check_positive(freq_hz, "freq_hz", func)
    if blur_sigma is not None:
        check_positive(blur_sigma, "blur_sigma", func)
    direct = phasor if blur_sigma is None else blur_phasor(phasor, blur_sigma)
    theta = 4.0 * math.pi * f * d_s / SPEED_OF_LIGHT
    return a * direct + b * complex(math.cos(theta), math.sin(theta))


def scattering_medium(
    x: torch.Tensor,
    alpha: float = 0.6,
    mode: str = "depth",
    depth_s: torch.Tensor | float = 0.0,
    blur_sigma: float | None = None,
    backscatter: torch.Tensor | float = 0.0,
    sheet_m: float = 0.5,
    freq_hz: float = 30e6,
) -> torch.Tensor:
    """Apply a scattering medium in the chosen domain.

    ``mode="depth"``: :func:`scatter_depth` (paper Eq. 15) on a real depth map, using
    ``depth_s``. ``mode="phasor"``: :func:`scatter_phasor` on a complex phasor, using
    ``blur_sigma``, ``backscatter``, ``sheet_m`` and ``freq_hz``.

    Args:
        x: real ``(B, C, H, W)`` depth (``"depth"``) or complex ``(B, 1, H, W)`` phasor.
        alpha: transmittance ``α ∈ (0, 1]``.
        mode: ``"depth"`` or ``"phasor"``.
        depth_s, blur_sigma, backscatter, sheet_m, freq_hz: see the two functions.

    Returns:
        Scattered ``x``, same shape and dtype.

    Raises:
        TypeError, ValueError: as the function of the mode, or on an unknown ``mode``.

    Example:
        >>> d = torch.full((1, 1, 2, 2), 4.0)
        >>> scattering_medium(d, alpha=0.5, depth_s=0.5).unique().tolist()
        [2.5]
    """
    if mode not in SCATTER_MODES:
        raise ValueError(f"scattering_medium: expected mode in {SCATTER_MODES}, got {mode!r}")
    if mode == "depth":
        return scatter_depth(x, alpha, depth_s)
    return scatter_phasor(x, alpha, blur_sigma, backscatter, sheet_m, freq_hz)


class ScatteringMedium(nn.Module):
    """Module wrapper of :func:`scattering_medium` with a fixed dust map.

    The dust map is generated once at construction from ``seed`` (:func:`dust_map` with a
    CPU generator, float64, non-persistent buffer ``dust`` of shape ``(1, 1, H, W)``) and
    cast to the input's dtype/device in ``forward``; inputs must then have spatial size
    ``size``. In ``"depth"`` mode ``Dˢ = depth_s`` if given (number or tensor, stored as is),
    else ``dust_m · dust``. In ``"phasor"`` mode the backscatter amplitude is
    ``backscatter_e · dust``.

    Args:
        alpha: transmittance ``α ∈ (0, 1]`` (default 0.6).
        mode: ``"depth"`` (paper Eq. 15, default) or ``"phasor"``.
        depth_s: explicit ``Dˢ`` in metres (``None``: the dust map times ``dust_m``).
        dust_m: scale of the dust map in metres for ``Dˢ`` (depth mode).
        size: ``(H, W)`` of the dust map (default: 64×64, the sensor region of this
            package's simulated experiment; the paper gives only the camera's 320×240).
        dust_sigma_px: correlation length of the dust in pixels.
        seed: seed of the dust map, an int (``torch.Generator``'s range).
        blur_sigma: forward-scatter blur in pixels (phasor mode; ``None``: none).
        backscatter_e: peak backscatter amplitude in e⁻ (phasor mode).
        sheet_m: sheet distance in metres (phasor mode).
        freq_hz: modulation frequency in Hz (phasor mode).

    Raises:
        TypeError: if ``seed`` is not an int or ``depth_s`` not a number or real tensor.
        ValueError: if ``alpha ∉ (0, 1]`` or another parameter is invalid (a ``depth_s``
            tensor with NaN/Inf or a negative entry included).

    Example:
        >>> medium = ScatteringMedium(alpha=0.6, size=(8, 8))
        >>> medium(torch.full((2, 1, 8, 8), 5.0)).shape
        torch.Size([2, 1, 8, 8])
    """

    dust: torch.Tensor

    def __init__(
        self,
        alpha: float = 0.6,
        mode: str = "depth",
        *,
        depth_s: torch.Tensor | float | None = None,
        dust_m: float = 1.0,
        size: int | tuple[int, int] = (64, 64),
        dust_sigma_px: float = 4.0,
        seed: int = 0,
        blur_sigma: float | None = 1.0,
        backscatter_e: float = 0.0,
        sheet_m: float = 0.5,
        freq_hz: float = 30e6,
    ) -> None:
        super().__init__()
        func = "ScatteringMedium"
        self.alpha = _check_alpha(alpha, func)
        if mode not in SCATTER_MODES:
            raise ValueError(f"{func}: expected mode in {SCATTER_MODES}, got {mode!r}")
        self.mode = mode
        self.size = size_pair(size, "size", func)
        self.dust_m = check_positive(dust_m, "dust_m", func, strict=False)
        self.blur_sigma = (
            None if blur_sigma is None else check_positive(blur_sigma, "blur_sigma", func)
        )
        self.backscatter_e = check_positive(backscatter_e, "backscatter_e", func, strict=False)
        self.sheet_m = check_positive(sheet_m, "sheet_m", func, strict=False)
        self.freq_hz = check_positive(freq_hz, "freq_hz", func)
        if isinstance(depth_s, torch.Tensor):
            check_real(depth_s, "depth_s", func)
            check_finite(depth_s, "depth_s", func)
            check_nonnegative(depth_s, "depth_s", func)
            self.register_buffer("depth_s", depth_s.detach().clone(), persistent=False)
        else:
            self.depth_s = (
                None if depth_s is None else check_positive(depth_s, "depth_s", func, strict=False)
            )
        if isinstance(seed, numbers.Integral) and not isinstance(seed, bool):
            seed = int(seed)  # a NumPy integer
        check_int(seed, "seed", func, lo=-(2**63), hi=2**64 - 1)  # torch.Generator's range
        gen = torch.Generator().manual_seed(seed)
        check_positive(dust_sigma_px, "dust_sigma_px", func)  # named here, not as dust_map's
        dust = dust_map(self.size, dust_sigma_px, gen, dtype=torch.float64)
        self.register_buffer("dust", dust, persistent=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        check_tensor(x, "x", "ScatteringMedium")
        if tuple(x.shape[-2:]) != self.size:
            raise ValueError(
                f"ScatteringMedium: expected x of spatial size {self.size} (the dust map), "
                f"got {tuple(x.shape)}"
            )
        dust = self.dust.to(dtype=x.real.dtype, device=x.device)
        depth_s = self.dust_m * dust if self.depth_s is None else self.depth_s
        return scattering_medium(
            x,
            self.alpha,
            self.mode,
            depth_s,
            self.blur_sigma,
            self.backscatter_e * dust,
            self.sheet_m,
            self.freq_hz,
        )

    def extra_repr(self) -> str:
        return (
            f"alpha={self.alpha}, mode={self.mode!r}, size={self.size}, dust_m={self.dust_m}, "
            f"blur_sigma={self.blur_sigma}, backscatter_e={self.backscatter_e}, "
            f"sheet_m={self.sheet_m}, freq_hz={self.freq_hz}"
        )
