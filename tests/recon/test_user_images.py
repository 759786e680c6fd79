"""The caller's own scenes in training (``torchtof.data.load_images``, the ``"user"`` family,
``train_learned(user_images=...)``, ``torchtof train --images``).

Known answers: a file's image comes back min–max normalised, whatever its units (so a depth
map in metres and the same map in millimetres load alike); a ``"user"`` scene is a crop of
one of the given images (its normalised pixels reappear after resizing to the image's own
side); the shipped mixture never draws the family, and a run's recipe records each file's
SHA-256 as ``hashlib`` computes it from the bytes.
"""

import hashlib
import json

import numpy as np
import pytest
import skimage.io
import torch

from torchtof.cli import main
from torchtof.data import FAMILIES, draw_scene, draw_scenes, load_images
from torchtof.recon.learned_train import P_USER, train_learned


def _ramp(h=24, w=32, scale=1.0):
    """A ramp plus a square: distinct values, known min and max."""
    a = np.add.outer(np.arange(h), np.arange(w)).astype(np.float64)
    a[4:10, 4:10] += 100.0
    return a * scale


def test_load_images_reads_every_format_and_normalises(tmp_path):
    a = _ramp()
    want = (a - a.min()) / (a.max() - a.min())
    np.save(tmp_path / "one.npy", a * 1e-3 + 2.0)  # metres, offset: the same image
    np.save(tmp_path / "stack.npy", np.stack([a, a[::-1]]))
    np.savez(tmp_path / "z.npz", second=a.T, first=a)
    u8 = np.round(want * 255).astype(np.uint8)
    skimage.io.imsave(tmp_path / "g.png", u8, check_contrast=False)
    skimage.io.imsave(tmp_path / "rgb.png", np.stack([u8] * 3, -1), check_contrast=False)
    (tmp_path / "notes.txt").write_text("ignored in a folder")

    (one,) = load_images(tmp_path / "one.npy")
    assert one.dtype == torch.float32 and one.shape == (24, 32)
    np.testing.assert_allclose(one.numpy(), want, atol=1e-6)
    stack = load_images(str(tmp_path / "stack.npy"))
    np.testing.assert_allclose(stack[1].numpy(), want[::-1], atol=1e-6)
    first, second = load_images(tmp_path / "z.npz")  # sorted by key
    np.testing.assert_allclose(first.numpy(), want, atol=1e-6)
    np.testing.assert_allclose(second.numpy(), want.T, atol=1e-6)
    (g,) = load_images(tmp_path / "g.png")
    (rgb,) = load_images(tmp_path / "rgb.png")
    np.testing.assert_allclose(g.numpy(), u8 / 255.0, atol=1e-6)
    np.testing.assert_allclose(rgb.numpy(), g.numpy(), atol=2e-3)  # grey by luminance
    # a folder: its image files in name order, other files skipped
    assert len(load_images(tmp_path)) == 1 + 1 + 2 + 2 + 1


@pytest.mark.parametrize(("make", "exc", "match"), [
    (lambda d: d / "missing.npy", FileNotFoundError, "missing.npy"),
    (lambda d: (d / "a.txt").write_text("x") and d / "a.txt", ValueError, "a.txt"),
    (lambda d: np.save(d / "nan.npy", np.where(_ramp() > 50, np.nan, _ramp())) or d / "nan.npy",
     ValueError, "finite.*nan.npy"),
    (lambda d: np.save(d / "flat.npy", np.ones((16, 16))) or d / "flat.npy",
     ValueError, "constant.*flat.npy"),
    (lambda d: np.save(d / "tiny.npy", _ramp(4, 30)) or d / "tiny.npy", ValueError, "side >= 8"),
    (lambda d: np.save(d / "vec.npy", np.arange(40.0)) or d / "vec.npy", ValueError, "2-D"),
    (lambda d: (d / "empty").mkdir() or d / "empty", ValueError, "found none"),
])
def test_load_images_rejects_bad_files_naming_them(tmp_path, make, exc, match):
    with pytest.raises(exc, match=match):
        load_images(make(tmp_path))


def test_load_images_rejects_what_is_not_a_path():
    for bad in (3, [], [3], torch.zeros(8, 8)):
        with pytest.raises(TypeError, match="paths"):
            load_images(bad)


