"""Method choice under a budget: the cheapest reconstructor that meets a target.

Reads a runtime-vs-error table, the ``points`` of ``torchtof bench tradeoff`` (one row per
``(n, SR, method, work knob)`` with seconds per image, PSNR, SSIM and depth RMSE, averaged
over the scenes). A table measured on this machine ships with the package
(``torchtof/adaptive/tradeoff_default.json``); regenerate it, or make your own, with::

    torchtof bench tradeoff --quick --out bench_out
    cp bench_out/budget_table.json torchtof/adaptive/tradeoff_default.json

(``bench tradeoff`` writes ``budget_table.json`` with :func:`save_table`.)

Rules (:func:`choose_method`): among the rows of the nearest ``n`` and the nearest SR
(``|log SR − log SR_row|`` smallest; the table lists few SRs):

- ``target_psnr`` / ``target_depth_rmse_m``: the *fastest* row that meets the target; if
  none does, the most accurate row (flagged ``met=False``);
- ``time_budget_s``: the most accurate row (highest PSNR) within the budget; if none fits,
  the fastest row (``met=False``);
- both: the fastest row meeting the target within the budget, else as above.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from .._checks import check_int, check_number, check_positive

__all__ = ["DEFAULT_TABLE", "MethodChoice", "load_table", "choose_method", "save_table"]

#: the shipped table (``torchtof bench tradeoff --quick`` on this project's 2-core machine).
DEFAULT_TABLE = "tradeoff_default.json"
_KEEP = ("n", "sr", "method", "budget", "label", "time_s", "psnr", "ssim", "depth_rmse_m")


@dataclass(frozen=True)
class MethodChoice:
    """The chosen row: ``method`` (a :data:`torchtof.methods.METHODS` name), ``n_iter`` (the
    work knob; ``None`` = the solver's own stopping rule), the table's ``time_s``, ``psnr``,
    ``depth_rmse_m``, whether the request was ``met``, and ``why``."""

    method: str
    n_iter: int | None
    time_s: float
    psnr: float
    depth_rmse_m: float | None
    met: bool
    why: str


def load_table(path: str | Path | None = None) -> list[dict]:
    """Rows of a runtime-vs-error table: ``path`` (a ``bench tradeoff``/``bench recon`` JSON,
    or a list of rows) or, with ``None``, the shipped default.

    Raises:
        ValueError: a file without rows or with rows lacking ``n``, ``sr``, ``method``,
            ``time_s``, ``psnr``.
    """
    if path is None:
        text = resources.files("torchtof.adaptive").joinpath(DEFAULT_TABLE).read_text()
    else:
        text = Path(path).read_text()
    data = json.loads(text)
    rows = data.get("points", data) if isinstance(data, dict) else data
    if not isinstance(rows, list) or not rows:
        raise ValueError(f"load_table: expected a list of rows or a dict with 'points', in {path}")
    need = ("n", "sr", "method", "time_s", "psnr")
    for r in rows:
        if not all(k in r for k in need):
            raise ValueError(f"load_table: expected rows with keys {need}, got {sorted(r)}")
    return rows


def save_table(src: str | Path, dst: str | Path) -> Path:
    """Keep the scene-averaged ``points`` of a ``bench tradeoff`` JSON (the shipped format)."""
    rows = load_table(src)
    dst = Path(dst)
    dst.write_text(json.dumps({"source": str(src), "points": [
        {k: r.get(k) for k in _KEEP} for r in rows]}, indent=1))
    return dst


def choose_method(n: int, sr: float, time_budget_s: float | None = None,
                  target_psnr: float | None = None, target_depth_rmse_m: float | None = None,
                  table: list[dict] | str | Path | None = None,
                  methods: tuple[str, ...] | None = None) -> MethodChoice:
    """Pick the cheapest reconstructor and iteration count that meets a budget (module doc).

    Args:
        n: image side (an int ``>= 1``; the table row of the nearest ``n`` is read).
        sr: sampling rate in ``(0, 1]``.
        time_budget_s: seconds per image, ``> 0`` (``inf``: no limit).
        target_psnr: PSNR (dB, the table's 8-bit protocol) to reach (finite).
        target_depth_rmse_m: depth RMSE (m) to stay under (``> 0``, finite).
        table: rows, a path, or ``None`` for the shipped default.
        methods: restrict to these method names, each one of the table's methods (a
            sequence of names; a single string is one name, not a set of letters).

    Returns:
        :class:`MethodChoice`.

    Raises:
        TypeError: ``n`` not an int, a budget, target or ``sr`` not a number, ``methods``
            not a string or a sequence of strings.
        ValueError: no budget or target given, bad values, a method name the table does not
            hold, no rows for the methods.

    Example:
        >>> choose_method(32, 0.125, time_budget_s=1e-3).method
        'PINV'
    """
    fn = "choose_method"
    if time_budget_s is None and target_psnr is None and target_depth_rmse_m is None:
        raise ValueError(f"{fn}: give time_budget_s, target_psnr or target_depth_rmse_m")
    check_int(n, "n", fn, lo=1)
    if time_budget_s is not None:
        if isinstance(time_budget_s, bool) or not isinstance(time_budget_s, (int, float)):
            raise TypeError(f"{fn}: expected time_budget_s to be a number, got "
                            f"{type(time_budget_s).__name__}")
        if not time_budget_s > 0:  # NaN too; inf: no limit
            raise ValueError(f"{fn}: expected time_budget_s > 0, got {time_budget_s}")
    if target_psnr is not None:
        check_number(target_psnr, "target_psnr", fn)
    if target_depth_rmse_m is not None:
        check_positive(target_depth_rmse_m, "target_depth_rmse_m", fn)
    if not 0 < check_number(sr, "sr", fn) <= 1:
        raise ValueError(f"{fn}: expected sr in (0, 1], got {sr}")
    if methods is not None:
        if isinstance(methods, str):
            methods = (methods,)  # one name (not its letters: "BPX" is no "BP")
        elif not isinstance(methods, (list, tuple, set, frozenset)) or not all(
                isinstance(m, str) for m in methods):
            raise TypeError(f"{fn}: expected methods to be a method name or a sequence of "
                            f"names, got {methods!r}")
    rows = table if isinstance(table, list) else load_table(table)
    if methods is not None:
        known = sorted({r["method"] for r in rows})
        unknown = [m for m in methods if m not in known]
        if unknown:
            raise ValueError(f"{fn}: expected methods among the table's {tuple(known)}, got "
                             f"{unknown[0]!r}")
    rows = [r for r in rows if methods is None or r["method"] in methods]
    if not rows:
        raise ValueError(f"{fn}: no table rows for methods {methods}")
    best_n = min({r["n"] for r in rows}, key=lambda v: abs(math.log(v / n)))
    rows = [r for r in rows if r["n"] == best_n]
    best_sr = min({r["sr"] for r in rows}, key=lambda v: abs(math.log(v / sr)))
    rows = [r for r in rows if r["sr"] == best_sr]

    def meets(r):
        ok = target_psnr is None or r["psnr"] >= target_psnr
        if target_depth_rmse_m is not None:
            rmse = r.get("depth_rmse_m")
            ok = ok and rmse is not None and rmse <= target_depth_rmse_m
        return ok

    fits = [r for r in rows if time_budget_s is None or r["time_s"] <= time_budget_s]
    where = f"table row n={best_n}, SR {best_sr:.2%}"
    fastest, most = (lambda rs: min(rs, key=lambda r: r["time_s"])), (
        lambda rs: max(rs, key=lambda r: r["psnr"]))
    if target_psnr is not None or target_depth_rmse_m is not None:
        good = [r for r in fits if meets(r)]
        if good:
            pick, met, why = fastest(good), True, "fastest meeting the target"
        elif fits:
            pick, met, why = most(fits), False, "target not reachable: most accurate"
        else:
            pick, met, why = fastest(rows), False, "nothing fits the budget: fastest"
    elif fits:
        pick, met, why = most(fits), True, "most accurate within the budget"
    else:
        pick, met, why = fastest(rows), False, "nothing fits the budget: fastest"
    return MethodChoice(method=pick["method"], n_iter=pick.get("budget"), time_s=pick["time_s"],
                        psnr=pick["psnr"], depth_rmse_m=pick.get("depth_rmse_m"), met=met,
                        why=f"{why} ({where})")
