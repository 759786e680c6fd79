import pytest
import torch

from torchtof.operators import DMDSplit, Hadamard, PatternOperator, random_binary_patterns
from torchtof.recon.correlation import CGI, DGI, TGI, cgi, dgi, g2, tgi
from torchtof.recon.pinv import PseudoInverse, pseudo_inverse

FUNCS = {"cgi": (cgi, CGI), "tgi": (tgi, TGI), "dgi": (dgi, DGI)}


def _scene(n=8, dtype=torch.float64):
    x = torch.zeros(1, 1, n, n, dtype=dtype)
    x[..., 2:5, 3:7] = 1.0
    return x


@pytest.fixture(params=sorted(FUNCS))
def pair(request):
    return FUNCS[request.param]


def _random_op(m=300, n=8):
    return PatternOperator(random_binary_patterns(m, n, generator=torch.Generator().manual_seed(4)))


def test_module_equals_function_and_shapes(pair, dtype):
    fn, mod = pair
    S = DMDSplit(Hadamard(8, sr=0.5))
    for b in (1, 3):
        y = S(torch.rand(b, 2, 8, 8, dtype=dtype))
        out = fn(y, S)
        assert out.shape == (b, 2, 8, 8) and out.dtype == dtype
        torch.testing.assert_close(mod(S)(y), out)


def test_batched_equals_stacked(pair):
    fn, _ = pair
    S = _random_op()
    y = S(torch.rand(3, 1, 8, 8, dtype=torch.float64))
    torch.testing.assert_close(fn(y, S), torch.cat([fn(y[i : i + 1], S) for i in range(3)]))


def test_recovers_object_with_random_patterns(pair):
    """Seeded statistics: with many random 0/1 patterns every estimator correlates with x."""
    fn, _ = pair
    A = _random_op(m=4000)
    x = _scene()
    img = fn(A(x), A)[0, 0].flatten()
    c = torch.corrcoef(torch.stack((img, x.flatten())))[0, 1]
    assert c > 0.9


def test_tgi_closed_form_equals_scaled_pinv_for_hadamard_pairs():
    """With DMD pairs, TGI is an affine function of Aᵀ(y⁺ − y⁻) (the pseudo-inverse)."""
    A = Hadamard(8, sr=0.5)
    S = DMDSplit(A)
    x = torch.rand(2, 1, 8, 8, dtype=torch.float64)
    t = tgi(S(x), S)
    p = A.pinv(A(x))
    torch.testing.assert_close(t, p * 64 / (4 * A.m))  # Sᵀ(y − ȳ)/(2M) = n² Aᵀa / (4M)


def test_g2_known_value_full_pairs():
    """g2 = <yφ>/(<y><φ>) with <φ>=1/2 for complementary pairs; check against a direct loop."""
    S = DMDSplit(Hadamard(4))
    x = _scene(4)
    x[..., 0, 0] = 0.5
    y = S(x)
    p = S.patterns(torch.float64)
    ref = (y[0, 0, :, None, None] * p).mean(0) / (y.mean() * p.mean(0))
    torch.testing.assert_close(g2(y, S)[0, 0], ref)


def test_dgi_reference_loop():
    A = _random_op(m=50)
    y = A(torch.rand(1, 1, 8, 8, dtype=torch.float64))[0, 0]
    p = A.patterns.double()
    r = p.sum(dim=(1, 2))
    ref = (y[:, None, None] * p).mean(0) - y.mean() / r.mean() * (r[:, None, None] * p).mean(0)
    torch.testing.assert_close(dgi(y[None, None], A)[0, 0], ref)


@pytest.mark.parametrize("name", sorted(FUNCS))
def test_zero_buckets_no_nan(name):
    fn, _ = FUNCS[name]
    for A in (DMDSplit(Hadamard(8, sr=0.25)), Hadamard(8, sr=0.25)):
        out = fn(torch.zeros(2, 1, A.m), A)
        assert torch.isfinite(out).all() and out.abs().max() == 0


def test_g2_zero_mean_bucket_finite():
    A = Hadamard(8, sr=0.25)
    y = torch.randn(1, 1, A.m)
    y = y - y.mean()
    assert torch.isfinite(cgi(y, A)).all()


def test_negative_image_from_depth_like_buckets():
    """Depth buckets fall with light (5 m where dark): g2 image is negative (paper §3.1)."""
    S = DMDSplit(Hadamard(8))
    x = _scene()
    y = 5.0 * 64 - 3.0 * S(x)  # D_i = 5·P − 3·(#lit)
    img = cgi(y, S)[0, 0]
    assert img[3, 4] < img[0, 0]


def test_gradcheck(pair):
    fn, _ = pair
    S = DMDSplit(Hadamard(4, sr=0.5))
    y = (S(torch.rand(1, 1, 4, 4, dtype=torch.float64)) + 1).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda t: fn(t, S), (y,))


def test_pinv_full_set_exact_and_module():
    A = Hadamard(16)
    x = torch.rand(2, 1, 16, 16, dtype=torch.float64)
    torch.testing.assert_close(pseudo_inverse(A(x), A), x, atol=1e-12, rtol=0)
    torch.testing.assert_close(PseudoInverse(A)(A(x)), x, atol=1e-12, rtol=0)
    # float32 too, within 1e-5
    assert (PseudoInverse(A)(A(x.float())) - x.float()).abs().max() < 1e-5


def test_bad_inputs(pair):
    fn, mod = pair
    A = Hadamard(8, sr=0.25)
    with pytest.raises(ValueError, match=r"expected y of shape \(\*, \*, 16\)"):
        fn(torch.zeros(1, 1, 15), A)
    with pytest.raises(ValueError, match="NaN"):
        fn(torch.full((1, 1, 16), float("nan")), A)
    with pytest.raises(ValueError, match="Inf"):
        fn(torch.full((1, 1, 16), float("inf")), A)
    with pytest.raises(TypeError, match="LinearOperator"):
        mod(torch.zeros(3))
    with pytest.raises(TypeError, match="LinearOperator"):
        pseudo_inverse(torch.zeros(1, 1, 3), "A")


def test_cgi_on_signed_patterns_warns_with_the_fix():
    import warnings

    from torchtof.operators import DMDSplit, Hadamard
    from torchtof.recon import CGI

    H = Hadamard(8, sr=0.5)
    x = torch.rand(1, 1, 8, 8, generator=torch.Generator().manual_seed(0))
    with pytest.warns(UserWarning, match="DMDSplit"):
        CGI(H)(H(x))
    S = DMDSplit(H)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        CGI(S)(S(x))  # light patterns: no warning
