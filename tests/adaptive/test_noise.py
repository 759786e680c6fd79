import pytest
import torch

from torchtof.adaptive import (
    noise_from_blocks,
    noise_from_pair_sums,
    noise_from_pairs,
    noise_from_repeats,
    pair_differences,
    pair_noise_dof,
    pair_sums,
)


def test_repeats_recovers_sigma_whatever_the_signal(gen):
    s = 50.0 * torch.randn(1, 2, 2048, generator=gen)  # strong signal, the same in every repeat
    y = s + torch.tensor([0.5, 2.0]).reshape(1, 2, 1) * torch.randn(5, 2, 2048, generator=gen)
    sig = noise_from_repeats(y)
    assert sig.shape == (2,)
    assert torch.allclose(sig, torch.tensor([0.5, 2.0]), rtol=0.05)


def test_blocks_on_pure_noise_and_with_low_order_signal(gen):
    y = 0.3 * torch.randn(3, 1, 1024, generator=gen)
    assert torch.allclose(noise_from_blocks(y, 32), torch.full((3, 1), 0.3), rtol=0.15)
    y2 = y.clone()
    y2[..., :256] += 10.0  # signal only in the low orders (first half) is ignored
    assert torch.equal(noise_from_blocks(y2, 32), noise_from_blocks(y, 32))


@pytest.mark.parametrize(
    ("fn", "arg", "match"),
    [
        (noise_from_repeats, torch.zeros(1, 1, 8), "R >= 2"),
        (noise_from_repeats, torch.zeros(2, 8), "y"),
        (noise_from_repeats, torch.tensor([[[1.0, float("nan")]], [[0.0, 0.0]]]), "NaN|finite"),
        (noise_from_blocks, torch.zeros(1, 1, 40), "at least 2\\*block"),
    ],
)
def test_bad_inputs(fn, arg, match):
    with pytest.raises(ValueError, match=match):
        fn(arg)


def test_blocks_bad_block():
    with pytest.raises(ValueError, match="block"):
        noise_from_blocks(torch.zeros(1, 1, 64), 2)


def test_variance_lower_factor_is_the_chi2_quantile():
    from scipy.stats import chi2

    from torchtof.adaptive import variance_lower_factor

    assert variance_lower_factor(32, 0.05) == pytest.approx(32 / chi2.ppf(0.95, 32))
    assert variance_lower_factor(32, 0.05) < 1.0 < variance_lower_factor(32, 0.95)
    assert variance_lower_factor(10**6, 0.05) == pytest.approx(1.0, abs=0.01)  # σ̂ exact


def test_variance_lower_factor_covers_the_noise_at_its_level():
    # seeded: q·σ̂² from B = 32 repeated differences exceeds σ² in about 5 % of the draws
    from torchtof.adaptive import variance_lower_factor

    g = torch.Generator().manual_seed(3)
    b, trials, sigma = 32, 20000, 0.7
    d = sigma * (torch.randn(trials, b, generator=g) - torch.randn(trials, b, generator=g))
    s2 = d.pow(2).sum(-1) / (2 * b)
    over = float((variance_lower_factor(b, 0.05) * s2 > sigma**2).double().mean())
    assert over == pytest.approx(0.05, abs=0.01)


@pytest.mark.parametrize(("dof", "level"), [(0, 0.05), (True, 0.05), (8, 0.0), (8, 1.0)])
def test_variance_lower_factor_rejects_bad_input(dof, level):
    from torchtof.adaptive import variance_lower_factor

    with pytest.raises(ValueError, match="variance_lower_factor"):
        variance_lower_factor(dof, level)


# --- free noise estimate from the complementary DMD pairs -------------------------------------


def _split(s, e_plus, e_minus, coef):
    """Interleaved (B, C, 2M) buckets whose pairs have sum s and difference coef (x n = 4)."""
    yp = (s + coef) / 2 + e_plus
    ym = (s - coef) / 2 + e_minus
    return torch.stack([yp, ym], dim=-1).flatten(-2)


def test_pair_sums_and_combine_split_share_the_frames():
    from torchtof.operators.split import combine_split

    y = torch.tensor([[[5.0, 1.0, 2.0, 4.0]]])
    assert torch.equal(pair_sums(y, 2), torch.tensor([[[3.0, 3.0]]]))
    # y+ = (sum + n*diff)/2: the two views give back the frames
    s, d = pair_sums(y, 2), combine_split(y, 2)
    assert torch.allclose(torch.stack([(s + d), (s - d)], -1).flatten(-2), y)


