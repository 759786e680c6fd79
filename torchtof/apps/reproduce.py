"""``torchtof reproduce``: the paper's figures and PSNR table, in simulation.

Four cases (paper Figs. 5/7, 8/9, 10/11, 12/13): air and the scattering sheet, each without
and with the 3 m depth gate. One simulation per medium serves both gate settings and every
SR (smaller SRs are prefixes). For each case: an image grid (object, raw ToF, each
reconstructor at SR 6.25 … 37.5 %), a PSNR-vs-SR plot (mean ± std over the noise
realisations), rows of a CSV, a Markdown table beside the paper's numbers, and the paper's
claims marked held / not held by our numbers. Beyond the paper: depth maps and
depth-RMSE-vs-SR curves of depth-resolved ghost imaging from the per-tap buckets
(:func:`torchtof.apps.depth_demo.depth_curves`).
"""

from __future__ import annotations

import csv
import json
import time
from pathlib import Path

import torch

from ..experiment import PAPER_PSNR, PAPER_SRS, PaperExperiment
from ..methods import evaluate, raw_tof_scores

__all__ = ["reproduce", "CASES", "check_claims"]

#: case -> (scattering, gate, figure numbers (images, curves))
CASES: dict[str, tuple[bool, bool, str]] = {
    "air": (False, False, "Figs. 5/7"),
    "air+gate": (False, True, "Figs. 8/9"),
    "scatter": (True, False, "Figs. 10/11"),
    "scatter+gate": (True, True, "Figs. 12/13"),
}
METHODS = ("CGI", "BP", "TVAL3", "Unrolled", "DIP")


def _plot_curves(path: Path, case: str, rows: list[dict], raw: dict) -> None:
    from ..report import no_plot, pyplot

    plt = pyplot()
    if plt is None:
        no_plot(path.name)
        return

    fig, ax = plt.subplots(figsize=(4.6, 3.4))
    for m in METHODS:
        rs = [r for r in rows if r["method"] == m]
        if not rs:
            continue
        sr = [100 * r["sr"] for r in rs]
        ax.errorbar(sr, [r["psnr"] for r in rs], yerr=[r["psnr_std"] for r in rs], marker="o",
                    ms=3, capsize=2, label=m)
    ax.axhline(raw["psnr"], color="k", ls="--", lw=1, label="raw ToF")
    for (c, sr), vals in PAPER_PSNR.items():
        if c != case:
            continue
        for m, v in vals.items():
            if m in METHODS:
                ax.plot(100 * sr, v, marker="x", color="gray", ms=5)
    ax.plot([], [], "x", color="gray", label="paper")
    ax.set_xlabel("sampling rate (%)")
    ax.set_ylabel("PSNR (dB)")
    ax.set_title(f"{case}: PSNR vs SR (mean ± std)", fontsize=9)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def check_claims(
    table: dict[str, list[dict]], raw: dict[str, dict]
) -> list[tuple[str, bool | None, str]]:
    """The paper's claims against our numbers: (claim, held, evidence);
    ``held`` is ``None`` when a method the claim needs was not evaluated."""
    def psnr(case, m, sr):
        for r in table[case]:
            if r["method"] == m and abs(r["sr"] - sr) < 1e-9:
                return r["psnr"]
        return None

    methods = sorted({r["method"] for rows in table.values() for r in rows})
    out = []
    worst = min((r["psnr"] - raw[c]["psnr"], c, r["method"], r["sr"])
                for c, rows in table.items() for r in rows)
    out.append(("every reconstruction beats the raw ToF image", worst[0] > 0,
                f"smallest margin {worst[0]:+.2f} dB ({worst[2]}, {worst[1]}, SR {worst[3]:.2%})"))
    drops = []
    for c in table:
        for m in methods:
            v = [psnr(c, m, sr) for sr in PAPER_SRS]
            v = [p for p in v if p is not None]
            if len(v) > 1 and v[-1] <= v[0]:
                drops.append(f"{m}/{c} {v[0]:.2f}→{v[-1]:.2f}")
    out.append(("PSNR rises with SR (6.25 % → 37.5 %)", not drops,
                "all rise" if not drops else "no rise: " + ", ".join(drops)))
    low = [0.0625, 0.125]
    fails = []
    if "TVAL3" not in methods or not {"CGI", "BP"} & set(methods):
        out.append(("TVAL3 ≥ CGI and BP at low SR (6.25, 12.5 %)", None,
                    "TVAL3 not evaluated" if "TVAL3" not in methods
                    else "neither CGI nor BP evaluated"))
    compared = [m for m in ("CGI", "BP") if m in methods]
    for c in table if "TVAL3" in methods and compared else ():
        for sr in low:
            t = psnr(c, "TVAL3", sr)
            for m in compared:
                o = psnr(c, m, sr)
                if t is not None and o is not None and t < o:
                    fails.append(f"{c} SR {sr:.2%}: TVAL3 {t:.2f} < {m} {o:.2f}")
    if "TVAL3" in methods and compared:
        only = "" if len(compared) == 2 else f" (only {compared[0]} evaluated)"
        out.append(("TVAL3 ≥ CGI and BP at low SR (6.25, 12.5 %)", not fails,
                    ("holds everywhere" if not fails else "; ".join(fails)) + only))
    fails = []
    if "DIP" not in methods:
        out.append(("the DIP is best at every SR", None, "DIP not evaluated"))
    for c in table if "DIP" in methods else ():
        for sr in PAPER_SRS:
            d = psnr(c, "DIP", sr)
            if d is None:
                continue
            best = max((psnr(c, m, sr) or -1e9, m) for m in methods if m != "DIP")
            if d < best[0]:
                fails.append(f"{c} SR {sr:.2%}: DIP {d:.2f} < {best[1]} {best[0]:.2f}")
    if "DIP" in methods:
        out.append(("the DIP is best at every SR", not fails,
                    "holds everywhere" if not fails
                    else f"{len(fails)} cases: " + "; ".join(fails)))
    for gate in ("", "+gate"):
        diffs = [psnr("air" + gate, m, sr) - psnr("scatter" + gate, m, sr)
                 for m in methods for sr in PAPER_SRS
                 if psnr("air" + gate, m, sr) is not None
                 and psnr("scatter" + gate, m, sr) is not None]
        if diffs:
            mean = sum(diffs) / len(diffs)
            out.append((f"scattering lowers PSNR ({'with' if gate else 'without'} gate)", mean > 0,
                        f"mean air − scatter {mean:+.2f} dB over {len(diffs)} points, "
                        f"{sum(d > 0 for d in diffs)} positive"))
    for med in ("air", "scatter"):
        diffs = [psnr(med + "+gate", m, sr) - psnr(med, m, sr) for m in methods for sr in PAPER_SRS
                 if psnr(med, m, sr) is not None and psnr(med + "+gate", m, sr) is not None]
        if diffs:
            mean = sum(diffs) / len(diffs)
            out.append((f"the depth gate restores PSNR ({med})", mean > 0,
                        f"mean gate − no gate {mean:+.2f} dB over {len(diffs)} points, "
                        f"{sum(d > 0 for d in diffs)} positive"))
    return out


