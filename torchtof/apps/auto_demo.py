"""``torchtof demo --auto``: the paper's experiment through the adaptive and the fixed pipeline."""

from __future__ import annotations

import json
import time
from pathlib import Path

__all__ = ["demo_auto", "AUTO_MAX_SR"]

#: the default maximum SR of ``demo --auto`` (the paper's largest).
AUTO_MAX_SR = 0.375


def demo_auto(args) -> int:
    """Simulate the scene once at the maximum SR (``--sr``, default :data:`AUTO_MAX_SR`; one
    noise realisation is enough: the noise level comes from the DMD pair sums), run
    :func:`~torchtof.adaptive.run_adaptive` (which also runs the fixed pipeline) and print
    what was skipped, patterns, iterations, stop reasons, times and PSNR; writes
    ``auto.png`` and ``auto.json`` under ``--out``."""
    from ..adaptive.pipeline import run_adaptive
    from ..experiment import PaperExperiment
    from ..metrics import compare
    from ..report import print_table, save_grid

    t0 = time.perf_counter()
    sr = AUTO_MAX_SR if args.sr is None else args.sr
    exp = PaperExperiment(sr=sr, scattering=args.scattering, scene=args.scene, n=args.n,
                          roi_px=2 * args.n, srs=(sr,))
    print(f"torchtof demo --auto: {exp}, maximum SR {sr:.2%}")
    data = exp.run(seed=args.seed, realisations=1, progress=True)
    res = run_adaptive(data, 0)
    fx = res.fixed
    print(res.summary())
    rows = []
    for name, r in (("adaptive", res), ("fixed", fx)):
        psnr = float(compare(r.image, data.x.to(r.image.dtype), r.polarity)["psnr"][0])
        rows.append({"pipeline": name, "buckets": r.kind, "patterns": r.patterns_used,
                     "method": r.method, "iterations": r.n_iter, "stop": r.solver_stop,
                     "time s": round(r.total_s, 2), "compute s": round(r.compute_s, 3),
                     "PSNR dB": round(psnr, 2)})
    print()
    print_table(rows, list(rows[0]))
    out = Path(args.out)
    png = save_grid(out / "auto.png", [("object", data.x), ("adaptive", res.image),
                                       ("fixed", fx.image)],
                    title=f"adaptive ({res.patterns_used} patterns) vs fixed ({fx.patterns_used})")
    (out / "auto.json").write_text(json.dumps(
        {"rows": rows, "skipped": res.skipped, "stages": res.stages,
         "acquisition_stop": res.acquisition_stop, "time_saved_s": res.time_saved_s},
        indent=2))
    print(f"\ntorchtof demo --auto: adaptive {rows[0]['PSNR dB']} dB with {res.patterns_used} "
          f"patterns, fixed {rows[1]['PSNR dB']} dB with {fx.patterns_used}; wrote {png} and "
          f"{out / 'auto.json'} in {time.perf_counter() - t0:.1f} s")
    return 0

