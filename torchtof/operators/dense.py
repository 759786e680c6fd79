"""Dense pattern operator: ``y_i = Σ_u φ_i(u) x(u)`` for arbitrary patterns (paper Eq. 11)."""

from __future__ import annotations

import torch
from torch import nn

from .._checks import cache_build, check_finite, check_rank, check_tensor, is_tracing
from .._memory import check_memory
from .base import LinearOperator

__all__ = ["PatternOperator", "pattern_forward", "pattern_adjoint"]


def pattern_forward(x: torch.Tensor, patterns: torch.Tensor) -> torch.Tensor:
    """``y = Φ x``: one matmul of the flattened images with the ``(M, n²)`` pattern matrix.

    Shape: ``x (B, C, n, n)``, ``patterns (M, n, n)`` → ``(B, C, M)``.
    """
    m = patterns.shape[0]
    return x.flatten(-2) @ patterns.reshape(m, -1).T


def pattern_adjoint(y: torch.Tensor, patterns: torch.Tensor) -> torch.Tensor:
    """``x = Φᵀ y``: ``(B, C, M)`` → ``(B, C, n, n)``."""
    m, n1, n2 = patterns.shape
    return (y @ patterns.reshape(m, -1)).reshape(*y.shape[:-1], n1, n2)


def _version(t: torch.Tensor) -> int | None:
    """``t``'s in-place version counter (``None`` for an inference tensor: it has none)."""
    try:
        return t._version
    except RuntimeError:
        return None


