"""DMD split of ±1 Hadamard rows into two 0/1 patterns.

A DMD mirror is on or off, so a ±1 row ``h`` is shown as ``φ⁺ = (1 + h)/2`` and
``φ⁻ = (1 − h)/2``; the differential bucket ``y⁺ − y⁻ = ⟨h, x⟩`` recovers the ±1
measurement and cancels offsets common to both frames (ambient light, the 5 m
"no photon" floor). ``DMDSplit(A)`` is the 0/1 operator with ``2M`` rows, interleaved
``[φ⁺_1, φ⁻_1, φ⁺_2, φ⁻_2, …]`` (the acquisition order); it is computed from the fast
Hadamard transform: ``y^± = (Σx ± √N·(Ax)) / 2``.
"""

from __future__ import annotations

import torch

from .._checks import check_finite, check_int, check_rank, check_shape
from .._memory import check_memory, check_rows, itemsize
from .base import LinearOperator
from .hadamard import Hadamard

#: ±1 rows split at a time by :meth:`DMDSplit.patterns`.
PATTERN_CHUNK = 256

__all__ = ["DMDSplit", "combine_split", "split_patterns"]


def split_patterns(patterns: torch.Tensor) -> torch.Tensor:
    """±1 patterns ``(M, n, n)`` → interleaved 0/1 DMD patterns ``(2M, n, n)``."""
    func = "split_patterns"
    check_rank(patterns, 3, "patterns", func, "(M, n, n)")
    if patterns.is_complex():
        raise TypeError(
            f"{func}: expected patterns to be a real tensor, got dtype {patterns.dtype}"
        )
    check_finite(patterns, "patterns", func)
    plus = (1 + patterns) / 2
    minus = (1 - patterns) / 2
    return torch.stack((plus, minus), dim=1).reshape(-1, *patterns.shape[1:])


