"""Learned proximal-gradient reconstructor, its procedural data and its training.

Known answers: with the prior switched off (``R ≡ 0``) the iteration's fixed point from
``Aᵀy`` is ``Aᵀy`` itself (``A Aᵀ = I``), for any step size; the reconstructor is equivariant
to any non-zero scale of ``y``; a DMD split's frames give what their combined ±1 buckets give;
the noise model's variances follow from the Poisson law of each frame.
"""

import hashlib
import itertools
import json
import math
import warnings

import pytest
import torch

from torchtof.data import (
    FAMILIES,
    HELD_OUT_IMAGES,
    TRAIN_IMAGES,
    NoiseRecipe,
    check_families,
    draw_scene,
    draw_scenes,
    grey_image,
    noisy_buckets,
)
from torchtof.data.scenes import pick_family, power_law_radii
from torchtof.operators import DMDSplit, Hadamard, PatternOperator, random_binary_patterns
from torchtof.operators.patterns import ORDERS
from torchtof.recon.learned import (
    DEFAULT_N_LAYERS,
    WEIGHTS_FILE,
    Learned,
    LearnedPrior,
    LearnedResult,
    learned,
)
from torchtof.recon.learned_train import (
    P_CLEAN,
    P_NOISE_REF,
    _batch,
    _recipes,
    noise_levels,
    psnr_loss,
    step_config,
    train_learned,
)


def _net(n=16, sr=0.25, K=3, width=4, seed=0, order="cake_cutting", noise_sigma="auto"):
    torch.manual_seed(seed)
    return Learned(Hadamard(n, sr=sr, order=order), n_layers=K, width=width, pretrained=False,
                   noise_sigma=noise_sigma)


def _y(A, b=2, c=1, dtype=torch.float32, seed=0):
    g = torch.Generator().manual_seed(seed)
    return A(torch.rand(b, c, A.n, A.n, generator=g, dtype=torch.float64)).to(dtype)


def _prior_off(net):
    with torch.no_grad():
        net.prior.out.weight.zero_()
        net.prior.out.bias.zero_()
    return net


# -- contract: shapes, dtypes, batching, function == module -----------------------------------


@pytest.mark.parametrize("b,c", [(1, 1), (3, 2)])
def test_shapes_dtype_batched_equals_stacked(b, c, dtype):
    net = _net().to(dtype)
    y = _y(net.A, b, c, dtype)
    out = net(y)
    assert out.shape == (b, c, 16, 16) and out.dtype == dtype
    stacked = torch.cat([net(y[i : i + 1]) for i in range(b)])
    torch.testing.assert_close(out, stacked, rtol=1e-5, atol=1e-6)


def test_float64_input_runs_in_float64_with_float32_weights():
    net = _net()
    y = _y(net.A, dtype=torch.float64)
    out = net(y)
    assert out.dtype == torch.float64
    torch.testing.assert_close(out.float(), net(y.float()), rtol=1e-4, atol=1e-5)


def test_empty_batch_and_zero_buckets():
    net = _net()
    assert net(torch.zeros(0, 2, net.A.m)).shape == (0, 2, 16, 16)
    assert torch.equal(net(torch.zeros(2, 1, net.A.m)), torch.zeros(2, 1, 16, 16))


def test_function_equals_module(tmp_path):
    net = _net(K=2)
    path = tmp_path / "w.pt"
    net.save_weights(path)
    y = _y(net.A)
    torch.testing.assert_close(learned(y, net.A, n_layers=2, pretrained=path, width=4), net(y))


def test_function_output_has_a_graph_only_through_y(tmp_path):
    net = _net(K=2)
    path = tmp_path / "w.pt"
    net.save_weights(path)
    y = _y(net.A)
    assert not learned(y, net.A, n_layers=2, pretrained=path, width=4).requires_grad
    yg = y.clone().requires_grad_(True)
    x = learned(yg, net.A, n_layers=2, pretrained=path, width=4)
    (g,) = torch.autograd.grad(x.square().sum(), yg)
    assert g.shape == y.shape and bool(g.abs().sum() > 0)


@pytest.mark.parametrize("c", [3.0, 1e-3, -2.0])
def test_scale_and_sign_equivariance(c):
    net = _net(noise_sigma="auto")
    y = _y(net.A, b=3, dtype=torch.float64)
    torch.testing.assert_close(net.double()(c * y), c * net.double()(y), rtol=1e-10, atol=1e-12)


# -- the iteration's arithmetic ----------------------------------------------------------------


@pytest.mark.parametrize("order", ["cake_cutting", "natural"])
@pytest.mark.parametrize("step", [-1.0, 0.0, 2.0])
def test_prior_off_is_the_pseudo_inverse(order, step):
    """R ≡ 0: x₀ = Aᵀy, z = x₀ − γAᵀ(AAᵀy − y) = x₀ for every γ (A Aᵀ = I)."""
    net = _prior_off(_net(order=order))
    with torch.no_grad():
        net.step_raw.fill_(step)
    y = _y(net.A, b=2, dtype=torch.float64)
    x = net.double()(y)
    torch.testing.assert_close(x, net.A.adjoint(y), rtol=1e-10, atol=1e-12)
    r = net.solve(y)
    assert isinstance(r, LearnedResult)
    assert torch.all(r.residual < 1e-12) and r.n_iter.tolist() == [[3], [3]]
    assert r.converged.all() and r.stop_reason == (("n_layers",), ("n_layers",))


def test_final_step_noise_free_is_the_exact_projection():
    """σ = 0: w = 1, x = x_K + Aᵀ(b − A x_K) satisfies A x = y exactly whatever the prior;
    σ ≫ τ: w → 0, the output is the network without the final step."""
    net = _net(noise_sigma=0.0).double()
    with torch.no_grad():
        net.prior.out.bias.fill_(0.3)  # the prior adds a bright offset at every step
    y = _y(net.A, b=2, dtype=torch.float64)
    r = net.solve(y)
    assert float(r.residual.max()) < 1e-12
    net.final_dc = False
    assert float(net.solve(y).residual.min()) > 1e-3  # the prior alone does not fit y
    loud = _net(noise_sigma=1e12).double()
    loud.load_state_dict(net.state_dict())
    on = loud(y)
    loud.final_dc = False
    torch.testing.assert_close(on, loud(y), rtol=1e-12, atol=1e-12)


def _conditioning(net, y):
    """The first prior call's input ``z`` and conditioning ``c`` (a forward pre-hook)."""
    seen = []
    h = net.prior.register_forward_pre_hook(
        lambda mod, args: seen.append(args) if not seen else None)
    try:
        with torch.no_grad():
            net(y)
    finally:
        h.remove()
    return seen[0]


