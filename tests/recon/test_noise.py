"""The one module of noise estimators (torchtof.recon.noise)."""

from __future__ import annotations

from statistics import NormalDist

import pytest
import torch

from torchtof.recon import noise

PHI = NormalDist().inv_cdf


def test_abs_quantile_sigma_known_answers():
    t = torch.tensor([[[1.0, -2.0, 3.0, -4.0]]], dtype=torch.float64)
    # |t| sorted 1 2 3 4; q = 0.5 at position 1.5: linear 2.5, lower 2; / Φ⁻¹(3/4)
    lin = noise.abs_quantile_sigma(t, 0.5, "linear")
    low = noise.abs_quantile_sigma(t, 0.5, "lower")
    assert float(lin) == pytest.approx(2.5 / PHI(0.75), rel=1e-15)
    assert float(low) == pytest.approx(2.0 / PHI(0.75), rel=1e-15)
    # q = 0.2 at position 0.6: 1 + 0.6 = 1.6, / Φ⁻¹(0.6)
    assert float(noise.abs_quantile_sigma(t, 0.2)) == pytest.approx(1.6 / PHI(0.6), rel=1e-15)
    assert float(noise.abs_quantile_sigma(t, 0.5, "lower")) == pytest.approx(
        float(t.abs().median()) / PHI(0.75), rel=1e-15)


def test_tail_noise_sigma_uses_the_last_measurements():
    y = torch.tensor([[[100.0, -50.0, 7.0, 9.0, 1.0, -2.0, 3.0, -4.0]]], dtype=torch.float64)
    # tail 1/2 of 8 = the last 4 (min_count 1): the large leading signal is ignored
    got = noise.tail_noise_sigma(y, tail=0.5, quantile=0.5, min_count=1)
    assert float(got) == pytest.approx(2.5 / PHI(0.75), rel=1e-15)
    # min_count 8 takes all 8: |y| sorted 1 2 3 4 7 9 50 100, median 5.5
    got = noise.tail_noise_sigma(y, tail=0.5, quantile=0.5)
    assert float(got) == pytest.approx(5.5 / PHI(0.75), rel=1e-15)


def test_tail_noise_sigma_is_tval3_estimate_and_bp_radius():
    from torchtof.recon.tval3 import bucket_noise_sigma

    y = torch.randn(3, 2, 203, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    assert torch.equal(noise.tail_noise_sigma(y), bucket_noise_sigma(y))
    # BP's eps="auto": √M times the MAD of the last ⌈M/4⌉ (lower median)
    k = (203 + 3) // 4
    want = y[..., -k:].abs().median(dim=-1).values / PHI(0.75)
    got = noise.tail_noise_sigma(y, 0.25, 0.5, min_count=1, interpolation="lower")
    torch.testing.assert_close(got, want, rtol=1e-15, atol=0)


def test_tail_noise_sigma_consistent_for_white_noise():
    # the sample q-quantile ξ̂ of |z| over k draws has standard error √(q(1−q)/k) / f(ξ),
    # f = 2φ the half-normal density (asymptotic normality of sample quantiles): 4 of them
    n, sigma = 1 << 16, 0.3
    y = sigma * torch.randn(4, 1, n, generator=torch.Generator().manual_seed(1))
    k = n // 4
    for q in (0.2, 0.5):
        xi = PHI((1 + q) / 2)
        rel = 4 * (q * (1 - q) / k) ** 0.5 / (2 * NormalDist().pdf(xi) * xi)
        torch.testing.assert_close(noise.tail_noise_sigma(y, quantile=q),
                                   torch.full((4, 1), sigma), rtol=rel, atol=0)


@pytest.mark.parametrize("kw, err", [({"tail": 0.0}, "tail"), ({"quantile": 1.0}, "quantile"),
                                     ({"min_count": 0}, "min_count"),
                                     ({"interpolation": "cubic"}, "interpolation")])
def test_tail_noise_sigma_bad_options(kw, err):
    with pytest.raises(ValueError, match=err):
        noise.tail_noise_sigma(torch.randn(1, 1, 16), **kw)


def test_adaptive_noise_reexports_the_same_functions():
    from torchtof.adaptive import noise as old

    for name in old.__all__:
        assert getattr(old, name) is getattr(noise, name), name


def test_noise_estimators_and_markov_covariance_check_their_inputs():
    from torchtof.recon.gauss import markov_covariance
    from torchtof.recon.noise import abs_quantile_sigma, tail_noise_sigma
    with pytest.raises(ValueError, match="tail_noise_sigma: y contains non-finite"):
        tail_noise_sigma(torch.full((1, 1, 16), float("nan")))
    with pytest.raises(TypeError, match="tail_noise_sigma: expected y to be a real"):
        tail_noise_sigma(torch.zeros(1, 1, 16, dtype=torch.complex64))
    with pytest.raises(ValueError, match="tail_noise_sigma: expected y with a measurement"):
        tail_noise_sigma(torch.tensor(1.0))
    for q in (0.0, 1.0, 2.0, float("nan")):
        with pytest.raises(ValueError, match="abs_quantile_sigma: expected quantile in"):
            abs_quantile_sigma(torch.rand(8), q)
    with pytest.raises(ValueError, match="abs_quantile_sigma: expected t with at least one"):
        abs_quantile_sigma(torch.zeros(3, 0))
    for ell in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="markov_covariance: expected ell"):
            markov_covariance(8, ell)
    with pytest.raises(ValueError, match="markov_covariance: expected n"):
        markov_covariance(6, 2.0)


def test_noise_from_repeats_and_pair_sums_at_the_ends_of_float32():
    from torchtof.recon.noise import noise_from_pair_sums, noise_from_repeats, pair_noise_dof
    g = torch.Generator().manual_seed(0)
    y = torch.randn(3, 2, 64, generator=g)
    y[:, 1] *= 1e-3  # channels of different scales: one factor per channel
    s = torch.randn(1, 1, 64, generator=g)
    ref_r, ref_p = noise_from_repeats(y), noise_from_pair_sums(s, robust=False)
    for c in (2.0**66, 2.0**-120):  # squares of these overflowed to inf / underflowed to 0
        torch.testing.assert_close(noise_from_repeats(c * y) / c, ref_r, rtol=1e-5, atol=0)
        torch.testing.assert_close(noise_from_pair_sums(c * s, robust=False) / c, ref_p,
                                   rtol=1e-5, atol=0)
    with pytest.raises(TypeError, match="noise_from_pair_sums: expected robust to be a bool"):
        noise_from_pair_sums(s, robust="no")
    with pytest.raises(TypeError, match="pair_noise_dof: expected robust to be a bool"):
        pair_noise_dof(10, robust="x")
