import copy
import io

import numpy as np
import onnxruntime as ort
import pytest
import torch

from torchtof.recon.unet import UNet


def _net(seed=0, **kw):
    torch.manual_seed(seed)
    return UNet(**kw)


@pytest.mark.parametrize("b", [1, 3])
@pytest.mark.parametrize(("n", "depth", "kernel"), [(16, 3, 3), (32, 3, 5), (32, 4, 3), (64, 2, 3)])
def test_shapes_and_range(b, n, depth, kernel, gen):
    net = _net(base=4, depth=depth, kernel=kernel)
    x = torch.randn(b, 1, n, n, generator=gen)
    out = net(x)
    assert out.shape == (b, 1, n, n)
    assert bool((out >= 0).all() and (out <= 1).all())


def test_channels(gen):
    net = _net(in_ch=2, out_ch=3, base=4, depth=2)
    assert net(torch.randn(2, 2, 16, 16, generator=gen)).shape == (2, 3, 16, 16)


def test_dtype_preserved(dtype, gen):
    net = _net(base=4, depth=2).to(dtype)
    x = torch.randn(2, 1, 16, 16, generator=gen, dtype=dtype)
    assert net(x).dtype == dtype


def test_input_not_modified(gen):
    net = _net(base=4, depth=2)
    x = torch.randn(2, 1, 16, 16, generator=gen)
    x_copy = x.clone()
    net(x)
    assert torch.equal(x, x_copy)


def test_eval_batched_equals_stacked(gen):
    net = _net(base=4, depth=2).eval()
    x = torch.randn(3, 1, 16, 16, generator=gen)
    with torch.no_grad():
        batched = net(x)
        singles = torch.cat([net(x[i : i + 1]) for i in range(3)])
    torch.testing.assert_close(batched, singles, rtol=1e-5, atol=1e-6)


def test_gradcheck_float64(gen):
    net = _net(base=2, depth=2).double()
    x = torch.randn(2, 1, 8, 8, generator=gen, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(net, (x,), eps=1e-6, atol=1e-5)
    net.eval()
    assert torch.autograd.gradcheck(net, (x,), eps=1e-6, atol=1e-5)


def test_fold_batch_stats_reproduces_training_mode(gen):
    net = _net(base=4, depth=3)
    x = torch.randn(1, 1, 32, 32, generator=gen)
    with torch.no_grad():
        train_out = net.train()(x)
    net.fold_batch_stats(x)
    assert not net.training
    with torch.no_grad():
        eval_out = net(x)
    torch.testing.assert_close(eval_out, train_out, rtol=1e-5, atol=1e-6)
    # the stored variance is the biased one (the one training-mode normalisation used)
    bn = net.inc[0][1]
    first = net.inc[0][0](x)
    torch.testing.assert_close(bn.running_var, first.var(dim=(0, 2, 3), unbiased=False))


def test_fold_differs_from_plain_eval(gen):
    """Known answer: without folding, eval mode uses the default running stats (0, 1), which
    gives a different function — folding is what makes eval == the fitted network."""
    net = _net(base=4, depth=2)
    x = 5 + 3 * torch.randn(1, 1, 16, 16, generator=gen)
    with torch.no_grad():
        train_out = net.train()(x)
        plain_eval = copy.deepcopy(net).eval()(x)
    assert (plain_eval - train_out).abs().max() > 1e-2


def test_params_unchanged_by_fold(gen):
    net = _net(base=4, depth=2)
    before = [p.clone() for p in net.parameters()]
    net.fold_batch_stats(torch.randn(1, 1, 16, 16, generator=gen))
    assert all(torch.equal(a, b) for a, b in zip(before, net.parameters()))


@pytest.mark.parametrize(
    ("kw", "exc", "match"),
    [
        ({"kernel": 4}, ValueError, "UNet: expected an odd kernel, got 4"),
        ({"depth": 0}, ValueError, "UNet: expected depth >= 1, got 0"),
        ({"base": 2.5}, TypeError, "UNet: expected base to be an int"),
        ({"in_ch": True}, TypeError, "UNet: expected in_ch to be an int"),
    ],
)
def test_bad_config(kw, exc, match):
    with pytest.raises(exc, match=match):
        UNet(**kw)


def test_bad_input(gen):
    net = _net(base=4, depth=3)
    with pytest.raises(
        ValueError,
        match=r"UNet: expected x of shape \(B, 1, H, W\) with H and W "
        r"divisible by 2\^depth = 8 and at least 16, got \(1, 1, 12, 12\)",
    ):
        net(torch.randn(1, 1, 12, 12, generator=gen))
    with pytest.raises(ValueError, match=r"at least 16, got \(1, 1, 8, 8\)"):
        net(torch.randn(1, 1, 8, 8, generator=gen))
    with pytest.raises(ValueError, match="UNet: expected x of shape"):
        net(torch.randn(1, 2, 16, 16, generator=gen))
    with pytest.raises(ValueError, match="UNet: expected x of rank 4"):
        net(torch.randn(1, 16, 16, generator=gen))
    with pytest.raises(TypeError, match="UNet: expected x to be a torch.Tensor"):
        net(np.zeros((1, 1, 16, 16)))


def test_onnx_export_dynamic_batch(gen):
    net = _net(base=4, depth=3, kernel=3)
    net.fold_batch_stats(torch.randn(1, 1, 32, 32, generator=gen))
    buf = io.BytesIO()
    torch.onnx.export(
        net,
        (torch.randn(2, 1, 32, 32, generator=gen),),
        buf,
        dynamo=False,
        input_names=["x"],
        output_names=["image"],
        dynamic_axes={"x": {0: "batch"}, "image": {0: "batch"}},
        opset_version=17,
    )
    sess = ort.InferenceSession(buf.getvalue(), providers=["CPUExecutionProvider"])
    x = torch.randn(3, 1, 32, 32, generator=gen)
    (got,) = sess.run(None, {"x": x.numpy()})
    with torch.no_grad():
        want = net(x).numpy()
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-5)