def reproduce(out: Path = Path("reproduce_out"), quick: bool = False,
              realisations: int | None = None, methods=METHODS, seed: int = 0, *,
              n: int = 32, depth: bool = True) -> dict:
    """Run the four cases and write PNGs, ``psnr.csv``, ``table.md``, ``claims.md``, JSON.

    ``realisations``: noise realisations per case (default 5, ``quick`` 2; ``>= 1``).
    ``n``: DMD side (the paper's 32; smaller only to test the plumbing quickly).
    ``depth``: also run the depth curves (:func:`~torchtof.apps.depth_demo.depth_curves`)."""
    from .._optional import progress_bar as tqdm
    from ..report import save_grid

    if realisations is not None and (isinstance(realisations, bool) or realisations < 1):
        raise ValueError(f"reproduce: expected realisations >= 1, got {realisations!r}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    r = realisations if realisations is not None else (2 if quick else 5)
    # --quick: 100 DIP steps instead of the default schedule (the DIP fits dominate the time)
    options = {"DIP": {"max_iter": 100}} if quick else {}
    from .bench.timing import machine_load

    t0, load_start = time.perf_counter(), machine_load()
    table: dict[str, list[dict]] = {}
    raw: dict[str, dict] = {}
    timings = {}
    work = [(case, sr) for case in CASES for sr in PAPER_SRS]
    bar = tqdm(total=len(work), desc="reproduce", leave=False)
    for scattering in (False, True):
        data = PaperExperiment(sr=max(PAPER_SRS), scattering=scattering, n=n,
                               roi_px=2 * n).run(seed=seed, realisations=r)
        timings["simulate_" + ("scatter" if scattering else "air")] = data.timings["simulate_s"]
        for case, (sc, gate, fig) in CASES.items():
            if sc != scattering:
                continue
            raw[case] = raw_tof_scores(data)
            rows, grid = [], {}
            for sr in PAPER_SRS:
                bar.set_postfix_str(f"{case} SR {sr:.2%}")
                rs, ims = evaluate(data, sr, gate, methods, options=options)
                for row in rs:
                    row["case"] = case
                rows += rs
                for m, im in ims.items():
                    grid.setdefault(m, []).append(im[:1])
                bar.update(1)
            table[case] = rows
            # image grid: rows = methods, columns = SRs (paper's layout, first realisation)
            cols = [(f"{sr:.2%}", torch.cat([data.x, data.raw_tof_image[:1]]
                                            + [grid[m][k] for m in methods]))
                    for k, sr in enumerate(PAPER_SRS)]
            save_grid(out / f"images_{case}.png", cols, rows=["object", "raw ToF", *methods],
                      title=f"{case} ({fig}): reconstructions vs SR")
            _plot_curves(out / f"psnr_{case}.png", case, rows, raw[case])
    bar.close()
    claims = check_claims(table, raw)
    with open(out / "psnr.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["case", "method", "sr", "psnr_mean", "psnr_std", "ssim_mean", "ssim_std",
                    "time_s", "paper_psnr"])
        for case, rows in table.items():
            w.writerow([case, "raw ToF", "", f"{raw[case]['psnr']:.3f}",
                        f"{raw[case]['psnr_std']:.3f}", f"{raw[case]['ssim']:.4f}",
                        f"{raw[case]['ssim_std']:.4f}", "",
                        PAPER_PSNR.get((case, 0.125), {}).get("raw ToF", "")])
            for row in rows:
                paper = PAPER_PSNR.get((case, row["sr"]), {}).get(
                    "DIP" if row["method"] == "DIP" else row["method"], "")
                w.writerow([case, row["method"], row["sr"], f"{row['psnr']:.3f}",
                            f"{row['psnr_std']:.3f}", f"{row['ssim']:.4f}",
                            f"{row['ssim_std']:.4f}", f"{row['time_s']:.4f}", paper])
    pm = (lambda mean, std: f"{mean:.2f} ± {std:.2f}") if r > 1 else (lambda m, s: f"{m:.2f}")
    md = [(f"PSNR (dB, mean ± std over {r} noise realisations" if r > 1 else
           "PSNR (dB, one noise realisation") + f", seed {seed}); paper values in brackets "
          "(torchtof.experiment.PAPER_PSNR). Scoring: README 'Scoring'."
          + (" Quick run: DIP with 100 steps." if quick else ""), ""]
    for case, rows in table.items():
        paper_raw = next((v["raw ToF"] for (c, _), v in PAPER_PSNR.items()
                          if c == case and "raw ToF" in v), None)  # the paper's, where given
        md += [f"### {case} ({CASES[case][2]}) — raw ToF "
               f"{pm(raw[case]['psnr'], raw[case]['psnr_std'])} dB"
               + (f" (paper {paper_raw:.2f})" if paper_raw is not None else ""), "",
               "| method | " + " | ".join(f"{sr:.2%}" for sr in PAPER_SRS) + " |",
               "|---|" + "---|" * len(PAPER_SRS)]
        for m in methods:
            cells = []
            for sr in PAPER_SRS:
                row = next(x for x in rows if x["method"] == m and x["sr"] == sr)
                p = PAPER_PSNR.get((case, sr), {}).get(m)
                cells.append(pm(row["psnr"], row["psnr_std"])
                             + (f" [{p:.2f}]" if p is not None else ""))
            md.append(f"| {m} | " + " | ".join(cells) + " |")
        md.append("")
    (out / "table.md").write_text("\n".join(md))
    cl = ["| claim | held | evidence |", "|---|---|---|"]
    verdict = {True: "held", False: "not held", None: "not evaluated"}
    cl += [f"| {c} | {verdict[h]} | {e} |" for c, h, e in claims]
    (out / "claims.md").write_text("\n".join(cl) + "\n")
    from .depth_demo import depth_curves  # depth maps and depth-RMSE-vs-SR curves (per-tap)

    depth = (depth_curves(out, quick=quick, realisations=realisations, seed=seed) if depth
             else None)
    result = {"realisations": r, "quick": quick, "options": options, "raw": raw, "table": table,
              "depth": depth,
              "claims": [{"claim": c, "held": h, "evidence": e} for c, h, e in claims],
              "timings": timings, "total_s": time.perf_counter() - t0,
              "machine": {"start": load_start, "end": machine_load()}}
    (out / "reproduce.json").write_text(json.dumps(result, indent=2))
    print("\n".join(md))
    print("\n".join(cl))
    print(f"\nwrote {out}/: images_*.png, psnr_*.png, psnr.csv, table.md, claims.md, "
          + ("depth_*.png, depth_rmse.csv, depth_table.md, " if depth else "")
          + f"reproduce.json ({result['total_s']:.0f} s)")
    return result
