"""``torchtof demo --depth`` and the depth curves of ``torchtof reproduce`` (real small runs)."""

import json

import pytest
import torch

from torchtof.apps.depth_demo import DEPTH_METHODS, affine_fit, depth_curves, evaluate_depth
from torchtof.cli import main
from torchtof.experiment import PaperExperiment


def test_demo_depth_writes_png_and_table(tmp_path, capsys):
    rc = main(["demo", "--depth", "steps", "--n", "16", "--sr", "0.25", "--out", str(tmp_path)])
    assert rc == 0
    out = capsys.readouterr().out
    assert "depth RMSE m" in out and "I/Q joint" in out and "oracle affine fit" in out
    assert (tmp_path / "depth.png").stat().st_size > 10_000
    rows = {r["method"]: r for r in json.loads((tmp_path / "depth.json").read_text())}
    assert set(rows) == set(DEPTH_METHODS)
    for m in ("I/Q pinv", "I/Q TVAL3", "I/Q vTV-separate", "I/Q joint"):
        assert rows[m]["rmse_m"] < rows["raw ToF"]["rmse_m"]
        assert rows[m]["mask"] > 0.9
    # the best is named among the methods that do not fit the true depth
    fair = min((r for m, r in rows.items() if m.startswith("I/Q")), key=lambda r: r["rmse_m"])
    assert f"best without the oracle fit {fair['method']} {fair['rmse_m']:.3f} m" in out


def test_demo_depth_on_a_single_depth_scene_names_no_oracle_row_best(tmp_path, capsys):
    # on 'sky' (one depth) the oracle affine fit of the depth-sum rows is exact (0.000 m)
    assert main(["demo", "--depth", "sky", "--n", "16", "--sr", "0.25", "--out",
                 str(tmp_path)]) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert "best without the oracle fit I/Q" in last and "depth-sum" not in last


def test_demo_default_scene_is_motorcycle():
    from torchtof.cli import build_parser

    assert build_parser().parse_args(["demo", "--depth"]).depth == "motorcycle"
    assert build_parser().parse_args(["demo"]).depth is None


def test_affine_fit_recovers_an_affine_image():
    z = torch.rand(2, 1, 8, 8, generator=torch.Generator().manual_seed(0)) + 1.0
    x = -3.0 * z + 7.0  # a "negative silhouette" of the depth
    mask = torch.ones(1, 1, 8, 8, dtype=torch.bool)
    torch.testing.assert_close(affine_fit(x, z, mask), z)
    flat = affine_fit(torch.ones_like(z), z, mask)  # no information -> the mean depth
    torch.testing.assert_close(flat, z.mean(dim=(1, 2, 3), keepdim=True).expand_as(z))


def test_affine_fit_is_the_library_fit_restricted_to_the_mask():
    from torchtof.metrics import affine_fit as library_fit

    g = torch.Generator().manual_seed(3)
    x = torch.rand(2, 1, 8, 8, generator=g, dtype=torch.float64)
    z = torch.rand(2, 1, 8, 8, generator=g, dtype=torch.float64) + 1.0
    everything = torch.ones(1, 1, 8, 8, dtype=torch.bool)
    torch.testing.assert_close(affine_fit(x, z, everything), library_fit(x, z))
    # a partial mask: on its pixels, the library's fit of those pixels alone ...
    mask = torch.zeros(1, 1, 8, 8, dtype=torch.bool)
    mask[..., 2:6, 1:7] = True
    got = affine_fit(x, z, mask)
    sel = mask.expand_as(x)
    alone = library_fit(x[sel].view(2, 1, 1, -1), z[sel].view(2, 1, 1, -1))
    torch.testing.assert_close(got[sel].view(2, 1, 1, -1), alone)
    # ... and the same (a, b) off the mask: every pixel lies on one line a·x + b per image
    for i in range(2):
        a = (got[i, 0, 2, 1] - got[i, 0, 2, 2]) / (x[i, 0, 2, 1] - x[i, 0, 2, 2])
        torch.testing.assert_close(got[i], a * (x[i] - x[i, 0, 2, 1]) + got[i, 0, 2, 1])
    assert not torch.allclose(got, library_fit(x, z))  # the mask matters


def test_evaluate_depth_sky_object_only_and_bad_method():
    data = PaperExperiment(sr=0.25, n=16, roi_px=32, srs=(0.25,)).run(seed=1, realisations=1)
    rows, maps = evaluate_depth(data, 0.25, methods=("raw ToF", "I/Q pinv"))
    assert [r["method"] for r in rows] == ["raw ToF", "I/Q pinv"]
    assert rows[1]["rmse_m"] < rows[0]["rmse_m"]
    assert maps["I/Q pinv"].shape == (1, 1, 16, 16)
    with pytest.raises(ValueError, match="evaluate_depth: unknown method 'CGI'"):
        evaluate_depth(data, 0.25, methods=("CGI",))


@pytest.mark.slow  # 13 s; the depth demo itself: test_demo_depth_writes_png_and_table
def test_depth_curves_quick(tmp_path):
    res = depth_curves(tmp_path, quick=True, scenes=("slanted",))
    assert (tmp_path / "depth_rmse_slanted.png").exists()
    assert (tmp_path / "depth_maps_slanted.png").exists()
    assert "I/Q joint" in (tmp_path / "depth_table.md").read_text()
    csv = (tmp_path / "depth_rmse.csv").read_text().splitlines()
    assert len(csv) == 1 + 3 * len(DEPTH_METHODS)
    assert res["realisations"] == 1
