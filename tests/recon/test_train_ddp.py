"""Training data and data-parallel training of the unrolled TVAL3.

The DDP test launches ``torch.distributed.run`` with 2 processes (gloo, loopback only) on
``examples/train_unrolled.py`` and checks that they train the same model as one process on
the same global batch.
"""

import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from torchtof.operators import Hadamard
from torchtof.recon.synthetic import (
    KINDS,
    measurement_noise,
    scene_seed,
    synthetic_scene,
    synthetic_scenes,
)
from torchtof.recon.train import noisy_measurements, train_unrolled
from torchtof.recon.unrolled import PARAM_NAMES, UnrolledTVAL3

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "examples" / "train_unrolled.py"


# -- synthetic scenes ----------------------------------------------------------------------------


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_scene_families(kind, dtype):
    x = synthetic_scene(16, seed=7, kind=kind, dtype=dtype)
    assert x.shape == (1, 1, 16, 16) and x.dtype == dtype
    assert x.min() >= 0 and x.max() <= 1
    torch.testing.assert_close(x, synthetic_scene(16, seed=7, kind=kind, dtype=dtype))
    if kind != "depth":
        assert set(x.unique().tolist()) <= {0.0, 1.0}


def test_batches_are_deterministic_and_shardable():
    full = synthetic_scenes(16, seed=0, step=3, indices=range(6))
    shards = [synthetic_scenes(16, seed=0, step=3, indices=range(r * 3, r * 3 + 3)) for r in (0, 1)]
    torch.testing.assert_close(torch.cat(shards), full)
    other = synthetic_scenes(16, seed=1, step=3, indices=range(6))  # held-out seed differs
    assert not torch.equal(other, full)
    assert len({tuple(x.flatten().tolist()) for x in full}) == 6  # distinct scenes
    A = Hadamard(16, sr=0.25)
    y = noisy_measurements(A, full, 0, 3, range(6), (0.0, 0.02))
    ys = [
        noisy_measurements(A, s, 0, 3, range(r * 3, r * 3 + 3), (0.0, 0.02))
        for r, s in enumerate(shards)
    ]
    torch.testing.assert_close(torch.cat(ys), y)


def test_scene_seed_and_synthetic_errors():
    assert scene_seed(0, 1, 2) == scene_seed(0, 1, 2) != scene_seed(0, 2, 1)
    with pytest.raises(ValueError, match="scene_seed: expected step to be an int >= 0, got -1"):
        scene_seed(0, -1, 0)
    with pytest.raises(ValueError, match="synthetic_scene: expected kind in"):
        synthetic_scene(16, seed=0, kind="faces")
    with pytest.raises(ValueError, match="synthetic_scene: expected n to be an int >= 4"):
        synthetic_scene(2, seed=0)
    with pytest.raises(ValueError, match="synthetic_scenes: expected a non-empty indices"):
        synthetic_scenes(16, seed=0, step=0, indices=[])


def test_measurement_noise():
    y = torch.linspace(-1.0, 3.0, 64, dtype=torch.float64).reshape(2, 1, 32)
    y0 = y.clone()
    torch.testing.assert_close(measurement_noise(y, 0.0), y)
    noisy = measurement_noise(y.repeat(500, 1, 1), 0.01, torch.Generator().manual_seed(0))
    spread = 4.0 * 31 / 63  # max − min of each row of y
    std = (noisy - y.repeat(500, 1, 1)).std()
    assert abs(float(std) / (0.01 * spread) - 1) < 0.02  # known answer: σ = level · spread
    assert torch.equal(y, y0)
    with pytest.raises(ValueError, match="measurement_noise: expected level in"):
        measurement_noise(y, -0.1)
    with pytest.raises(ValueError, match="measurement_noise: expected y of rank 3"):
        measurement_noise(y[0], 0.01)


# -- train_unrolled ------------------------------------------------------------------------------


def test_train_unrolled_errors(monkeypatch):
    with pytest.raises(ValueError, match="train_unrolled: expected steps to be an int >= 1"):
        train_unrolled(n=16, steps=0)
    with pytest.raises(ValueError, match="train_unrolled: expected noise_level\\[1\\] in"):
        train_unrolled(n=16, steps=1, noise_level=(0.02, 0.01))
    for k in ("RANK", "WORLD_SIZE", "MASTER_ADDR", "MASTER_PORT"):
        monkeypatch.delenv(k, raising=False)
    with pytest.raises(ValueError, match="train_unrolled: distributed=True needs torchrun"):
        train_unrolled(n=16, steps=1, distributed=True)


@pytest.mark.slow  # two spawned processes: 25 s on 2 cores
def test_ddp_two_processes_train_the_single_process_model(tmp_path):
    args = "--n 16 --sr 0.25 --n-iter 3 --steps 5 --batch 8 --seed 3 --log-every 0".split()
    out = tmp_path / "ddp.pt"
    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1", GLOO_SOCKET_IFNAME="lo")
    for k in ("RANK", "WORLD_SIZE", "LOCAL_RANK", "MASTER_ADDR", "MASTER_PORT"):
        env.pop(k, None)
    # --standalone: the c10d rendezvous picks a free port itself (no bind-then-release race
    # with other tests running in parallel)
    launcher = "-m torch.distributed.run --standalone --nproc_per_node 2".split()
    cmd = [sys.executable, *launcher, "--", str(SCRIPT), *args]
    cmd += ["--out", str(out)]
    proc = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-4000:]
    blob = torch.load(out, weights_only=True)
    meta = blob["meta"]
    assert meta["world_size"] == 2 and meta["batch_size"] == 8 and meta["steps"] == 5

    single = train_unrolled(
        n=16, sr=0.25, n_layers=3, steps=5, batch_size=8, seed=3, distributed=False
    ).model
    untrained = UnrolledTVAL3(single.A, n_iter=3, pretrained=False)
    for name in PARAM_NAMES:
        got, want = blob["state_dict"][name], getattr(single, name).detach()
        torch.testing.assert_close(got, want, rtol=1e-4, atol=1e-6)
        assert (got - getattr(untrained, name).detach()).abs().min() > 1e-3  # it did train
