"""``torchtof.onnx.export``: the file holds the opset asked for (the dynamo exporter's failed
down-conversion to 17 falls back to the tracer, or is refused), names the exporter that
wrote it, and declares every output axis but the batch with its size."""

import importlib.util
import json
import logging
from pathlib import Path

import pytest
import torch

onnx = pytest.importorskip("onnx")
pytest.importorskip("onnxruntime")
pytest.importorskip("onnxscript")

import torchtof.onnx as tto  # noqa: E402
from torchtof.apps.onnx_models import MODELS  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def _opset(path) -> int:
    return next(o.version for o in onnx.load(path).opset_import if o.domain in ("", "ai.onnx"))


def _meta(path) -> dict:
    return {p.key: p.value for p in onnx.load(path).metadata_props}


def _out_dims(path) -> list[list]:
    return [[d.dim_param or d.dim_value for d in v.type.tensor_type.shape.dim]
            for v in onnx.load(path).graph.output]


def _export_script():
    spec = importlib.util.spec_from_file_location("export_script_opset",
                                                  ROOT / "export" / "export.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def g2_17(tmp_path_factory):
    """g2 (a dynamo model whose down-conversion to 17 fails) at opset 17 by export/export.py:
    the file and its manifest, one export for every test."""
    out = tmp_path_factory.mktemp("g2_17")
    logging.disable(logging.CRITICAL)
    try:
        manifest = _export_script().main(["g2", "--n", "8", "--opset", "17", "--out",
                                          str(out), "--no-check"])
    finally:
        logging.disable(logging.NOTSET)
    return out, manifest


def test_opset17_of_a_dynamo_model_the_converter_fails_on_is_written_by_the_tracer(g2_17):
    assert MODELS["g2"].exporter == "dynamo"
    out, _ = g2_17
    p = out / "g2.onnx"
    assert _opset(p) == 17  # was 18, silently
    assert _meta(p)[tto.EXPORTER_KEY] == "torchscript"
    module, inputs = MODELS["g2"](8, 0.25, batch=3, seed=1)
    assert tto.check(p, module, inputs)["ok"]


def test_manifest_records_the_opset_and_exporter_stored_in_the_file(g2_17):
    out, manifest = g2_17
    on_disk = json.loads((out / "manifest.json").read_text())
    assert manifest == on_disk
    (entry,) = on_disk
    assert entry["opset"] == 17 and entry["exporter"] == "torchscript"
    assert entry["outputs"] == {"x": ["batch", 1, 8, 8]}


def test_opset17_that_neither_exporter_writes_is_refused_and_no_file_is_left(tmp_path,
                                                                          monkeypatch):
    run = tto._run_exporter

    def fake(exporter, module, inputs, path, opset, *rest):
        if exporter == "torchscript":
            raise RuntimeError("the tracer cannot trace this model")
        # the dynamo exporter's behaviour: opset 18 kept whatever was asked (the tracer at
        # 18 stands in for it here, it is faster)
        return run("torchscript", module, inputs, path, 18, *rest)

    monkeypatch.setattr(tto, "_run_exporter", fake)
    module, inputs = MODELS["g2"](8, 0.25)
    path = tmp_path / "g2.onnx"
    with pytest.raises(ValueError, match=r"export: expected an opset .*opset=17.*tracer cannot"):
        tto.export(module, inputs, path, opset=17, exporter="dynamo")
    assert not path.exists()


class _HalfSlice(torch.nn.Module):
    """The tracer names the sliced axis symbolically (``Sliceoutput_0_dim_2``)."""

    def forward(self, y):
        return y[:, :, : y.shape[-1] // 2]


@pytest.mark.filterwarnings("ignore:Constant folding")  # the tracer's note on the slice
@pytest.mark.parametrize("dynamic_batch", [True, False])
def test_torchscript_outputs_declare_every_axis_but_the_batch(tmp_path, dynamic_batch):
    x = torch.rand(2, 1, 16)
    p = tto.export(_HalfSlice(), x, tmp_path / "s.onnx", exporter="torchscript",
                   dynamic_batch=dynamic_batch)
    assert _out_dims(p) == [["batch" if dynamic_batch else 2, 1, 8]]
    assert _meta(p)[tto.EXPORTER_KEY] == "torchscript"
    assert tto.check(p, _HalfSlice(), torch.rand(3 if dynamic_batch else 2, 1, 16))["ok"]

