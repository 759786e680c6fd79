"""Bad-input matrix: every public call of the listed modules, misused as a user would.

Each :class:`Spec` is one public call with a valid argument set. From it the matrix derives
the misuses mechanically — per tensor argument: a Python list, an int64 tensor, a NaN, an
Inf, a wrong rank; over all tensor arguments together: float64, float16, bfloat16, complex,
an empty batch (B = 0) and meta tensors — plus the bad scalars each spec lists (negative or
zero sizes, floats for ints, strings, NaN, Inf). Every case is classified:

- ``clear``: ``ValueError``/``TypeError`` from the library's own checks, a message
  ``"<call>: ..."`` that names the call the user made (the spec's, e.g. ``Hadamard.forward``
  or ``Hadamard`` for ``Hadamard()``; not a helper it called) and, for a single-argument
  misuse, the argument;
- ``correct``: a result that passes the case's oracle — the float32 result for float64 and
  lists (tolerance from the dtype), ``f(Re z) + i·f(Im z)`` for a complex input to a linear
  map, ``f(float(k))`` for integers, shapes ``(0, …)`` for B = 0, meta tensors of the right
  shape for meta input;
- ``silent-wrong``: a result where an error was due (NaN/Inf/wrong rank/bad scalar accepted)
  or one that fails the oracle;
- ``cryptic``: any other exception (a library traceback: ``RuntimeError`` from torch, an
  ``IndexError``, a ``ValueError`` that does not name the call, …);
- ``crash``: ``MemoryError``, ``RecursionError``, ``SystemError``.

The oracles come from the definitions (linearity, dtype promotion, the empty sum), not from
the library's own tolerances. Run ``python -m tests.reliability.matrix`` for the counts
(``--out FILE.json`` also writes them, per module, for the README).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import torch

CLASSES = ("clear", "correct", "silent-wrong", "cryptic", "crash")
NAN, INF = float("nan"), float("inf")


@dataclass
class T:
    """Traits of one tensor argument."""

    batch: bool = True  # axis 0 is the batch
    any_rank: bool = False  # documented for any shape: no wrong-rank case
    complex_in: bool = False  # the valid input is complex (no complex/int cases)
    joint: bool = True  # take part in the joint dtype / B = 0 / meta cases


@dataclass
class Spec:
    name: str  # "module: call", e.g. "operators: Hadamard.forward"
    module: str  # operators, sensor, metrics, scenes, experiment, bucket, recon
    call: Callable[..., Any]
    good: Callable[[], dict]
    tensors: dict[str, T] = field(default_factory=dict)
    bad: dict[str, list] = field(default_factory=dict)  # scalar argument -> bad values
    linear: bool = False  # linear in its (joint) tensor arguments: complex oracle
    random: bool = False  # draws noise: dtype oracles check shape/finiteness only
    batch0: bool = True  # has a batch axis to empty
    no_meta: bool = False  # meta case not applicable (works on numpy / Python values)
    xfail: dict[str, str] = field(default_factory=dict)  # case id -> reason (outside our modules)
    #: other names an error may give for this call: a module's forward that validates in its
    #: function (``CGI.forward`` -> ``cgi``)
    aliases: tuple[str, ...] = ()


@dataclass
class Case:
    spec: Spec
    kind: str  # list, int64, nan, inf, rank, float64, float16, bfloat16, complex, batch0, meta, bad
    arg: str | None
    value: Any = None

    @property
    def id(self) -> str:
        extra = f"={self.value!r}" if self.kind == "bad" else ""
        return f"{self.spec.name} | {self.kind}{'(' + self.arg + extra + ')' if self.arg else ''}"


# ------------------------------------------------------------------ helpers

def _tensors(out: Any) -> list[torch.Tensor]:
    if isinstance(out, torch.Tensor):
        return [out]
    if isinstance(out, dict):
        return [t for v in out.values() for t in _tensors(v)]
    if isinstance(out, (tuple, list)):
        return [t for v in out for t in _tensors(v)]
    return []


def _close(got: torch.Tensor, want: torch.Tensor, rtol: float) -> bool:
    if got.shape != want.shape or got.is_complex() != want.is_complex():
        return False
    g, w = got.detach().to(torch.complex128 if got.is_complex() else torch.float64), \
        want.detach().to(torch.complex128 if want.is_complex() else torch.float64)
    if not bool(torch.isfinite(g).all()) or not bool(torch.isfinite(w).all()):
        return bool(torch.equal(torch.isnan(g), torch.isnan(w))) and bool(
            (g[torch.isfinite(w)] - w[torch.isfinite(w)]).abs().max() <= rtol
            if bool(torch.isfinite(w).any()) else True)
    scale = float(w.abs().max()) if w.numel() else 0.0
    return w.numel() == 0 or float((g - w).abs().max()) <= rtol * max(scale, 1.0)


def _same(got: Any, want: Any, rtol: float) -> bool:
    a, b = _tensors(got), _tensors(want)
    return len(a) == len(b) and all(_close(x, y, rtol) for x, y in zip(a, b))


def _finite_shapes(got: Any, want: Any) -> bool:
    a, b = _tensors(got), _tensors(want)
    return len(a) == len(b) and all(
        x.shape == y.shape and bool(torch.isfinite(x.detach().to(torch.complex128 if x.is_complex()
                                                               else torch.float64)).all())
        for x, y in zip(a, b))


def _map(kw: dict, spec: Spec, fn: Callable[[torch.Tensor, T], Any], only: str | None = None):
    out = dict(kw)
    for name, traits in spec.tensors.items():
        if (only is None and traits.joint) or name == only:
            out[name] = fn(kw[name], traits)
    return out


def _real_dtype(t: torch.Tensor, dtype: torch.dtype) -> torch.Tensor:
    if t.is_complex():
        c = {torch.float64: torch.complex128, torch.float32: torch.complex64}.get(dtype)
        return t.to(c) if c is not None else t.real.to(dtype)
    return t.to(dtype)


# ------------------------------------------------------------------ cases

def cases(specs: list[Spec]) -> list[Case]:
    out = []
    for s in specs:
        for name, tr in s.tensors.items():
            kinds = ["list", "nan", "inf"] + ([] if tr.any_rank else ["rank"])
            if not tr.complex_in:
                kinds.insert(1, "int64")
            out += [Case(s, k, name) for k in kinds]
        if s.tensors:
            out += [Case(s, k, None) for k in ("float64", "float16", "bfloat16")]
            if not any(t.complex_in for t in s.tensors.values()):
                out.append(Case(s, "complex", None))
            if s.batch0 and any(t.batch and t.joint for t in s.tensors.values()):
                out.append(Case(s, "batch0", None))
            if not s.no_meta:
                out.append(Case(s, "meta", None))
        for name, values in s.bad.items():
            out += [Case(s, "bad", name, v) for v in values]
    return out


def _variant(case: Case) -> tuple[dict, Callable[[Any, Any], bool] | None]:
    """Arguments of the case and its oracle ``(result, reference) -> ok`` (``None``: any
    result is wrong, an error was due)."""
    s, kw = case.spec, case.spec.good()
    k, arg = case.kind, case.arg
    if k == "list":
        kw[arg] = kw[arg].tolist()
        return kw, lambda got, ref: _same(got, ref, 1e-6)
    if k == "int64":
        kw[arg] = kw[arg].round().long()
        return kw, "int64"
    if k in ("nan", "inf"):
        t = kw[arg].clone()
        t.reshape(-1)[t.numel() // 2] = NAN if k == "nan" else INF
        kw[arg] = t
        return kw, None
    if k == "rank":
        t = kw[arg]
        kw[arg] = t[0] if t.ndim > 1 else t[None, None]
        return kw, None
    if k in ("float64", "float16", "bfloat16"):
        dt = getattr(torch, k)
        kw = _map(kw, s, lambda t, tr: _real_dtype(t, dt))
        if s.random:
            return kw, _finite_shapes
        rtol = {"float64": 1e-5, "float16": 2e-2, "bfloat16": 5e-2}[k]
        return kw, lambda got, ref: _same(got, ref, rtol)
    if k == "complex":
        kw = _map(kw, s, lambda t, tr: torch.complex(t, 0.5 * t.flip(-1)))
        return kw, "complex" if s.linear else None
    if k == "batch0":
        kw = _map(kw, s, lambda t, tr: t[:0] if tr.batch else t)

        def empty(got, ref):
            a, b = _tensors(got), _tensors(ref)
            return len(a) == len(b) and all(
                x.shape == (0,) + tuple(y.shape[1:]) for x, y in zip(a, b))
        return kw, empty
    if k == "meta":
        kw = _map(kw, s, lambda t, tr: t.to("meta"))

        def meta(got, ref):
            a, b = _tensors(got), _tensors(ref)
            return len(a) == len(b) and all(x.is_meta and x.shape == y.shape for x, y in zip(a, b))
        return kw, meta
    if k == "bad":
        kw[arg] = case.value
        return kw, None
    raise AssertionError(k)


def classify(case: Case) -> tuple[str, str]:
    """``(class, detail)`` of one case."""
    s = case.spec
    kw, oracle = _variant(case)
    try:
        got = s.call(**kw)
    except (MemoryError, RecursionError, SystemError) as e:
        return "crash", f"{type(e).__name__}: {e}"
    except (ValueError, TypeError) as e:
        msg = str(e)
        # the library's own check: "<call>: expected ..." naming the call the user made
        # and the misused argument
        calls = (s.name.split(": ", 1)[-1].removesuffix("()"), *s.aliases)
        ours = any(re.match(rf"^{re.escape(c)}(\(\))?: ", msg) for c in calls)
        named = case.arg is None or re.search(rf"\b{re.escape(case.arg)}\b", msg) is not None
        return ("clear" if ours and named else "cryptic"), f"{type(e).__name__}: {msg[:160]}"
    except Exception as e:  # noqa: BLE001 - the point is to classify every exception
        return "cryptic", f"{type(e).__name__}: {str(e)[:160]}"
    if oracle is None:
        return "silent-wrong", "returned where an error was due"
    ref_kw = s.good()
    if oracle == "int64":
        ref_kw[case.arg] = ref_kw[case.arg].round()
        ok = _same(got, s.call(**ref_kw), 1e-6) if not s.random else _finite_shapes(
            got, s.call(**ref_kw))
    elif oracle == "complex":
        re_kw = _map(ref_kw, s, lambda t, tr: t)
        im_kw = _map(s.good(), s, lambda t, tr: 0.5 * t.flip(-1))
        want = [torch.complex(a, b) for a, b in
                zip(_tensors(s.call(**re_kw)), _tensors(s.call(**im_kw)))]
        ok = _same(got, want, 1e-5)
    else:
        ok = oracle(got, s.call(**ref_kw))
    return ("correct", "") if ok else ("silent-wrong", "result fails the oracle")


def run_matrix(specs: list[Spec]) -> list[tuple[Case, str, str]]:
    return [(c, *classify(c)) for c in cases(specs)]


def counts(rows) -> dict[str, dict[str, int]]:
    table: dict[str, dict[str, int]] = {}
    for case, cls, _ in rows:
        table.setdefault(case.spec.module, dict.fromkeys(CLASSES, 0))[cls] += 1
    return table


def main(argv: list[str] | None = None) -> None:
    import argparse
    import json
    from pathlib import Path

    from .specs import OUTSIDE, SPECS

    p = argparse.ArgumentParser(description="Classify every misuse of the public calls.")
    p.add_argument("--out", default=None, help="also write the counts per module to this JSON")
    args = p.parse_args(argv)
    torch.manual_seed(0)
    rows = run_matrix(SPECS + OUTSIDE)
    table = counts(rows)
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps({
            "calls": len(SPECS), "modules": sorted({s.module for s in SPECS}),
            "outside_calls": len(OUTSIDE),
            "outside_modules": sorted({s.module for s in OUTSIDE} - {s.module for s in SPECS}),
            "classes": list(CLASSES), "counts": table, "torch": torch.__version__,
            "command": "python -m tests.reliability.matrix --out " + args.out},
            indent=1) + "\n", encoding="utf-8")
    width = max(len(m) for m in table) + 2
    print("module".ljust(width) + "".join(c.rjust(14) for c in CLASSES) + "total".rjust(8))
    for mod, row in sorted(table.items()):
        print(mod.ljust(width) + "".join(str(row[c]).rjust(14) for c in CLASSES)
              + str(sum(row.values())).rjust(8))
    tot = {c: sum(r[c] for r in table.values()) for c in CLASSES}
    print("all".ljust(width) + "".join(str(tot[c]).rjust(14) for c in CLASSES)
          + str(sum(tot.values())).rjust(8))
    bad = [(c, k, d) for c, k, d in rows if k not in ("clear", "correct")]
    if bad:
        print("\nnot clear / correct:")
        for c, k, d in bad:
            print(f"  [{k}] {c.id}: {d}")


if __name__ == "__main__":
    main()
