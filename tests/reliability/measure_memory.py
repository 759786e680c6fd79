"""Peak memory and time of the dense entry points, each in a fresh process.

    python tests/reliability/measure_memory.py [case ...] [--out FILE]

Each case runs in its own interpreter with one thread (``OMP_NUM_THREADS=1``); the peak is
the growth of the maximum resident set size (``resource.getrusage``, the number
``/usr/bin/time -v`` reports) over the process after ``import torchtof``. Not a test
(several seconds to minutes per case). ``--out FILE`` writes every case's peak and time
with the machine's load to a JSON file, which ``docs/build.py`` renders into the README
(``memory``).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

CASES = {
    "split_patterns_128": "from torchtof.operators import DMDSplit, Hadamard\n"
    "p = DMDSplit(Hadamard(128, sr=0.25)).patterns()",
    "split_stream_128": "from torchtof.operators import DMDSplit, Hadamard\n"
    "for _, p in DMDSplit(Hadamard(128, sr=0.25)).iter_patterns(256): pass",
    "split_stream_256": "from torchtof.operators import DMDSplit, Hadamard\n"
    "for _, p in DMDSplit(Hadamard(256, sr=0.25)).iter_patterns(256): pass",
    "experiment_64_roi128_c64": "from torchtof import PaperExperiment\n"
    "PaperExperiment(n=64, roi_px=128, srs=(0.0625,), sr=0.0625, chunk_frames=64).run()",
    "experiment_64_roi128_c256": "from torchtof import PaperExperiment\n"
    "PaperExperiment(n=64, roi_px=128, srs=(0.0625,), sr=0.0625, chunk_frames=256).run()",
    "experiment_64_roi256_c64": "from torchtof import PaperExperiment\n"
    "PaperExperiment(n=64, roi_px=256, srs=(0.0625,), sr=0.0625, chunk_frames=64).run()",
    "experiment_128_roi128": "from torchtof import PaperExperiment\n"
    "PaperExperiment(n=128, roi_px=128, srs=(0.125,), sr=0.125).run()",
    "exact_factors_64": "from torchtof.operators import Hadamard\n"
    "from torchtof.recon.tv import exact_factors\n"
    "exact_factors(Hadamard(64, sr=0.25), torch.zeros(1))",
    "exact_factors_128": "from torchtof.operators import Hadamard\n"
    "from torchtof.recon.tv import exact_factors\n"
    "exact_factors(Hadamard(128, sr=0.25), torch.zeros(1))",
    "exact_tval3_64": "from torchtof.operators import Hadamard\n"
    "from torchtof.recon import tval3\nfrom torchtof.scenes import sky_character\n"
    "A = Hadamard(64, sr=0.25)\ntval3(A(sky_character(64)), A, u_step='exact')",
    "jointtv_64": "from torchtof.operators import Hadamard\n"
    "from torchtof.recon import JointTV\nfrom torchtof.scenes import sky_character\n"
    "A = Hadamard(64, sr=0.25)\nx = sky_character(64)\n"
    "JointTV(A)(A(torch.cat([x, 0.5 * x], dim=1)))",
}

PROBE = """
import resource, time, json
import torch, torchtof
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
t0 = time.perf_counter()
{code}
dt = time.perf_counter() - t0
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(json.dumps({{"peak_mib": (peak - base) / 1024, "time_s": dt}}))
"""


def _load() -> float | None:
    try:
        return round(os.getloadavg()[0], 2)
    except OSError:
        return None


def main(argv: list[str]) -> dict:
    out_path = None
    if "--out" in argv:
        i = argv.index("--out")
        out_path, argv = argv[i + 1], argv[:i] + argv[i + 2:]
    unknown = [a for a in argv if a not in CASES]
    if unknown:
        raise SystemExit(f"measure_memory: unknown case(s) {unknown}; known: {list(CASES)}")
    start, rows = _load(), {}
    for name in argv or list(CASES):
        out = subprocess.run([sys.executable, "-c", PROBE.format(code=CASES[name])],
                             capture_output=True, text=True,
                             env={**os.environ, "OMP_NUM_THREADS": "1"})
        if out.returncode:
            print(f"{name}: failed: {out.stderr.strip().splitlines()[-1]}")
            rows[name] = {"failed": out.stderr.strip().splitlines()[-1]}
            continue
        r = json.loads(out.stdout.strip().splitlines()[-1])
        rows[name] = r
        print(f"{name}: peak +{r['peak_mib']:.0f} MiB, {r['time_s']:.2f} s", flush=True)
    from torchtof.operators import Hadamard
    from torchtof.recon.tv import exact_factors_bytes

    estimates = {n: exact_factors_bytes(Hadamard(n, sr=0.25)) for n in (64, 128, 256)}
    res = {"command": "python tests/reliability/measure_memory.py",
           "cases": rows, "exact_factors_estimate_bytes_sr25": estimates,
           "machine": {"start": {"load_1min": start, "cpus": os.cpu_count(),
                                 "threads": 1},
                       "end": {"load_1min": _load(), "cpus": os.cpu_count()}}}
    if out_path:
        with open(out_path, "w") as f:
            f.write(json.dumps(res, indent=1) + "\n")
    return res


if __name__ == "__main__":
    main(sys.argv[1:])
