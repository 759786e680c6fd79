"""``torchtof bench stability``: the numerical stress matrix of every public module.

The matrix, its edge cases and its tolerance table live in :mod:`torchtof.testing.stability`
(the stress tests use the same oracle); this prints it.
"""

from __future__ import annotations

from ...testing.stability import bench_stability

__all__ = ["bench_stability", "print_stability"]


def print_stability(result: dict) -> None:
    """Print the matrix: one code per cell, numbered notes for every error, n/r, n/a and FAIL."""
    dts = result["dtypes"]
    notes: dict[str, int] = {}
    table = []
    for r in result["rows"]:
        line = [r["module"], r["edge"]]
        for d in dts:
            cell = r["cells"][d]
            code = cell["status"]
            if code != "ok":
                key = f"{code}: {cell['detail']}"
                code = f"{code}[{notes.setdefault(key, len(notes) + 1)}]"
            line.append(code)
        table.append(line)
    head = ["module", "edge case", *dts]
    widths = [max(len(row[i]) for row in [head, *table]) for i in range(len(head))]
    print(f"numerical stress matrix: {len(table)} rows x {len(dts)} dtypes, "
          f"torch {result['torch']}, {result['time_s']:.1f} s")
    print("  ".join(h.ljust(w) for h, w in zip(head, widths, strict=True)))
    print("  ".join("-" * w for w in widths))
    for row in table:
        print("  ".join(v.ljust(w) for v, w in zip(row, widths, strict=True)).rstrip())
    print("\ncounts:")
    for d in dts:
        print(f"  {d:9s} " + ", ".join(f"{v} {k}" for k, v in result["counts"][d].items()))
    if notes:
        print("\nnotes:")
        for key, num in notes.items():
            print(f"  [{num}] {key}")
    print("\ntolerances (against float64 on the same rounded inputs):")
    for fam, t in result["tolerances"].items():
        vals = ", ".join(f"{d} {t[d]:g}" for d in dts if d in t)
        print(f"  {fam:16s} {t['metric']:5s} {vals or '-'}")
