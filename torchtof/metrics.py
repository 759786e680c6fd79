"""Image and depth quality metrics, and the protocol that scores a reconstruction.

Metrics (all per image, over ``(C, H, W)``, returning ``(B,)`` or, with
``reduction="mean"``, the batch mean):

- :func:`psnr` — paper Eqs. (13)–(14), bit depth ``k`` explicit.
- :func:`ssim` — Wang et al. (2004), through ``kornia.metrics.ssim``.
- :func:`depth_rmse` — root-mean-square depth error in metres.

**Scoring protocol** (:func:`compare`; used by the demo, the CLI and the experiment):

1. Both images are min-max normalised per image to ``[0, 1]``
   (:func:`normalize_image`; a constant image becomes 0). The ground truth is
   taken as positive (object bright: the binary 天 is 1 on the strokes).
2. The polarity of the reconstruction is resolved (:func:`resolve_sign`). Depth
   images reconstructed from the raw depth bucket are *negative* (paper §3.1:
   pixels without light report 5 m, so the object is darker than the background):

   - ``"positive"``: ``minmax(x_hat)`` (intensity buckets, gated depth buckets);
   - ``"negative"``: ``1 - minmax(x_hat)``, the polarity known from the physics
     (ungated depth buckets); it does **not** look at the ground truth;
   - ``"auto"``: the one of the two above with the higher Pearson correlation
     with the ground truth — this **uses the ground truth** and is an oracle
     choice of sign;
   - ``"affine"``: ``clamp(a·x_hat + b, 0, 1)`` with ``a, b`` fitted by least
     squares to the ground truth (:func:`affine_fit`) — an oracle upper bound
     for any per-image gain/offset/sign correction.
3. PSNR on the ``k``-bit scale: both images are scaled by ``MAX = 2^k - 1`` and
   rounded to integers (``quantize=True``, the stored ``k``-bit image the paper
   scored), then Eq. (13)–(14). SSIM on the ``[0, 1]`` images (data range 1,
   Gaussian window 7, σ = 1.5).

Example:
    >>> x = torch.zeros(1, 1, 8, 8); x[..., 2:6, 2:6] = 1
    >>> scores = compare(5.0 - 3.0 * x, x, polarity="negative")  # a negative depth image
    >>> float(scores["psnr"][0]), round(float(scores["ssim"][0]), 4)
    (100.0, 1.0)
"""

from __future__ import annotations

import math

import torch
from torch import nn

from torchtof._checks import check_bool, check_finite, check_positive, check_rank, is_tracing

__all__ = [
    "POLARITIES",
    "psnr",
    "PSNR",
    "ssim",
    "SSIM",
    "depth_rmse",
    "DepthRMSE",
    "normalize_image",
    "NormalizeImage",
    "resolve_sign",
    "ResolveSign",
    "affine_fit",
    "compare",
]

#: Polarities accepted by :func:`resolve_sign`; :func:`compare` also accepts ``"affine"``.
POLARITIES: tuple[str, ...] = ("positive", "negative", "auto")


def _check_image(x: object, name: str, func: str) -> None:
    """A real floating ``(B, C, H, W)`` tensor (images are real: complex is refused)."""
    check_rank(x, 4, name, func, "(B, C, H, W)")
    if x.is_complex():
        raise TypeError(f"{func}: expected {name} to be a real tensor, got dtype {x.dtype}")


def _check_nonempty(x: torch.Tensor, name: str, func: str) -> None:
    """At least one pixel per image: a metric of an empty ``(C, H, W)`` has no value (PSNR
    scored it 100 dB, the RMSE NaN)."""
    if math.prod(x.shape[1:]) == 0:
        raise ValueError(f"{func}: expected {name} with at least one pixel per image "
                         f"(C, H, W > 0), got shape {tuple(x.shape)}")


def _check_reduction(reduction: object, func: str) -> str:
    if reduction not in ("mean", "none"):
        raise ValueError(f"{func}: expected reduction in ('mean', 'none'), got {reduction!r}")
    return reduction


