"""The peer benchmark's problem generation and scoring (``benchmarks/peers_scenes.py``,
``benchmarks/peers.py``); the adapters to deepinv/spyrit/pylops only where those are
installed (``pip install -e '.[peers]'``)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest
import torch

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"
sys.path.insert(0, str(BENCH))

import peers as pb  # noqa: E402
import peers_scenes as ps  # noqa: E402


def _has(name: str) -> bool:
    return importlib.util.find_spec(name) is not None


# --------------------------------------------------------------------------- scenes
@pytest.mark.parametrize("name", ps.SCENES + ps.HELD_OUT_SCENES)
def test_scenes_shape_range(name):
    x = ps.make_scene(name, 32)
    assert x.shape == (1, 1, 32, 32) and x.dtype == torch.float32
    assert float(x.min()) >= 0.0 and float(x.max()) <= 1.0
    assert float(x.std()) > 0.05  # not a constant image


def test_binary_scenes_are_binary():
    for name in ("sky", "horse", "glyph", "blobs"):
        x = ps.make_scene(name, 32)
        assert set(torch.unique(x).tolist()) <= {0.0, 1.0}


def test_held_out_scenes_are_unseen():
    """The held-out set shares no image with the benchmark's own scenes or the learned
    network's training photographs, and no scene seed with the shipped training run."""
    import json

    from torchtof.data import EVAL_SEED_BASE, TRAIN_IMAGES
    from torchtof.recon.synthetic import scene_seed

    assert not set(ps.HELD_OUT_SCENES) & set(ps.SCENES)
    assert not {"astronaut", "shepp_logan_phantom"} & set(TRAIN_IMAGES)
    seeds = {EVAL_SEED_BASE + 9000 + k for _, k in ps._DRAWN.values()}
    assert min(seeds) >= EVAL_SEED_BASE
    recipe = json.loads((Path(__file__).resolve().parents[1] / "torchtof" / "weights"
                         / "learned" / "recipe.json").read_text())
    steps, batch, seed = recipe["steps_run"], recipe["batch_size"], recipe["seed"]
    assert steps * batch > 10_000  # the shipped run's recipe is the one read
    seen = {scene_seed(seed, t, i) for t in range(steps) for i in range(batch)}
    assert not seeds & seen
    # the foreground rule that picked the blobs seed
    x = ps.make_scene("blobs", 128)
    assert 0.2 <= float((x == x.max()).float().mean()) <= 0.8


def test_planes_piecewise_planar():
    d = ps.planes_depth(64, seed=3).double()[0, 0]
    assert abs(float(d.min()) - 0.1) < 1e-6 and abs(float(d.max()) - 0.9) < 1e-6
    # a plane has zero second differences; only pixels next to a cell boundary do not
    dyy = d[2:, 1:-1] - 2 * d[1:-1, 1:-1] + d[:-2, 1:-1]
    dxx = d[1:-1, 2:] - 2 * d[1:-1, 1:-1] + d[1:-1, :-2]
    flat = ((dyy.abs() < 1e-5) & (dxx.abs() < 1e-5)).double().mean()
    assert float(flat) > 0.8
    assert not torch.equal(ps.planes_depth(64, seed=3), ps.planes_depth(64, seed=4))
    assert torch.equal(ps.planes_depth(64, seed=3), ps.planes_depth(64, seed=3))


def test_bad_inputs():
    with pytest.raises(ValueError, match="name"):
        ps.make_scene("nope", 32)
    with pytest.raises(ValueError, match="n"):
        ps.planes_depth(2)
    with pytest.raises(ValueError, match="cells"):
        ps.planes_depth(16, cells=1)
    with pytest.raises(ValueError, match="order"):
        ps.make_problem("sky", 32, 0.25, "zigzag", 0.01)
    with pytest.raises(ValueError, match="level"):
        ps.make_problem("sky", 32, 0.25, "sequency", -0.01)


