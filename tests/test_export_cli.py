"""``torchtof export``: an elapsed-time bar on stderr while the one long call runs (only on a
terminal, never with --no-progress), then one summary line on stdout with the file, its size
and the onnxruntime parity result."""

import io
import time
from pathlib import Path

import pytest

pytest.importorskip("onnx")
pytest.importorskip("onnxruntime")

import torchtof.apps.onnx_models as onnx_models  # noqa: E402
from torchtof.cli import main  # noqa: E402


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def _slow_fake(seconds=0.8, ok=True):
    """Stands in for the export: takes ``seconds`` without printing, writes a 2 kB file."""

    def fake(name, n, sr, path, opset):
        time.sleep(seconds)
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        Path(path).write_bytes(b"\0" * 2000)
        parity = ({"ok": True, "outputs": [{"max_abs_err": 3e-7}, {"max_abs_err": 1e-6}]} if ok
                  else {"ok": False, "error": "x: max abs error 0.5"})
        return {"path": Path(path), "bytes": 2000, "parity": parity}

    return fake


def test_bar_on_a_terminal_goes_to_stderr_and_the_summary_to_stdout(tmp_path, monkeypatch,
                                                                     capsys):
    monkeypatch.setattr(onnx_models, "export_checked", _slow_fake())
    err = _Terminal()
    monkeypatch.setattr("sys.stderr", err)
    assert main(["export", "hadamard", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    bar = err.getvalue()
    assert "torchtof export: tracing hadamard (n=32, SR 25.00%)" in bar
    assert "00:00" in bar  # the elapsed time
    assert sum(c in bar for c in "|/-\\") >= 2, bar  # the thread redrew the spinner
    assert len(out) == 1 and "tracing" not in out[0]
    path = tmp_path / "hadamard_n32_sr0.25.onnx"
    assert out[0].startswith("torchtof export: hadamard (n=32, SR 25.00%) in ")
    assert f"wrote {path} (2 kB)" in out[0]
    assert "matches PyTorch at batch 3 (max abs error 1.0e-06)" in out[0]


@pytest.mark.parametrize("terminal,flag", [(True, ["--no-progress"]), (False, [])])
def test_no_bar_with_no_progress_or_off_a_terminal(tmp_path, monkeypatch, capsys, terminal,
                                                   flag):
    monkeypatch.setattr(onnx_models, "export_checked", _slow_fake(0.6))
    err = _Terminal() if terminal else io.StringIO()
    monkeypatch.setattr("sys.stderr", err)
    assert main(["export", "hadamard", *flag, "--out", str(tmp_path)]) == 0
    assert err.getvalue() == ""
    assert len(capsys.readouterr().out.strip().splitlines()) == 1


def test_a_parity_failure_is_said_in_the_summary_and_exits_1(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(onnx_models, "export_checked", _slow_fake(0.0, ok=False))
    assert main(["export", "hadamard", "--out", str(tmp_path)]) == 1
    out = capsys.readouterr().out.strip()
    assert "DIFFERS from PyTorch at batch 3: x: max abs error 0.5" in out


def test_export_checked_really_exports_and_compares_at_batch_3(tmp_path):
    res = onnx_models.export_checked("bp", n=8, sr=0.5, path=tmp_path / "bp.onnx", n_iter=3)
    assert res["path"] == tmp_path / "bp.onnx"
    assert res["bytes"] == (tmp_path / "bp.onnx").stat().st_size > 0
    assert res["parity"]["ok"]
    assert [o["shape"][0] for o in res["parity"]["outputs"]] == [3]
    assert res["parity"]["outputs"][0]["max_abs_err"] < 1e-4


def test_export_checked_reports_an_out_of_tolerance_output(tmp_path, monkeypatch):
    import torchtof.onnx

    def off(path, module, inputs, rtol, atol):
        assert inputs[0].shape[0] == 3
        raise AssertionError("check: x differs: max abs error 0.5\nmore detail")

    monkeypatch.setattr(torchtof.onnx, "check", off)
    res = onnx_models.export_checked("bp", n=8, sr=0.5, path=tmp_path / "bp.onnx", n_iter=3)
    assert res["parity"] == {"ok": False, "error": "check: x differs: max abs error 0.5"}


def test_export_checked_names_an_unknown_model():
    with pytest.raises(ValueError, match="export_checked: expected name in"):
        onnx_models.export_checked("nope")


def test_bench_onnx_models_are_checked_up_front(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["bench", "onnx", "--models", "g2,nope"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "argument --models" in err[0] and "'g2,nope'" in err[0], err


def test_bench_onnx_passes_models_and_no_compile(monkeypatch, tmp_path, capsys):
    import torchtof.apps.bench.onnx as bench

    seen = {}

    def fake(models=None, compile=True, progress=False):
        seen.update(models=models, compile=compile)
        return {"benchmark": "onnx", "rows": []}

    monkeypatch.setattr(bench, "bench_onnx", fake)
    monkeypatch.setattr(bench, "print_onnx", lambda res: None)
    assert main(["bench", "onnx", "--models", "G2,bp", "--no-compile", "--out",
                 str(tmp_path)]) == 0
    assert seen == {"models": ["g2", "bp"], "compile": False}
    saved = __import__("json").loads((tmp_path / "bench_onnx.json").read_text())
    assert saved["machine"]["start"]["cpus"] >= 1


@pytest.mark.slow
@pytest.mark.skipif(not hasattr(__import__("os"), "openpty"), reason="needs a pseudo-terminal")
def test_a_real_terminal_gets_the_bar_and_a_pipe_the_summary(tmp_path):
    """End to end: stderr on a pseudo-terminal 100 columns wide, stdout a pipe."""
    import fcntl
    import os
    import struct
    import subprocess
    import sys
    import termios

    master, slave = os.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 100, 0, 0))
    proc = subprocess.Popen([sys.executable, "-m", "torchtof.cli", "export", "unrolled_tval3",
                             "--out", str(tmp_path)], stdout=subprocess.PIPE, stderr=slave)
    os.close(slave)
    seen = b""
    while True:
        try:
            chunk = os.read(master, 4096)
        except OSError:  # the terminal closed with the process
            break
        if not chunk:
            break
        seen += chunk
    out = proc.stdout.read().decode()
    assert proc.wait() == 0
    frames = [f for f in seen.decode().split("\r") if f.strip()]
    assert frames and all(f.startswith("torchtof export: tracing unrolled_tval3") for f in frames)
    assert "00:0" in frames[-1]
    assert out.count("\n") == 1 and "onnxruntime matches PyTorch at batch 3" in out


def test_export_learned_with_a_trained_weights_file(tmp_path, capsys):
    """``--weights`` exports that file's network: onnxruntime gives what ``Learned(A,
    pretrained=file)`` gives on new buckets, which differs from the shipped network's."""
    import numpy as np
    import onnxruntime as ort
    import torch

    from torchtof.operators import Hadamard
    from torchtof.recon.learned import Learned
    from torchtof.recon.learned_train import train_learned

    train_learned(steps=1, batch_size=2, sizes=(16,), n_layers=2, width=4, progress=False,
                  calibrate=False, out=tmp_path / "run")
    w = tmp_path / "run" / "learned.pt"
    onnx_file = tmp_path / "mine.onnx"
    assert main(["export", "learned", "--n", "16", "--sr", "0.25", "--weights", str(w),
                 "--no-progress", "-o", str(onnx_file)]) == 0
    out = capsys.readouterr().out
    assert f"learned from {w} (n=16" in out and "matches PyTorch at batch 3" in out
    A = Hadamard(16, sr=0.25)
    y = A(torch.rand(2, 1, 16, 16, generator=torch.Generator().manual_seed(3)))
    with torch.no_grad():
        mine, shipped = Learned(A, pretrained=w)(y), Learned(A)(y)
    sess = ort.InferenceSession(str(onnx_file), providers=["CPUExecutionProvider"])
    got = sess.run(None, {"y": y.numpy()})[0]
    np.testing.assert_allclose(got, mine.numpy(), atol=1e-4)
    assert float((mine - shipped).abs().max()) > 1e-2  # the file, not the shipped weights
    with pytest.raises(ValueError, match="weights"):
        onnx_models.export_model("bp", n=8, sr=0.5, path=tmp_path / "x.onnx", weights=w)


@pytest.mark.parametrize(("argv", "msg"), [
    (["export", "bp", "--weights", "{w}"], "only the learned model loads a weights file"),
    (["export", "learned", "--weights", "{missing}"], "no such weights file"),
    (["export", "learned", "--weights", "{w}"], "is not a learned weights file"),  # b"x"
])
def test_export_weights_mistakes_are_usage_errors(tmp_path, capsys, argv, msg):
    (tmp_path / "w.pt").write_bytes(b"x")
    argv = [a.format(w=tmp_path / "w.pt", missing=tmp_path / "none.pt") for a in argv]
    with pytest.raises(SystemExit) as exc:
        main([*argv, "--out", str(tmp_path / "o")])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "argument --weights:" in err and msg in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()
