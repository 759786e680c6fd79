"""One table of every reconstructor, by name: the CLI, benches, adaptive mode and tests read it.

Each entry is a :class:`ReconSpec`: the function ``function(y, A, **options)``, the module
``module(A, **options)`` (``forward(y) -> x``, ``solve(y)`` -> typed result), the options that
the demo, the benches and the adaptive mode use (``defaults``), and what the reconstructor is:

- ``iterative``: it runs an iteration loop (budget keyword ``budget``; ``None`` for direct ones);
- ``differentiable``: ``x`` is differentiable in ``y``: gradients flow through ``forward`` and,
  for an iterative one, are those of the iterations it ran (float64 ``gradcheck`` of the
  default options with a fixed budget). TVAL3 is not: its ``mu="auto"`` weight follows a
  quantile of the buckets and a hold-out choice, whose derivative is not the solution's
  (with a fixed ``mu`` its gradients pass ``gradcheck``); ``auto`` chooses among fits and
  the DIP fits its network without a graph to ``y``;
- ``exportable``: the module exports to ONNX as it is (``torchtof export``);
- ``operator``: ``"split"`` when it is meant for the raw 0/1 DMD buckets of
  :class:`~torchtof.operators.DMDSplit` (the correlation estimators, paper Eq. 10), else
  ``"signed"`` (the ±1 operator and the differential buckets ``(y⁺ − y⁻)/n``);
- ``per_sample``: the module fits one sample at a time (the DIP);
- ``positive_prior``: its output is biased to a bright object on a dark background (the DIP's
  sigmoid), so negative-polarity buckets should be fitted as ``−y`` and negated back;

Example:
    >>> import torchtof.recon as recon
    >>> recon.get("TVAL3").label, recon.get("tval3").budget
    ('TVAL3', 'max_iter')
    >>> "dip" in recon.names()
    True
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

from torch import nn

from .auto import Auto, auto
from .bp import BasisPursuit, basis_pursuit
from .correlation import CGI, DGI, TGI, cgi, dgi, tgi
from .depth import JointTV, joint_tv
from .dip import DIP, dip
from .learned import Learned, learned
from .pinv import PseudoInverse, pseudo_inverse
from .tgv import TGV, tgv
from .tval3 import TVAL3, tval3
from .unrolled import UnrolledTVAL3, unrolled_tval3

__all__ = ["ReconSpec", "REGISTRY", "get", "names", "specs"]


@dataclass(frozen=True)
class ReconSpec:
    """One reconstructor (module docstring)."""

    name: str
    label: str
    function: Callable
    module: type[nn.Module]
    defaults: Mapping = field(default_factory=dict)
    iterative: bool = False
    differentiable: bool = False
    exportable: bool = False
    summary: str = ""
    budget: str | None = None
    #: options added to a given ``budget`` (BP, TVAL3: no adaptive stop, exactly ``budget``)
    fixed_budget: Mapping = field(default_factory=dict)
    operator: str = "signed"
    per_sample: bool = False
    positive_prior: bool = False

    def build(self, A, **options) -> nn.Module:
        """``module(A, **{**defaults, **options})``."""
        return self.module(A, **{**self.defaults, **options})

    def budget_options(self, budget: int | None) -> dict:
        """Options that give the method a budget of ``budget`` iterations (``None``: the
        solver's own rule): exactly that many where ``fixed_budget`` switches the adaptive stop
        off (BP, TVAL3, TGV², JointTV) and for the unrolled depth; a cap for the DIP (its
        early stop still applies); for ``auto`` the iterations of each cross-validation fit
        (``cv_iter``; its final refit runs ``max_iter``, so its ``n_iter`` can exceed it)."""
        if budget is None:
            return {}
        if self.budget is None:
            raise ValueError(f"ReconSpec.budget_options: {self.label} has no iteration budget")
        return {self.budget: int(budget), **self.fixed_budget}


def _spec(*args, defaults=None, fixed_budget=None, **kw) -> ReconSpec:
    return ReconSpec(*args, defaults=MappingProxyType(dict(defaults or {})),
                     fixed_budget=MappingProxyType(dict(fixed_budget or {})), **kw)


_SPECS = (
    _spec("cgi", "CGI", cgi, CGI, differentiable=True, exportable=True, operator="split",
          summary="normalised second-order correlation g2 (paper Eqs. 9-10)"),
    _spec("tgi", "TGI", tgi, TGI, differentiable=True, exportable=True, operator="split",
          summary="traditional ghost imaging <y phi> - <y><phi>"),
    _spec("dgi", "DGI", dgi, DGI, differentiable=True, exportable=True, operator="split",
          summary="differential ghost imaging (Ferri et al. 2010)"),
    _spec("pinv", "PINV", pseudo_inverse, PseudoInverse, differentiable=True, exportable=True,
          summary="pseudo-inverse A^+ y (minimum-norm least squares)"),
    # noise-aware BPDN: the equality-constrained form over-fits noisy buckets
    _spec("bp", "BP", basis_pursuit, BasisPursuit, defaults={"eps": "auto"}, iterative=True,
          differentiable=True, exportable=True, budget="n_iter", fixed_budget={"adaptive": False},
          summary="basis pursuit (denoising) in the DCT basis by ADMM"),
    _spec("tval3", "TVAL3", tval3, TVAL3, iterative=True, exportable=True, budget="max_iter",
          fixed_budget={"adaptive": False},
          summary="TVAL3: min TV s.t. Ax = y by augmented Lagrangian (Li et al. 2013)"),
    _spec("auto", "Auto", auto, Auto, iterative=True, budget="cv_iter",
          summary="TV/TGV with prior, bounds and weight chosen by cross-validation on the "
                  "buckets, stacked with the learned network"),
    _spec("tgv", "TGV", tgv, TGV, iterative=True, differentiable=True, exportable=True,
          budget="max_iter",
          fixed_budget={"adaptive": False},
          summary="second-order TGV (Bredies et al. 2010) by primal-dual: planes, no staircase"),
    _spec("unrolled", "Unrolled", unrolled_tval3, UnrolledTVAL3, iterative=True,
          differentiable=True, exportable=True, budget="n_layers",
          summary="unrolled TVAL3, K layers with learned per-layer scalars"),
    _spec("learned", "Learned", learned, Learned, differentiable=True, exportable=True,
          summary="learned proximal gradient: shared FiLM CNN prior, one weights file, any n/SR"),
    # a DIP budget is a cap: ES-WMV still stops the fit earlier
    _spec("dip", "DIP", dip, DIP, iterative=True, budget="max_iter", per_sample=True,
          positive_prior=True,
          summary="deep image prior: an untrained U-Net fitted to y (paper Eq. 12)"),
    _spec("joint_tv", "JointTV", joint_tv, JointTV, iterative=True, differentiable=True,
          budget="n_iter",
          fixed_budget={"adaptive": False},
          summary="vectorial (joint) TV of C images sharing their edges (I/Q pair) by ADMM"),
)

#: name -> :class:`ReconSpec`, in the demo's column order.
REGISTRY: Mapping[str, ReconSpec] = MappingProxyType({s.name: s for s in _SPECS})
_ALIASES = {**{s.label.lower(): s.name for s in _SPECS},
            "pseudoinverse": "pinv", "basispursuit": "bp", "unrolledtval3": "unrolled",
            "g2": "cgi"}


def names() -> tuple[str, ...]:
    """Registered names, in table order."""
    return tuple(REGISTRY)


def specs() -> tuple[ReconSpec, ...]:
    """Registered specs, in table order."""
    return tuple(REGISTRY.values())


def get(name: str) -> ReconSpec:
    """The spec of ``name`` (case-insensitive; a label such as ``"TVAL3"`` or a class name such
    as ``"BasisPursuit"`` also works).

    Raises:
        ValueError: unknown name (the message lists the names).
    """
    if not isinstance(name, str):
        raise TypeError(f"get: expected name to be a str, got {type(name).__name__}")
    key = name.lower()
    key = key if key in REGISTRY else _ALIASES.get(key, key)
    if key not in REGISTRY:
        raise ValueError(f"get: expected name in {names()}, got {name!r}")
    return REGISTRY[key]