def combine_split(y_split: torch.Tensor, n: int) -> torch.Tensor:
    """Interleaved DMD buckets ``(B, C, 2M)`` → orthonormal Hadamard measurements
    ``(B, C, M)``: ``y = (y⁺ − y⁻) / n`` (``n = √N``, a positive int: the DMD side), so
    ``combine_split(S x) = A x``."""
    check_shape(y_split, (None, None, None), "y_split", "combine_split", "(B, C, 2M)")
    check_int(n, "n", "combine_split", lo=1)
    if y_split.shape[-1] % 2:
        raise ValueError(
            f"combine_split: expected y_split with an even number of measurements, "
            f"got {y_split.shape[-1]}"
        )
    check_finite(y_split, "y_split", "combine_split")
    y = y_split.reshape(*y_split.shape[:-1], y_split.shape[-1] // 2, 2)  # no -1: B = 0
    return (y[..., 0] - y[..., 1]) / n


class DMDSplit(LinearOperator):
    """0/1 DMD operator of a :class:`Hadamard` operator: ``2M`` rows ``φ⁺, φ⁻`` interleaved.

    Args:
        hadamard: the ±1 operator ``A`` whose rows are split.

    Shape:
        ``(B, C, n, n) -> (B, C, 2M)``.

    Note:
        The buckets come from the transform as a difference, ``(Σx − √N·(Ax))/2`` for ``φ⁻``
        (``Σx`` is the all-on row's own coefficient, so that row's all-off frame reads exactly
        0); any other bucket whose exact value is 0 for ``x ≥ 0`` (a scene dark wherever its
        ``φ⁻`` is on) is computed to within rounding, about ``ε·Σ|x|``, and can be slightly
        negative. Clamp before drawing counts from it
        (``torch.poisson(scale * y.clamp_min(0))``); ``PatternOperator(S.patterns())``
        sums non-negative products instead (exactly ``≥ 0``, at dense cost).
    """

    def __init__(self, hadamard: Hadamard) -> None:
        if not isinstance(hadamard, Hadamard):
            raise TypeError(
                "DMDSplit: expected hadamard to be a Hadamard operator, "
                f"got {type(hadamard).__name__}"
            )
        super().__init__(hadamard.n, 2 * hadamard.m)
        self.hadamard = hadamard
        # every Hadamard order starts with the all-on row, natural index 0 (its sort key is
        # the smallest in each order; tests/operators: test_every_order_starts_with_the_dc_row);
        # a subclass with its own forward (e.g. signed rows) may change that row: summed
        self._dc_first = type(hadamard).forward is Hadamard.forward

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        self._check_x(x, "DMDSplit.forward")
        if x.dtype in (torch.float16, torch.bfloat16):
            # as Hadamard: computed in float32, rounded once (in float16 ⟨1, x⟩/2 and
            # n/2·⟨h, x⟩ each overflowed to inf where their difference y⁻ is small: NaN)
            return self._forward(x.float()).to(x.dtype)
        return self._forward(x)

    def _forward(self, x: torch.Tensor) -> torch.Tensor:
        half_h = self.hadamard(x) * (self.n / 2)  # ⟨h, x⟩/2 with ±1 rows
        if self._dc_first:
            # ⟨1, x⟩/2 from the same transform: the all-on row's own coefficient, so the
            # all-off frame φ⁻ of that row is exactly 0 (not ±ε·Σx from two roundings)
            half_total = half_h[..., :1]
        else:
            half_total = (x / 2).sum(dim=(-2, -1)).unsqueeze(-1)  # ⟨1, x⟩/2, halved first
        return torch.stack((half_total + half_h, half_total - half_h), dim=-1).flatten(-2)

    def adjoint(self, y: torch.Tensor) -> torch.Tensor:
        self._check_y(y, "DMDSplit.adjoint")
        if y.dtype in (torch.float16, torch.bfloat16):  # see forward
            return self._adjoint(y.float()).to(y.dtype)
        return self._adjoint(y)

    def _adjoint(self, y: torch.Tensor) -> torch.Tensor:
        y2 = y.reshape(*y.shape[:-1], self.m // 2, 2)  # no -1: B = 0 has no size to infer
        s, d = y2[..., 0] + y2[..., 1], y2[..., 0] - y2[..., 1]
        ones = s.sum(dim=-1)[..., None, None] / 2
        return ones + self.hadamard.adjoint(d) * (self.n / 2)

    def combine(self, y_split: torch.Tensor) -> torch.Tensor:
        """``(y⁺ − y⁻)/n``: the measurements of the underlying orthonormal ``A``."""
        return combine_split(y_split, self.n)

    def patterns(
        self, dtype: torch.dtype = torch.float32, start: int = 0, stop: int | None = None
    ) -> torch.Tensor:
        """The ``2M`` 0/1 DMD patterns ``(2M, n, n)`` in acquisition order, or only rows
        ``start:stop`` of them.

        Built in chunks of :data:`PATTERN_CHUNK` ±1 rows straight into the result, so the
        peak is the result itself (``(stop − start)·n²`` entries) plus one chunk, never the
        ±1 stack next to its two halves; :meth:`iter_patterns` streams them instead.

        Raises:
            ValueError: for a range outside ``[0, 2M]`` or a result larger than the memory
                limit (:func:`torchtof.set_memory_limit`).
        """
        func = "DMDSplit.patterns"
        # 0/1 masks: any real dtype, bool and uint8 (a DMD's own) included; for an integer
        # or bool dtype the ±1 rows are built in float32 (exact) and each chunk cast once
        if not isinstance(dtype, torch.dtype) or dtype.is_complex:
            raise TypeError(f"{func}: expected dtype a real torch.dtype (floating, integer or "
                            f"bool: the patterns are 0/1), got {dtype!r}")
        build = dtype if dtype.is_floating_point else torch.float32
        start, stop = check_rows(start, stop, self.m, func)
        n = self.n
        rows = stop - start + min(2 * PATTERN_CHUNK, stop - start + 2)  # result + one chunk
        check_memory(rows * n * n * itemsize(dtype, func),
                     f"{stop - start} DMD patterns of {n}x{n}", func,
                     "stream them with DMDSplit.iter_patterns(chunk) or ask for rows "
                     "start:stop")
        out = torch.empty(stop - start, n, n, dtype=dtype, device=self.hadamard.h.device)
        lo, hi = start // 2, (stop + 1) // 2  # the ±1 rows that cover split rows start:stop
        for a in range(lo, hi, PATTERN_CHUNK):
            b = min(a + PATTERN_CHUNK, hi)
            rows = split_patterns(self.hadamard.patterns(build, a, b))  # split rows 2a:2b
            s0, s1 = max(2 * a, start), min(2 * b, stop)
            out[s0 - start : s1 - start] = rows[s0 - 2 * a : s1 - 2 * a]
        return out

    def iter_patterns(self, chunk: int = 256, dtype: torch.dtype = torch.float32):
        """Yield ``(start, patterns[start:start + chunk])`` over the ``2M`` DMD patterns in
        acquisition order: at most ``chunk·n²`` entries alive at a time."""
        if isinstance(chunk, bool) or not isinstance(chunk, int) or chunk < 1:
            raise ValueError(f"DMDSplit.iter_patterns: expected chunk to be an int >= 1, "
                             f"got {chunk!r}")
        for start in range(0, self.m, chunk):
            yield start, self.patterns(dtype, start, min(start + chunk, self.m))