def _check_psnr_args(bits: object, quantize: object, max_db: object, func: str
                     ) -> tuple[float, float]:
    """The scalar arguments of :func:`psnr` (also checked by :class:`PSNR` at construction);
    returns ``(MAX, max_db)`` with ``MAX = 2^bits − 1`` (1 for ``bits=None``)."""
    check_bool(quantize, "quantize", func)
    max_db = check_positive(max_db, "max_db", func)
    if bits is None:
        if quantize:
            raise ValueError(f"{func}: quantize=True needs bits, got bits=None")
        return 1.0, max_db
    if isinstance(bits, bool) or not isinstance(bits, int):
        raise TypeError(f"{func}: expected bits to be an int or None, got {type(bits).__name__}")
    if not 1 <= bits <= 64:
        raise ValueError(f"{func}: expected bits in [1, 64], got {bits}")
    return float(2**bits - 1), max_db


def _check_window(window_size: object, func: str) -> int:
    """An odd int ``>= 3`` (the image-size bound is checked by :func:`ssim` on the images)."""
    if isinstance(window_size, bool) or not isinstance(window_size, int):
        raise TypeError(f"{func}: expected window_size to be an int, got {type(window_size)}")
    if window_size < 3 or window_size % 2 == 0:
        raise ValueError(f"{func}: expected an odd window_size >= 3, got {window_size}")
    return window_size


def _check_pair(
    x_hat: torch.Tensor, x: torch.Tensor, func: str, names: tuple[str, str] = ("x_hat", "x")
) -> None:
    _check_image(x_hat, names[0], func)
    _check_image(x, names[1], func)
    if x_hat.shape != x.shape:
        raise ValueError(
            f"{func}: expected {names[0]} and {names[1]} of the same shape, got "
            f"{tuple(x_hat.shape)} and {tuple(x.shape)}"
        )


def _reduce(v: torch.Tensor, reduction: str, func: str) -> torch.Tensor:
    if reduction == "none":
        return v
    if reduction == "mean":
        if v.shape[0] == 0:
            raise ValueError(f"{func}: reduction='mean' of an empty batch has no value (use "
                             "reduction='none')")
        return v.mean()
    raise ValueError(f"{func}: expected reduction in ('mean', 'none'), got {reduction!r}")