@pytest.mark.parametrize("sigma,floored", [(0.0, False), (0.5, False), (2.0, True)])
def test_noise_corrected_norm_scales_input_and_conditioning(sigma, floored):
    """ν² = max(‖y‖² − Mσ², ε‖y‖²) (ε = 10⁻²), computed here by hand: the first step's
    z = Aᵀb = Aᵀy·n/ν has RMS ‖y‖/ν, and log(σ_n + 10⁻³) = log(σ n/ν + 10⁻³) with the SR and
    k/K entries after it. A file without ``meta["scale"]`` keeps ν = ‖y‖."""
    n, sr = 16, 0.25
    net = _net(n=n, sr=sr, noise_sigma=sigma).double()
    m = net.A.m
    y = _y(net.A, b=1, dtype=torch.float64)  # ‖y‖² ≈ 67, M = 64: σ = 2 drives ν to its floor
    ny2 = float((y**2).sum())
    nu2 = ny2 - m * sigma**2
    assert (nu2 < 0.01 * ny2) == floored
    nu = math.sqrt(max(nu2, 0.01 * ny2))
    z, c = _conditioning(net, y)
    assert float(z.pow(2).mean().sqrt()) == pytest.approx(math.sqrt(ny2) / nu, rel=1e-9)
    assert float(c[0, 0]) == pytest.approx(math.log(sigma * n / nu + 1e-3), rel=1e-9, abs=1e-12)
    assert float(c[0, 1]) == pytest.approx(math.log(m / n**2), rel=1e-12)
    assert float(c[0, 2]) == pytest.approx(1 / 3, rel=1e-12)
    net.clean_scale = False  # the rule of weights files without meta["scale"]
    z, c = _conditioning(net, y)
    assert float(z.pow(2).mean().sqrt()) == pytest.approx(1.0, rel=1e-9)
    assert float(c[0, 0]) == pytest.approx(math.log(sigma * n / math.sqrt(ny2) + 1e-3), rel=1e-9,
                                           abs=1e-12)


def test_weights_file_records_the_scale_rule_and_old_files_keep_the_noisy_norm(tmp_path):
    A = Hadamard(16, sr=0.25)
    torch.manual_seed(0)
    a = Learned(A, n_layers=2, width=4, pretrained=False, noise_sigma=0.05)
    assert a.clean_scale
    new, old = tmp_path / "new.pt", tmp_path / "old.pt"
    a.save_weights(new)
    assert torch.load(new, weights_only=True)["meta"]["scale"] == "clean"
    blob = torch.load(new, weights_only=True)
    del blob["meta"]["scale"]  # a file written before the noise-corrected norm
    torch.save(blob, old)
    b_new = Learned(A, n_layers=2, pretrained=new, noise_sigma=0.05)
    b_old = Learned(A, n_layers=2, pretrained=old, noise_sigma=0.05)
    assert b_new.clean_scale and not b_old.clean_scale
    y = _y(A)
    torch.testing.assert_close(b_new(y), a(y))
    c_new, c_old = _conditioning(b_new, y)[1], _conditioning(b_old, y)[1]
    assert float(c_new[0, 0] - c_old[0, 0]) > 1e-4  # σ > 0: ν < ‖y‖, a larger σ_n
    a.clean_scale = False
    torch.testing.assert_close(b_old(y), a(y))


def test_calibrate_tau_picks_the_grid_minimum():
    from torchtof.recon.learned_train import calibrate_tau

    net = _net(n=16, K=2)
    out = calibrate_tau(net, seed=1, batches=2, batch_size=2, sizes=(16,), grid=(0.01, 0.1, 1.0))
    assert out["tau"] == min(out["losses"], key=out["losses"].get)
    assert math.isclose(float(net.log_tau.exp()), out["tau"], rel_tol=1e-6) and net.final_dc


def test_dmd_split_frames_equal_combined_buckets():
    A = Hadamard(16, sr=0.25)
    S = DMDSplit(A)
    torch.manual_seed(0)
    net_a = Learned(A, n_layers=2, width=4, pretrained=False, noise_sigma=0.01)
    net_s = Learned(S, n_layers=2, width=4, pretrained=False, noise_sigma=0.01 * 16 / math.sqrt(2))
    net_s.load_state_dict(net_a.state_dict())
    x = torch.rand(2, 1, 16, 16, dtype=torch.float64)
    torch.testing.assert_close(net_s.double()(S(x)), net_a.double()(A(x)), rtol=1e-9, atol=1e-10)


def test_gradcheck_float64():
    torch.manual_seed(0)
    net = Learned(Hadamard(8, sr=0.5), n_layers=2, width=2, pretrained=False, noise_sigma=0.01)
    net = net.double()
    y = _y(net.A, b=1, dtype=torch.float64).requires_grad_(True)
    assert torch.autograd.gradcheck(net, (y,), eps=1e-6, atol=1e-5)


def test_state_dict_round_trip_and_weights_file(tmp_path):
    a, b = _net(seed=0), _net(seed=1)
    y = _y(a.A)
    assert not torch.allclose(a(y), b(y))
    b.load_state_dict(a.state_dict())
    torch.testing.assert_close(b(y), a(y))
    path = tmp_path / "w.pt"
    a.save_weights(path, note="x")
    c = Learned(a.A, n_layers=3, width=4, pretrained=path)
    torch.testing.assert_close(c(y), a(y))
    with pytest.raises(ValueError, match="n_layers"):
        Learned(a.A, n_layers=4, width=4, pretrained=path)


@pytest.mark.parametrize("shuffle", [1, 2, 4])
def test_pixel_unshuffle_prior_shape_and_pseudo_inverse(shuffle):
    """Any pixel-unshuffle factor keeps the shapes, and with the prior off the output is still
    ``Aᵀy`` (the fixed point of the data step, module docstring)."""
    A = Hadamard(16, sr=0.25)
    torch.manual_seed(0)
    net = Learned(A, n_layers=2, width=4, shuffle=shuffle, pretrained=False, noise_sigma=0.0)
    y = _y(A, b=2, c=2)
    assert net.prior.inc.in_channels == shuffle**2 == net.prior.out.out_channels
    assert net(y).shape == (2, 2, 16, 16)
    torch.testing.assert_close(_prior_off(net)(y), A.adjoint(y), rtol=1e-5, atol=1e-5)
    with pytest.raises(ValueError, match="shuffle"):
        Learned(Hadamard(8, sr=0.5), width=4, shuffle=8, pretrained=False)
    with pytest.raises(ValueError, match="shuffle"):
        Learned(A, width=4, shuffle=0, pretrained=False)


