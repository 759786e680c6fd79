"""Finite but extreme solver weights are refused at the entry with a ValueError naming the
argument, instead of a NaN image blamed on the operator or a raw overflow error; the edges of
the accepted range still give finite images (float32, Hadamard and random 0/1 patterns)."""

from __future__ import annotations

import pytest
import torch

import torchtof.recon as recon
from torchtof.operators import Hadamard, PatternOperator
from torchtof.recon.depth import joint_tv

A = Hadamard(8, m=32)
P = PatternOperator(torch.rand(32, 8, 8, generator=torch.Generator().manual_seed(0)))


def _y(op, c=1):
    return op(torch.rand(1, c, 8, 8, generator=torch.Generator().manual_seed(1)))


BAD = [
    (recon.tval3, dict(mu=1e39), "tval3: expected mu in"),
    (recon.tval3, dict(mu=1e30, max_iter=20), "tval3: expected mu in"),
    (recon.tval3, dict(mu=256.0, beta=1e-30, max_iter=20), "tval3: expected beta in"),
    (recon.tval3, dict(mu=256.0, ctn_steps=150), r"tval3: expected beta·rate_ctn\^-ctn_steps"),
    (recon.tval3, dict(noise_sigma=1e300), "tval3: expected noise_sigma representable"),
    (recon.tgv, dict(mu=1e39, tvl2=True, max_iter=20), "tgv: expected mu in"),
    (recon.tgv, dict(alpha=(1e38, 1.0), max_iter=20), "tgv: expected alpha in"),
    (joint_tv, dict(mu=1e300), "joint_tv: expected mu in"),
    (joint_tv, dict(mu=256.0, beta=2.0**-20), r"joint_tv: expected mu/beta <= 2\^23"),
]


@pytest.mark.parametrize("f, kw, msg", BAD, ids=[f"{f.__name__}-{kw}" for f, kw, _ in BAD])
def test_extreme_weights_are_refused_by_name(f, kw, msg):
    y = _y(A, 2 if f is joint_tv else 1)
    with pytest.raises(ValueError, match=msg):
        f(y, A, **kw)


EDGE = [
    (recon.tval3, dict(mu=2.0**56)), (recon.tval3, dict(mu=2.0**-56)),
    (recon.tval3, dict(mu=2.0**56, tvl2=True)), (recon.tval3, dict(mu=2.0**-56, tvl2=True)),
    (recon.tval3, dict(mu=256.0, beta=2.0**-56)), (recon.tval3, dict(mu=256.0, beta=2.0**56)),
    (recon.tval3, dict(mu=2.0**23, beta=1.0, u_step="exact")),
    (recon.tgv, dict(mu=2.0**56, tvl2=True)), (recon.tgv, dict(mu=2.0**-56, tvl2=True)),
    (recon.tgv, dict(alpha=(2.0**56, 1.0))), (recon.tgv, dict(alpha=(2.0**-56, 2.0**-56))),
    (joint_tv, dict(mu=2.0**23, beta=1.0)), (joint_tv, dict(mu=2.0**-56)),
    (joint_tv, dict(mu=256.0, beta=2.0**56)),
]


@pytest.mark.parametrize("op", [A, P], ids=["hadamard", "patterns"])
@pytest.mark.parametrize("f, kw", EDGE, ids=[f"{f.__name__}-{kw}" for f, kw in EDGE])
def test_weights_at_the_edges_of_the_range_give_finite_images(op, f, kw):
    if f is joint_tv:
        x = f(_y(op, 2), op, n_iter=50, **kw)
    else:
        x = f(_y(op), op, max_iter=50, **kw)
    assert torch.isfinite(x).all()


def test_float64_takes_a_wider_range():
    y = _y(A).double()
    assert torch.isfinite(recon.tval3(y, A, mu=1e30, max_iter=20)).all()