def test_user_scenes_are_crops_of_the_given_images():
    """Each draw crops one of the images: an image of constant rows gives scenes constant along
    one axis (a quarter turn may swap it), an image of constant columns likewise; the family
    needs images and the shipped mixture never draws it."""
    rows = torch.linspace(0, 1, 48)[:, None].expand(48, 48).contiguous()  # constant rows
    for seed in range(8):
        x = draw_scene(32, seed, "user", user_images=[rows])[0, 0]
        along_r = float((x[:, 1:] - x[:, :-1]).abs().max())
        along_c = float((x[1:] - x[:-1]).abs().max())
        assert min(along_r, along_c) < 1e-5 < max(along_r, along_c), seed
        assert 0 <= float(x.min()) and float(x.max()) <= 1
    with pytest.raises(ValueError, match="user_images"):
        draw_scene(32, 0, "user")
    with pytest.raises(ValueError, match="user_images"):
        draw_scenes(32, 0, 0, range(2), families={"user": 0.5, "planar": 0.5})
    with pytest.raises(ValueError, match="user_images"):
        draw_scene(32, 0, "user", user_images=[torch.zeros(4, 40)])
    with pytest.raises(TypeError, match="user_images"):
        draw_scene(32, 0, "user", user_images=torch.zeros(40, 40))
    assert FAMILIES["user"] == 0.0
    # with the default mixture the images change nothing
    assert torch.equal(draw_scenes(32, 0, 3, range(8), user_images=[rows]),
                       draw_scenes(32, 0, 3, range(8)))


def test_a_run_with_user_images_draws_them_and_records_the_files(tmp_path):
    a = np.zeros((40, 40))
    a[10:30, 5:35] = 1.0  # a bar: crops of it are binary
    np.save(tmp_path / "bar.npy", a)
    r = train_learned(steps=2, batch_size=2, sizes=(16,), n_layers=2, width=4, progress=False,
                      calibrate=False, user_images=tmp_path / "bar.npy", out=tmp_path / "run")
    assert len(r.losses) == 2
    recipe = json.loads((tmp_path / "run" / "recipe.json").read_text())
    fam = recipe["data"]["families"]
    assert fam["user"] == P_USER and sum(fam.values()) == pytest.approx(1.0)
    assert fam["planar"] == pytest.approx(FAMILIES["planar"] * (1 - P_USER))
    (rec,) = recipe["data"]["user_images"]
    assert rec["sha256"] == hashlib.sha256((tmp_path / "bar.npy").read_bytes()).hexdigest()
    assert rec["images"] == 1 and rec["path"].endswith("bar.npy")
    # a mixture of the user family alone draws crops of the bar: two levels, plus the grey
    # values the anti-aliased resize leaves along its edges
    from torchtof.recon.learned_train import _batch

    _, x, _ = _batch(0, 0, 16, 64, "cake_cutting", range(4), families={"user": 1.0},
                     user_paths=(str(tmp_path / "bar.npy"),))
    for img in x:
        assert len(torch.unique(torch.round(img * 1e4))) <= 40  # the resize's edge only
    with pytest.raises(ValueError, match="user_images"):
        train_learned(steps=1, families={"user": 1.0})
    with pytest.raises(ValueError, match="user"):
        train_learned(steps=1, families={"planar": 1.0}, user_images=tmp_path / "bar.npy")
    with pytest.raises(FileNotFoundError, match="nope"):
        train_learned(steps=1, user_images=tmp_path / "nope.npy")
    with pytest.raises(TypeError, match="user_images"):
        train_learned(steps=1, user_images=[3])


def test_cli_images_reach_the_run_and_calibration(tmp_path, capsys, monkeypatch):
    np.save(tmp_path / "r.npy", _ramp(40, 40))
    out = tmp_path / "run"
    common = ["--steps", "1", "--batch-size", "2", "--sizes", "16", "--n-layers", "2",
              "--width", "4", "--no-progress", "--out", str(out)]
    assert main(["train", "--images", str(tmp_path / "r.npy"), "--no-calibrate", *common]) == 0
    recipe = json.loads((out / "recipe.json").read_text())
    assert recipe["data"]["families"]["user"] == P_USER
    assert recipe["data"]["user_images"][0]["path"] == str((tmp_path / "r.npy").resolve())
    # --calibrate-only draws the run's own images again (from recipe.json)
    import torchtof.apps.train as app

    seen = {}
    monkeypatch.setattr(app, "calibrate_tau", lambda model, seed, **kw: seen.update(kw) or {
        "tau": 0.1, "losses": {}, "loss_off": 0.0})
    assert main(["train", "--calibrate-only", "--sizes", "16", "--out", str(out)]) == 0
    assert seen["user_images"] == [str((tmp_path / "r.npy").resolve())]
    assert seen["families"]["user"] == P_USER
    capsys.readouterr()
    # mistakes: one line naming the option, exit status 2, before any work
    for argv, flag in ((["--images", str(tmp_path / "none.npy")], "--images"),
                       (["--families", "planar=0.5", "user=0.5"], "--families"),
                       (["--images", str(tmp_path / "r.npy"), "--families", "planar=1"],
                        "--images")):
        with pytest.raises(SystemExit) as exc:
            main(["train", *argv, "--out", str(tmp_path / "x")])
        assert exc.value.code == 2
        err = capsys.readouterr().err
        assert f"argument {flag}:" in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "x").exists()


