"""Every single and every double fault within one acquisition sequence, in both frame-id
modes: each run's buckets, read back from the store it wrote, compared bit for bit with a
clean run's.

The set-up is the hardware tests' short run: an 8×8 DMD, 8×8 px camera ROI, SR 12.5 %,
noise-free, 8 ±1 Hadamard patterns = 16 frames shown as one sequence (``block=8``),
``retries=4``, ``frame_timeout_s=0.15``. A fault is one of the seven frame-level faults of
:class:`torchtof.hardware.simulated.Faults` (``drop``, ``extra``, ``duplicate``,
``frame_timeout``, ``corrupt``, ``split``, ``stall``) at one of the 16 frame ordinals of the
first attempt: 7 × 16 = 112 single faults and C(112, 2) = 6216 unordered pairs of distinct
faults (two kinds at one ordinal, one kind at two ordinals, anything else), each run with
device frame numbers (``frame_ids="device"``) and with host counting (``"count"``):
2 × (112 + 6216) = 12 656 runs.

Per run: a fresh :class:`~torchtof.hardware.simulated.SimulatedBench` with the faults, a
fresh store, :func:`torchtof.hardware.acquire` (the library code, unchanged), then
:func:`torchtof.hardware.load_buckets` on that store (every chunk's CRC-32C checked) and a
bit-for-bit comparison of all four bucket kinds with the clean run of the same mode, which
is acquired once per mode by the plain bench. A run that raises is a failure; what it had
recorded before is compared too. Speed-ups that do not touch what is checked: the frames
are rendered once per displayed pattern and reused (a noise-free frame is a function of its
pattern; :class:`_ReusedFrames`), the stores live in ``/dev/shm`` when it exists, and runs
go to a pool of worker processes.

    python benchmarks/fault_sweep.py                       # all 12 656 runs, 2 workers
    python benchmarks/fault_sweep.py --sample 20 --out -   # 20 random cases per mode

Writes JSON (``docs/reliability/fault_sweep.json`` by default): runs per mode (singles,
doubles), wrong buckets, runs with wrong buckets, failures (each with its faults and
error), the histogram of retries per run, wall and CPU time, load average, workers. A
progress bar goes to stderr.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import platform
import random
import shutil
import sys
import tempfile
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:  # run as a script from a checkout
    sys.path.insert(0, str(REPO))

KINDS = ("drop", "extra", "duplicate", "frame_timeout", "corrupt", "split", "stall")
POSITIONS = 16  # frames of the one sequence (8 patterns × φ±)
MODES = ("device", "count")
BUCKETS = ("depth", "depth_gated", "intensity", "taps")
SETUP = {"n": 8, "roi_px": 8, "sr": 0.125, "block": 8, "retries": 4, "frame_timeout_s": 0.15,
         "seed": 0, "noise": "none"}
DEFAULT_OUT = REPO / "docs" / "reliability" / "fault_sweep.json"


def singles() -> list[tuple[tuple[str, int], ...]]:
    """The 112 single faults ``((kind, ordinal),)``."""
    return [((k, p),) for k in KINDS for p in range(POSITIONS)]


def doubles() -> list[tuple[tuple[str, int], ...]]:
    """The 6216 unordered pairs of distinct single faults."""
    return list(itertools.combinations([s[0] for s in singles()], 2))


def all_cases() -> list[tuple[tuple[str, int], ...]]:
    return singles() + doubles()


def _config():
    from torchtof.experiment import ExperimentConfig

    return ExperimentConfig(n=SETUP["n"], roi_px=SETUP["roi_px"], srs=(SETUP["sr"],), shot=None,
                            read_noise_e=0.0)


def _faults(case) -> dict[str, set[int]]:
    out: dict[str, set[int]] = {}
    for kind, pos in case:
        if kind not in KINDS or not 0 <= pos < POSITIONS:
            raise ValueError(f"fault_sweep: unknown fault {(kind, pos)!r}")
        out.setdefault(kind, set()).add(int(pos))
    return out


def _bench_class(reuse: dict | None):
    from torchtof.hardware.simulated import SimulatedBench

    if reuse is None:
        return SimulatedBench

    class _ReusedFrames(SimulatedBench):
        """Renders each (pattern, modulation frequency) once per process and hands out the
        same frame afterwards: the simulated frame of a noise-free set-up depends on
        nothing else (its noise generator is seeded from the pattern alone)."""

        def render(self, pattern, freq_hz):
            key = (pattern.shape, pattern.tobytes(), float(freq_hz))
            frame = reuse.get(key)
            if frame is None:
                frame = reuse[key] = super().render(pattern, freq_hz)
            return frame

    return _ReusedFrames


def acquire_once(path, case=(), ids: str = "device", reuse: dict | None = None):
    """One acquisition of the set-up with the faults of ``case`` into ``path``."""
    from torchtof.hardware import acquire
    from torchtof.hardware.simulated import Faults

    cfg = _config()
    bench = _bench_class(reuse)(cfg, seed=SETUP["seed"], faults=Faults(**_faults(case)))
    return acquire(path, bench.lightcrafter(timeout_ms=100), bench.camera(), n=cfg.n,
                   sr=SETUP["sr"], block=SETUP["block"], progress=False,
                   retries=SETUP["retries"], frame_timeout_s=SETUP["frame_timeout_s"],
                   frame_ids=ids,
                   metadata={"simulation": {"config": asdict(cfg), "seed": SETUP["seed"]}})


def read_buckets(path) -> dict[str, np.ndarray]:
    """The store's buckets as read back by :func:`torchtof.hardware.load_buckets`."""
    from torchtof.hardware import load_buckets

    return {k: v.numpy() for k, v in load_buckets(path)[0].items()}