def psnr(
    x_hat: torch.Tensor,
    x: torch.Tensor,
    bits: int | None = 8,
    quantize: bool = False,
    max_db: float = 100.0,
    reduction: str = "none",
) -> torch.Tensor:
    r"""Peak signal-to-noise ratio, paper Eqs. (13)–(14).

    .. math::
        \mathrm{PSNR} = 10 \log_{10} \frac{\mathrm{MAX}^2}{\mathrm{MSE}}, \quad
        \mathrm{MSE} = \frac{1}{CHW} \sum (\mathrm{MAX}\,\hat x - \mathrm{MAX}\,x)^2,
        \quad \mathrm{MAX} = 2^k - 1.

    Convention: inputs are images in ``[0, 1]`` and are compared on the ``k``-bit
    scale, i.e. the MSE is computed on ``MAX·x``. Without quantisation the factor
    ``MAX²`` cancels and the PSNR equals ``10 log10(1 / MSE_[0,1])`` for every ``k``;
    ``quantize=True`` rounds ``MAX·x`` to the integers ``0 … MAX`` (after clamping),
    as in the stored ``k``-bit images the paper scored, and then ``k`` matters.
    ``bits=None`` means data range 1 (``MAX = 1``, no scaling). Values outside
    ``[0, 1]`` are not clamped unless ``quantize=True``.

    Identical images (MSE = 0) score ``max_db``: the MSE is floored at
    ``MAX² · 10^(-max_db / 10)``, so the result never exceeds ``max_db`` and is
    never ``inf`` or NaN (gradients stay finite too).

    Args:
        x_hat: reconstruction, values in ``[0, 1]``.
        x: ground truth, values in ``[0, 1]``.
        bits: bit depth ``k >= 1`` of the stored image, or ``None`` for ``MAX = 1``.
        quantize: round to ``k``-bit integers before comparing (not differentiable).
        max_db: cap in dB for (near-)identical images, ``> 0``.
        reduction: ``"none"`` → one value per image, ``"mean"`` → batch mean.

    Returns:
        PSNR in dB.

    Raises:
        TypeError: if an input is not a floating tensor, ``bits`` is not an int or
            ``quantize`` is not a bool.
        ValueError: on rank/shape mismatch, images without pixels, ``bits < 1``, ``quantize``
            without ``bits``, a non-positive ``max_db``, non-finite inputs, or an unknown
            reduction.

    Shape:
        - x_hat, x: :math:`(B, C, H, W)`.
        - Output: :math:`(B,)`, or :math:`()` for ``reduction="mean"``.

    Example:
        >>> x = torch.zeros(1, 1, 4, 4)
        >>> float(psnr(x + 0.1, x, bits=None))  # MSE = 0.01 -> 20 dB
        20.0
    """
    func = "psnr"
    _check_pair(x_hat, x, func)
    _check_nonempty(x, "x", func)
    check_finite(x_hat, "x_hat", func)
    check_finite(x, "x", func)
    peak, max_db = _check_psnr_args(bits, quantize, max_db, func)
    # MAX² cancels in MAX²/MSE_k, so the ratio is formed on the [0, 1] scale and in the log
    # domain: PSNR = −10 log10(4 s² · mean((h/s)²)) with h = (x̂ − x)/2, s = max|h|. No
    # square or product can overflow (bits = 64 squares 2^64 − 1 past float32, data far
    # outside [0, 1] squares past any float), and the float16 floor does not underflow.
    wide = torch.promote_types(x.dtype, torch.float32)
    a, b = x_hat.to(wide), x.to(wide)
    if quantize:
        a = (a * peak).clamp(0.0, peak).round()
        b = (b * peak).clamp(0.0, peak).round()
        h = (a - b) / (2.0 * peak)
    else:
        h = a / 2 - b / 2  # halves: no overflow of x̂ − x at ±3e38
    h = h.flatten(1)
    s = h.abs().amax(1) if h.shape[1] else h.new_zeros(h.shape[0])
    some = s > 0
    s_safe = torch.where(some, s, torch.ones_like(s))
    inner = (h / s_safe.unsqueeze(1)).pow(2).mean(1)
    inner = torch.where(some, inner, torch.ones_like(inner))
    log_mse = math.log10(4.0) + 2.0 * torch.log10(s_safe) + torch.log10(inner)
    db = torch.where(some, -10.0 * log_mse, torch.full_like(log_mse, max_db))
    return _reduce(db.clamp_max(max_db), reduction, func).to(x.dtype)