@pytest.mark.parametrize("scales,shuffle", [(3, 1), (4, 1), (3, 2)])
def test_multi_scale_prior_shape_pseudo_inverse_and_receptive_field(scales, shuffle):
    """A U-Net prior of ``scales`` resolutions keeps the shapes and the prior-off fixed point,
    checks the side's divisibility by ``2^(scales-1)·shuffle``, and reaches further: one
    pass's output pixel depends on more input pixels than the two-scale net's (its receptive
    field, 19 px at r = 1)."""
    A = Hadamard(32, sr=0.25)
    torch.manual_seed(0)
    net = Learned(A, n_layers=2, width=4, shuffle=shuffle, scales=scales, pretrained=False,
                  noise_sigma=0.0)
    assert net.prior.scales == scales and len(net.prior.deeper) == scales - 2
    y = _y(A, b=2, c=2)
    assert net(y).shape == (2, 2, 32, 32)
    torch.testing.assert_close(_prior_off(net)(y), A.adjoint(y), rtol=1e-5, atol=1e-5)

    def reach(prior):  # width − 1 of the input support of one output pixel (18 for S = 2)
        z = torch.zeros(1, 1, 64, 64, dtype=torch.float64, requires_grad=True)
        prior(z, torch.zeros(1, 3, dtype=torch.float64))[0, 0, 32, 32].backward()
        cols = z.grad[0, 0].abs().sum(0).nonzero().flatten()
        return int(cols.max() - cols.min())

    torch.manual_seed(0)
    two = LearnedPrior(4, shuffle=shuffle, scales=2).double()
    torch.manual_seed(0)
    deep = LearnedPrior(4, shuffle=shuffle, scales=scales).double()
    assert reach(deep) > reach(two)
    f = 2**scales * shuffle  # one scale more than the net above: n = 4 is too small
    with pytest.raises(ValueError, match=rf"scales-1\)·shuffle = {f}, got n=4"):
        Learned(Hadamard(4, sr=1.0), width=4, shuffle=shuffle, scales=scales + 1,
                pretrained=False)


@pytest.mark.parametrize("bad", [1, 0, True, 2.0])
def test_scales_must_be_an_int_of_at_least_two(bad):
    with pytest.raises(ValueError, match="scales"):
        Learned(Hadamard(16, sr=0.25), width=4, scales=bad, pretrained=False)
    with pytest.raises(ValueError, match="LearnedPrior: expected scales"):
        LearnedPrior(4, scales=bad)


@pytest.mark.parametrize("scales", [2, 3, 4])
def test_every_film_slot_modulates_its_own_layer(scales):
    """Each FiLM slot (a gain and a shift per channel of one hidden layer) reaches the output
    and has the channel count of its layer: the gradient of the output with respect to every
    slot's rows of the FiLM projection is non-zero, so no slot is skipped or used twice in
    place of another."""
    torch.manual_seed(0)
    prior = LearnedPrior(4, scales=scales).double()
    assert len(prior.film_sizes) == 6 + 4 * (scales - 2)
    z = torch.rand(2, 1, 32, 32, dtype=torch.float64)
    prior(z, torch.rand(2, 3, dtype=torch.float64)).square().sum().backward()
    g = prior.film[-1].weight.grad.abs().sum(dim=1)  # one entry per gain, then per shift
    total = sum(prior.film_sizes)
    assert g.shape == (2 * total,)
    start = 0
    for size in prior.film_sizes:
        for half in (0, total):  # gains, shifts
            assert bool((g[half + start : half + start + size] > 0).all())
        start += size


def _file_without(net, path, key):
    """``net``'s weights file as written before the option ``key`` existed (key absent)."""
    net.save_weights(path)
    blob = torch.load(path, weights_only=True)
    del blob["meta"][key]
    torch.save(blob, path)
    return path


def test_scales_come_from_the_weights_file_and_must_match(tmp_path):
    """The file records ``scales``; files without the key are two-scale; a mismatch raises."""
    A = Hadamard(16, sr=0.25)
    torch.manual_seed(0)
    a = Learned(A, n_layers=2, width=4, scales=3, pretrained=False)
    path = tmp_path / "s3.pt"
    a.save_weights(path)
    b = Learned(A, pretrained=path)
    assert (b.prior.scales, b.n_layers, b.prior.width) == (3, 2, 4)
    y = _y(A)
    torch.testing.assert_close(b(y), a(y))
    with pytest.raises(ValueError, match="scales"):
        Learned(A, scales=2, pretrained=path)
    old = _file_without(Learned(A, n_layers=2, width=4, pretrained=False), tmp_path / "old.pt",
                        "scales")
    assert Learned(A, pretrained=old).prior.scales == 2
    with pytest.raises(ValueError, match="scales"):
        Learned(A, scales=3, pretrained=old)


def test_weights_file_sets_the_architecture_and_old_files_load_as_shuffle_1(tmp_path):
    A = Hadamard(16, sr=0.25)
    torch.manual_seed(0)
    a = Learned(A, n_layers=2, width=4, shuffle=1, pretrained=False)
    path = _file_without(a, tmp_path / "old.pt", "shuffle")
    b = Learned(A, n_layers=2, pretrained=path)  # width and shuffle from the file
    assert (b.prior.width, b.prior.shuffle) == (4, 1)
    y = _y(A)
    torch.testing.assert_close(b(y), a(y))
    with pytest.raises(ValueError, match="shuffle"):
        Learned(A, n_layers=2, width=4, shuffle=2, pretrained=path)
    c = Learned(A, pretrained=path)  # the depth from the file too (default 6 would not match)
    assert c.n_layers == 2
    torch.testing.assert_close(c(y), a(y))
    torch.testing.assert_close(learned(y, A, pretrained=path), a(y))
    assert Learned(A, pretrained=False).n_layers == DEFAULT_N_LAYERS


# -- bad inputs ----------------------------------------------------------------------------


def test_bad_inputs_raise():
    A = Hadamard(16, sr=0.25)
    with pytest.raises(TypeError, match="A"):
        Learned("A", pretrained=False)
    P = PatternOperator(random_binary_patterns(64, 16, generator=torch.Generator().manual_seed(0)))
    with pytest.raises(ValueError, match="orthonormal"):
        Learned(P, pretrained=False)
    with pytest.raises(ValueError, match="n_layers"):
        Learned(A, n_layers=0, pretrained=False)
    with pytest.raises(TypeError, match="n_layers"):
        Learned(A, n_layers=2.0, pretrained=False)
    with pytest.raises(ValueError, match="noise_sigma"):
        Learned(A, noise_sigma=-1.0, pretrained=False)
    with pytest.raises(ValueError, match="noise_sigma"):
        Learned(A, noise_sigma="pairs?", pretrained=False)
    net = Learned(A, pretrained=False, width=4)
    with pytest.raises(ValueError, match="y"):
        net(torch.zeros(1, 1, A.m + 1))
    with pytest.raises(ValueError, match="y"):
        net(torch.full((1, 1, A.m), float("nan")))
    with pytest.raises(TypeError, match="y"):
        net(torch.zeros(1, 1, A.m, dtype=torch.int64))
    bad = Learned(A, pretrained=False, width=4, noise_sigma=torch.ones(3))
    with pytest.raises(ValueError, match="noise_sigma"):
        bad(torch.zeros(2, 1, A.m))


# -- data --------------------------------------------------------------------------------------


