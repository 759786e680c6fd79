"""Edge cases of torchtof.onnx (export/check), torchtof.experiment and torchtof.methods:
bad arguments raise a clear TypeError/ValueError naming the argument."""

import pytest
import torch
from torch import nn

from torchtof.experiment import ExperimentConfig, PaperExperiment
from torchtof.methods import build_method, evaluate, score_image


@pytest.fixture(scope="module")
def data():
    return PaperExperiment(sr=0.125, n=16, roi_px=32, srs=(0.125,)).run(seed=0)


# ------------------------------------------------------------------ experiment
def test_duplicate_srs_rejected():
    with pytest.raises(ValueError, match="distinct sampling rates in srs"):
        ExperimentConfig(n=16, roi_px=32, srs=(0.125, 0.125)).validate()


def test_seed_out_of_generator_range():
    exp = PaperExperiment(sr=0.125, n=16, roi_px=32, srs=(0.125,))
    with pytest.raises(ValueError, match=rf"PaperExperiment.run: expected seed <= {2**64 - 1}, "
                                         rf"got {2**70}"):
        exp.run(seed=2**70)


def test_split_buckets_sr_not_simulated(data):
    # used to return the 2M acquired buckets silently truncated, not the 2·M(sr) asked for
    with pytest.raises(ValueError, match="the run acquired 32"):
        data.split_buckets(0.25)
    with pytest.raises(ValueError, match="the run acquired 32"):
        build_method("CGI", data, 0.25, False)


@pytest.mark.parametrize("kind", ["depth_gated", "x"])
def test_split_buckets_kind(data, kind):
    with pytest.raises(ValueError, match="expected kind in"):
        data.split_buckets(0.125, kind=kind)


def test_gate_must_be_bool(data):
    with pytest.raises(TypeError, match="gate to be a bool"):
        data.split_buckets(0.125, gate="no")
    with pytest.raises(TypeError, match="gate to be a bool"):
        data.polarity("no")
    with pytest.raises(TypeError, match="gate to be a bool"):
        build_method("CGI", data, 0.125, "yes")


def test_polarity_unknown_kind(data):
    with pytest.raises(ValueError, match="expected kind in"):
        data.polarity(False, "xx")


# ------------------------------------------------------------------ methods
def test_build_method_data_type():
    with pytest.raises(TypeError, match="build_method: expected data"):
        build_method("CGI", "data", 0.125, False)


def test_evaluate_argument_types(data):
    with pytest.raises(TypeError, match="expected methods"):
        evaluate(data, 0.125, False, methods="CGI")
    with pytest.raises(TypeError, match="expected options"):
        evaluate(data, 0.125, False, methods=("CGI",), options=[1])
    with pytest.raises(TypeError, match="expected options"):
        evaluate(data, 0.125, False, methods=("CGI",), options={"CGI": 3})
    with pytest.raises(TypeError, match="evaluate: expected data"):
        evaluate(None, 0.125, False, methods=("CGI",))


def test_score_image_types(data):
    with pytest.raises(TypeError, match="score_image: expected img"):
        score_image([1.0, 2.0], data, "positive")
    with pytest.raises(TypeError, match="score_image: expected data"):
        score_image(data.raw_tof_image, None, "positive")


# ------------------------------------------------------------------ onnx
tto = pytest.importorskip("torchtof.onnx")
pytest.importorskip("onnxruntime")


class _Scale(nn.Module):
    def __init__(self):
        super().__init__()
        self.inner = nn.Dropout(0.5)

    def forward(self, x):
        return 2 * x


class _Two(nn.Module):
    def forward(self, a, b):
        return a + b.sum()


@pytest.fixture(scope="module")
def scale_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("onnx") / "scale.onnx"
    return tto.export(_Scale(), torch.rand(2, 3), path)


def test_export_path_is_a_folder(tmp_path):
    with pytest.raises(ValueError, match="export: expected path to be an .onnx file"):
        tto.export(_Scale(), torch.rand(2, 3), tmp_path)
    with pytest.raises(TypeError, match="export: expected path"):
        tto.export(_Scale(), torch.rand(2, 3), 3)


def test_export_mismatched_batches(tmp_path):
    with pytest.raises(ValueError, match="one batch size"):
        tto.export(_Two(), (torch.rand(2, 3), torch.rand(3, 3)), tmp_path / "two.onnx")


def test_export_argument_types(tmp_path):
    x = torch.rand(2, 3)
    with pytest.raises(TypeError, match="dynamic_batch to be a bool"):
        tto.export(_Scale(), x, tmp_path / "a.onnx", dynamic_batch="no")
    with pytest.raises(TypeError, match="input_names"):
        tto.export(_Scale(), x, tmp_path / "a.onnx", input_names="x")
    with pytest.raises(ValueError, match="opset 17 or 18"):
        tto.export(_Scale(), x, tmp_path / "a.onnx", opset=17.0)
    with pytest.raises(TypeError, match="export: expected example_inputs"):
        tto.export(_Scale(), x.numpy(), tmp_path / "a.onnx")


def test_export_and_check_keep_submodule_modes(scale_file, tmp_path):
    m = _Scale()
    m.train()
    m.inner.eval()  # a submodule the caller left in eval mode
    tto.export(m, torch.rand(2, 3), tmp_path / "m.onnx")
    assert m.training and not m.inner.training
    tto.check(scale_file, m, torch.rand(3, 3))
    assert m.training and not m.inner.training


@pytest.mark.parametrize("kw,err", [({"rtol": -1.0}, ValueError),
                                    ({"atol": float("nan")}, ValueError),
                                    ({"rtol": "1e-4"}, TypeError)])
def test_check_tolerances(scale_file, kw, err):
    with pytest.raises(err, match="check: expected"):
        tto.check(scale_file, _Scale(), torch.rand(3, 3), **kw)


def test_check_bad_arguments(scale_file, tmp_path):
    x = torch.rand(3, 3)
    with pytest.raises(TypeError, match="check: expected module"):
        tto.check(scale_file, "module", x)
    with pytest.raises(ValueError, match="existing .onnx file"):
        tto.check(tmp_path / "missing.onnx", _Scale(), x)
    with pytest.raises(ValueError, match="check: expected path to be an .onnx file"):
        tto.check(tmp_path, _Scale(), x)
    with pytest.raises(ValueError, match="tensor\\(float\\), got a torch.float64"):
        tto.check(scale_file, _Scale(), x.double())
    with pytest.raises(TypeError, match="check: expected inputs"):
        tto.check(scale_file, _Scale(), [])
