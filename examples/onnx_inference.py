"""Deploy a reconstructor without PyTorch: buckets (.npy) → image, numpy + onnxruntime only.

On the machine that has torchtof, export a reconstructor and save buckets::

    torchtof export g2 --n 32 --sr 0.25 -o g2.onnx          # or unrolled_tval3, tgi, bp ...
    python -c "import numpy as np; np.save('buckets.npy', my_buckets)"  # (B, C, M) float32

then, where only numpy and onnxruntime are installed::

    python examples/onnx_inference.py g2.onnx buckets.npy --out image.npy

The model's input and output names and shapes are read from the file (``export/README.md``
lists them); a bucket vector of shape ``(M,)`` or ``(C, M)`` is given the batch and channel
axes. The script never imports torch, and asserts so at the end.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import onnxruntime as ort


def reconstruct(model: str, buckets: np.ndarray) -> tuple[dict[str, np.ndarray], float]:
    """Run the ONNX reconstructor on ``buckets``; returns ``({output name: array}, seconds)``
    with every output of the graph, in its order (``depth_resolved``: depth and amplitude;
    ``camera``: phase, amplitude and depth)."""
    y = np.asarray(buckets, dtype=np.float32)
    while y.ndim < 3:  # (M,) or (C, M) -> (1, C, M)
        y = y[None]
    sess = ort.InferenceSession(model, providers=["CPUExecutionProvider"])
    inp = sess.get_inputs()[0]
    if inp.shape[-1] != y.shape[-1]:
        raise ValueError(f"{model} expects {inp.shape[-1]} measurements, got {y.shape[-1]}")
    t0 = time.perf_counter()
    outs = sess.run(None, {inp.name: y})
    seconds = time.perf_counter() - t0
    return {o.name: v for o, v in zip(sess.get_outputs(), outs)}, seconds


def preview(img: np.ndarray, width: int = 32) -> str:
    """Coarse text rendering of one ``(H, W)`` image (dark to bright)."""
    ramp = " .:-=+*#%@"
    step = max(1, img.shape[1] // width)
    small = img[::step, ::step]
    lo, hi = float(small.min()), float(small.max())
    idx = (
        np.zeros(small.shape, dtype=int)
        if hi <= lo
        else ((small - lo) / (hi - lo) * (len(ramp) - 1)).round().astype(int)
    )
    return "\n".join("".join(ramp[i] * 2 for i in row) for row in idx)


def main(argv: list[str] | None = None) -> np.ndarray:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("model", help=".onnx file written by `torchtof export`")
    p.add_argument("buckets", help=".npy file of buckets (B, C, M), (C, M) or (M,)")
    p.add_argument("--out", default=None,
                   help="save the first output (B, C, n, n) to this .npy; a graph with more "
                   "outputs saves each other one beside it as STEM_NAME.npy")
    p.add_argument("--quiet", action="store_true", help="no text preview")
    args = p.parse_args(argv)
    for flag, path, ext in (("model", args.model, ".onnx"), ("buckets", args.buckets, ".npy")):
        if not Path(path).is_file():
            p.error(f"argument {flag}: no such {ext} file: {path}")
    try:
        y = np.load(args.buckets)
        outs, seconds = reconstruct(args.model, y)
    except ValueError as exc:  # wrong bucket count, not a .npy
        p.error(str(exc))
    except ort.capi.onnxruntime_pybind11_state.Fail as exc:  # not an ONNX file
        p.error(f"argument model: onnxruntime cannot load {args.model}: {exc}")
    names = list(outs)
    x = outs[names[0]]
    shapes = ", ".join(f"{k} {v.shape}" for k, v in outs.items())
    print(f"{args.model}: {x.shape} image(s) in {seconds * 1e3:.2f} ms, "
          f"range [{x.min():.4g}, {x.max():.4g}]" + (f" (outputs: {shapes})"
                                                      if len(names) > 1 else ""))
    if not args.quiet:
        print(preview(x[0, 0]))
    if args.out:
        out = Path(args.out)
        np.save(out, x)
        written = [str(out)]
        for k in names[1:]:  # every other output beside it, by name
            other = out.with_name(f"{out.stem}_{k}.npy")
            np.save(other, outs[k])
            written.append(str(other))
        if len(written) > 1:
            print("wrote " + ", ".join(written))
    assert "torch" not in sys.modules, "onnx_inference.py must run without torch"
    return x


if __name__ == "__main__":
    main()
