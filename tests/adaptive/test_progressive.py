import pytest
import torch

from torchtof.adaptive import ProgressiveStop, block_statistics, run_progressive
from torchtof.operators import Hadamard

N = 32


def _rect(n=N):
    x = torch.zeros(1, 1, n, n, dtype=torch.float64)
    x[..., 10:22, 8:20] = 1.0
    x[..., 14:18, 20:26] = 0.5
    return x


def _buckets(x, sigma, seed=0, sr=0.375):
    y = Hadamard(N, sr=sr)(x)
    g = torch.Generator().manual_seed(seed)
    return y + sigma * torch.randn(y.shape, generator=g, dtype=y.dtype)


def test_change_rule_is_the_relative_image_change_when_noise_free():
    # Parseval: ||x_m - x_{m-B}|| / ||x_m|| of the pseudo-inverse images equals r_b at sigma=0
    x = _rect()
    y = _buckets(x, 0.0)
    st = block_statistics(y, 32, 0.0)
    for k, m in enumerate(st["m"].long().tolist()):
        if k == 0:
            continue
        a, b = Hadamard(N, m=m).adjoint(y[..., :m]), Hadamard(N, m=m - 32).adjoint(y[..., : m - 32])
        direct = (a - b).norm() / a.norm()
        assert torch.allclose(st["change"][0, 0, k], direct, rtol=1e-9)


def test_energy_bound_is_exact_for_a_binary_object_noise_free():
    x = torch.zeros(1, 1, N, N, dtype=torch.float64)
    x[..., 8:24, 8:24] = 1.0  # a square: its energy sits in few low-order coefficients
    y = Hadamard(N, sr=1.0)(x)
    st = block_statistics(y, 32, 0.0, n=N)
    assert float(st["fraction"].max()) <= 1.0 + 1e-9
    assert float(st["fraction"][..., -1]) == pytest.approx(1.0, abs=1e-9)  # ||x||^2 = max|x| sum x


def test_innovation_stops_a_piecewise_constant_scene_early_and_says_why():
    y = _buckets(_rect(), 0.01)
    res = run_progressive({"gated": y}, ProgressiveStop(N, noise_sigma=0.01))
    assert res.m < res.m_max == 384
    assert res.m >= 128  # min_patterns
    assert "predicted by the tv image" in res.reason


def test_innovation_runs_to_the_end_on_unpredictable_texture():
    # i.i.d. pixels: no prior predicts unmeasured coefficients, every block carries signal
    g = torch.Generator().manual_seed(3)
    x = torch.rand(1, 1, N, N, generator=g, dtype=torch.float64)
    y = _buckets(x, 0.01)
    res = run_progressive({"gated": y}, ProgressiveStop(N, noise_sigma=0.01))
    assert res.m == res.m_max
    assert res.reason.startswith("end of record")


def test_pure_noise_stops_at_min_patterns():
    y = _buckets(torch.zeros(1, 1, N, N, dtype=torch.float64), 1.0)
    res = run_progressive({"depth": y}, ProgressiveStop(N, kind="depth", noise_sigma=1.0))
    assert res.m == 128


def test_plain_change_rule_never_stops_under_noise_debiased_one_does():
    # the plain change of a block is at least sqrt(B) sigma / ||x_m|| (0.2 here): above tol
    y = _buckets(_rect(), 0.7)
    plain = run_progressive({"gated": y}, ProgressiveStop(N, rule="change", noise_sigma=0.0,
                                                          tol=0.15, patience=2))
    debiased = run_progressive({"gated": y}, ProgressiveStop(N, rule="change", noise_sigma=0.7,
                                                             tol=0.15, patience=2))
    assert plain.m == 384
    assert debiased.m < 384


def test_estimated_noise_without_sigma():
    y = _buckets(_rect(), 0.01)
    stop = ProgressiveStop(N)
    res = run_progressive({"gated": y}, stop)
    assert res.m < 384
    assert 0.005 < res.history[-1]["sigma"] < 0.05


def test_call_matches_the_replay_block_by_block():
    y = _buckets(_rect(), 0.01)
    stop = ProgressiveStop(N, noise_sigma=0.01)
    live = next(m for m in range(32, 385, 32) if stop({"gated": y[..., :m]}))
    assert live == run_progressive({"gated": y}, ProgressiveStop(N, noise_sigma=0.01)).m


def test_call_does_not_modify_buckets():
    y = _buckets(_rect(), 0.01)
    ref = y.clone()
    ProgressiveStop(N, noise_sigma=0.01)({"gated": y})
    assert torch.equal(y, ref)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"rule": "bogus"}, "rule"),
        ({"kind": "taps"}, "kind"),
        ({"block": 2}, "block"),
        ({"patience": 0}, "patience"),
        ({"target": 1.5}, "target"),
        ({"tol": -1.0}, "tol"),
        ({"snr": -1.0}, "snr"),
        ({"recon": "dip"}, "recon"),
        ({"noise_sigma": -1.0}, "noise_sigma"),
    ],
)
def test_bad_config(kwargs, match):
    with pytest.raises(ValueError, match=match):
        ProgressiveStop(N, **kwargs)


def test_bad_buckets():
    stop = ProgressiveStop(N)
    with pytest.raises(ValueError, match="gated"):
        stop({"depth": torch.zeros(1, 1, 64)})
    with pytest.raises(ValueError, match="shape"):
        stop({"gated": torch.zeros(1, 64)})
    with pytest.raises(ValueError, match="NaN|finite"):
        stop({"gated": torch.full((1, 1, 64), float("nan"))})
    with pytest.raises(ValueError, match="one M"):
        run_progressive({"gated": torch.zeros(1, 1, 64), "depth": torch.zeros(1, 1, 32)}, stop)


def test_a_shorter_prefix_starts_a_new_acquisition():
    y = _buckets(_rect(), 0.01)
    stop = ProgressiveStop(N, noise_sigma=0.01)
    first = next(m for m in range(32, 385, 32) if stop({"gated": y[..., :m]}))
    again = next(m for m in range(32, 385, 32) if stop({"gated": y[..., :m]}))
    assert first == again


def test_pairs_noise_reads_the_pair_sums_and_needs_them(gen):
    from torchtof.adaptive import ProgressiveStop

    x = torch.zeros(1, 1, 16, 16)
    x[..., 4:9, 5:10] = 1.0
    from torchtof.operators import Hadamard

    y = Hadamard(16, sr=0.5)(x)
    sums = 2.0 + 0.05 * torch.randn(y.shape, generator=gen)
    y = y + 0.05 * torch.randn(y.shape, generator=gen)
    stop = ProgressiveStop(16, block=16, noise_sigma="pairs", kind="gated")
    stop({"gated": y[..., :32], "gated_sum": sums[..., :32]})
    assert stop.last["sigma"] == pytest.approx(0.05, rel=0.35)
    with pytest.raises(ValueError, match="gated_sum"):
        stop({"gated": y[..., :48]})
    with pytest.raises(ValueError, match="noise_sigma"):
        ProgressiveStop(16, noise_sigma="frames")
