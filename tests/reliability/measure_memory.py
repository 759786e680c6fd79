"""Peak memory and time of the dense entry points, each in a fresh process.

    OMP_NUM_THREADS=1 python tests/reliability/measure_memory.py [case ...]

Each case runs in its own interpreter; the peak is the growth of the maximum resident set
size (``resource.getrusage``, the number ``/usr/bin/time -v`` reports) over the process
after ``import torchtof``. Not a test (several seconds to minutes per case).
"""

from __future__ import annotations

import json
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


def main(names: list[str]) -> None:
    for name in names or list(CASES):
        out = subprocess.run([sys.executable, "-c", PROBE.format(code=CASES[name])],
                             capture_output=True, text=True)
        if out.returncode:
            print(f"{name}: failed: {out.stderr.strip().splitlines()[-1]}")
            continue
        r = json.loads(out.stdout.strip().splitlines()[-1])
        print(f"{name}: peak +{r['peak_mib']:.0f} MiB, {r['time_s']:.2f} s")


if __name__ == "__main__":
    main(sys.argv[1:])