class PSNR(nn.Module):
    """Module wrapper of :func:`psnr` (paper Eqs. 13–14)."""

    def __init__(
        self,
        bits: int | None = 8,
        quantize: bool = False,
        max_db: float = 100.0,
        reduction: str = "none",
    ) -> None:
        super().__init__()
        _check_psnr_args(bits, quantize, max_db, "PSNR")
        _check_reduction(reduction, "PSNR")
        self.bits, self.quantize, self.max_db, self.reduction = bits, quantize, max_db, reduction

    def forward(self, x_hat: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        return psnr(x_hat, x, self.bits, self.quantize, self.max_db, self.reduction)


def ssim(
    x_hat: torch.Tensor,
    x: torch.Tensor,
    data_range: float = 1.0,
    window_size: int = 7,
    reduction: str = "none",
) -> torch.Tensor:
    r"""Mean structural similarity per image (Wang, Bovik, Sheikh, Simoncelli, 2004).

    .. math::
        \mathrm{SSIM} = \frac{(2\mu_{\hat x}\mu_x + c_1)(2\sigma_{\hat x x} + c_2)}
        {(\mu_{\hat x}^2 + \mu_x^2 + c_1)(\sigma_{\hat x}^2 + \sigma_x^2 + c_2)},
        \quad c_1 = (0.01 L)^2,\ c_2 = (0.03 L)^2,

    with local statistics under a Gaussian window (σ = 1.5, ``window_size`` taps;
    7 suits 32×32 images), reflect padding, averaged over ``(C, H, W)``. Computed by
    ``kornia.metrics.ssim`` with ``eps=0`` (identical images score exactly 1).

    This is not scikit-image's ``structural_similarity(gaussian_weights=True, sigma=1.5,
    use_sample_covariance=False, data_range=L)``, which truncates the Gaussian at 3.5σ
    (11 taps, not 7) and averages only the map cropped by 5 pixels on every side: on a
    32×32 float64 image of a 16×16 unit square plus N(0, 0.2²) noise (``torch.randn`` with
    seed 0) against the clean square, this function gives 0.261 and scikit-image 0.592.

    Args:
        x_hat: reconstruction.
        x: ground truth.
        data_range: dynamic range ``L`` of the pixel values, ``> 0``.
        window_size: odd window size, ``3 <= window_size``, ``window_size // 2 < min(H, W)``.
        reduction: ``"none"`` → one value per image, ``"mean"`` → batch mean.

    Returns:
        SSIM in ``[-1, 1]``.

    Raises:
        TypeError: if an input is not a floating tensor.
        ValueError: on rank/shape mismatch, a bad window, non-positive ``data_range``,
            non-finite inputs, or an unknown reduction.

    Shape:
        - x_hat, x: :math:`(B, C, H, W)`.
        - Output: :math:`(B,)`, or :math:`()` for ``reduction="mean"``.

    Example:
        >>> x = torch.rand(2, 1, 16, 16)
        >>> ssim(x, x).tolist()
        [1.0, 1.0]
    """
    from kornia.metrics import ssim as _kornia_ssim

    func = "ssim"
    _check_pair(x_hat, x, func)
    _check_nonempty(x, "x", func)
    check_finite(x_hat, "x_hat", func)
    check_finite(x, "x", func)
    data_range = check_positive(data_range, "data_range", func)
    if isinstance(window_size, bool) or not isinstance(window_size, int):
        raise TypeError(f"{func}: expected window_size to be an int, got {type(window_size)}")
    if window_size < 3 or window_size % 2 == 0 or window_size // 2 >= min(x.shape[-2:]):
        raise ValueError(
            f"{func}: expected an odd window_size >= 3 with window_size // 2 < min(H, W) = "
            f"{min(x.shape[-2:])}, got {window_size}"
        )
    # SSIM is invariant under x -> x/L with c1, c2 scaled by 1/L² (numerator and
    # denominator both scale by 1/L⁴): compare on the unit range, where (0.01·L)² and
    # μ², σ² cannot overflow (L = 1e30 gave NaN in float32)
    if x.is_meta or x_hat.is_meta:  # shape inference: kornia's window has no meta kernel
        return _reduce(x.new_empty(x.shape[0]), reduction, func)
    xh, xs = x_hat / data_range, x / data_range
    for name, t in (("x_hat", xh), ("x", xs)):
        if not is_tracing() and not bool(torch.isfinite(t).all()):  # one host read, at entry
            raise ValueError(f"{func}: data_range {data_range:g} is too small for {name}: "
                             f"{name} / data_range overflows {t.dtype}")
    smap = _kornia_ssim(xh, xs, window_size, max_val=1.0, eps=0.0)
    return _reduce(smap.flatten(1).mean(1), reduction, func)


class SSIM(nn.Module):
    """Module wrapper of :func:`ssim` (Wang et al., 2004)."""

    def __init__(self, data_range: float = 1.0, window_size: int = 7, reduction: str = "none"):
        super().__init__()
        check_positive(data_range, "data_range", "SSIM")
        _check_window(window_size, "SSIM")
        _check_reduction(reduction, "SSIM")
        self.data_range, self.window_size, self.reduction = data_range, window_size, reduction

    def forward(self, x_hat: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        return ssim(x_hat, x, self.data_range, self.window_size, self.reduction)


def depth_rmse(
    depth_hat: torch.Tensor,
    depth: torch.Tensor,
    mask: torch.Tensor | None = None,
    reduction: str = "none",
) -> torch.Tensor:
    r"""Root-mean-square depth error in metres, over the pixels of ``mask``.

    .. math::
        \mathrm{RMSE} = \sqrt{\frac{\sum_p m(p)\,(\hat z(p) - z(p))^2}{\sum_p m(p)}}

    A zero error has a zero gradient (not the NaN of ``sqrt`` at 0).

    Args:
        depth_hat: estimated depth in metres.
        depth: true depth in metres.
        mask: bool tensor broadcastable to ``depth`` (e.g. ``(B, 1, H, W)`` or ``(H, W)``),
            ``True`` where the error counts; ``None`` = every pixel. Each image needs at
            least one ``True`` pixel.
        reduction: ``"none"`` → one value per image, ``"mean"`` → batch mean.

    Returns:
        RMSE in metres.

    Raises:
        TypeError: if an input is not a floating tensor or ``mask`` is not bool.
        ValueError: on rank/shape mismatch, images without pixels, a mask that does not
            broadcast or leaves an image empty, non-finite inputs, or an unknown reduction.

    Shape:
        - depth_hat, depth: :math:`(B, C, H, W)`.
        - Output: :math:`(B,)`, or :math:`()` for ``reduction="mean"``.

    Example:
        >>> z = torch.full((1, 1, 4, 4), 2.0)
        >>> float(depth_rmse(z + 0.5, z))
        0.5
    """
    func = "depth_rmse"
    _check_image(depth_hat, "depth_hat", func)
    _check_image(depth, "depth", func)
    if depth_hat.shape != depth.shape:
        raise ValueError(
            f"{func}: expected depth_hat and depth of the same shape, got "
            f"{tuple(depth_hat.shape)} and {tuple(depth.shape)}"
        )
    _check_nonempty(depth, "depth", func)
    _check_reduction(reduction, func)
    check_finite(depth_hat, "depth_hat", func)
    check_finite(depth, "depth", func)
    if mask is not None:
        if not isinstance(mask, torch.Tensor) or mask.dtype != torch.bool:
            got = mask.dtype if isinstance(mask, torch.Tensor) else type(mask).__name__
            raise TypeError(f"{func}: expected mask to be a bool tensor or None, got {got}")
        try:
            m = torch.broadcast_to(mask.to(device=depth.device), depth.shape)
        except RuntimeError:
            raise ValueError(f"{func}: expected mask broadcastable to {tuple(depth.shape)}, "
                             f"got {tuple(mask.shape)}") from None
        count = m.flatten(1).sum(1)
        if not bool((count > 0).all()):
            raise ValueError(f"{func}: mask selects no pixel in some image")
    # RMSE = 2·s·sqrt(mean((h/s)²)) with h = (ẑ − z)/2, s = max|h| per image: no square or
    # difference overflows (a 1e30 m error is 1e30, not inf, in float32)
    h = depth_hat / 2 - depth / 2
    s = h.abs().flatten(1).amax(1)
    if mask is not None:
        # s is the largest error over all pixels; where the masked pixels' largest error is
        # below s·tiny^(1/4), their (h/s)² would underflow (1e-3 m next to a masked-out 1e25 m
        # gave 0 in float32): scale by the masked pixels there. Elsewhere s stays, so the
        # value is the one of the unmasked formula, bit for bit.
        s_in = torch.where(m, h.abs(), torch.zeros_like(h)).flatten(1).amax(1)
        far = (s_in > 0) & (s_in < s * torch.finfo(h.dtype).tiny ** 0.25)
        s = torch.where(far, s_in, s)
    s = torch.where(s > 0, s, torch.ones_like(s))
    if mask is not None:  # masked-out errors may exceed s a lot now: keep them out of h/s
        h = torch.where(m, h, torch.zeros_like(h))
    err = (h / s.view(-1, *([1] * (h.ndim - 1)))).pow(2)
    if mask is None:
        ms = err.flatten(1).mean(1)
    else:
        ms = torch.where(m, err, torch.zeros_like(err)).flatten(1).sum(1) / count.to(err.dtype)
    # sqrt with a zero (not NaN) gradient at a zero error: sqrt'(0) = inf times 0
    some = ms > 0
    root = torch.where(some, torch.where(some, ms, torch.ones_like(ms)).sqrt(),
                       torch.zeros_like(ms))
    return _reduce(2 * s * root, reduction, func)


class DepthRMSE(nn.Module):
    """Module wrapper of :func:`depth_rmse`."""

    def __init__(self, reduction: str = "none") -> None:
        super().__init__()
        self.reduction = _check_reduction(reduction, "DepthRMSE")

    def forward(
        self, depth_hat: torch.Tensor, depth: torch.Tensor, mask: torch.Tensor | None = None
    ) -> torch.Tensor:
        return depth_rmse(depth_hat, depth, mask, self.reduction)


def normalize_image(x: torch.Tensor, mode: str = "minmax") -> torch.Tensor:
    r"""Bring each image of a batch to ``[0, 1]``.

    .. math::
        \operatorname{minmax}(x) = \frac{x - \min x}{\max x - \min x}

    with min and max over ``(C, H, W)`` of each image. A constant image maps to
    zeros (no division by zero, no NaN). ``mode="clip"`` only clamps to ``[0, 1]``
    (for images already on the right scale, e.g. after :func:`affine_fit`).

    Args:
        x: images.
        mode: ``"minmax"`` or ``"clip"``.

    Returns:
        Normalised images, same shape and dtype.

    Raises:
        TypeError: if ``x`` is not a floating tensor.
        ValueError: if ``x`` is not rank 4, holds NaN/Inf, or ``mode`` is unknown.

    Shape:
        - x: :math:`(B, C, H, W)`.
        - Output: :math:`(B, C, H, W)`.

    Example:
        >>> normalize_image(torch.tensor([[[[2.0, 4.0]]]])).tolist()
        [[[[0.0, 1.0]]]]
    """
    func = "normalize_image"
    _check_image(x, "x", func)
    _check_nonempty(x, "x", func)
    check_finite(x, "x", func)
    if mode == "clip":
        return x.clamp(0.0, 1.0)
    if mode != "minmax":
        raise ValueError(f"{func}: expected mode in ('minmax', 'clip'), got {mode!r}")
    flat = x.flatten(1)
    lo = flat.min(1).values.view(-1, 1, 1, 1)
    hi = flat.max(1).values.view(-1, 1, 1, 1)
    # max − min overflows for images spanning more than the dtype's range ([−3e38, 3e38] in
    # float32 gave NaN): halve both sides there (exact, a power of two)
    scale = torch.where(torch.isfinite(hi - lo), torch.ones_like(lo), torch.full_like(lo, 0.5))
    lo = lo * scale
    span = hi * scale - lo
    return (x * scale - lo) / torch.where(span > 0, span, torch.ones_like(span))


class NormalizeImage(nn.Module):
    """Module wrapper of :func:`normalize_image`."""

    def __init__(self, mode: str = "minmax") -> None:
        super().__init__()
        self.mode = mode

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return normalize_image(x, self.mode)


def _pearson(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Per-image Pearson correlation of two ``(B, ...)`` tensors (0 if either is constant).

    Each image, and then each centred image, is first multiplied by the power of two that
    brings its ``max |·|`` into ``[0.5, 1)`` (:func:`~torchtof.recon.base.pow2_scale`): the
    correlation is scale-free, so this changes nothing (exact scaling, bit for bit the same
    value), but ``Σa²·Σb²`` then neither overflows nor underflows (float32 images of
    ``1e±20``)."""
    from .recon.base import pow2_scale  # here: importing the metrics does not load the solvers

    def centred(v: torch.Tensor) -> torch.Tensor:
        v = v.flatten(1)
        v = v * pow2_scale(v, dim=1, band=0)
        v = v - v.mean(1, keepdim=True)
        return v * pow2_scale(v, dim=1, band=0)

    a, b = centred(a), centred(b)
    den = (a.pow(2).sum(1) * b.pow(2).sum(1)).sqrt()
    return (a * b).sum(1) / torch.where(den > 0, den, torch.ones_like(den))


def resolve_sign(
    x_hat: torch.Tensor, polarity: str = "positive", reference: torch.Tensor | None = None
) -> torch.Tensor:
    r"""Normalise a reconstruction to ``[0, 1]`` with the object bright.

    Depth images from the ungated depth bucket ``D_i`` (paper Eq. 10) are negative
    (§3.1): no-photon pixels read 5 m, so ``D_i`` falls as more light arrives.

    .. math::
        \text{positive: } \operatorname{minmax}(\hat x), \quad
        \text{negative: } 1 - \operatorname{minmax}(\hat x), \quad
        \text{auto: } \text{the sign with larger } \operatorname{corr}(\cdot, x_\text{ref})

    ``"negative"`` uses the polarity known from the physics, not the ground truth.
    ``"auto"`` picks per image the sign with the higher Pearson correlation with
    ``reference`` — it **uses the ground truth** (an oracle sign); ties keep positive.

    Args:
        x_hat: reconstructed images.
        polarity: ``"positive"``, ``"negative"`` or ``"auto"``.
        reference: ground truth, same shape as ``x_hat``; required for ``"auto"`` only.

    Returns:
        Images in ``[0, 1]``.

    Raises:
        TypeError: if an input is not a floating tensor.
        ValueError: for an unknown polarity, ``"auto"`` without ``reference``, a shape
            mismatch, or non-finite input.

    Shape:
        - x_hat, reference: :math:`(B, C, H, W)`.
        - Output: :math:`(B, C, H, W)`.

    Example:
        >>> x = torch.tensor([[[[0.0, 1.0]]]])
        >>> resolve_sign(5.0 - x, "auto", reference=x).tolist()
        [[[[0.0, 1.0]]]]
    """
    func = "resolve_sign"
    if polarity not in POLARITIES:
        raise ValueError(f"{func}: expected polarity in {POLARITIES}, got {polarity!r}")
    _check_image(x_hat, "x_hat", func)
    _check_nonempty(x_hat, "x_hat", func)
    check_finite(x_hat, "x_hat", func)
    pos = normalize_image(x_hat)
    if polarity == "positive":
        return pos
    if polarity == "negative":
        return 1.0 - pos
    if reference is None:
        raise ValueError(f"{func}: polarity='auto' needs a reference (the ground truth)")
    _check_pair(x_hat, reference, func, ("x_hat", "reference"))
    check_finite(reference, "reference", func)
    flip = (_pearson(pos, reference) < 0).view(-1, 1, 1, 1)
    return torch.where(flip, 1.0 - pos, pos)


class ResolveSign(nn.Module):
    """Module wrapper of :func:`resolve_sign` (paper §3.1, negative depth images)."""

    def __init__(self, polarity: str = "positive") -> None:
        super().__init__()
        self.polarity = polarity

    def forward(self, x_hat: torch.Tensor, reference: torch.Tensor | None = None) -> torch.Tensor:
        return resolve_sign(x_hat, self.polarity, reference)


def affine_fit(x_hat: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    r"""Least-squares gain and offset that map ``x_hat`` onto ``x``, per image (an oracle).

    .. math::
        (a, b) = \arg\min_{a, b} \lVert a \hat x + b - x \rVert_2^2, \quad
        a = \frac{\operatorname{cov}(\hat x, x)}{\operatorname{var}(\hat x)}, \quad
        b = \bar x - a \bar{\hat x}

    It uses the ground truth, so scores after it are an upper bound for any
    gain/offset/sign correction. A constant ``x_hat`` gives ``a = 0``, ``b = mean(x)``.

    Args:
        x_hat: reconstructed images.
        x: ground truth.

    Returns:
        ``a·x_hat + b`` (not clamped).

    Raises:
        TypeError: if an input is not a floating tensor.
        ValueError: on rank/shape mismatch or non-finite input.

    Shape:
        - x_hat, x: :math:`(B, C, H, W)`.
        - Output: :math:`(B, C, H, W)`.

    Example:
        >>> x = torch.tensor([[[[0.0, 1.0, 0.5]]]])
        >>> torch.allclose(affine_fit(3.0 - 2.0 * x, x), x)
        True
    """
    func = "affine_fit"
    _check_pair(x_hat, x, func)
    check_finite(x_hat, "x_hat", func)
    check_finite(x, "x", func)
    # fit on x̂/s, s = max|x̂| per image (the same affine map, without squares of 1e30 values)
    scale = (x_hat.abs().flatten(1).amax(1) if math.prod(x_hat.shape[1:])
             else x_hat.new_ones(x_hat.shape[0]))
    scale = torch.where(scale > 0, scale, torch.ones_like(scale)).view(-1, 1, 1, 1)
    x_hat = x_hat / scale
    u, v = x_hat.flatten(1), x.flatten(1)
    du = u - u.mean(1, keepdim=True)
    var = du.pow(2).sum(1)
    a = (du * (v - v.mean(1, keepdim=True))).sum(1) / torch.where(
        var > 0, var, torch.ones_like(var)
    )
    b = v.mean(1) - a * u.mean(1)
    return a.view(-1, 1, 1, 1) * x_hat + b.view(-1, 1, 1, 1)


def compare(
    x_hat: torch.Tensor,
    x: torch.Tensor,
    polarity: str = "positive",
    bits: int | None = 8,
    window_size: int = 7,
) -> dict[str, torch.Tensor]:
    """Score a reconstruction against the ground truth with the documented protocol.

    Steps (module docstring): min-max normalise both images per image; resolve the
    polarity of ``x_hat`` (``"positive"``, ``"negative"`` — physics, ``"auto"`` —
    oracle sign, ``"affine"`` — oracle gain/offset, clamped to ``[0, 1]``); PSNR
    (Eqs. 13–14) on ``k``-bit quantised images (``bits=None``: data range 1, no
    quantisation); SSIM with data range 1.

    Args:
        x_hat: reconstruction (any scale, e.g. metres or bucket units).
        x: ground truth (any scale; normalised, taken as positive).
        polarity: ``"positive"``, ``"negative"``, ``"auto"`` or ``"affine"``.
        bits: bit depth ``k`` for the PSNR, or ``None``.
        window_size: SSIM window.

    Returns:
        ``{"psnr": (B,) dB, "ssim": (B,)}``.

    Raises:
        TypeError: if an input is not a floating tensor.
        ValueError: on rank/shape mismatch, non-finite input or unknown polarity.

    Shape:
        - x_hat, x: :math:`(B, C, H, W)`.

    Example:
        >>> x = torch.zeros(2, 1, 8, 8); x[..., 2:6, 3:5] = 1
        >>> compare(x * 7.0 + 1.0, x)["psnr"].tolist()
        [100.0, 100.0]
    """
    func = "compare"
    _check_pair(x_hat, x, func)
    _check_nonempty(x, "x", func)
    check_finite(x_hat, "x_hat", func)
    check_finite(x, "x", func)
    if bits is not None and (isinstance(bits, bool) or not isinstance(bits, int)):
        raise TypeError(f"{func}: expected bits to be an int or None, got {type(bits).__name__}")
    if bits is not None and not 1 <= bits <= 64:
        raise ValueError(f"{func}: expected bits in [1, 64], got {bits}")
    ref = normalize_image(x)
    if polarity == "affine":
        est = normalize_image(affine_fit(x_hat, ref), mode="clip")
    elif polarity in POLARITIES:
        est = resolve_sign(x_hat, polarity, ref)
    else:
        raise ValueError(
            f"{func}: expected polarity in {POLARITIES + ('affine',)}, got {polarity!r}"
        )
    return {
        "psnr": psnr(est, ref, bits=bits, quantize=bits is not None),
        "ssim": ssim(est, ref, 1.0, window_size),
    }