@pytest.mark.parametrize("family", list(FAMILIES))
def test_scenes_seeded_in_range_and_shard_invariant(family):
    # the "user" family crops the caller's images: two smooth random fields here
    g = torch.Generator().manual_seed(0)
    kw = {"user_images": [torch.rand(40, 56, generator=g), torch.rand(64, 64, generator=g)]
          if family == "user" else ()}
    a = draw_scene(32, 7, family, **kw)
    assert torch.equal(a, draw_scene(32, 7, family, **kw))
    assert not torch.equal(a, draw_scene(32, 8, family, **kw))
    assert a.shape == (1, 1, 32, 32) and 0 <= float(a.min()) and float(a.max()) <= 1
    whole = draw_scenes(32, 3, 5, range(4), family, **kw)
    torch.testing.assert_close(whole, torch.cat([draw_scenes(32, 3, 5, range(0, 2), family, **kw),
                                                 draw_scenes(32, 3, 5, range(2, 4), family, **kw)]))


def test_held_out_images_are_disjoint_and_never_drawn_for_training():
    assert not set(TRAIN_IMAGES) & set(HELD_OUT_IMAGES)
    held = [torch.nn.functional.interpolate(grey_image(k)[None, None], size=(8, 8),
                                            mode="area") for k in HELD_OUT_IMAGES]
    with pytest.raises(ValueError, match="name"):
        grey_image("not_an_image")
    with pytest.raises(ValueError, match="family"):
        draw_scene(32, 0, "cats")
    assert len(held) == 4


def test_power_law_radii_follow_the_r_minus_3_law():
    """The dead-leaves radii invert ``F(r) = (rmin⁻² − r⁻²)/(rmin⁻² − rmax⁻²)``: at the
    quantiles u the radius is where that CDF equals u (written from the density ``∝ r⁻³``),
    and the median of 0.1–1 lies at ``(0.5 (0.1⁻² + 1))^(−1/2)``."""
    rmin, rmax = 0.1, 1.0
    u = torch.linspace(0, 0.999, 1000, dtype=torch.float64)
    r = power_law_radii(u, rmin, rmax)
    cdf = (rmin ** -2 - r ** -2) / (rmin ** -2 - rmax ** -2)
    torch.testing.assert_close(cdf, u, rtol=0, atol=1e-12)
    assert float(r[0]) == pytest.approx(rmin) and float(r.max()) < rmax
    med = power_law_radii(torch.tensor([0.5], dtype=torch.float64), rmin, rmax)
    assert float(med) == pytest.approx((0.5 * (rmin ** -2 + rmax ** -2)) ** -0.5)
    # the density: twice the radius, an eighth of the probability per unit radius
    big = power_law_radii(torch.rand(200_000, generator=torch.Generator().manual_seed(0),
                                     dtype=torch.float64), rmin, rmax)
    near = lambda c: float(((big > c * 0.98) & (big < c * 1.02)).double().mean())  # noqa: E731
    assert near(0.4) / near(0.2) == pytest.approx(1 / 4, rel=0.05)  # (0.4/0.2)⁻³ · (0.4/0.2)


def test_leaves_occlude_with_many_grey_levels():
    """Dead leaves: not binary, many grey levels, edges (large neighbouring differences) and
    flat areas both present, different per seed."""
    x = draw_scene(64, 11, "leaves")[0, 0]
    d = (x[1:] - x[:-1]).abs()
    assert len(x.unique()) > 500
    assert float((d > 0.1).double().mean()) > 0.01  # occlusion edges
    assert float((d < 0.02).double().mean()) > 0.5  # inside the leaves
    assert not torch.equal(x, draw_scene(64, 12, "leaves")[0, 0])


def test_families_mixture_and_its_checks():
    """A family of probability 1 draws what asking for it draws; the default mixture is
    :data:`FAMILIES` (``"leaves"`` at 0); bad mixtures raise naming ``families``."""
    for seed in range(5):
        assert torch.equal(draw_scene(32, seed, families={"leaves": 1.0}),
                           draw_scene(32, seed, "leaves"))
    assert FAMILIES["leaves"] == 0.0 and FAMILIES["user"] == 0.0
    # the shipped weights' mixture picks as it did before "leaves" existed: the previous
    # release's rule, a running float sum over the five families, written out here
    names = ("planar", "smooth", "silhouette", "strokes", "natural")
    old = list(zip(names, itertools.accumulate((0.25, 0.15, 0.2, 0.15, 0.25))))
    for r in [k / 4000 for k in range(4000)] + [0.25, 0.4 - 1e-12, 0.999999999]:
        assert pick_family(r, FAMILIES) == next(f for f, c in old if r < c), r
    assert pick_family(0.9999999, {"planar": 0.9999995, "leaves": 0.0}) == "planar"
    assert torch.equal(draw_scenes(32, 0, 5, range(16), families=dict(FAMILIES)),
                       draw_scenes(32, 0, 5, range(16)))
    mix = {"planar": 0.5, "leaves": 0.5}
    assert check_families(mix, "f") == mix
    for bad in ({"cats": 1.0}, {"planar": 0.6, "leaves": 0.6}, {"planar": -0.5, "leaves": 1.5},
                {"planar": float("nan")}):
        with pytest.raises(ValueError, match="families"):
            draw_scene(32, 0, families=bad)
    with pytest.raises(TypeError, match="families"):
        draw_scene(32, 0, families=[("planar", 1.0)])
    with pytest.raises(ValueError, match="families"):
        train_learned(steps=1, families={"planar": 0.5})


def test_noise_clean_gaussian_and_shot_variances():
    n = 64
    A = Hadamard(n)  # M = n² measurements: sample variances are tight
    x = draw_scene(n, 1, "planar", dtype=torch.float64)
    g = [torch.Generator().manual_seed(0)]
    assert torch.equal(noisy_buckets(A, x, [NoiseRecipe()], g), A(x))
    y0 = A(x)
    spread = float(y0.max() - y0.min())
    e = noisy_buckets(A, x, [NoiseRecipe(level=0.01)], g) - y0
    assert abs(float(e.std()) / (0.01 * spread) - 1) < 0.03
    # shot noise: var((c⁺ − c⁻)/(p n)) = (c⁺ + c⁻)/(p n)² with c⁺ + c⁻ = p Σx (1 + stray)
    for stray in (0.0, 2.0):
        p = 50.0
        e = noisy_buckets(A, x, [NoiseRecipe(photons=p, stray=stray)], g) - y0
        want = math.sqrt(p * float(x.sum()) * (1 + stray)) / (p * n)
        assert abs(float(e.std()) / want - 1) < 0.03
        assert abs(float(e.mean())) < 4 * want / n  # stray light cancels in y⁺ − y⁻


def test_p_clean_one_gives_noise_free_buckets_and_bad_values_raise():
    A, x, y = _batch(0, 5, 16, 64, "cake_cutting", range(6), p_clean=1.0)
    torch.testing.assert_close(y, A(x), rtol=0, atol=0)
    _, _, y0 = _batch(0, 5, 16, 64, "cake_cutting", range(6), p_clean=0.0)
    assert bool((y0 != A(x)).any(dim=-1).all())  # every sample noisy
    for bad in (-0.1, 1.5, True):
        with pytest.raises(ValueError, match="p_clean"):
            train_learned(steps=1, p_clean=bad, progress=False)


