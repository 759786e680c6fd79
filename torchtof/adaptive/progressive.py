r"""Progressive acquisition: measure patterns in blocks and stop when the image is done.

Patterns are shown in a low-to-high order (cake-cutting by default, Yu 2019), so every
prefix of ``m`` patterns is a good low-resolution basis and the smaller sampling rates are
prefixes of the larger ones. After each block of ``block`` patterns a cheap reconstruction
(the pseudo-inverse ``x̂_m = A_mᵀ y_{1..m}``, which equals g2/DGI up to an affine map for DMD
pairs) is formed and a stopping rule decides whether to go on.

**Rules.** Each coefficient is ``y_i = s_i + e_i`` with noise ``e_i ~ N(0, σ²)``. With
orthonormal rows (``A Aᵀ = I``) Parseval gives ``‖x̂_m − x̂_{m−B}‖² = Σ_{block} y_i²`` for
the pseudo-inverse image, so the rules read coefficients.

- ``"innovation"`` (default): the new block as a validation set for the image of the blocks
  before it. ``x̂`` is the cheap reconstruction of the first ``m − B`` coefficients (TVAL3 with
  the known or estimated ``σ``, or the pseudo-inverse with ``recon="pinv"``); its predicted
  coefficients ``A_b x̂`` are compared with the measured block ``y_b``:

  .. math:: \rho_b = \frac{\|y_b - A_b \hat x\|^2}{B\sigma^2}.

  A block whose innovation is pure noise has ``Bρ_b ~ χ²_B`` (mean 1, std ``√(2/B)``), so
  ``ρ_b − 1`` estimates the signal the block adds beyond the prediction, in units of its
  noise energy. The block is *explained* when

  .. math:: \rho_b \le 1 + \kappa + z\sqrt{2/B},

  i.e. its unexplained signal is at most ``κ`` (``snr``) times its noise energy, with a
  ``z``-σ margin for the χ² spread (``z = 2``). ``κ = 1`` is the Wiener point: a coefficient
  whose signal energy is below its noise energy lowers the error of the linear estimate
  when it is left out, so acquiring it buys nothing; ``κ = 0`` is the pure-noise test. Stop
  after ``patience`` consecutive explained blocks: the scene's prior (TV) already predicts
  what the next patterns measure, up to the noise. Under noise this is the robust rule: it
  compares with ``σ``, not with zero, and it keeps acquiring as long as blocks carry
  detail above the noise, however small that detail is next to the image. With
  ``recon="pinv"`` the prediction is 0 (``A_b A_{<b}ᵀ = 0``) and the rule tests the raw
  block energy, ``‖y_b‖² ≤ Bσ²(1 + κ + z√(2/B))``.
- ``"change"``: the noise-debiased relative change of the image,

  .. math:: r_b = \sqrt{\frac{\max(\sum_{i\in b} y_i^2 - B\sigma^2,\ 0)}
                 {\max(\sum_{i\le m} y_i^2 - m\sigma^2,\ \epsilon)}},

  stop after ``patience`` consecutive blocks with ``r_b < tol``. With ``σ = 0`` it is the
  plain ``‖x̂_m − x̂_{m−B}‖/‖x̂_m‖``; without the debiasing every block adds noise energy
  ``Bσ²`` and the plain change never falls below ``√(Bσ²)/‖x̂‖``. Being relative, it stops
  dense scenes early (their energy sits in the low orders) even when later blocks still
  carry signal.
- ``"energy"``: stop when the captured signal energy ``Σ(y_i² − σ²)`` reaches ``target`` of
  a bound on the total energy from the intensity/depth sum, ``‖x‖² ≤ max|x| · Σ|x|``
  (Hölder; equality for a binary object), ``Σx = n·y₀`` from the DC coefficient of the
  orthonormal rows and ``max|x|`` from the pseudo-inverse image. Noise inflates ``max|x̂|``,
  so the rule stops late rather than early; it needs the DC row measured first.

``σ`` is ``noise_sigma`` when the caller knows it (repeated frames:
:func:`~torchtof.adaptive.noise.noise_from_repeats`); with ``noise_sigma="pairs"`` it is
re-estimated after every block from the pair sums of all pairs so far, read from
``buckets[kind + "_sum"]`` (:func:`~torchtof.adaptive.noise.pair_sums`,
:func:`~torchtof.adaptive.noise.noise_from_pair_sums`: free, no repeated patterns);
otherwise (``None``) it is estimated from the high-order half of the blocks measured so far
(:func:`~torchtof.adaptive.noise.noise_from_blocks`).

**Defaults** ``block=32``, ``snr=1``, ``z=2``, ``patience=1``, ``min_patterns=128`` (SR 12.5 %
at n = 32: from 64 coefficients the TV prediction of a small object is still poor, and one
lucky block stopped it at 64 in 2 of 6 runs, −5 dB). Chosen on the paper's experiment at
n = 32, SR ≤ 37.5 %, seeds other than the bench's (README ``--auto`` section).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch

from .._checks import (
    check_broadcast,
    check_finite,
    check_in_range,
    check_int,
    check_nonnegative,
    check_positive,
    check_real,
    check_tensor,
)
from ..operators.patterns import ORDERS, check_n_order
from .noise import noise_from_blocks, noise_from_pair_sums

__all__ = ["PROGRESSIVE_RULES", "BUCKET_KINDS", "ProgressiveStop", "ProgressiveResult",
           "block_statistics", "run_progressive"]

PROGRESSIVE_RULES = ("innovation", "change", "energy")
#: keys of the bucket dict that :class:`ProgressiveStop` is called with.
BUCKET_KINDS = ("depth", "gated", "intensity")


def block_statistics(y: torch.Tensor, block: int, noise_sigma: torch.Tensor | float,
                     n: int | None = None, order: str = "cake_cutting") -> dict[str, torch.Tensor]:
    """Per-block statistics of the rules in the module docstring (functional core).

    Args:
        y: signed orthonormal-Hadamard buckets ``(B, C, M)`` in acquisition order (real
            floating point, finite).
        block: block length (an int ``>= 1``).
        noise_sigma: ``σ >= 0`` (a number, or a tensor broadcastable to ``(B, C)``).
        n: image side (needed for ``"energy"``; ``None`` skips it), a power of two with
            ``M <= n²``.
        order: Hadamard order of the patterns (its first row must be the constant one).

    Returns:
        ``"m"`` ``(K,)`` patterns after each block, ``"change"`` ``(B, C, K)`` debiased
        relative change ``r_b``, ``"captured"`` ``(B, C, K)`` debiased captured energy and,
        with ``n``, ``"fraction"`` ``(B, C, K)``: captured energy over the Hölder bound.

    Raises:
        TypeError: ``y`` not a real floating-point tensor, ``block`` or ``n`` not an int,
            ``noise_sigma`` neither a number nor a real floating-point tensor.
        ValueError: ``y`` not ``(B, C, M >= 1)`` or with NaN/Inf, ``block < 1``,
            ``noise_sigma`` negative, NaN/Inf or not broadcastable to ``(B, C)``, ``n`` not a
            power of two in range or ``M > n²``, unknown ``order``.
    """
    fn = "block_statistics"
    check_real(y, "y", fn)
    if y.ndim != 3 or y.shape[-1] < 1:
        raise ValueError(f"{fn}: expected y of shape (B, C, M >= 1), got {tuple(y.shape)}")
    check_int(block, "block", fn, lo=1)
    if order not in ORDERS:
        raise ValueError(f"{fn}: expected order in {ORDERS}, got {order!r}")
    if n is not None:
        n = check_n_order(n, order, fn)
        if y.shape[-1] > n * n:
            raise ValueError(f"{fn}: expected at most n² = {n * n} buckets for n = {n}, got "
                             f"M = {y.shape[-1]} (the n of another record?)")
    _check_sigma(noise_sigma, fn, tuple(y.shape[:-1]))
    check_finite(y, "y", fn)
    return _block_statistics(y, block, noise_sigma, n, order)


def _check_sigma(noise_sigma, fn: str, shape: tuple | None = None) -> None:
    """``noise_sigma`` a number ``>= 0`` or a real tensor ``>= 0`` (broadcastable to
    ``shape`` when given), finite."""
    if isinstance(noise_sigma, torch.Tensor):
        check_real(noise_sigma, "noise_sigma", fn)
        if shape is not None:
            check_broadcast(noise_sigma, shape, "noise_sigma", fn, "(B, C)")
        elif noise_sigma.ndim > 2:
            raise ValueError(f"{fn}: expected noise_sigma broadcastable to (B, C), got shape "
                             f"{tuple(noise_sigma.shape)}")
        check_finite(noise_sigma, "noise_sigma", fn)
        check_nonnegative(noise_sigma, "noise_sigma", fn)
    else:
        check_positive(noise_sigma, "noise_sigma", fn, strict=False)


def _block_statistics(y: torch.Tensor, block: int, noise_sigma, n: int | None,
                      order: str) -> dict[str, torch.Tensor]:
    """:func:`block_statistics` without the checks (inputs checked by the caller)."""
    m = y.shape[-1]
    ends = list(range(block, m + 1, block))
    if not ends or ends[-1] != m:
        ends.append(m)
    sig2 = torch.as_tensor(noise_sigma, dtype=y.dtype, device=y.device) ** 2
    sig2 = sig2.expand(y.shape[:-1])[..., None]
    cum = torch.cumsum(y * y, dim=-1)
    idx = torch.tensor([e - 1 for e in ends], device=y.device)
    tot = cum[..., idx]
    ms = torch.tensor(ends, dtype=y.dtype, device=y.device)
    prev = torch.cat([torch.zeros_like(tot[..., :1]), tot[..., :-1]], dim=-1)
    width = ms - torch.cat([ms.new_zeros(1), ms[:-1]])
    gain = (tot - prev - width * sig2).clamp_min(0)
    captured = (tot - ms * sig2).clamp_min(torch.finfo(y.dtype).tiny)
    out = {"m": ms, "change": (gain / captured).sqrt(), "captured": captured}
    if n is not None:
        from ..operators import Hadamard

        bounds = []
        for e in ends:  # cheap pinv image after each block (Aᵀy): max|x̂| for the bound
            xm = Hadamard(n, m=e, order=order).adjoint(y[..., :e])
            bounds.append(xm.abs().amax(dim=(-2, -1)) * (n * y[..., 0]).abs())
        out["fraction"] = captured / torch.stack(bounds, -1).clamp_min(torch.finfo(y.dtype).tiny)
    return out


class ProgressiveStop:
    """Stopping rule of progressive acquisition, called after each block of patterns.

    ``stop(buckets) -> bool``: ``buckets["depth"|"gated"|"intensity"]`` are the SIGNED
    orthonormal-Hadamard buckets measured so far, ``(1, 1, m)`` in pattern order; the rule
    reads ``buckets[kind]``. A hardware ``acquire(..., block=..., stop=...)`` passes the
    differences ``y⁺ − y⁻`` of the DMD pairs, ``n`` times the orthonormal buckets: divide them
    by ``n`` first (``stop=lambda b: rule({k: v / n for k, v in b.items()})``, as
    ``torchtof acquire --auto`` does), or a known ``noise_sigma`` is ``n`` times too
    small for them and the rule never stops. ``True`` means: stop, more patterns would not
    change the image beyond the noise (module docstring).

    Args:
        n: image side (DMD grid ``n × n``), a power of two in ``[4, 256]``: the ``n`` of the
            record (the rule's operators are ``Hadamard(n, m, order)``).
        block: patterns per block (the caller's block), an int ``>= 4`` (a Python or NumPy
            integer, as ``patience`` and ``min_patterns``).
        rule: ``"innovation"`` (default), ``"change"`` or ``"energy"``.
        kind: which buckets the rule reads (``"gated"``, ``"depth"`` or ``"intensity"``).
        snr: ``"innovation"``: ``κ``, a block is explained when ``ρ_b ≤ 1 + κ + z√(2/B)``.
        z: ``"innovation"``: margin for the χ² spread of ``ρ_b``.
        tol: ``"change"``: stop when ``r_b < tol``.
        patience: consecutive explained (``"innovation"``) or small (``"change"``) blocks
            (an int ``>= 1``).
        target: ``"energy"``: captured fraction of the energy bound, in ``(0, 1]``.
        noise_sigma: known noise std of the buckets (a number, or a tensor broadcastable to
            the buckets' ``(B, C)``; ``>= 0``, finite); ``"pairs"``: estimated from the pair
            sums ``buckets[kind + "_sum"]`` after every block; ``None``: from the blocks.
        min_patterns: never stop before this many patterns (an int ``>= 0``; at least two
            blocks).
        recon: cheap reconstruction of ``"innovation"``: ``"tv"`` (TVAL3) or ``"pinv"``.
        order: Hadamard order of the patterns.

    Attributes:
        last: statistics of the last call (``m``, ``sigma``, ``rho``/``change``/``fraction``,
            ``reason``).

    Raises:
        TypeError, ValueError: bad configuration (checked at construction, ``noise_sigma``
            also whenever it is set); at call time buckets without ``kind``, of a wrong shape,
            with NaN/Inf or with more than ``n²`` patterns, a tensor ``noise_sigma`` that does
            not broadcast to their ``(B, C)``.

    Example:
        >>> from torchtof.operators import Hadamard
        >>> x = torch.zeros(1, 1, 32, 32); x[..., 10:20, 12:18] = 1.0
        >>> y = Hadamard(32, sr=0.375)(x)
        >>> y = y + 0.01 * torch.randn(y.shape, generator=torch.Generator().manual_seed(0))
        >>> stop = ProgressiveStop(32, noise_sigma=0.01)
        >>> next(m for m in range(32, 385, 32) if stop({"gated": y[..., :m]})) < 384
        True
    """

    def __init__(self, n: int, block: int = 32, rule: str = "innovation", kind: str = "gated",
                 snr: float = 1.0, z: float = 2.0, tol: float = 0.1, patience: int = 1,
                 target: float = 0.9,
                 noise_sigma: float | torch.Tensor | None = None, min_patterns: int = 128,
                 recon: str = "tv", order: str = "cake_cutting") -> None:
        fn = "ProgressiveStop"
        n = check_n_order(n, order, fn)
        block = check_int(block, "block", fn, lo=4)
        if rule not in PROGRESSIVE_RULES:
            raise ValueError(f"{fn}: expected rule in {PROGRESSIVE_RULES}, got {rule!r}")
        if kind not in BUCKET_KINDS:
            raise ValueError(f"{fn}: expected kind in {BUCKET_KINDS}, got {kind!r}")
        if recon not in ("tv", "pinv"):
            raise ValueError(f"{fn}: expected recon in ('tv', 'pinv'), got {recon!r}")
        check_positive(tol, "tol", fn)
        check_positive(z, "z", fn, strict=False)
        check_positive(snr, "snr", fn, strict=False)
        patience = check_int(patience, "patience", fn, lo=1)
        target = check_in_range(target, 0.0, 1.0, "target", fn, lo_open=True)
        min_patterns = check_int(min_patterns, "min_patterns", fn, lo=0)
        self.n, self.block, self.rule, self.kind, self.recon = n, block, rule, kind, recon
        self.z, self.tol, self.patience, self.target = float(z), float(tol), patience, float(target)
        self.snr = float(snr)
        self.noise_sigma, self.order = noise_sigma, order  # noise_sigma: checked by its setter
        self.min_patterns = max(min_patterns, 2 * block)
        self.last: dict = {}
        self._streak = 0
        self._cache: tuple | None = None  # (kind, m, first-bucket checksum, x̂)

    @property
    def noise_sigma(self) -> float | torch.Tensor | str | None:
        """Known ``σ`` (a number or a tensor broadcastable to ``(B, C)``, ``>= 0``), ``"pairs"``
        or ``None`` (class docstring); checked whenever it is set."""
        return self._noise_sigma

    @noise_sigma.setter
    def noise_sigma(self, value) -> None:
        fn = "ProgressiveStop"
        if isinstance(value, str):
            if value != "pairs":
                raise ValueError(f"{fn}: expected noise_sigma to be a number, a tensor, 'pairs' "
                                 f"or None, got {value!r}")
        elif value is not None:
            _check_sigma(value, fn)
        self._noise_sigma = value

    def _sigma(self, y: torch.Tensor, buckets: dict) -> torch.Tensor:
        if self.noise_sigma is None:
            return noise_from_blocks(y, self.block)
        if isinstance(self.noise_sigma, str):  # "pairs": from the pair sums so far
            key = f"{self.kind}_sum"
            if key not in buckets or buckets[key].shape != y.shape:
                raise ValueError(f"ProgressiveStop: noise_sigma='pairs' needs buckets[{key!r}] "
                                 f"of shape {tuple(y.shape)}, got "
                                 f"{tuple(buckets[key].shape) if key in buckets else None}")
            return noise_from_pair_sums(buckets[key].to(y.dtype)).clamp_min(1e-300)
        return torch.as_tensor(self.noise_sigma, dtype=y.dtype).expand(y.shape[:-1])

    def _image(self, y: torch.Tensor, sigma: torch.Tensor) -> torch.Tensor:
        """Cheap reconstruction of the prefix ``y`` (cached for the next block)."""
        from ..operators import Hadamard
        from ..recon.tval3 import tval3

        key = (self.kind, y.shape[-1], float(y[..., 0].sum()), float(y[..., -1].sum()))
        if self._cache is not None and self._cache[0] == key:
            return self._cache[1]
        A = Hadamard(self.n, m=y.shape[-1], order=self.order)
        with torch.no_grad():
            x = A.adjoint(y) if self.recon == "pinv" else tval3(y, A, noise_sigma=sigma)
        self._cache = (key, x)
        return x

    def __call__(self, buckets: dict[str, torch.Tensor]) -> bool:
        fn = "ProgressiveStop"
        if not isinstance(buckets, dict) or self.kind not in buckets:
            raise ValueError(f"{fn}: expected a dict of buckets with key {self.kind!r}, got "
                             f"{sorted(buckets) if isinstance(buckets, dict) else type(buckets)}")
        y = buckets[self.kind]
        check_tensor(y, f"buckets[{self.kind!r}]", fn)
        if y.ndim != 3 or y.shape[-1] < 1:
            raise ValueError(f"{fn}: expected buckets[{self.kind!r}] of shape (B, C, m >= 1), "
                             f"got {tuple(y.shape)}")
        m, bsz = y.shape[-1], self.block
        if m > self.n * self.n:
            raise ValueError(f"{fn}: buckets[{self.kind!r}] hold {m} patterns, more than the "
                             f"n² = {self.n * self.n} of n = {self.n} (the n of another record?)")
        if isinstance(self.noise_sigma, torch.Tensor):
            check_broadcast(self.noise_sigma, tuple(y.shape[:-1]), "noise_sigma", fn, "(B, C)")
        check_finite(y, f"buckets[{self.kind!r}]", fn)
        if m <= self.last.get("m", 0):  # not a continuation of the last call: a new acquisition
            self.reset()
        self.last = {"m": m, "reason": None}
        if m < 2 * bsz:
            self._streak = 0
            return False
        y = y.to(torch.float64)
        sigma = self._sigma(y, buckets)
        self.last["sigma"] = float(sigma.max())
        if self.rule == "innovation":
            from ..operators import Hadamard

            mb = bsz * ((m - 1) // bsz)  # start of the last (possibly partial) block
            x = self._image(y[..., :mb], sigma)
            pred = Hadamard(self.n, m=m, order=self.order)(x)[..., mb:]
            w = m - mb
            rho = ((y[..., mb:] - pred) ** 2).sum(-1) / (w * sigma**2).clamp_min(1e-300)
            explained = bool((rho <= 1 + self.snr + self.z * (2.0 / w) ** 0.5).all())
            self.last["rho"] = float(rho.max())
            self._image(y, sigma)  # the image of this prefix predicts the next block
            self._streak = self._streak + 1 if explained else 0
            done = m >= self.min_patterns and self._streak >= self.patience
            if done:
                self.last["reason"] = (
                    f"last {self._streak} block(s) predicted by the {self.recon} image: "
                    f"rho {float(rho.max()):.2f} <= 1 + {self.snr:g} + {self.z:g}*sqrt(2/B)")
            return done
        st = _block_statistics(y, bsz, sigma, self.n if self.rule == "energy" else None,
                               self.order)
        if self.rule == "change":
            r = st["change"][..., -1]
            self.last["change"] = float(r.max())
            self._streak = self._streak + 1 if bool((r < self.tol).all()) else 0
            done = m >= self.min_patterns and self._streak >= self.patience
            if done:
                self.last["reason"] = f"debiased change < {self.tol:g} for {self._streak} blocks"
            return done
        frac = st["fraction"][..., -1]
        self.last["fraction"] = float(frac.min())
        done = m >= self.min_patterns and bool((frac >= self.target).all())
        if done:
            self.last["reason"] = f"captured energy >= {self.target:g} of the Hölder bound"
        return done

    def reset(self) -> None:
        """Forget the streak and the cached image (a new acquisition)."""
        self._streak, self._cache, self.last = 0, None, {}


@dataclass
class ProgressiveResult:
    """What :func:`run_progressive` did: ``m`` patterns used, why it stopped, the statistics
    after every block (``history``: list of :attr:`ProgressiveStop.last` dicts)."""

    m: int
    m_max: int
    reason: str
    history: list[dict] = field(default_factory=list)


def run_progressive(buckets: dict[str, torch.Tensor], stop: ProgressiveStop,
                    block: int | None = None) -> ProgressiveResult:
    """Replay a recorded or simulated full-length run through ``stop``, block by block.

    Calls ``stop({k: v[..., :m]})`` for ``m = block, 2·block, …`` exactly as a live
    acquisition loop would, and returns at the first ``True`` (or at the end of the record).
    Tensors in, no hardware needed.

    Args:
        buckets: signed buckets ``(1, 1, M)`` per kind (``"depth"``, ``"gated"``, ``"intensity"``;
            only ``stop.kind`` is required).
        stop: the rule (a :class:`ProgressiveStop`; it is reset first and its ``last`` holds
            the statistics of the last block afterwards).
        block: block length, an int ``>= 1`` (``None``: ``stop.block``).

    Returns:
        :class:`ProgressiveResult`.

    Raises:
        TypeError: ``buckets`` not a dict of tensors, ``stop`` not a :class:`ProgressiveStop`,
            ``block`` not an int.
        ValueError: buckets of different lengths or not ``(B, C, M)``, without
            ``stop.kind``, more than ``stop.n²`` patterns; ``block < 1``.
    """
    fn = "run_progressive"
    if not isinstance(buckets, dict) or not buckets:
        raise TypeError(f"{fn}: expected a non-empty dict of bucket tensors, got "
                        f"{type(buckets).__name__ if not isinstance(buckets, dict) else '{}'}")
    for k, v in buckets.items():
        check_tensor(v, f"buckets[{k!r}]", fn)
    if not isinstance(stop, ProgressiveStop):
        raise TypeError(f"{fn}: expected stop to be a ProgressiveStop, got {type(stop).__name__}")
    if block is not None:
        block = check_int(block, "block", fn, lo=1)
    lens = {v.shape[-1] for v in buckets.values()}
    if len(lens) != 1 or any(v.ndim != 3 for v in buckets.values()):
        raise ValueError(f"{fn}: expected buckets of shape (B, C, M) with one M, got "
                         f"{ {k: tuple(v.shape) for k, v in buckets.items()} }")
    if stop.kind not in buckets:
        raise ValueError(f"{fn}: expected buckets with the stop's kind {stop.kind!r}, got "
                         f"{sorted(buckets)}")
    big_m = lens.pop()
    if big_m > stop.n * stop.n:
        raise ValueError(f"{fn}: the buckets hold {big_m} patterns, more than the n² = "
                         f"{stop.n * stop.n} of the stop's n = {stop.n} (the n of another record?)")
    block = stop.block if block is None else block
    stop.reset()
    history = []
    for m in list(range(block, big_m, block)) + [big_m]:
        done = stop({k: v[..., :m] for k, v in buckets.items()})
        history.append(dict(stop.last))
        if done:
            return ProgressiveResult(m, big_m, stop.last.get("reason") or "rule", history)
    return ProgressiveResult(big_m, big_m, "end of record (max SR)", history)