# --------------------------------------------------------------------------- rows, noise
def test_rows_follow_the_order():
    import torchtof as tt

    for order in ps.ORDERS:
        _, A, y, _ = ps.make_problem("camera", 32, 0.125, order, 0.0)
        assert A.m == 128 and y.shape == (1, 1, 128)
        assert torch.equal(A.index, tt.operators.hadamard_order(32, order)[:128])
    # lowest sequency: the first rows have the smallest summed sequency of the two factors
    s = tt.operators.patterns.row_sequency(32)
    _, A, _, _ = ps.make_problem("camera", 32, 0.125, "sequency", 0.0)
    tot = s[A.index // 32] + s[A.index % 32]
    assert int(tot.max()) <= int((s[:, None] + s[None, :]).flatten().sort().values[127])


def test_noise_is_relative_and_seeded():
    x, A, y, sigma = ps.make_problem("coins", 64, 0.25, "cake_cutting", 0.05, seed=1)
    y0 = A(x)
    assert sigma == pytest.approx(0.05 * float(y0.norm()) / y0.shape[-1] ** 0.5, rel=1e-6)
    rel = float((y - y0).norm() / y0.norm())
    assert rel == pytest.approx(0.05, rel=0.1)  # M = 1024 draws: chi spread ~2 %
    _, _, y_again, _ = ps.make_problem("coins", 64, 0.25, "cake_cutting", 0.05, seed=1)
    _, _, y_other, _ = ps.make_problem("coins", 64, 0.25, "cake_cutting", 0.05, seed=2)
    assert torch.equal(y, y_again) and not torch.equal(y, y_other)
    _, _, y_clean, s0 = ps.make_problem("coins", 64, 0.25, "cake_cutting", 0.0)
    assert s0 == 0.0 and torch.equal(y_clean, y0)


# --------------------------------------------------------------------------- score
def test_score_known_answers():
    x = torch.full((1, 1, 8, 8), 0.5)
    assert ps.score(x + 0.1, x) == pytest.approx(20.0, abs=1e-4)  # MSE 0.01 (float32 input)
    assert ps.score(x + 0.01, x) == pytest.approx(40.0, abs=1e-4)
    one = torch.ones(1, 1, 8, 8)
    assert ps.score(3 * one, one) == pytest.approx(100.0)  # clipped to 1: identical, capped
    half = torch.full((1, 1, 8, 8), float("nan"))
    assert ps.score(half, x) == pytest.approx(100.0)  # NaN -> 0.5 = the truth here
    assert ps.score(x.reshape(1, 64), x) == pytest.approx(100.0)  # any layout of n² values


def test_tune_picks_the_oracle_point_and_flags_edges():
    x = torch.full((1, 1, 8, 8), 0.5)
    r = pb.tune(lambda p: x + p, x, [-0.2, -0.1, 0.0, 0.1])
    assert r["param"] == 0.0 and not r["edge"] and len(r["trace"]) == 4
    r = pb.tune(lambda p: x + p, x, [0.0, 0.1, 0.2])
    assert r["param"] == 0.0 and r["edge"]
    grid = [(a, b) for a in (0.1, 0.2) for b in (0.0, 1.0, 2.0)]
    r = pb.tune(lambda p: x + p[0] * p[1], x, grid)
    assert r["param"][1] == 0.0 and r["edge"]  # edge in the second coordinate
    r = pb.tune(lambda p: x + p[0] * (p[1] - 1.0), x, grid)
    assert r["param"][1] == 1.0 and not r["edge"]  # two values of the first: not a scan
    r = pb.tune(lambda p: x + p, x, [0.4, 0.2], refine=lambda b: [b / 2])
    assert r["param"] == 0.1 and len(r["trace"]) == 3


def test_tune_survives_a_failing_point():
    x = torch.full((1, 1, 8, 8), 0.5)

    def run(p):
        if p == 1:
            raise RuntimeError("diverged")
        return x + p

    r = pb.tune(run, x, [1, 0.1])
    assert r["param"] == 0.1 and r["trace"][0]["psnr"] == float("-inf")


def test_report_tables():
    def res(ours, peer):
        return {
            "torchtof tval3": {"peer": "torchtof", "psnr": ours, "time_s": 0.1, "edge": False},
            "pylops SB-TV": {"peer": "pylops", "psnr": peer, "time_s": 1.0, "edge": True},
        }

    cells = []
    for sr, (a, b) in zip((0.125, 0.25), ((20.0, 22.5), (30.0, 29.0))):
        c = {"scene": "sky", "n": 32, "sr": sr, "order": "sequency", "level": 0.01,
             "results": res(a, b)}
        c["headline"] = pb.headline(c["results"])
        cells.append(c)
    assert cells[0]["headline"]["gap_db"] == pytest.approx(-2.5)
    assert cells[1]["headline"]["best_peer"] == "pylops SB-TV"
    md = pb.markdown({"cells": cells})
    assert "| -2.50 |" in md and "| +1.00 |" in md and "(edge)" in md
    means = pb.method_means({"cells": cells})
    assert "| torchtof tval3 | 2 | 25.00 | -0.75 (-2.50 … +1.00) | 0 |" in means
    assert "| pylops SB-TV | 2 | 25.75 | +0.00 (+0.00 … +0.00) | 2 |" in means
    grid = pb.winners({"cells": cells})
    assert "| sky | -2.50 (pylops SB-TV) | +1.00 (pylops SB-TV) |" in grid


def test_learned_row_only_for_orthonormal_rows():
    import torchtof as tt

    P = pb.Problem("sky", 32, 0.125, "cake_cutting", 0.01, 0)
    assert pb.method_table(P, dip=False)["torchtof learned"][1] is pb.tt_learned
    torch.testing.assert_close(pb.tt_learned(P), tt.recon.Learned(P.A)(P.y))
    P.A = tt.operators.PatternOperator(tt.operators.random_binary_patterns(
        P.m, 32, generator=torch.Generator().manual_seed(0)))  # 0/1 rows: not orthonormal
    assert "torchtof learned" not in pb.method_table(P, dip=False)


def test_merge_unites_cells_of_the_same_problem():
    def cell(results):
        c = {"scene": "sky", "n": 32, "sr": 0.25, "order": "sequency", "level": 0.01,
             "results": results}
        c["headline"] = pb.headline(results)
        return c

    peer = {"peer": "pylops", "psnr": 25.0, "time_s": 1.0, "edge": False}
    run1 = {"cells": [cell({"torchtof tval3": {"peer": "torchtof", "psnr": 20.0},
                            "pylops SB-TV": peer})]}
    run2 = {"cells": [cell({"torchtof tval3": {"peer": "torchtof", "psnr": 99.0},
                            "torchtof auto": {"peer": "torchtof", "psnr": 26.0}})]}
    m = pb.merge([run1, run2])
    assert len(m["cells"]) == 1
    r = m["cells"][0]["results"]
    assert r["torchtof tval3"]["psnr"] == 20.0  # the earlier run's result is kept
    assert r["torchtof auto"]["other_process"]
    h = m["cells"][0]["headline"]
    assert h["default"] == "torchtof auto" and h["gap_db"] == pytest.approx(1.0)
    # a later run that names a method (--only) re-measures it: its result replaces the old
    run3 = {"args": {"only": ["torchtof auto"]},
            "cells": [cell({"torchtof tval3": {"peer": "torchtof", "psnr": 98.0},
                            "torchtof auto": {"peer": "torchtof", "psnr": 24.0}})]}
    m2 = pb.merge([m, run3])
    r2 = m2["cells"][0]["results"]
    assert r2["torchtof auto"]["psnr"] == 24.0 and r2["torchtof tval3"]["psnr"] == 20.0
    assert m2["cells"][0]["headline"]["gap_db"] == pytest.approx(-1.0)
    assert len(m2["runs"]) == 3  # the merged document's run list is flattened


# --------------------------------------------------------------------------- adapters
@pytest.mark.skipif(not _has("pylops"), reason="pylops not installed (pip install -e '.[peers]')")
def test_pylops_operator_is_the_hadamard_operator():
    from pylops.utils import dottest

    P = pb.Problem("camera", 16, 0.25, "sequency", 0.0, 0)
    op = pb._pylops_op(P)
    assert dottest(op, P.m, 256, rtol=1e-6)
    v = P.x.double().reshape(-1).numpy()
    assert torch.allclose(torch.from_numpy(op @ v).float(), P.A(P.x).reshape(-1), atol=1e-5)


@pytest.mark.skipif(not (_has("spyrit") and _has("torchvision")),
                    reason="spyrit not installed (pip install -e '.[peers]')")
def test_spyrit_adapters_match_torchtof():
    pb._import_torchvision()
    import spyrit.core.meas as meas

    P = pb.Problem("sky", 16, 0.25, "cake_cutting", 0.01, 0)
    lin = meas.Linear(P.dense(), meas_shape=(16, 16))
    fast = pb._FastAcq(P.A)
    assert torch.allclose(lin.measure(P.x), fast.measure_H(P.x), atol=1e-5)
    # orthonormal rows: spyrit's pseudo-inverse is Aᵀ
    assert torch.allclose(pb.spyrit_pinv(P), P.A.pinv(P.y), atol=1e-4)
    # one box-projected gradient step from 0.5 by hand
    x1 = (0.5 + P.A.adjoint(P.y - P.A(torch.full_like(P.x, 0.5)))).clamp(0, 1)
    assert torch.allclose(pb.spyrit_pgd_box(P, 1), x1, atol=1e-5)


@pytest.mark.skipif(not (_has("deepinv") and _has("torchvision")),
                    reason="deepinv not installed (pip install -e '.[peers]')")
def test_deepinv_fista_tv_zero_weight_is_least_squares():
    pb._import_torchvision()
    P = pb.Problem("camera", 16, 0.25, "sequency", 0.0, 0)
    # λ = 0: FISTA from Aᵀy on ½‖Ax − y‖² stays at the minimum-norm solution Aᵀy
    x = pb.dinv_fista_tv(P, 0.0, iters=5)
    assert torch.allclose(x, P.A.pinv(P.y), atol=1e-4)


def test_auto_eval_orders_selects_peers_cells(tmp_path):
    import argparse
    import json

    import auto_eval

    def cell(order, scene):
        return {"scene": scene, "n": 32, "sr": 0.25, "order": order, "level": 0.01,
                "results": {"torchtof auto": {"psnr": 20.0, "peer": "torchtof"},
                            "pylops SB-TV": {"psnr": 21.0, "peer": "pylops"}}}

    path = tmp_path / "p.json"
    path.write_text(json.dumps({"cells": [cell("cake_cutting", "sky"), cell("sequency", "sky"),
                                          cell("sequency", "horse")]}))
    args = argparse.Namespace(peers_cells=str(path), n=[32], sr=[0.25], seed=0,
                              orders=["sequency"], scenes=None, noise=None)
    keys = [p[0] for p in auto_eval.problems(args)]
    assert keys == [("sky", 32, 0.25, "sequency", 0.01), ("horse", 32, 0.25, "sequency", 0.01)]
    args.orders = None
    assert len(auto_eval.problems(args)) == 3
    args.scenes = ["horse"]  # --scenes and --noise select cells too (they were ignored)
    assert [p[0][0] for p in auto_eval.problems(args)] == ["horse"]
    args.scenes, args.noise = None, 0.05
    assert auto_eval.problems(args) == []
    with pytest.raises(SystemExit) as e:  # its own grid has cake-cutting rows only
        auto_eval.main(["--orders", "sequency"])
    assert e.value.code == 2


def test_auto_stack_rules_runs_the_stacking_stage_as_auto_does(tmp_path):
    # the study called auto's stacking stage with an options dict of its own, which lacked
    # tv_solver and fit_iter once auto gained them (KeyError in every measuring mode); it now
    # takes auto_options(), and the stage reproduces auto(y, A)
    from torchtof.operators import Hadamard

    am = importlib.import_module("torchtof.recon.auto")  # the module: recon.auto is the function
    assert set(am.auto_options()) == set(am.STAGE_OPTIONS)
    with pytest.raises(ValueError, match="auto_options: expected options among"):
        am.auto_options(nope=1)
    A = Hadamard(32, sr=0.25)
    x = torch.zeros(1, 1, 32, 32)
    x[..., 6:20, 8:24] = 1.0
    y = A(x) + 0.01 * torch.randn(1, 1, A.m, generator=torch.Generator().manual_seed(0))
    opts = dict(cv_iter=20, max_iter=60, priors=("tv",))
    r = am.auto(y, A, learned=False, infer_box=False, gauss=False, return_result=True, **opts)
    stacked = am._with_learned(r, y, A, None, am.auto_options(**opts))
    want = am.auto(y, A, infer_box=False, gauss=False, **opts)
    torch.testing.assert_close(stacked.x, want, rtol=0, atol=0)
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    import auto_stack_rules  # noqa: F401 - the script imports (its options come from auto)