def test_pairs_recover_sigma_of_the_signed_coefficients_whatever_the_signal(gen):
    n, m, sig_frame = 4, 4096, 0.6
    coef = 100.0 * torch.randn(1, 2, m, generator=gen)  # strong, varying signal in y+ - y-
    e = sig_frame * torch.randn(2, 1, 2, m, generator=gen)
    y = _split(torch.full((1, 2, m), 50.0), e[0], e[1], coef)
    # signed coefficient (y+ - y-)/n has std sqrt(2) sig_frame / n
    true = 2**0.5 * sig_frame / n
    for robust in (True, False):
        est = noise_from_pairs(y, n, robust=robust)
        assert est.shape == (1, 2)
        assert torch.allclose(est, torch.full((1, 2), true), rtol=0.06), (robust, est)
    # the same value from the signed coefficients of two independent realisations
    from torchtof.operators.split import combine_split

    e2 = sig_frame * torch.randn(2, 1, 2, m, generator=gen)
    y2 = _split(torch.full((1, 2, m), 50.0), e2[0], e2[1], coef)
    rep = noise_from_repeats(torch.cat([combine_split(y, n), combine_split(y2, n)]))
    assert torch.allclose(rep, torch.full((2,), true), rtol=0.06)


def test_pairs_skip_the_all_on_pair_and_ignore_a_slow_drift(gen):
    m = 2048
    s = 3.0 + 0.1 * torch.randn(1, 1, m, generator=gen)
    s_jump = s.clone()
    s_jump[..., 0] = 1e4  # the all-on/dark pair: a different sum, skipped by default
    assert torch.equal(noise_from_pair_sums(s_jump), noise_from_pair_sums(s))
    assert float(noise_from_pair_sums(s_jump, skip=0, robust=False)) > 10.0
    drift = s + torch.linspace(0.0, 20.0, m)  # the light drifts by 200 sigma over the run
    assert float(noise_from_pair_sums(drift)) == pytest.approx(0.1, rel=0.08)
    assert float(drift[..., 1:].std()) > 5.0  # the plain spread would be 50x too large
    glitch = s.clone()
    glitch[..., 100:110] += 50.0  # a few glitch frames move the robust estimate little
    assert float(noise_from_pair_sums(glitch)) == pytest.approx(0.1, rel=0.08)
    assert float(noise_from_pair_sums(glitch, robust=False)) > 1.0


def test_pair_differences_have_twice_the_variance(gen):
    s = 1.0 + 0.5 * torch.randn(1, 1, 8192, generator=gen)
    d = pair_differences(s)
    assert d.shape == (1, 1, 8190)
    assert float(d.var()) == pytest.approx(2 * 0.25, rel=0.05)


@pytest.mark.parametrize(
    ("fn", "args", "match"),
    [
        (pair_sums, (torch.zeros(1, 1, 3), 2), "even"),
        (pair_sums, (torch.zeros(1, 4), 2), "y_split"),
        (pair_sums, (torch.zeros(1, 1, 4), 0), "n"),
        (pair_sums, (torch.tensor([[[1.0, float("inf")]]]), 2), "y_split"),
        (pair_differences, (torch.zeros(1, 1, 3),), "skip \\+ 3"),
        (pair_differences, (torch.zeros(1, 1, 8), -1), "skip"),
        (noise_from_pair_sums, (torch.tensor([[[1.0, 2.0, float("nan"), 3.0]]]),), "s"),
        (noise_from_pairs, (torch.zeros(1, 1, 7), 2), "even"),
    ],
)
def test_pairs_bad_inputs(fn, args, match):
    with pytest.raises(ValueError, match=match):
        fn(*args)


@pytest.mark.parametrize("robust", [True, False])
def test_pair_noise_dof_matches_the_spread_of_the_estimate(gen, robust):
    k = 256
    s = torch.randn(4000, 1, k + 2, generator=gen, dtype=torch.float64)
    v = noise_from_pair_sums(s, robust=robust).pow(2).flatten()
    nu = float(2 * v.mean() ** 2 / v.var())  # chi2_nu / nu has variance 2 / nu
    assert nu == pytest.approx(pair_noise_dof(k, robust), rel=0.1)
    assert float(v.mean()) == pytest.approx(1.0, abs=0.02)  # unbiased for white noise
    with pytest.raises(ValueError, match="k"):
        pair_noise_dof(0)
