"""Tests of torchtof.scenes: the character 天, depth scenes, scikit-image scenes, registry."""

import math

import pytest
import torch

from torchtof.scenes import (
    SCENES,
    SKIMAGE_NAMES,
    Scene,
    binary_scene,
    depth_scene,
    depth_steps,
    get_scene,
    motorcycle_depth,
    skimage_scene,
    sky_character,
)


def _runs(row: torch.Tensor) -> list[tuple[int, int]]:
    """(start, length) of the runs of ones in a 1-D 0/1 tensor."""
    out, start = [], None
    for j, v in enumerate(row.tolist() + [0.0]):
        if v and start is None:
            start = j
        elif not v and start is not None:
            out.append((start, j - start))
            start = None
    return out


# ---------------------------------------------------------------- sky_character
@pytest.mark.parametrize("n", [8, 16, 31, 32, 64])
def test_sky_shape_binary_symmetric(n):
    x = sky_character(n)
    assert x.shape == (1, 1, n, n)
    assert x.dtype == torch.float32
    assert set(x.unique().tolist()) == {0.0, 1.0}
    assert torch.equal(x, x.flip(-1)), "天 must be left-right symmetric"
    assert torch.equal(x, sky_character(n)), "must be deterministic"


def test_sky_dtype_device():
    x = sky_character(16, dtype=torch.float64, device="cpu")
    assert x.dtype == torch.float64 and x.device.type == "cpu"


@pytest.mark.parametrize("n, width", [(32, 2), (64, 4), (48, 3), (47, 3)])
def test_sky_stroke_structure(n, width):
    x = sky_character(n)[0, 0]
    rows = x.sum(1)
    # margin: nothing on the outer rows/columns
    assert rows[0] == 0 and rows[-1] == 0 and x[:, 0].sum() == 0 and x[:, -1].sum() == 0
    # two horizontal bars = two groups of `width` wide rows, the upper one shorter
    bar_rows = (rows >= 0.4 * n).nonzero().flatten().tolist()
    groups = _runs((rows >= 0.4 * n).float())
    assert [g[1] for g in groups] == [width, width], groups
    top, mid = groups
    assert rows[top[0]] < rows[mid[0]]
    assert bar_rows[0] > 0.1 * n and bar_rows[-1] < 0.6 * n
    # between the bars: only the vertical stroke, `width` px wide, centred
    for r in range(top[0] + top[1], mid[0]):
        (run,) = _runs(x[r])
        assert run[1] == width + (n - width) % 2 and run[0] + run[1] / 2 == n / 2
    # below the crossing: two legs whose gap widens downwards, reaching the lower quarter
    gaps = []
    for r in range(mid[0] + mid[1] + width + 1, n):
        runs = _runs(x[r])
        if not runs:
            break
        assert len(runs) == 2, (r, runs)
        gaps.append(runs[1][0] - (runs[0][0] + runs[0][1]))
    assert len(gaps) > n // 4
    assert all(b >= a for a, b in zip(gaps[:-1], gaps[1:], strict=True)) and gaps[-1] > gaps[0]


def test_sky_errors():
    with pytest.raises(ValueError, match="sky_character: expected n >= 8"):
        sky_character(7)
    with pytest.raises(TypeError, match="sky_character: expected n to be an int"):
        sky_character(32.0)


# ---------------------------------------------------------------- depth_scene
def test_depth_scene_known_answer():
    m = torch.tensor([[[[0.0, 1.0], [1.0, 0.0]]]])
    m0 = m.clone()
    s = depth_scene(m, object_m=2.0)
    assert isinstance(s, Scene)
    assert torch.equal(s.reflectance, m) and torch.equal(s.depth_m, 2.0 * m)
    s = depth_scene(m, object_m=2.0, background_m=4.0)
    assert torch.equal(s.reflectance, torch.ones_like(m))
    assert torch.equal(s.depth_m, torch.tensor([[[[4.0, 2.0], [2.0, 4.0]]]]))
    assert torch.equal(m, m0)


@pytest.mark.parametrize("b", [1, 3])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_depth_scene_batch_dtype(b, dtype):
    m = (torch.rand(b, 1, 5, 5, generator=torch.Generator().manual_seed(0)) > 0.5).to(dtype)
    s = depth_scene(m, 1.5, 3.0)
    assert s.depth_m.shape == (b, 1, 5, 5) and s.depth_m.dtype == dtype
    singles = torch.cat([depth_scene(m[i : i + 1], 1.5, 3.0).depth_m for i in range(b)])
    assert torch.equal(s.depth_m, singles)


def test_depth_scene_bool_mask():
    s = depth_scene(sky_character(16).bool())
    assert s.reflectance.dtype == torch.float32 and float(s.depth_m.max()) == 2.0