def test_noise_levels_give_every_size_the_top_image_noise_of_the_reference():
    """A constant scene ``c`` has one non-zero Hadamard coefficient, ``y₀ = c·n`` (the
    all-ones row over ``n``), so the spread of ``y`` is ``c·n`` and a level ``L`` puts a
    per-pixel std ``L·c·n·√SR`` into ``Aᵀy``: the top of :func:`noise_levels` scaled by
    ``128/n`` gives ``0.06·128·c·√SR`` at every ``n <= 128`` (1.92 for c = 0.5, SR = 25 %)."""
    assert noise_levels(32, 128) == (0.002, 0.24)
    assert noise_levels(256, 128) == (0.002, 0.06) == noise_levels(32, None)
    for n in (32, 64, 128):
        A = Hadamard(n, sr=0.25)
        x = torch.full((1, 1, n, n), 0.5, dtype=torch.float64)
        level = noise_levels(n, 128)[1]
        e = noisy_buckets(A, x, [NoiseRecipe(level=level)], [torch.Generator().manual_seed(n)])
        got = float(A.adjoint(e - A(x)).std())
        assert abs(got / 1.92 - 1) < 0.05, (n, got)


def test_p_noise_ref_mixes_the_two_level_ranges_sample_by_sample():
    """``p_noise_ref = Q``: each sample's recipe is the one it draws with the scaled levels
    (``Q = 1``) or the one with the unscaled levels (``Q = 0``) -- the same noise stream, only
    the range differs -- and the scaled one in a fraction ``Q`` of the samples. Log-uniform in
    ``[0.002, 0.24]`` (n = 32, reference 128), a level exceeds the unscaled top 0.06 with
    probability ``ln(0.24/0.06)/ln(0.24/0.002) = ln 4/ln 120 = 0.2896``, so with ``Q = 0.5`` a
    fraction ``0.1448`` of the noisy samples does."""
    idx = range(3000)
    _, scaled = _recipes(0, 7, 32, idx, 128, p_clean=0.0, p_noise_ref=1.0)
    _, plain = _recipes(0, 7, 32, idx, 128, p_clean=0.0, p_noise_ref=0.0)
    _, mixed = _recipes(0, 7, 32, idx, 128, p_clean=0.0, p_noise_ref=0.5)
    _, unref = _recipes(0, 7, 32, idx, None, p_clean=0.0)
    assert plain == unref  # Q = 0 is the run without noise_ref
    assert max(r.level for r in plain) <= 0.06 < max(r.level for r in scaled) <= 0.24
    assert all(m in (a, b) for m, a, b in zip(mixed, scaled, plain, strict=True))
    frac_scaled = sum(m == a != b for m, a, b in zip(mixed, scaled, plain, strict=True)) / 3000
    assert abs(frac_scaled - 0.5) < 4 * math.sqrt(0.25 / 3000)
    p = math.log(4) / math.log(120)
    for recipes, want in ((scaled, p), (mixed, 0.5 * p)):
        got = sum(r.level > 0.06 for r in recipes) / 3000
        assert abs(got - want) < 4 * math.sqrt(want * (1 - want) / 3000), (got, want)
    # at n >= the reference both ranges are the same: the mixture changes nothing
    _, big = _recipes(0, 7, 256, range(50), 128, p_clean=0.3, p_noise_ref=0.5)
    assert big == _recipes(0, 7, 256, range(50), 128, p_clean=0.3, p_noise_ref=1.0)[1]
    for bad in (-0.1, 1.5, True, "0.5"):
        with pytest.raises(ValueError, match="p_noise_ref"):
            train_learned(steps=1, noise_ref=128, p_noise_ref=bad, progress=False)


# -- training ---------------------------------------------------------------------------------


def test_short_training_run_lowers_the_loss():
    """25 steps of the shipped recipe (batch 2, n = 32, lr 3e-3) lower the loss (negative
    mean PSNR) on fixed batches drawn by the same recipe at steps the run does not see; the
    untrained network starts at the pseudo-inverse's loss."""
    kw = dict(sizes=(32,), sr_range=(0.0625, 0.5), seed=5)
    held = []
    for step in (1000, 1001, 1002):
        n, m, order = step_config(5, step, (32,), 0.0, kw["sr_range"], ("cake_cutting",))
        held.append(_batch(5, step, n, m, order, range(4)))

    def loss(model):
        with torch.no_grad():
            tot = 0.0
            for A, x, y in held:
                model.A = A
                tot += float(psnr_loss(model(y), x))
            return tot / len(held)

    torch.manual_seed(5)
    untrained = Learned(Hadamard(32, sr=0.25), pretrained=False)  # train_learned's defaults
    untrained.final_dc = False  # as the prior trains
    before = loss(untrained)
    r = train_learned(steps=25, batch_size=2, lr=3e-3, progress=False, calibrate=False, **kw)
    after = loss(r.model)
    assert after < before - 0.2, (before, after)


def test_resume_continues_the_same_run(tmp_path):
    kw = dict(batch_size=2, sizes=(16,), n_layers=2, width=4, progress=False, log_every=1,
              calibrate=False)
    straight = train_learned(steps=4, **kw).model
    train_learned(steps=4, out=tmp_path, checkpoint_every=1, max_minutes=0.0, **kw)
    resumed = train_learned(steps=4, out=tmp_path, resume=True, **kw).model
    for k, v in straight.state_dict().items():
        torch.testing.assert_close(resumed.state_dict()[k], v, rtol=1e-5, atol=1e-6)
    log = json.loads((tmp_path / "log.json").read_text())
    assert [r["step"] for r in log] == [1, 2, 3, 4]
    assert (tmp_path / "recipe.json").is_file() and (tmp_path / "learned.pt").is_file()


def test_resume_refuses_a_checkpoint_of_another_network(tmp_path):
    """A checkpoint records its network; resuming with another width names it, and an older
    checkpoint without that record still fails with a ValueError, not a size-mismatch
    traceback."""
    kw = dict(batch_size=2, sizes=(16,), n_layers=2, progress=False, calibrate=False)
    train_learned(steps=1, width=4, out=tmp_path, **kw)
    ckpt = tmp_path / "checkpoint.pt"
    assert torch.load(ckpt, weights_only=False)["meta"]["width"] == 4
    with pytest.raises(ValueError, match=r"another network: width=4 \(got 8\)"):
        train_learned(steps=2, width=8, out=tmp_path, resume=True, **kw)
    state = torch.load(ckpt, weights_only=False)
    del state["meta"]
    torch.save(state, ckpt)
    with pytest.raises(ValueError, match="does not match the network"):
        train_learned(steps=2, width=8, out=tmp_path, resume=True, **kw)