def wrong_buckets(got: dict[str, np.ndarray], ref: dict[str, np.ndarray],
                  prefix: bool = False) -> int:
    """Buckets whose float32 bits differ from the reference (all four kinds). A missing
    kind or a different length counts every reference bucket as wrong; with ``prefix`` a
    shorter recording (an interrupted run) is compared with the reference's first frames."""
    wrong = 0
    for k in BUCKETS:
        r, g = ref[k], got.get(k)
        if g is not None and prefix and g.shape[:-1] == r.shape[:-1] \
                and g.shape[-1] <= r.shape[-1]:
            r = r[..., : g.shape[-1]]
        if g is None or g.shape != r.shape or g.dtype != r.dtype:
            wrong += r.size
            continue
        wrong += int((g.view(np.uint32) != r.view(np.uint32)).sum())
    return wrong


def check_case(case, ids: str, ref: dict[str, np.ndarray], workdir, reuse: dict | None):
    """Run one case and compare: ``{"wrong", "retries", "duplicates", "error"}``."""
    path = Path(tempfile.mkdtemp(dir=workdir)) / "run.zarr"
    out = {"wrong": 0, "retries": None, "duplicates": None, "error": None}
    try:
        try:
            res = acquire_once(path, case, ids, reuse)
        except Exception as exc:  # noqa: BLE001 - a failure of the run: reported, then checked
            out["error"] = f"{type(exc).__name__}: {exc}"
            try:  # whatever was recorded before must still be right
                out["wrong"] = wrong_buckets(read_buckets(path), ref, prefix=True)
            except ValueError:  # nothing (no complete pair) recorded
                pass
            return out
        out["retries"], out["duplicates"] = res.retries, res.duplicates
        if res.m_acquired * 2 != ref["depth"].shape[-1]:
            out["error"] = f"m_acquired {res.m_acquired}"
        out["wrong"] = wrong_buckets(read_buckets(path), ref)
        return out
    finally:
        shutil.rmtree(path.parent, ignore_errors=True)


def clean_reference(ids: str, workdir) -> dict[str, np.ndarray]:
    """The clean run's buckets, acquired by the plain bench (every frame rendered)."""
    path = Path(tempfile.mkdtemp(dir=workdir)) / "clean.zarr"
    try:
        res = acquire_once(path, (), ids, reuse=None)
        if res.retries or res.duplicates:
            raise RuntimeError(f"fault_sweep: the clean run retried ({res})")
        return read_buckets(path)
    finally:
        shutil.rmtree(path.parent, ignore_errors=True)


# -- worker processes ----------------------------------------------------------------------
_STATE: dict = {}


def _init(refs, workdir) -> None:
    import torch

    torch.set_num_threads(1)
    _STATE.update(refs=refs, workdir=workdir, reuse={})


def _work(task):
    ids, case = task
    return ids, case, check_case(case, ids, _STATE["refs"][ids], _STATE["workdir"],
                                 _STATE["reuse"])


def _scratch() -> str | None:
    shm = Path("/dev/shm")
    return str(shm) if shm.is_dir() and os.access(shm, os.W_OK) else None