def test_depth_scene_errors():
    with pytest.raises(ValueError, match="depth_scene: expected object_mask to hold only 0 and 1"):
        depth_scene(torch.full((1, 1, 2, 2), 0.5))
    with pytest.raises(ValueError, match="depth_scene: expected object_mask of rank 4"):
        depth_scene(torch.ones(2, 2))
    with pytest.raises(ValueError, match="depth_scene: expected object_m > 0"):
        depth_scene(torch.ones(1, 1, 2, 2), object_m=0.0)
    with pytest.raises(ValueError, match="depth_scene: expected background_m > 0"):
        depth_scene(torch.ones(1, 1, 2, 2), background_m=-1.0)
    with pytest.raises(TypeError, match="depth_scene: expected object_mask to be a torch.Tensor"):
        depth_scene([[1.0]])


# ---------------------------------------------------------------- depth_steps
def test_depth_steps():
    s = depth_steps(32)
    assert s.depth_m.shape == (1, 1, 32, 32) and s.depth_m.dtype == torch.float32
    assert torch.equal(s.reflectance, torch.ones_like(s.reflectance))
    assert set(s.depth_m.unique().tolist()) == {1.5, 2.0, 2.5, 3.0}
    assert float(s.depth_m[0, 0, 0, 0]) in {1.5, 2.0, 2.5, 3.0}
    assert torch.equal(s.depth_m, depth_steps(32).depth_m), "same seed, same scene"
    assert not torch.equal(s.depth_m, depth_steps(32, seed=1).depth_m)
    t = depth_steps(16, levels=(1.0, 4.0), dtype=torch.float64)
    assert t.depth_m.dtype == torch.float64 and set(t.depth_m.unique().tolist()) <= {1.0, 4.0}
    assert float(t.depth_m.max()) == 4.0  # the farthest level is the background


def test_depth_steps_errors():
    with pytest.raises(ValueError, match="depth_steps: expected at least two levels"):
        depth_steps(16, levels=(2.0,))
    with pytest.raises(ValueError, match="depth_steps: expected levels > 0"):
        depth_steps(16, levels=(2.0, -1.0))
    with pytest.raises(TypeError, match="depth_steps: expected seed to be an int"):
        depth_steps(16, seed=1.5)
    with pytest.raises(ValueError, match="depth_steps: expected seed >= 0"):
        depth_steps(16, seed=-1)


# ---------------------------------------------------------------- scikit-image scenes
@pytest.mark.parametrize("name", SKIMAGE_NAMES)
def test_skimage_scene_all_names(name):
    x = skimage_scene(name, 16)
    assert x.shape == (1, 1, 16, 16) and x.dtype == torch.float32
    assert torch.isfinite(x).all() and x.min() >= 0 and x.max() <= 1 and x.max() > x.min()


def test_skimage_scene_deterministic_and_errors():
    assert torch.equal(skimage_scene("camera", 32), skimage_scene("camera", 32))
    with pytest.raises(ValueError, match="skimage_scene: expected name in"):
        skimage_scene("kidney", 32)  # not bundled (needs a download)
    with pytest.raises(ValueError, match="skimage_scene: expected n >= 8"):
        skimage_scene("camera", 4)


def test_binary_scene_horse():
    x = binary_scene("horse", 32)
    assert x.shape == (1, 1, 32, 32)
    assert set(x.unique().tolist()) == {0.0, 1.0}
    assert 0.1 < float(x.mean()) < 0.5  # the horse is the object, not the white background
    assert float(x[0, 0, 0].mean()) < 0.5
    assert binary_scene("coins", 16, dtype=torch.float64).dtype == torch.float64


# ---------------------------------------------------------------- motorcycle
def test_motorcycle_depth():
    z = motorcycle_depth(32)
    assert z.shape == (1, 1, 32, 32) and z.dtype == torch.float32
    assert torch.isfinite(z).all()
    assert float(z.min()) == pytest.approx(1.0, abs=1e-6)
    assert float(z.max()) == pytest.approx(4.0, abs=1e-6)
    assert z.std() > 0.3  # a real, structured depth map
    z2 = motorcycle_depth(16, near_m=2.0, far_m=3.0, dtype=torch.float64)
    assert z2.dtype == torch.float64 and z2.min() >= 2.0 - 1e-12 and z2.max() <= 3.0 + 1e-12


def test_motorcycle_errors():
    with pytest.raises(ValueError, match="motorcycle_depth: expected far_m > near_m"):
        motorcycle_depth(16, near_m=3.0, far_m=2.0)


