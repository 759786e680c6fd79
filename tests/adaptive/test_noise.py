import pytest
import torch

from torchtof.adaptive import noise_from_blocks, noise_from_repeats


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