def test_init_starts_from_the_weights_file_and_records_it(tmp_path):
    """``init``: the first step's loss is the loss of the file's network on that step's batch
    (computed here from the recipe's draws, not read from the run), not the random start's;
    ``recipe.json`` names the file and its SHA-256."""
    kw = dict(batch_size=2, sizes=(16,), n_layers=2, width=4, progress=False, calibrate=False,
              noise_ref=None)
    torch.manual_seed(3)
    start = Learned(Hadamard(16, sr=0.25), pretrained=False, n_layers=2, width=4)
    with torch.no_grad():  # far from the random start
        for p in start.prior.parameters():
            p.add_(0.3 * torch.randn_like(p))
    src = tmp_path / "start.pt"
    start.save_weights(src)
    start.final_dc = False  # as the prior trains
    n, m, order = step_config(7, 0, (16,), 0.3, (0.0625, 0.5), ORDERS)
    A, x, y = _batch(7, 0, n, m, order, range(2), None, P_CLEAN, P_NOISE_REF)
    start.A = A
    with torch.no_grad():
        want = float(psnr_loss(start(y), x))
    tuned = train_learned(steps=2, seed=7, lr=1e-4, out=tmp_path / "b", init=src, **kw)
    scratch = train_learned(steps=1, seed=7, **kw)
    assert tuned.losses[0] == pytest.approx(want, rel=1e-5)
    assert abs(scratch.losses[0] - want) > 0.1
    rec = json.loads((tmp_path / "b" / "recipe.json").read_text())["init"]
    assert rec["path"] == str(src)
    assert rec["sha256"] == hashlib.sha256(src.read_bytes()).hexdigest()


def test_families_are_recorded_in_the_recipe(tmp_path):
    mix = {"silhouette": 0.5, "leaves": 0.5}
    train_learned(steps=1, batch_size=2, sizes=(16,), n_layers=2, width=4, progress=False,
                  calibrate=False, families=mix, out=tmp_path)
    assert json.loads((tmp_path / "recipe.json").read_text())["data"]["families"] == mix


def test_init_rejects_a_missing_file_and_another_architecture(tmp_path):
    kw = dict(steps=1, batch_size=1, sizes=(16,), n_layers=2, width=4, progress=False,
              calibrate=False)
    with pytest.raises(ValueError, match="init"):
        train_learned(init=tmp_path / "none.pt", **kw)
    with pytest.raises(TypeError, match="init"):
        train_learned(init=3, **kw)
    train_learned(out=tmp_path, **kw)
    with pytest.raises(ValueError, match="width"):
        train_learned(init=tmp_path / "learned.pt", **{**kw, "width": 8})


def test_data_processes_train_the_same_model():
    """``workers=2`` draws every step's data in two processes, ahead of the optimiser: the
    steps' data depend only on (seed, step, index), so the model is the one-process model."""
    kw = dict(steps=5, batch_size=2, sizes=(16,), n_layers=2, width=4, progress=False,
              calibrate=False, seed=4)
    one = train_learned(**kw)
    two = train_learned(workers=2, **kw)
    assert one.losses == two.losses
    for k, v in one.model.state_dict().items():
        torch.testing.assert_close(two.model.state_dict()[k], v, rtol=0, atol=0)


@pytest.mark.parametrize(("kw", "name"), [({"device": "nope"}, "device"),
                                          ({"device": 3.5}, "device"),
                                          ({"workers": -1}, "workers"),
                                          ({"workers": 1.0}, "workers")])
def test_train_rejects_bad_device_and_workers(kw, name):
    with pytest.raises(ValueError, match=name):
        train_learned(steps=1, batch_size=1, sizes=(16,), progress=False, calibrate=False, **kw)


# -- ONNX ----------------------------------------------------------------------------------


@pytest.mark.parametrize("n,shuffle,scales",
                         [(32, None, None), pytest.param(128, None, None, marks=pytest.mark.slow),
                          (16, 2, 2), (32, 1, 3)])
def test_onnx_parity_other_batch_sizes(n, shuffle, scales, tmp_path):
    """Exported at batch 2 (dynamic batch axis), onnxruntime at batch 1 and 3, images in
    [0, 1]: max abs error <= 1e-4 (shipped weights; and untrained pixel-unshuffled and
    three-scale priors)."""
    ort = pytest.importorskip("onnxruntime")
    import numpy as np

    A = Hadamard(n, sr=0.125)
    torch.manual_seed(0)
    if shuffle is None:
        net = Learned(A, pretrained=WEIGHTS_FILE.is_file()).eval()
    else:
        net = Learned(A, width=8, shuffle=shuffle, scales=scales, pretrained=False).eval()
    path = tmp_path / "learned.onnx"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(net, (A(torch.rand(2, 1, n, n)),), path, dynamo=False, opset_version=17,
                          input_names=["y"], output_names=["x"],
                          dynamic_axes={"y": {0: "batch"}, "x": {0: "batch"}})
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1
    sess = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
    for b in (1, 3):
        x = draw_scenes(n, 99, 0, range(b))
        y = A(x)
        with torch.no_grad():
            ref = net(y)
        out = sess.run(None, {"y": y.numpy()})[0]
        assert np.abs(out - ref.numpy()).max() <= 1e-4


# -- shipped weights -----------------------------------------------------------------------


@pytest.mark.skipif(not WEIGHTS_FILE.is_file(), reason="weights not trained yet")
def test_shipped_weights_serve_every_size_sr_order_without_warning():
    recipe = json.loads((WEIGHTS_FILE.parent / "recipe.json").read_text())
    assert {"command", "seed", "data", "torch_version", "wall_s"} <= set(recipe)
    assert WEIGHTS_FILE.stat().st_size < 5 * 2**20
    cases = [Hadamard(32, sr=0.0625), Hadamard(64, sr=0.375, order="natural"),
             Hadamard(128, sr=1.0, order="sequency"), DMDSplit(Hadamard(32, sr=0.25))]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for A in cases:
            x = draw_scene(A.n, 123_456_789, "silhouette")
            out = Learned(A)(A(x))
            assert out.shape == x.shape and torch.isfinite(out).all()