# ---------------------------------------------------------------- registry
@pytest.mark.parametrize("name", [*SCENES, "skimage:camera", "binary:horse"])
@pytest.mark.parametrize("dtype", [None, torch.float64])
def test_get_scene_every_name(name, dtype):
    s = get_scene(name, 16, dtype=dtype, device="cpu")
    assert isinstance(s, Scene)
    for t in s:
        assert t.shape == (1, 1, 16, 16)
        assert t.dtype == (dtype or torch.float32)
        assert torch.isfinite(t).all()
    assert s.reflectance.min() >= 0 and s.reflectance.max() <= 1
    assert s.depth_m.min() >= 0
    lit = s.reflectance > 0
    assert (s.depth_m[lit] > 0).all(), "every pixel that returns light has a distance"


def test_get_scene_sky_is_paper_object():
    s = get_scene()
    assert torch.equal(s.reflectance, sky_character(32))
    assert torch.equal(s.depth_m, 2.0 * sky_character(32))


def test_get_scene_errors():
    with pytest.raises(ValueError, match="get_scene: expected name in"):
        get_scene("moon")
    with pytest.raises(ValueError, match="skimage_scene: expected name in"):
        get_scene("skimage:nope")
    with pytest.raises(ValueError, match="get_scene: expected object_m > 0"):
        get_scene("skimage:camera", object_m=0.0)


def test_slanted_plane_is_a_plane_and_far_steps_pass_5_m():
    from torchtof.scenes import FAR_LEVELS, slanted_plane

    s = slanted_plane(16, 1.5, 3.5, angle_deg=30.0, dtype=torch.float64)
    z = s.depth_m[0, 0]
    assert float(z.min()) == 1.5 and abs(float(z.max()) - 3.5) < 1e-12
    # a plane: constant first differences along each axis, ratio tan(30°)
    dx, dy = z[:, 1:] - z[:, :-1], z[1:, :] - z[:-1, :]
    assert float(dx.std()) < 1e-12 and float(dy.std()) < 1e-12
    assert abs(float(dy.mean() / dx.mean()) - math.tan(math.radians(30))) < 1e-9
    assert bool((s.reflectance == 1).all())
    far = get_scene("steps_far", 32)
    assert sorted(far.depth_m.unique().tolist()) == list(FAR_LEVELS) and max(FAR_LEVELS) > 5
    with pytest.raises(ValueError, match="slanted_plane: expected far_m > near_m"):
        slanted_plane(16, 3.0, 2.0)
    with pytest.raises(TypeError, match="slanted_plane: expected angle_deg to be a number"):
        slanted_plane(16, angle_deg="45")


def test_return_types_follow_the_documented_rule():
    # scene builders return Scene(reflectance, depth_m); image drawers return one tensor
    from torchtof import scenes as sc

    builders = [sc.get_scene("sky", 16), sc.depth_steps(16), sc.slanted_plane(16),
                sc.depth_scene(torch.ones(1, 1, 8, 8))]
    for s in builders:
        assert type(s) is sc.Scene
        assert s.reflectance.shape == s.depth_m.shape
    images = [sc.sky_character(16), sc.skimage_scene("camera", 16), sc.binary_scene("horse", 16),
              sc.motorcycle_depth(16)]
    for x in images:
        assert type(x) is torch.Tensor and x.shape == (1, 1, 16, 16)
    # every public function is in one of the two lists above
    public = {n for n in sc.__all__ if callable(getattr(sc, n)) and n != "Scene"}
    assert public == {"get_scene", "depth_steps", "slanted_plane", "depth_scene",
                      "sky_character", "skimage_scene", "binary_scene", "motorcycle_depth"}


def test_scene_inputs_review_edges(tmp_path):
    import numpy as np

    from torchtof.data import draw_scene, grey_image, load_images, planar_depth
    # the cached photograph is never handed out: editing a result changes no later call
    img = grey_image("camera")
    img.zero_()
    assert float(grey_image("camera").max()) > 0.5
    # seeds: negative ones wrapped onto other seeds' scenes, floats were truncated
    with pytest.raises(ValueError, match="draw_scene: expected seed"):
        draw_scene(32, -1, "planar")
    with pytest.raises(TypeError, match="planar_depth: expected seed"):
        planar_depth(16, 1.7)
    with pytest.raises(TypeError, match="draw_scene: expected images to be a sequence"):
        draw_scene(32, 1, "natural", images="coins")
    # an image spanning nearly the whole float64 range normalises without NaN
    a = np.zeros((8, 8))
    a[0, 0], a[1, 1] = -1e308, 1e308
    np.save(tmp_path / "big.npy", a)
    got = load_images(tmp_path / "big.npy")[0]
    assert torch.isfinite(got).all() and float(got.min()) == 0.0 and float(got.max()) == 1.0
