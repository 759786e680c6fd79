"""ONNX export of every registered model and onnxruntime parity (torchtof.onnx).

Each model is exported at batch 2 with a dynamic batch axis by the registry's exporter and
compared with eager PyTorch at batch 1 and 3 on fresh inputs (rtol 1e-4, atol 1e-5 in
units of the output's peak, float32). An export failure fails the test.
"""

import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch

import torchtof.onnx as tto
from torchtof.apps.onnx_models import MODELS, export_model
from torchtof.operators import Hadamard
from torchtof.recon import TVAL3, BasisPursuit
from torchtof.sensor import CameraReadout, camera_readout
from torchtof.sensor.functional import correlation_taps, phasor_from_depth

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "onnx_inference.py"

#: Small sizes for the tests (the shipped unrolled weights exist for n = 32 only).
N, SR = 16, 0.25
SIZES = {"unrolled_tval3": 32, "depth_resolved": 32}
ITERS = {"bp": 5, "tval3": 3, "tgv": 5, "dip": 5}


def _spec_args(name):
    return SIZES.get(name, N), SR, {"n_iter": ITERS[name]} if name in ITERS else {}


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """``get(name) -> (module, path)``: each model built and exported once per module."""
    cache = {}
    folder = tmp_path_factory.mktemp("onnx")

    def get(name):
        if name not in cache:
            spec = MODELS[name]
            n, sr, kw = _spec_args(name)
            module, inputs = spec(n, sr, **kw)
            path = tto.export(
                module,
                inputs,
                folder / f"{name}.onnx",
                input_names=spec.inputs,
                output_names=spec.outputs,
                exporter=spec.exporter,
            )
            cache[name] = module, path
        return cache[name]

    return get


def test_registry_covers_every_inference_stage():
    wanted = {
        "hadamard",
        "hadamard_adjoint",
        "hadamard_pinv",
        "pattern_operator",
        "camera",
        "depth_gate",
        "depth_bucket",
        "intensity_bucket",
        "tap_buckets",
        "g2",
        "tgi",
        "dgi",
        "pinv",
        "bp",
        "tval3",
        "tgv",
        "unrolled_tval3",
        "unet",
        "dip",
    }
    assert wanted <= set(MODELS)
    for spec in MODELS.values():
        assert spec.exporter in tto.EXPORTERS
        assert set(spec.shapes) == set(spec.inputs) | set(spec.outputs)


#: Exported in the slow run only: each is a thin variant of a model exported in the default
#: run (the adjoint and pseudo-inverse of ``hadamard``, TGI and DGI of ``g2``, the U-Net inside
#: ``dip``, the intensity bucket beside ``depth_bucket``), or a model whose own test file
#: exports it with an onnxruntime parity check in the default run (``dip``:
#: tests/recon/test_dip.py, ``tval3``: test_tval3.py, ``unrolled_tval3``: test_unrolled.py,
#: ``learned``: test_learned.py, ``depth_resolved``: test_depth.py); the default suite keeps
#: under five minutes on a 2-core machine.
SLOW_EXPORTS = {"hadamard_adjoint", "hadamard_pinv", "tgi", "dgi", "unet", "intensity_bucket",
                "dip", "tval3", "unrolled_tval3", "learned", "depth_resolved"}


@pytest.mark.parametrize(
    "name", [pytest.param(k, marks=pytest.mark.slow) if k in SLOW_EXPORTS else k for k in MODELS]
)
def test_export_and_parity(name, exported):
    module, path = exported(name)
    model = onnx.load(path)
    assert {o.domain: o.version for o in model.opset_import}[""] == tto.DEFAULT_OPSET
    spec = MODELS[name]
    assert [i.name for i in model.graph.input] == list(spec.inputs)
    assert [o.name for o in model.graph.output] == list(spec.outputs)
    for value in list(model.graph.input) + list(model.graph.output):
        assert value.type.tensor_type.shape.dim[0].dim_param, f"{value.name}: static batch"
    n, sr, kw = _spec_args(name)
    for batch in (1, 3):
        _, inputs = spec(n, sr, batch=batch, seed=1, **kw)
        report = tto.check(path, module, inputs, rtol=1e-4, atol=1e-5)
        assert report["ok"]
        assert all(o["shape"][0] == batch for o in report["outputs"])
        # the parity floor, literally: numpy.allclose(rtol=1e-4, atol=1e-5) on every output
        sess = ort.InferenceSession(path, providers=["CPUExecutionProvider"])
        feeds = {i.name: t.detach().numpy() for i, t in zip(sess.get_inputs(), inputs)}
        with torch.no_grad():
            ref = module(*inputs)
        ref = ref if isinstance(ref, (tuple, list)) else (ref,)
        for got, want in zip(sess.run(None, feeds), ref):
            np.testing.assert_allclose(got, want.detach().numpy(), rtol=1e-4, atol=1e-5)