def test_user_domain_benchmark_scores_given_held_out_images(tmp_path, capsys):
    """``benchmarks/learned_user_domain.py --eval-images``: the caller's scenes, centre-cropped
    and resized, scored against TVAL3 on the same buckets; the motorcycle split's halves do
    not overlap."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[2] / "benchmarks" / "learned_user_domain.py"
    spec = importlib.util.spec_from_file_location("learned_user_domain", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    left, right = mod.halves()
    assert left.shape[0] == right.shape[0] and left.shape[1] + right.shape[1] == 741
    np.save(tmp_path / "held.npy", np.stack([_ramp(40, 56), _ramp(40, 56)[::-1]]))
    x = mod.eval_scenes(16, load_images(tmp_path / "held.npy"))
    assert x.shape == (2, 1, 16, 16) and float(x.min()) == 0.0 and float(x.max()) == 1.0
    out = tmp_path / "r.json"
    assert mod.main(["--sizes", "16", "--srs", "0.25", "--levels", "0.01", "--eval-images",
                     str(tmp_path / "held.npy"), "--out", str(out)]) == 0
    rows = json.loads(out.read_text())["rows"]
    assert len(rows) == 1 and {"tval3", "shipped"} <= set(rows[0])
    assert "| shipped |" in capsys.readouterr().out


def test_user_images_are_scanned_once_unless_modified():
    """A run draws from the same images every step: each is scanned for NaN/Inf once, and
    again after an in-place change (which a NaN written into it is)."""
    from torchtof.data import scenes

    u = torch.rand(40, 40, generator=torch.Generator().manual_seed(0))
    draw_scenes(16, 0, 0, range(2), family="user", user_images=[u])
    assert scenes._FINITE[id(u)][0]() is u
    u[3, 3] = float("nan")
    with pytest.raises(ValueError, match=r"finite values in user_images\[0\]"):
        draw_scenes(16, 0, 1, range(2), family="user", user_images=[u])


def test_a_later_run_reads_a_changed_image_file_again(tmp_path):
    """Within a run the images are read once (the run draws from them as they were); a later
    run in the same process reads the files again."""
    from torchtof.recon.learned_train import _user_images

    f = tmp_path / "img.npy"
    np.save(f, _ramp(20, 20))
    (a,) = _user_images((str(f),))
    np.save(f, _ramp(20, 20)[::-1])
    assert _user_images((str(f),))[0] is a  # the same run: unchanged
    train_learned(steps=1, batch_size=2, sizes=(16,), n_layers=2, width=4, progress=False,
                  calibrate=False, user_images=f)
    (b,) = _user_images((str(f),))
    torch.testing.assert_close(b, a.flip(0))


def test_resume_continues_with_the_runs_own_images(tmp_path):
    """A resume that names neither images nor families continues with the checkpoint's; other
    images, or the run's images changed on disk, are refused by name."""
    f, g = tmp_path / "a.npy", tmp_path / "b.npy"
    np.save(f, _ramp(24, 24))
    np.save(g, _ramp(24, 24).T)
    kw = dict(batch_size=2, sizes=(16,), n_layers=2, width=4, progress=False, calibrate=False)
    run = tmp_path / "run"
    train_learned(steps=1, user_images=f, out=run, **kw)
    train_learned(steps=2, resume=True, out=run, **kw)
    recipe = json.loads((run / "recipe.json").read_text())
    assert recipe["steps_run"] == 2 and recipe["data"]["families"]["user"] == P_USER
    assert [r["path"] for r in recipe["data"]["user_images"]] == [str(f.resolve())]
    with pytest.raises(ValueError, match="trained on families"):
        train_learned(steps=3, resume=True, user_images=g, out=run, **kw)
    np.save(f, _ramp(24, 24)[::-1])
    with pytest.raises(ValueError, match="images changed"):
        train_learned(steps=3, resume=True, out=run, **kw)
