"""Tests of the orthonormal DCT-II and Haar sparsity bases (torchtof/recon/dct.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.fft
import torch

from torchtof.recon.dct import DCT2, Haar2, dct2, dct_matrix, haar2, idct2, ihaar2

PAIRS = [(dct2, idct2), (haar2, ihaar2)]


def _rand(*shape, dtype=torch.float64, seed=0):
    return torch.rand(*shape, generator=torch.Generator().manual_seed(seed), dtype=dtype)


def _full_matrix(fwd, n):
    """The ``(n², n²)`` matrix of a 2-D transform, built from unit images (row-major)."""
    eye = torch.eye(n * n, dtype=torch.float64).reshape(n * n, 1, n, n)
    return fwd(eye).reshape(n * n, n * n).T


@pytest.mark.parametrize("n", [1, 3, 8, 17])
def test_dct_matrix_orthonormal(n):
    d = dct_matrix(n)
    eye = torch.eye(n, dtype=torch.float64)
    torch.testing.assert_close(d @ d.T, eye, rtol=0, atol=1e-13)
    torch.testing.assert_close(d.T @ d, eye, rtol=0, atol=1e-13)
    assert dct_matrix(n, torch.float32).dtype == torch.float32


@pytest.mark.parametrize("n", [5, 8])
def test_dct2_matches_scipy(n):
    x = _rand(2, 3, n, n)
    ref = scipy.fft.dctn(x.numpy(), type=2, norm="ortho", axes=(-2, -1))
    np.testing.assert_allclose(dct2(x).numpy(), ref, rtol=0, atol=1e-13)
    np.testing.assert_allclose(
        idct2(torch.from_numpy(ref)).numpy(),
        scipy.fft.idctn(ref, type=2, norm="ortho", axes=(-2, -1)),
        rtol=0,
        atol=1e-13,
    )


@pytest.mark.parametrize(("fwd", "inv"), PAIRS)
def test_round_trip_float64(fwd, inv):
    x = _rand(3, 2, 16, 16)
    torch.testing.assert_close(inv(fwd(x)), x, rtol=0, atol=1e-12)
    torch.testing.assert_close(fwd(inv(x)), x, rtol=0, atol=1e-12)


@pytest.mark.parametrize(("fwd", "inv"), PAIRS)
def test_full_transform_orthonormal(fwd, inv):
    t = _full_matrix(fwd, 8)
    eye = torch.eye(64, dtype=torch.float64)
    torch.testing.assert_close(t @ t.T, eye, rtol=0, atol=1e-12)
    torch.testing.assert_close(_full_matrix(inv, 8), t.T, rtol=0, atol=1e-12)  # inverse = Tᵀ


@pytest.mark.parametrize("levels", [0, 1, 2, 3])
def test_haar_levels_round_trip_and_parseval(levels):
    x = _rand(1, 1, 8, 8, seed=levels)
    c = haar2(x, levels)
    torch.testing.assert_close(ihaar2(c, levels), x, rtol=0, atol=1e-12)
    torch.testing.assert_close(c.norm(), x.norm(), rtol=1e-13, atol=0)
    if levels == 0:
        assert torch.equal(c, x)


def test_haar_known_2x2():
    a, b, c, d = 1.0, 2.0, 4.0, 8.0
    x = torch.tensor([[[[a, b], [c, d]]]], dtype=torch.float64)
    want = torch.tensor(
        [[[[a + b + c + d, a - b + c - d], [a + b - c - d, a - b - c + d]]]], dtype=torch.float64
    )
    torch.testing.assert_close(haar2(x), want / 2, rtol=0, atol=1e-14)


def test_haar_one_level_equals_separable_matrix():
    n = 8
    w = torch.zeros(n, n, dtype=torch.float64)
    for i in range(n // 2):
        w[i, 2 * i] = w[i, 2 * i + 1] = 1 / math.sqrt(2)
        w[n // 2 + i, 2 * i], w[n // 2 + i, 2 * i + 1] = 1 / math.sqrt(2), -1 / math.sqrt(2)
    x = _rand(2, 1, n, n)
    torch.testing.assert_close(haar2(x, 1), w @ x @ w.T, rtol=0, atol=1e-14)


@pytest.mark.parametrize("fwd", [dct2, haar2])
def test_constant_image_has_one_coefficient(fwd):
    c = fwd(torch.full((1, 1, 8, 8), 2.0, dtype=torch.float64))
    assert abs(float(c[0, 0, 0, 0]) - 16.0) < 1e-12  # n · mean
    c[0, 0, 0, 0] = 0
    assert float(c.abs().max()) < 1e-12


@pytest.mark.parametrize(("fwd", "inv"), PAIRS)
@pytest.mark.parametrize("shape", [(1, 1, 8, 8), (3, 2, 8, 8), (8, 8)])
def test_shapes(fwd, inv, shape):
    x = _rand(*shape, dtype=torch.float32)
    assert fwd(x).shape == shape and inv(x).shape == shape


@pytest.mark.parametrize(("fwd", "inv"), PAIRS)
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_dtype_preserved_and_float32_accuracy(fwd, inv, dtype):
    x = _rand(2, 1, 8, 8, dtype=dtype)
    c = fwd(x)
    assert c.dtype == dtype and inv(c).dtype == dtype and c.device == x.device
    torch.testing.assert_close(c.double(), fwd(x.double()), rtol=0, atol=1e-5)


@pytest.mark.parametrize(("fwd", "inv"), PAIRS)
def test_input_not_modified_and_batched_equals_singles(fwd, inv):
    x = _rand(3, 1, 8, 8)
    x0 = x.clone()
    c = fwd(x)
    assert torch.equal(x, x0)
    singles = torch.cat([fwd(x[i : i + 1]) for i in range(3)])
    torch.testing.assert_close(c, singles, rtol=0, atol=1e-14)


def test_modules_equal_functions():
    x = _rand(2, 1, 8, 8)
    m = DCT2(8)
    torch.testing.assert_close(m(x), dct2(x))
    torch.testing.assert_close(m.inverse(x), idct2(x))
    torch.testing.assert_close(m(x.float()), dct2(x.float()))  # buffer cast to the input
    h = Haar2(8, levels=2)
    torch.testing.assert_close(h(x), haar2(x, 2))
    torch.testing.assert_close(h.inverse(x), ihaar2(x, 2))
    assert "matrix" not in m.state_dict()  # non-persistent buffer


@pytest.mark.parametrize("fwd", [dct2, idct2, haar2, ihaar2])
def test_gradcheck(fwd):
    x = _rand(1, 2, 4, 4).requires_grad_()
    assert torch.autograd.gradcheck(fwd, (x,))


def test_dct_matrix_argument_used():
    x = _rand(1, 1, 4, 4)
    torch.testing.assert_close(dct2(x, dct_matrix(4)), dct2(x))
    torch.testing.assert_close(idct2(x, torch.eye(4, dtype=torch.float64)), x)


def test_errors():
    with pytest.raises(ValueError, match=r"dct2: expected x of shape \(\.\.\., n, n\), got \(2, 3"):
        dct2(torch.zeros(2, 3))
    with pytest.raises(ValueError, match=r"idct2: expected x of shape"):
        idct2(torch.zeros(4))
    with pytest.raises(ValueError, match=r"dct2: expected matrix of shape \(4, 4\)"):
        dct2(torch.zeros(1, 4, 4), torch.eye(3))
    with pytest.raises(TypeError, match=r"dct2: expected x to be a torch.Tensor"):
        dct2(np.zeros((4, 4)))
    with pytest.raises(TypeError, match=r"haar2: expected x to be a floating-point tensor"):
        haar2(torch.zeros(4, 4, dtype=torch.int64))
    with pytest.raises(ValueError, match=r"haar2: expected n \(the image side\) to be a power"):
        haar2(torch.zeros(1, 1, 6, 6))
    with pytest.raises(ValueError, match=r"ihaar2: expected levels in \[0, 3\] for n=8, got 4"):
        ihaar2(torch.zeros(1, 1, 8, 8), levels=4)
    with pytest.raises(TypeError, match=r"Haar2: expected levels to be an int"):
        Haar2(8, levels=1.5)
    with pytest.raises(ValueError, match=r"dct_matrix: expected n >= 1, got 0"):
        dct_matrix(0)
    with pytest.raises(TypeError, match=r"dct_matrix: expected n to be an int"):
        dct_matrix(4.0)