@pytest.mark.slow
def test_ddp_two_processes_train_the_single_process_model(tmp_path):
    """``torchrun`` with 2 processes (gloo, loopback) on ``torchtof train --model learned``
    trains the model one process trains on the same global batch."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    args = ("train --model learned --steps 3 --batch-size 4 --sizes 16 --n-layers 2 --width 4 "
            "--seed 3 --no-progress --checkpoint-every 0 --no-calibrate").split()
    env = dict(os.environ, PYTHONPATH=str(root), OMP_NUM_THREADS="1", GLOO_SOCKET_IFNAME="lo")
    for k in ("RANK", "WORLD_SIZE", "LOCAL_RANK", "MASTER_ADDR", "MASTER_PORT"):
        env.pop(k, None)
    launcher = "-m torch.distributed.run --standalone --nproc_per_node 2".split()
    cmd = [sys.executable, *launcher, "-m", "torchtof.cli", *args, "--out", str(tmp_path)]
    proc = subprocess.run(cmd, cwd=root, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-4000:]
    recipe = json.loads((tmp_path / "recipe.json").read_text())
    assert recipe["world_size"] == 2 and recipe["steps_run"] == 3
    got = torch.load(tmp_path / "learned.pt", weights_only=True)
    single = train_learned(steps=3, batch_size=4, sizes=(16,), n_layers=2, width=4, seed=3,
                           progress=False, distributed=False, calibrate=False).model
    for k, v in single.prior.state_dict().items():
        torch.testing.assert_close(got["prior"][k], v, rtol=1e-4, atol=1e-6)
    torch.testing.assert_close(got["step_raw"], single.step_raw.detach(), rtol=1e-4, atol=1e-6)


# -- self-ensemble over image flips ------------------------------------------------------------


def _flip(x, fl):
    dims = [d for d, f in zip((-2, -1), fl, strict=True) if f]
    return torch.flip(x, dims) if dims else x


@pytest.mark.parametrize("n,order", [(16, "natural"), (32, "cake_cutting"), (64, "sequency")])
def test_flipped_image_buckets_are_signed_buckets(n, order):
    """Sylvester arithmetic: H[k, n-1-j] = (-1)^popcount(k) H[k, j], so row a·n + b of A
    changes sign under a column flip when popcount(b) is odd, under a row flip when
    popcount(a) is odd; checked against the operator applied to the flipped image."""
    from torchtof.recon.learned import FLIPS, _flip_signs

    A = Hadamard(n, sr=0.3, order=order)
    x = torch.rand(2, 1, n, n, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    d = _flip_signs(A, 4, x)
    a, b = A.index // n, A.index % n
    par = lambda v: torch.tensor([bin(int(k)).count("1") % 2 for k in v])  # noqa: E731
    want = torch.stack([torch.ones(A.m), 1 - 2.0 * par(b), 1 - 2.0 * par(a),
                        (1 - 2.0 * par(a)) * (1 - 2.0 * par(b))]).to(torch.float64)
    torch.testing.assert_close(d, want)
    for k, fl in enumerate(FLIPS):
        torch.testing.assert_close(A(_flip(x, fl)), A(x) * d[k])


@pytest.mark.parametrize("flips", [2, 4])
def test_flips_average_the_estimates_of_the_flipped_images(flips):
    from torchtof.recon.learned import FLIPS, _flip_signs

    net = _net(n=16, K=2)
    y = _y(net.A, b=3)
    ens = Learned(net.A, n_layers=2, width=4, pretrained=False, flips=flips)
    ens.load_state_dict(net.state_dict())
    d = _flip_signs(net.A, 4, y)
    want = sum(_flip(net(y * d[k]), FLIPS[k]) for k in range(flips)) / flips
    torch.testing.assert_close(ens(y), want)
    # a DMD split's frames give what their combined buckets give, with the ensemble too
    S = DMDSplit(net.A)
    ens_s = Learned(S, n_layers=2, width=4, pretrained=False, flips=flips)
    ens_s.load_state_dict(net.state_dict())
    x = torch.rand(3, 1, 16, 16, generator=torch.Generator().manual_seed(2))
    torch.testing.assert_close(ens_s(S(x)), ens(net.A(x)), rtol=1e-4, atol=1e-5)


def test_flips_bad_values_raise():
    A = Hadamard(16, sr=0.25)
    with pytest.raises(ValueError, match="Learned: expected flips in"):
        Learned(A, flips=3, pretrained=False)
    with pytest.raises(TypeError, match="Learned: expected flips to be an int"):
        Learned(A, flips=2.0, pretrained=False)
    P = PatternOperator(A.patterns() / 16)  # orthonormal rows, but no Hadamard sign rule
    assert P.orthonormal_rows
    Learned(P, pretrained=False)  # flips=1 is fine
    with pytest.raises(ValueError, match="flips > 1 needs a Hadamard operator"):
        Learned(P, flips=2, pretrained=False)


@pytest.mark.parametrize("kw", [{"flips": 4}, {"x0": "markov"}], ids=["flips4", "markov"])
def test_onnx_parity_flips_and_markov_start(kw, tmp_path):
    """The flip self-ensemble and the Markov start (its float64 CG included) export and run in
    onnxruntime at batch sizes other than the exported one."""
    ort = pytest.importorskip("onnxruntime")
    import numpy as np

    A = Hadamard(32, sr=0.125)
    torch.manual_seed(0)
    net = Learned(A, width=4, n_layers=2, pretrained=False, **kw).eval()
    path = tmp_path / "learned.onnx"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(net, (A(torch.rand(2, 1, 32, 32)),), path, dynamo=False,
                          opset_version=17, input_names=["y"], output_names=["x"],
                          dynamic_axes={"y": {0: "batch"}, "x": {0: "batch"}})
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    for b in (1, 3):
        y = A(draw_scenes(32, 99, 0, range(b)))
        with torch.no_grad():
            ref = net(y)
        assert np.abs(sess.run(None, {"y": y.numpy()})[0] - ref.numpy()).max() <= 1e-4


# -- the Gaussian–Markov starting estimate (x0="markov") -------------------------------------


def _dense_markov(A, b, lam, rho):
    """``Σ Aᵀ (A Σ Aᵀ + λ I)⁻¹ b`` with the dense ``Σ_(ij),(kl) = ρ^|i−k| ρ^|j−l|`` and the
    dense pattern matrix (the Wiener estimate written out, float64)."""
    n = A.n
    i = torch.arange(n, dtype=torch.float64)
    T = rho ** (i[:, None] - i[None, :]).abs()
    S = torch.kron(T, T)
    P = A.patterns().reshape(A.m, n * n).to(torch.float64)
    if isinstance(A, Hadamard):
        P = P / n  # the ±1 patterns of an orthonormal Hadamard operator, scaled
    G = P @ S @ P.T + lam * torch.eye(A.m, dtype=torch.float64)
    return (S @ P.T @ torch.linalg.solve(G, b.T)).T.reshape(-1, 1, n, n)


@pytest.mark.parametrize("order", ["cake_cutting", "natural"])
@pytest.mark.parametrize("rho", [0.5, 0.95])
def test_markov_completion_is_the_dense_wiener_estimate(order, rho):
    """Preconditioned CG run to 2M steps equals the dense solve, for the Hadamard operator
    (diagonal preconditioner from the Kronecker rule) and a plain orthonormal operator (no
    preconditioner); it fits the measured coefficients up to the noise term."""
    from torchtof.recon.gauss import markov_completion

    A = Hadamard(8, sr=0.375, order=order)
    P = PatternOperator(A.patterns().to(torch.float64) / 8)
    b = torch.randn(3, 1, A.m, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    lam = torch.tensor([1e-3, 0.1, 2.0], dtype=torch.float64)[:, None, None]
    for op in (A, P):
        x = markov_completion(b, op, lam, rho=rho, iters=2 * A.m)
        for k in range(3):
            ref = _dense_markov(A, b[k, 0][None], float(lam[k]), rho)
            err = float((x[k] - ref[0]).abs().max())
            assert err <= 1e-6 * float(ref.abs().max()), (type(op).__name__, k, err)
    # λ → 0: the estimate reproduces the buckets (A x = b)
    fwd = A.loop_pair(b)[0]
    x = markov_completion(b, A, torch.full((3, 1, 1), 1e-9, dtype=torch.float64),
                          rho=0.8, iters=A.m)
    assert torch.allclose(fwd(x), b, atol=1e-5)


def test_markov_kronecker_diagonal_is_the_dense_diagonal():
    """``diag(A Σ Aᵀ)_r = T[a, a] T[b, b]`` for row ``r = a·n + b`` (the preconditioner),
    against ``diag(P (S ⊗ S) Pᵀ)`` from the dense patterns, for two orders."""
    from torchtof.recon.gauss import markov_covariance

    for order in ("cake_cutting", "natural"):
        A = Hadamard(8, sr=0.5, order=order)
        s, t = markov_covariance(8, 3.0)
        P = A.patterns().reshape(A.m, 64).to(torch.float64) / 8
        dense = torch.einsum("ri,ij,rj->r", P, torch.kron(s, s), P)
        d = t.diagonal()
        assert torch.allclose(d[A.index // 8] * d[A.index % 8], dense, atol=1e-12)


def test_markov_diagonal_preconditioner_converges_faster_than_none():
    """After the default 20 steps the diagonally preconditioned CG is closer to the dense
    Wiener estimate than the same steps without a preconditioner (n = 32, SR 12.5 %)."""
    from torchtof.recon.gauss import MARKOV_ITERS, MARKOV_RHO, markov_completion

    A = Hadamard(32, sr=0.125)
    x = draw_scenes(32, 5, 0, range(2)).double()
    b = A(x) * 32 / x.norm(dim=(-2, -1))[..., None]
    lam = torch.full((2, 1, 1), 1e-3, dtype=torch.float64)
    ref = torch.cat([_dense_markov(A, b[k, 0][None], 1e-3, MARKOV_RHO) for k in range(2)])
    P = PatternOperator(A.patterns().to(torch.float64) / 32)  # no preconditioner
    err = [float((markov_completion(b, op, lam, iters=MARKOV_ITERS) - ref).norm() / ref.norm())
           for op in (A, P)]
    assert err[0] < 0.5 * err[1], err


def test_markov_completion_bad_arguments_raise():
    from torchtof.recon.gauss import markov_completion

    A = Hadamard(8, sr=0.5)
    b, lam = torch.zeros(1, 1, A.m), torch.ones(1, 1, 1)
    for rho in (0.0, 1.0, -0.5, 1.5):
        with pytest.raises(ValueError, match="expected rho in"):
            markov_completion(b, A, lam, rho=rho)
    for iters in (0, 2.0, True):
        with pytest.raises(ValueError, match="expected iters"):
            markov_completion(b, A, lam, iters=iters)


def test_x0_option_is_validated_recorded_and_changes_the_start(tmp_path):
    A = Hadamard(16, sr=0.25)
    with pytest.raises(ValueError, match="Learned: expected x0"):
        Learned(A, x0="wiener", pretrained=False)
    torch.manual_seed(0)
    net = _prior_off(Learned(A, n_layers=2, width=4, pretrained=False, x0="markov"))
    net.final_dc = False
    y = _y(A)
    with torch.no_grad():
        out = net(y)
        plain = _prior_off(Learned(A, n_layers=2, width=4, pretrained=False))
        plain.final_dc = False
        pinv = plain(y)
    assert not torch.allclose(out, pinv, atol=1e-3)  # the completion fills the null space
    # the null-space part of the start survives the data steps: A keeps the same buckets
    assert torch.allclose(A(out), A(pinv), atol=1e-3)
    path = tmp_path / "w.pt"
    net.save_weights(path)
    assert Learned(A, pretrained=path).x0 == "markov"  # the file's
    assert Learned(A, pretrained=path, x0="adjoint").x0 == "adjoint"  # given: overrides
    r = train_learned(steps=2, batch_size=2, sizes=(16,), progress=False, calibrate=False,
                      out=tmp_path / "run", x0="markov")
    assert r.model.x0 == "markov"
    assert json.loads((tmp_path / "run" / "recipe.json").read_text())["x0"] == "markov"
    assert Learned(A, pretrained=tmp_path / "run" / "learned.pt").x0 == "markov"
    with pytest.raises(ValueError, match="was trained with x0='markov'"):
        train_learned(steps=3, batch_size=2, sizes=(16,), progress=False, calibrate=False,
                      out=tmp_path / "run", resume=True, x0="adjoint")
    with pytest.raises(ValueError, match="train_learned: expected x0"):
        train_learned(steps=1, batch_size=1, sizes=(16,), progress=False, calibrate=False,
                      x0="nope")


@pytest.mark.parametrize("c", [3.0, -2.0])
def test_markov_start_keeps_scale_equivariance(c):
    torch.manual_seed(0)
    net = Learned(Hadamard(16, sr=0.25), n_layers=2, width=4, pretrained=False, x0="markov")
    y = _y(net.A, dtype=torch.float64)
    net = net.double()
    with torch.no_grad():
        assert torch.allclose(net(c * y), c * net(y), atol=1e-9)


def test_markov_completion_float32_input_matches_float64():
    """A float32 input is solved in float64 and returned in float32: the result equals the
    float64 input's to float32 rounding."""
    from torchtof.recon.gauss import markov_completion

    A = Hadamard(32, sr=0.125)
    x = draw_scenes(32, 98, 0, range(3)).double()
    b = A(x) * 32 / x.norm(dim=(-2, -1))[..., None]
    lam = torch.full((3, 1, 1), 1e-3, dtype=torch.float64)
    x64 = markov_completion(b, A, lam)
    x32 = markov_completion(b.float(), A, lam.float())
    assert x32.dtype == torch.float32 and x64.dtype == torch.float64
    assert float((x32.double() - x64).abs().max()) <= 1e-5 * float(x64.abs().max())


def test_markov_completion_any_size_orthonormal_rows():
    """A side that is not a power of two (no Hadamard preconditioner): the dense estimate."""
    from torchtof.recon.gauss import markov_completion

    g = torch.Generator().manual_seed(3)
    q = torch.linalg.qr(torch.randn(36, 36, dtype=torch.float64, generator=g))[0]
    P = PatternOperator(q[:12].reshape(12, 6, 6))
    assert P.orthonormal_rows
    b = torch.randn(2, 1, 12, dtype=torch.float64, generator=g)
    lam = torch.full((2, 1, 1), 0.05, dtype=torch.float64)
    x = markov_completion(b, P, lam, rho=0.7, iters=24)
    i = torch.arange(6, dtype=torch.float64)
    S = torch.kron(0.7 ** (i[:, None] - i[None, :]).abs(), 0.7 ** (i[:, None] - i[None, :]).abs())
    Pm = q[:12]
    ref = (S @ Pm.T @ torch.linalg.solve(Pm @ S @ Pm.T + 0.05 * torch.eye(12, dtype=torch.float64),
                                         b[:, 0].T)).T.reshape(2, 1, 6, 6)
    assert torch.allclose(x, ref, atol=1e-8)