def test_unrolled_uses_the_shipped_weights():
    net, _ = MODELS["unrolled_tval3"](32, 0.25)
    assert net.weights_file is not None and Path(net.weights_file).is_file()


def test_check_detects_a_different_model(exported, tmp_path):
    module, path = exported("g2")
    _, (y,) = MODELS["g2"](N, SR, batch=3, seed=1)
    other, _ = MODELS["tgi"](N, SR)
    with pytest.raises(AssertionError, match="differs from PyTorch"):
        tto.check(path, other, (y,))


def test_check_judges_float32_rounding_against_float64(tmp_path):
    # pinv at n = 16, SR 100 % (κ ≈ 7e3): onnxruntime and PyTorch float32 both lie ~1e-3 of
    # the peak from the float64 pseudo-inverse; the check passes them as rounding and reports
    # the errors, while a wrong model stays a failure
    module, (y,) = MODELS["pinv"](16, 1.0)
    path = tto.export(module, (y,), tmp_path / "pinv.onnx")
    _, (y3,) = MODELS["pinv"](16, 1.0, batch=3, seed=0)
    rep = tto.check(path, module, (y3,))
    row = rep["outputs"][0]
    assert rep["ok"] and row["max_abs_err"] > 1e-5 * max(1.0, row["peak"])  # the bound alone fails
    assert row["float64_err_ort"] <= 2 * row["float64_err_torch"] + 1e-5 * max(1.0, row["peak"])


    class OnePercentOff(torch.nn.Module):  # a model 1 % away: far beyond rounding
        def __init__(self):
            super().__init__()
            self.inner = module

        def forward(self, y):
            return 1.01 * self.inner(y)

    with pytest.raises(AssertionError, match="differs from PyTorch"):
        tto.check(path, OnePercentOff(), (y3,))


def test_export_errors(tmp_path):
    A = tto.OperatorMethod(Hadamard(8, sr=0.5), "adjoint")
    y = torch.rand(2, 1, 32)
    with pytest.raises(ValueError, match="export: expected exporter"):
        tto.export(A, y, tmp_path / "a.onnx", exporter="jit")
    with pytest.raises(ValueError, match="export: expected opset 17 or 18, got 13"):
        tto.export(A, y, tmp_path / "a.onnx", opset=13)
    with pytest.raises(ValueError, match="batch axis of size > 1"):
        tto.export(A, y[:1], tmp_path / "a.onnx")
    with pytest.raises(ValueError, match="expected 1 input and 1 output names"):
        tto.export(A, y, tmp_path / "a.onnx", input_names=["a", "b"], exporter="torchscript")
    with pytest.raises(TypeError, match="export: expected module to be an nn.Module"):
        tto.export(lambda t: t, y, tmp_path / "a.onnx")
    with pytest.raises(ValueError, match="OperatorMethod: expected method"):
        tto.OperatorMethod(Hadamard(8, sr=0.5), "normal")
    with pytest.raises(ValueError, match="export_model: expected name in"):
        export_model("nope", path=tmp_path / "a.onnx")
    with pytest.raises(ValueError, match="n_iter given for a model without iterations"):
        MODELS["g2"](N, SR, n_iter=3)
    assert not (tmp_path / "a.onnx").exists()