def sweep(cases=None, modes=MODES, workers: int = 2, progress: bool = True) -> dict:
    """Run ``cases`` (default: every single and double fault) in each frame-id mode.

    Args:
        cases: sequences of ``(kind, ordinal)`` faults; default :func:`all_cases`.
        modes: frame-id modes.
        workers: worker processes (0: in this process).
        progress: a progress bar on stderr.

    Returns:
        The summary written as JSON by :func:`main` (module docstring).
    """
    import torch

    from torchtof._optional import progress_bar

    cases = all_cases() if cases is None else [tuple(tuple(f) for f in c) for c in cases]
    for c in cases:
        _faults(c)
    load0, t0 = os.getloadavg(), time.perf_counter()
    cpu0 = os.times()
    workdir = tempfile.mkdtemp(prefix="fault_sweep-", dir=_scratch())
    try:
        refs = {ids: clean_reference(ids, workdir) for ids in modes}
        tasks = [(ids, c) for ids in modes for c in cases]
        summary = {ids: {"runs": 0, "singles": 0, "doubles": 0, "wrong_buckets": 0,
                         "runs_with_wrong_buckets": 0, "failures": 0, "retries": {}}
                   for ids in modes}
        failures = []
        bar = progress_bar(total=len(tasks), desc="fault sweep", unit="run", file=sys.stderr,
                           disable=not progress)

        def record(ids, case, r):
            s = summary[ids]
            s["runs"] += 1
            s["singles" if len(case) == 1 else "doubles"] += 1
            s["wrong_buckets"] += r["wrong"]
            s["runs_with_wrong_buckets"] += r["wrong"] > 0
            key = str(r["retries"]) if r["retries"] is not None else "failed"
            s["retries"][key] = s["retries"].get(key, 0) + 1
            if r["error"] is not None or r["wrong"]:
                s["failures"] += r["error"] is not None
                failures.append({"frame_ids": ids, "faults": [list(f) for f in case], **r})
            bar.update(1)

        if workers <= 0:
            torch_threads = torch.get_num_threads()
            _init(refs, workdir)
            try:
                for t in tasks:
                    record(*_work(t))
            finally:
                torch.set_num_threads(torch_threads)
        else:
            import multiprocessing as mp

            ctx = mp.get_context("spawn")  # no fork of a process with zarr's and torch's threads
            with ctx.Pool(workers, initializer=_init, initargs=(refs, workdir)) as pool:
                for out in pool.imap_unordered(_work, tasks, chunksize=16):
                    record(*out)
        bar.close()
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
    cpu1 = os.times()
    for s in summary.values():
        s["retries"] = dict(sorted(s["retries"].items()))
    return {
        "what": "every single and double frame fault within one 16-frame sequence, both "
                "frame-id modes; buckets read back from each run's store, compared bit for bit "
                "with the clean run's",
        "setup": {**SETUP, "kinds": list(KINDS), "positions": POSITIONS, "frames": POSITIONS},
        "runs": sum(s["runs"] for s in summary.values()),
        "wrong_buckets": sum(s["wrong_buckets"] for s in summary.values()),
        "runs_with_wrong_buckets": sum(s["runs_with_wrong_buckets"] for s in summary.values()),
        "failed_runs": sum(s["failures"] for s in summary.values()),
        "modes": summary,
        "failures": failures,
        "wall_s": round(time.perf_counter() - t0, 1),
        "cpu_s": round(sum(cpu1[:4]) - sum(cpu0[:4]), 1),  # this process and its workers
        "workers": workers,
        "load_avg_start": [round(x, 2) for x in load0],
        "load_avg_end": [round(x, 2) for x in os.getloadavg()],
        "cores": os.cpu_count(),
        "torch_threads_per_worker": 1,
        "python": platform.python_version(),
        "torch": torch.__version__,
        "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="fault_sweep.py", description=__doc__.split("\n\n")[0])
    p.add_argument("--workers", type=int, default=2, help="worker processes (0: this one)")
    p.add_argument("--sample", type=int, default=None,
                   help="only this many random cases (seeded) instead of all 6328 per mode")
    p.add_argument("--seed", type=int, default=0, help="seed of --sample")
    p.add_argument("--modes", nargs="+", choices=MODES, default=list(MODES))
    p.add_argument("--out", default=None,
                   help=f"JSON file ('-': stdout; default {DEFAULT_OUT.name} in docs/reliability/ "
                   "for the full sweep, which a --sample or --modes run must not replace)")
    p.add_argument("--no-progress", action="store_true")
    a = p.parse_args(argv)
    if a.workers < 0:
        p.error(f"argument --workers: expected >= 0, got {a.workers}")
    if a.sample is not None and a.sample < 1:
        p.error(f"argument --sample: expected >= 1, got {a.sample}")
    partial = a.sample is not None or set(a.modes) != set(MODES)
    if a.out is None:
        if partial:  # the committed record holds the full sweep (tests check it)
            p.error("argument --out: a --sample or --modes run needs its own --out (or '-'); "
                    f"the default {DEFAULT_OUT} holds the full sweep")
        a.out = str(DEFAULT_OUT)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    cases = all_cases()
    if a.sample is not None:
        cases = random.Random(a.seed).sample(cases, min(a.sample, len(cases)))
    out = sweep(cases, tuple(a.modes), a.workers, progress=not a.no_progress)
    out["command"] = "python benchmarks/fault_sweep.py " + " ".join(argv if argv is not None
                                                                     else sys.argv[1:])
    text = json.dumps(out, indent=1) + "\n"
    if a.out == "-":
        sys.stdout.write(text)
    else:
        Path(a.out).parent.mkdir(parents=True, exist_ok=True)
        Path(a.out).write_text(text)
    print(f"{out['runs']} runs, {out['wrong_buckets']} wrong buckets, {out['failed_runs']} "
          f"failed, {out['wall_s']} s wall, {out['cpu_s']} s CPU", file=sys.stderr)
    return 0 if out["wrong_buckets"] == 0 and out["failed_runs"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