class PatternOperator(LinearOperator):
    """Linear operator from an explicit stack of DMD patterns (dense matmul).

    Args:
        patterns: ``(M, n, n)`` real patterns (0/1 DMD masks, ±1 rows, speckle ...). A
            tensor is copied into a buffer; an ``nn.Parameter`` is kept as it is, a
            parameter of this module, so an optimiser stepping it learns the patterns (the
            buckets are differentiable in them).

    What is derived from the patterns (``orthonormal_rows``, the float64 ``A⁺`` and the
    ``state_version`` that solvers' caches key on) follows them: after an in-place edit
    (``P.patterns.mul_(g)``, an optimiser step), a new tensor assigned to ``P.patterns``, a
    ``load_state_dict`` or a dtype/device move it is derived again on its next eager use.
    Not followed: an edit seen only by code compiled with ``torch.compile`` or being exported
    (tracing never re-derives; make one eager call, e.g. ``P.orthonormal_rows``, after the
    edit), and in-place edits of patterns created inside ``torch.inference_mode()`` (inference
    tensors keep no version counter; assign a new tensor instead).

    Example:
        >>> P = PatternOperator(torch.ones(3, 4, 4))
        >>> P(torch.ones(1, 1, 4, 4))
        tensor([[[16., 16., 16.]]])
    """

    def __init__(self, patterns: torch.Tensor) -> None:
        func = "PatternOperator"
        check_tensor(patterns, "patterns", func)
        if patterns.is_complex():  # the float64 copy below would drop the imaginary part
            raise TypeError(
                f"{func}: expected patterns to be a real tensor (DMD patterns are real), "
                f"got dtype {patterns.dtype}"
            )
        check_rank(patterns, 3, "patterns", func, "(M, n, n)")
        m, n1, n2 = patterns.shape
        if n1 != n2 or m < 1 or n1 < 1:
            raise ValueError(
                f"{func}: expected patterns of shape (M, n, n) with M >= 1 and n >= 1, "
                f"got {tuple(patterns.shape)}"
            )
        # the float64 copy and its SVD pseudo-inverse: about 3·M·n² doubles at the peak
        check_memory(3 * m * n1 * n1 * 8 + 8 * min(m, n1 * n1) ** 2, f"an ({m}, {n1}, {n1}) "
                     "pattern stack with its float64 pseudo-inverse", func,
                     "use the fast Hadamard operator or fewer/smaller patterns")
        check_finite(patterns, "patterns", func)
        super().__init__(patterns.shape[1], patterns.shape[0])
        self.__dict__["_state_version"] = 0
        if isinstance(patterns, nn.Parameter):  # learned patterns: the caller's parameter
            self.patterns = patterns
        else:  # persistent: a model on random patterns is checkpointed with them (state_dict)
            self.register_buffer("patterns", patterns.detach().clone())
        self._derive()
        self.register_load_state_dict_post_hook(PatternOperator._loaded)

    def _derive(self) -> None:
        """``orthonormal_rows`` and the pseudo-inverse from the current patterns (ordinary
        tensors even when first used inside ``torch.inference_mode()``)."""
        with cache_build():
            self._derive_values()

    def _derive_values(self) -> None:
        p = self.patterns
        g = p.detach().reshape(self.m, -1).double()
        self.__dict__.pop("_pinv_cache", None)
        if g.is_meta:  # shape inference: no values to test or invert
            self._orthonormal = False
            self.register_buffer("pinv_matrix", g.new_empty(g.shape[1], self.m), persistent=False)
        else:
            self._orthonormal = bool(
                torch.allclose(g @ g.T, torch.eye(self.m, dtype=torch.float64, device=g.device),
                               atol=1e-6)
            )
            # A⁺ (float64 SVD) computed once here, not lazily, so pinv traces/exports to ONNX
            pinv = None if self._orthonormal else torch.linalg.pinv(g)
            self.register_buffer("pinv_matrix", pinv, persistent=False)
        self.__dict__["_derived_from"] = (p, _version(p))

    def _refresh(self) -> None:
        """Derive again if the patterns changed since :meth:`_derive` (module docstring)."""
        seen, version = self.__dict__.get("_derived_from", (None, None))
        p = self.patterns
        if is_tracing() or (p is seen and (version is None or _version(p) == version)):
            return
        check_finite(p, "patterns", "PatternOperator")
        self._derive()
        self.__dict__["_state_version"] = self.__dict__.get("_state_version", 0) + 1

    @property
    def orthonormal_rows(self) -> bool:  # type: ignore[override]
        self._refresh()
        return self._orthonormal

    @property
    def state_version(self) -> int:  # type: ignore[override]
        self._refresh()
        # (a module pickled whole by an earlier version has no _state_version: 0)
        return self.__dict__.get("_state_version", 0)

    @state_version.setter
    def state_version(self, value: int) -> None:
        self.__dict__["_state_version"] = int(value)

    def _apply(self, fn, recurse: bool = True):
        """``Module.to``/``.half``/``.double`` cast the buffers, ``A⁺`` among them: derive it
        again, in float64, from the patterns as cast (a ``.half().float()`` round trip left a
        float16-rounded ``A⁺``, 2000× less accurate, behind the float32 patterns)."""
        module = super()._apply(fn, recurse)
        p = self.patterns
        try:
            derived = p.is_meta or bool(torch.isfinite(p).all())
            if derived:
                self._derive()
        except torch.linalg.LinAlgError:  # finite values too large for the SVD
            derived = False
        if not derived:  # to_empty: uninitialised memory, derived on first use (after a load)
            self.__dict__["_derived_from"] = (None, None)
        self.__dict__["_state_version"] = self.__dict__.get("_state_version", 0) + 1
        return module

    @staticmethod
    def _loaded(module: PatternOperator, incompatible_keys) -> None:
        """After ``load_state_dict``: check the loaded patterns, derive again what depends
        on them, and bump ``state_version`` (solvers' per-operator caches key on it)."""
        check_finite(module.patterns, "patterns", "PatternOperator.load_state_dict")
        module._derive()
        module.state_version += 1

    def _cached_pinv(self, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
        self._refresh()
        return self.pinv_matrix.to(dtype=dtype, device=device)

    def _p(self, like: torch.Tensor) -> torch.Tensor:
        return self.patterns.to(dtype=like.dtype, device=like.device)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        self._check_x(x, "PatternOperator.forward")
        return pattern_forward(x, self._p(x))

    def adjoint(self, y: torch.Tensor) -> torch.Tensor:
        self._check_y(y, "PatternOperator.adjoint")
        return pattern_adjoint(y, self._p(y))

    def matrix(self, dtype: torch.dtype = torch.float64, device=None) -> torch.Tensor:
        return self.patterns.reshape(self.m, -1).to(dtype=dtype, device=device)