def test_export_model_static_batch_opset17(tmp_path):
    path = export_model(
        "hadamard_adjoint",
        n=8,
        sr=0.5,
        path=tmp_path / "h.onnx",
        opset=17,
        exporter="torchscript",
        dynamic_batch=False,
    )
    model = onnx.load(path)
    assert {o.domain: o.version for o in model.opset_import}[""] == 17
    assert model.graph.input[0].type.tensor_type.shape.dim[0].dim_value == 2
    module, (y,) = MODELS["hadamard_adjoint"](8, 0.5)
    tto.check(path, module, (y,))


def test_export_refuses_an_adaptive_solver_in_one_line(tmp_path):
    A = Hadamard(8, sr=0.5)
    y = torch.rand(2, 1, A.m)
    for solver in (TVAL3(A), BasisPursuit(A)):
        with pytest.raises(ValueError) as err:
            tto.export(solver, y, tmp_path / "a.onnx")
        msg = str(err.value)
        assert "\n" not in msg and "adaptive=False" in msg and type(solver).__name__ in msg
    assert not (tmp_path / "a.onnx").exists()


def test_dynamo_export_prints_no_torchvision_notes(tmp_path, capfd):
    """torch's dynamo exporter logs "torchvision is not installed. Skipping torchvision::nms"
    (and three more) on every export; torchtof uses no torchvision operator, so export drops
    them."""
    tto.export(Hadamard(8, sr=0.5), torch.rand(2, 1, 8, 8), tmp_path / "h.onnx",
               exporter="dynamo")
    captured = capfd.readouterr()
    assert "torchvision" not in captured.err + captured.out


def test_default_exporter_per_model():
    """The tracer for iterative solvers (the dynamo exporter is slow on their unrolled
    loops), dynamo for the rest; the registry's choices agree."""
    A = Hadamard(8, sr=0.5)
    assert tto.default_exporter(A) == "dynamo"
    assert tto.default_exporter(tto.OperatorMethod(A, "pinv")) == "dynamo"
    assert tto.default_exporter(TVAL3(A, max_iter=3, adaptive=False)) == "torchscript"
    for name in ("hadamard", "g2", "camera", "tval3", "unrolled_tval3", "depth_resolved"):
        module, _ = MODELS[name](*_spec_args(name)[:2], **_spec_args(name)[2])
        assert tto.default_exporter(module) == MODELS[name].exporter, name


def test_camera_readout_known_answer():
    depth = torch.tensor([0.3, 2.1, 3.37, 4.6]).view(1, 1, 2, 2)  # metres
    amp = torch.tensor([100.0, 100.0, 100.0, 0.0]).view(1, 1, 2, 2)
    taps = correlation_taps(phasor_from_depth(amp, depth, 30e6), offset=50.0)
    amplitude, phase, d = CameraReadout(step_m=0.25)(taps)
    # clip to 1 m, round to 0.25 m, dark pixel -> 5 m (paper §2.2); amplitude = |P|/2 (Eq. 8)
    assert d.flatten().tolist() == [1.0, 2.0, 3.25, 5.0]
    torch.testing.assert_close(amplitude.flatten(), torch.tensor([50.0, 50.0, 50.0, 0.0]))
    assert phase.shape == (1, 1, 2, 2)
    same = camera_readout(taps, step_m=0.25)
    assert all(torch.equal(a, b) for a, b in zip(same, (amplitude, phase, d), strict=True))
    with pytest.raises(ValueError, match="expected max_m > min_m"):
        CameraReadout(min_m=5.0, max_m=1.0)


#: Run the example with an import hook that makes every ``import torch…`` raise ImportError.
_BLOCK_TORCH = """
import runpy, sys
class _NoTorch:
    def find_spec(self, name, path=None, target=None):
        if name == "torch" or name.startswith("torch."):
            raise ImportError("torch is blocked in this process")
sys.meta_path.insert(0, _NoTorch())
sys.argv = {argv!r}
runpy.run_path(sys.argv[0], run_name="__main__")
"""


def _run_example(args, block_torch):
    env = dict(os.environ, PYTHONPATH="")
    argv = [str(EXAMPLE), *args]
    cmd = (
        [sys.executable, "-c", _BLOCK_TORCH.format(argv=argv)]
        if block_torch
        else [sys.executable, *argv]
    )
    return subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=ROOT, timeout=120)


