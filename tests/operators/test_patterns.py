import numpy as np
import pytest
import scipy.ndimage
import torch

from torchtof.operators import (
    ORDERS,
    gaussian_speckle_patterns,
    hadamard_order,
    hadamard_patterns,
    random_binary_patterns,
    row_sequency,
)
from torchtof.operators.fwht import fwht, sylvester


def _regions(p):
    a = p.numpy() > 0
    return scipy.ndimage.label(a)[1] + scipy.ndimage.label(~a)[1]


def _sign_changes(p):
    return int((p[:, 1:] != p[:, :-1]).sum(1).max() + (p[1:, :] != p[:-1, :]).sum(0).max())


@pytest.mark.parametrize("n", [4, 8, 16, 32, 64, 128, 256])
@pytest.mark.parametrize("order", ORDERS)
def test_every_order_is_a_permutation(n, order):
    idx = hadamard_order(n, order)
    assert idx.dtype == torch.int64 and idx.shape == (n * n,)
    assert torch.equal(torch.sort(idx).values, torch.arange(n * n))


@pytest.mark.parametrize("n", [4, 8, 16])
def test_cake_cutting_regions_nondecreasing(n):
    p = hadamard_patterns(n, order="cake_cutting")
    counts = [_regions(p[i]) for i in range(n * n)]
    assert all(a <= b for a, b in zip(counts, counts[1:]))
    assert counts[0] == 1 and counts[-1] == n * n


@pytest.mark.parametrize("n", [4, 8, 16])
def test_sequency_sign_changes_nondecreasing(n):
    p = hadamard_patterns(n, order="sequency")
    s = [_sign_changes(p[i]) for i in range(n * n)]
    assert all(a <= b for a, b in zip(s, s[1:]))


@pytest.mark.parametrize("n", [4, 8])
def test_orders_are_the_full_sort_keys_of_their_definitions(n):
    """The whole permutation, ties included, from scipy's Hadamard matrix: sequency sorts by
    (s_i + s_j, max(s_i, s_j), natural index), s the sign changes of a 1-D row; cake-cutting
    by (4-connected regions of the 2-D pattern, natural index) (Yu et al., Sensors 19:4122,
    2019). The nondecreasing tests above pin only the first key."""
    import scipy.linalg

    h = scipy.linalg.hadamard(n)  # natural (Sylvester) rows
    s = [int((row[1:] != row[:-1]).sum()) for row in h]
    keys_seq, keys_cc = [], []
    for k in range(n * n):
        i, j = divmod(k, n)
        keys_seq.append((s[i] + s[j], max(s[i], s[j]), k))
        keys_cc.append((_regions(torch.from_numpy(np.outer(h[i], h[j]))), k))
    seq = [k for *_, k in sorted(keys_seq)]
    cc = [k for *_, k in sorted(keys_cc)]
    assert hadamard_order(n, "sequency").tolist() == seq
    assert hadamard_order(n, "cake_cutting").tolist() == cc


@pytest.mark.parametrize("n", [8, 16, 32])
def test_russian_doll_prefixes_are_block_bases(n):
    idx = hadamard_order(n, "russian_doll")
    s = row_sequency(n)
    for k in range(int(np.log2(n)) + 1):
        first = idx[: 4**k]
        mx = torch.maximum(s[first // n], s[first % n])
        assert int(mx.max()) < 2**k
    # 4 patterns at n=8 are the 2x2 block averages: constant on 4x4 blocks
    p = hadamard_patterns(8, 4, order="russian_doll")
    blocks = p.reshape(4, 2, 4, 2, 4)
    assert torch.all(blocks == blocks[:, :, :1, :, :1])


def test_natural_matches_sylvester_and_sequency_of_rows():
    h = sylvester(8)
    p = hadamard_patterns(8, order="natural")
    torch.testing.assert_close(p[8 * 3 + 5], torch.outer(h[3], h[5]))
    assert sorted(row_sequency(8).tolist()) == list(range(8))


def test_fwht_matches_matrix_and_involution():
    x = torch.randn(3, 64, dtype=torch.float64)
    h = sylvester(64, torch.float64)
    torch.testing.assert_close(fwht(x), x @ h.T)
    torch.testing.assert_close(fwht(fwht(x)), 64 * x)
    with pytest.raises(ValueError, match="power of two"):
        fwht(torch.zeros(6))


def test_random_patterns_seeded():
    a = random_binary_patterns(5, 8, generator=torch.Generator().manual_seed(3))
    b = random_binary_patterns(5, 8, generator=torch.Generator().manual_seed(3))
    assert torch.equal(a, b) and set(a.unique().tolist()) <= {0.0, 1.0}
    assert 0.35 < float(random_binary_patterns(50, 16, generator=torch.Generator()).mean()) < 0.65
    g = gaussian_speckle_patterns(200, 16, generator=torch.Generator().manual_seed(0))
    assert abs(float(g.mean())) < 0.05 and abs(float(g.std()) - 1) < 0.05
    s = gaussian_speckle_patterns(4, 16, grain=2.0, generator=torch.Generator().manual_seed(0))
    # grains: neighbouring pixels correlated
    c = float((s[..., 1:] * s[..., :-1]).mean())
    assert c > 0.5
    with pytest.raises(ValueError, match="p"):
        random_binary_patterns(3, 4, p=1.0)


def test_pattern_sizes_take_numpy_integers_and_dtypes_are_checked():
    import numpy as np

    from torchtof.operators import hadamard_patterns
    from torchtof.operators.patterns import num_patterns
    assert num_patterns(8, m=np.int64(16)) == 16 and type(num_patterns(8, m=np.int64(16))) is int
    assert torch.equal(hadamard_patterns(4, np.int64(3)), hadamard_patterns(4, 3))
    assert hadamard_patterns(4, 2, dtype=torch.int8).dtype == torch.int8
    with pytest.raises(TypeError, match=r"hadamard_patterns: expected dtype"):
        hadamard_patterns(4, 2, dtype=torch.bool)


@pytest.mark.parametrize("n", [4, 8, 16, 32, 64, 128])
@pytest.mark.parametrize("order", ORDERS)
def test_every_order_starts_with_the_dc_row(n, order):
    # DMDSplit reads ⟨1, x⟩ from the first row's coefficient: the all-on row comes first
    assert int(hadamard_order(n, order)[0]) == 0