def test_torch_blocker_blocks(tmp_path):
    script = tmp_path / "uses_torch.py"
    script.write_text("import torch\n")
    env = dict(os.environ, PYTHONPATH="")
    res = subprocess.run(
        [sys.executable, "-c", _BLOCK_TORCH.format(argv=[str(script)])],
        capture_output=True,
        text=True,
        env=env,
        timeout=60,
    )
    assert res.returncode != 0 and "torch is blocked" in res.stderr


@pytest.mark.parametrize("block_torch", [False, True], ids=["plain", "torch_blocked"])
def test_example_runs_without_torch(exported, tmp_path, block_torch):
    module, path = exported("g2")
    _, (y,) = MODELS["g2"](N, SR, batch=3, seed=2)
    np.save(tmp_path / "buckets.npy", y.numpy())
    out = tmp_path / "image.npy"
    res = _run_example([str(path), str(tmp_path / "buckets.npy"), "--out", str(out)], block_torch)
    assert res.returncode == 0, res.stderr
    assert "(3, 1, 16, 16) image(s)" in res.stdout
    with torch.no_grad():
        want = module(y).numpy()
    np.testing.assert_allclose(np.load(out), want, rtol=1e-4, atol=1e-5 * np.abs(want).max())


def test_example_single_bucket_vector(exported, tmp_path):
    module, path = exported("g2")
    _, (y,) = MODELS["g2"](N, SR, batch=2, seed=3)
    np.save(tmp_path / "b.npy", y[0, 0].numpy())  # (M,): batch and channel axes added
    res = _run_example([str(path), str(tmp_path / "b.npy"), "--quiet"], block_torch=True)
    assert res.returncode == 0, res.stderr
    assert "(1, 1, 16, 16) image(s)" in res.stdout
    np.save(tmp_path / "bad.npy", y[0, 0, :-1].numpy())
    res = _run_example([str(path), str(tmp_path / "bad.npy")], block_torch=True)
    assert res.returncode != 0 and "expects" in res.stderr


def test_bench_onnx_smoke():
    from torchtof.apps.bench.onnx import bench_onnx, print_onnx

    res = bench_onnx(
        models=["hadamard_adjoint"], batches=(1, 3), n=8, sr=0.5, compile=False, repeat=1
    )
    assert [r["batch"] for r in res["rows"]] == [1, 3]
    for r in res["rows"]:
        assert r["eager_s"] > 0 and r["ort_s"] > 0 and r["ort_speedup"] > 0
        assert r["compile_s"] is None
    print_onnx(res)
    with pytest.raises(ValueError, match="bench_onnx: unknown models"):
        bench_onnx(models=["nope"])


def _export_script():
    import importlib.util

    spec = importlib.util.spec_from_file_location("export_script", ROOT / "export" / "export.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_export_script_and_readme(tmp_path):
    script = _export_script()
    readme = (ROOT / "export" / "README.md").read_text()
    assert script.readme_table() in readme, "export/README.md is stale: run export.py --readme"
    manifest = script.main(
        [
            "hadamard_adjoint",
            "--n",
            "8",
            "--sr",
            "0.5",
            "--exporter",
            "torchscript",
            "--out",
            str(tmp_path),
        ]
    )
    (entry,) = manifest
    assert (tmp_path / "hadamard_adjoint.onnx").is_file()
    assert entry["inputs"] == {"y": ["batch", 1, 32]}
    assert entry["outputs"] == {"x": ["batch", 1, 8, 8]}
    assert entry["max_abs_err_batch3"] < 1e-4
    assert (tmp_path / "manifest.json").is_file()


@pytest.mark.parametrize("name", ["tap_buckets", "intensity_bucket"])
def test_frame_models_build_at_the_default_size(name):
    # n = 32 (the CLI's default) draws 2.6 M noisy samples: the noise's far tail must not
    # give the taps a negative amplitude (seeds 0 and 2 did)
    for seed in (0, 2):
        module, (x,) = MODELS[name](32, 0.25, batch=2, seed=seed)
        assert torch.isfinite(module(x)).all()


@pytest.mark.parametrize("cls", ["DIP", "Auto"])
def test_export_refuses_a_reconstructor_the_registry_marks_not_exportable(cls, tmp_path):
    # before: the FX graph printed twice and a TorchExportError (DIP), an internal assert (Auto)
    import torchtof.recon as recon
    A = Hadamard(8, sr=0.5)
    with pytest.raises(ValueError, match=rf"^export: {cls} does not export to ONNX"):
        tto.export(getattr(recon, cls)(A), A(torch.rand(2, 1, 8, 8)), tmp_path / "m.onnx")
    assert not (tmp_path / "m.onnx").exists()


def test_opset17_fallback_prints_no_converter_traceback(tmp_path):
    # the dynamo exporter's down-conversion of g2 to opset 17 fails and logs a traceback;
    # export() falls back to the tracer itself, so the user sees neither (a fresh process:
    # pytest's log capture would hide the logging)
    import subprocess
    import sys
    code = ("import onnx, torchtof.onnx as tto\n"
            "from torchtof.apps.onnx_models import MODELS\n"
            f"m, (y,) = MODELS['g2']({N}, {SR})\n"
            f"p = tto.export(m, (y,), {str(tmp_path / 'g2.onnx')!r}, opset=17)\n"
            "print(tto.model_opset(onnx.load(p)))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=240)
    assert out.returncode == 0 and out.stdout.strip() == "17", out.stderr[-1000:]
    assert "Traceback" not in out.stderr and "version" not in out.stderr, out.stderr[-1000:]


def test_float64_export_warns_that_onnxruntime_may_not_run_it(tmp_path):
    module, (y,) = MODELS["learned"](16, 0.25)
    with pytest.warns(UserWarning, match="export: float64 example inputs give a float64 graph"):
        path = tto.export(module, (y.double(),), tmp_path / "l64.onnx")
    with pytest.raises(Exception, match="NOT_IMPLEMENTED|Could not find an implementation"):
        tto.check(path, module.double(), y.double())  # Conv(11) has no double kernel


def test_example_keeps_every_output_and_names_missing_files(exported, tmp_path):
    module, path = exported("camera")  # three outputs: phase, amplitude, depth
    _, (taps,) = MODELS["camera"](N, SR, batch=2, seed=1)
    np.save(tmp_path / "t.npy", taps.numpy())
    res = _run_example([str(path), str(tmp_path / "t.npy"), "--quiet", "--out",
                        str(tmp_path / "o.npy")], block_torch=True)
    assert res.returncode == 0, res.stderr
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    names = [o.name for o in sess.get_outputs()]
    with torch.no_grad():
        want = module(taps)
    assert np.allclose(np.load(tmp_path / "o.npy"), want[0].numpy(), atol=1e-3)
    for k, w in zip(names[1:], want[1:]):
        np.testing.assert_allclose(np.load(tmp_path / f"o_{k}.npy"), w.numpy(), rtol=1e-4,
                                   atol=1e-3)
    for args, msg in (([str(tmp_path / "none.onnx"), str(tmp_path / "t.npy")],
                       "argument model: no such .onnx file"),
                      ([str(path), str(tmp_path / "none.npy")],
                       "argument buckets: no such .npy file")):
        res = _run_example(args, block_torch=True)
        assert res.returncode == 2 and msg in res.stderr and "Traceback" not in res.stderr


def test_depth_resolved_says_when_its_unrolled_tval3_is_untrained():
    with pytest.warns(UserWarning, match=r"MODELS\['depth_resolved'\]: no shipped unrolled "):
        MODELS["depth_resolved"](8, 0.5)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the shipped weights: no warning
        MODELS["depth_resolved"](32, 0.25)


def test_frame_models_check_their_memory_before_drawing_the_frames():
    # tap_buckets at n = 128 draws ~9 GB of frames: a limit below the estimate is a clear
    # ValueError before any allocation (was a raw allocator error or the OOM killer)
    import torchtof
    torchtof.set_memory_limit("64M")
    try:
        for name in ("tap_buckets", "depth_gate", "intensity_bucket"):
            with pytest.raises(ValueError, match=r"onnx_models: 2x1024 ToF frames of 136x136"):
                MODELS[name](64, 0.25, batch=2)
    finally:
        torchtof.set_memory_limit(None)  # back to the environment's / the machine's
