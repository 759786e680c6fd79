"""Tables and figures of the command-line tools: aligned text tables and labelled image grids.

Used by the CLI, the demos, ``torchtof reproduce``, the benchmarks and the hardware
commands; it imports nothing from them (the library proper never imports it).
"""

from __future__ import annotations

import sys
from pathlib import Path

import torch

__all__ = ["print_table", "print_method_rows", "save_grid"]


def print_table(rows: list[dict], cols: list[str], floatfmt: str = "{:.3g}") -> None:
    """Print ``rows`` as an aligned text table with the given column order.

    Floats are formatted with ``floatfmt``, anything else with ``str``; a missing key prints
    an empty cell.

    Example:
        >>> print_table([{"a": 1, "b": 0.5}, {"a": 22}], ["a", "b"])
         a    b
        --  ---
         1  0.5
        22
    """
    cells = [list(cols)] + [
        [floatfmt.format(r[c]) if isinstance(r.get(c), float) else str(r.get(c, "")) for c in cols]
        for r in rows
    ]
    widths = [max(len(row[i]) for row in cells) for i in range(len(cols))]
    for k, row in enumerate(cells):
        print("  ".join(v.rjust(w) for v, w in zip(row, widths)).rstrip())
        if k == 0:
            print("  ".join("-" * w for w in widths))


_BUCKETS = {"raw": "raw ToF map", "depth": "depth", "depth_gated": "depth, 3 m gate",
            "taps": "taps I/Q"}


def print_method_rows(rows: list[dict]) -> None:
    """Print the rows of :func:`torchtof.methods.evaluate` (method, gate, PSNR ± std, SSIM,
    time) as a table; ``psnr_std`` is shown only when more than one realisation was run."""
    table = []
    for r in rows:
        std = r.get("psnr_std")
        table.append({
            "method": r["method"],
            "buckets": _BUCKETS.get(r.get("buckets"), "depth, 3 m gate" if r.get("gate")
                                    else "depth"),
            "PSNR dB": f"{r['psnr']:.2f}" + (f" ± {std:.2f}" if std else ""),
            "SSIM": f"{r['ssim']:.3f}",
            "time s": f"{r['time_s']:.3f}" if r.get("time_s") is not None else "-",
        })
    print_table(table, ["method", "buckets", "PSNR dB", "SSIM", "time s"])


def pyplot():
    """``matplotlib.pyplot`` on the Agg backend, or ``None`` without the ``plot`` extra (the
    callers then write a plain montage or skip a curve plot, saying so)."""
    try:
        import matplotlib
    except ImportError:
        return None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def no_plot(what: str) -> None:
    """Say on stderr that ``what`` was not drawn for want of matplotlib."""
    print(f"(no matplotlib: {what} not drawn; pip install 'torchtof[plot]' for it)",
          file=sys.stderr)


def save_montage(path: Path, grid: list[list[torch.Tensor]]) -> Path:
    """A plain grey PNG of ``grid`` (rows of ``(H, W)`` images in ``[0, 1]``, same sizes),
    without matplotlib."""
    import numpy as np
    from skimage.io import imsave

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    img = np.concatenate([np.concatenate([t.float().clamp(0, 1).numpy() for t in row], axis=1)
                          for row in grid])
    imsave(str(path), (img * 255).round().astype("uint8"), check_contrast=False)
    return path


def save_grid(path: Path, columns: list[tuple[str, torch.Tensor]], rows: list[str] | None = None,
              title: str = "") -> Path:
    """Save images as a labelled grid PNG (matplotlib; a plain montage without it).

    Each image is min-max normalised (:func:`torchtof.metrics.normalize_image`) for display.

    Args:
        path: the PNG to write (parent folders are created).
        columns: ``(label, tensor (R, 1, H, W))``; each tensor's first ``len(rows)`` images
            fill the rows (row ``r`` uses image ``r`` or the last one).
        rows: row labels (default one unlabelled row).
        title: figure title.

    Returns:
        ``path``.
    """
    from .metrics import normalize_image

    path = Path(path)
    rows = rows or [""]
    imgs = [[normalize_image(t[min(r, t.shape[0] - 1) : min(r, t.shape[0] - 1) + 1].float())[0, 0]
             for r in range(len(rows))] for _, t in columns]
    path.parent.mkdir(parents=True, exist_ok=True)
    plt = pyplot()
    if plt is None:  # the plot extra is not installed: a plain montage
        return save_montage(path, [[c[r] for c in imgs] for r in range(len(rows))])
    fig, axes = plt.subplots(len(rows), len(columns),
                             figsize=(1.6 * len(columns), 1.75 * len(rows)), squeeze=False)
    for c, (label, _) in enumerate(columns):
        for r in range(len(rows)):
            ax = axes[r][c]
            ax.imshow(imgs[c][r].numpy(), cmap="gray", vmin=0, vmax=1)
            ax.set_xticks([])
            ax.set_yticks([])
            if r == 0:
                ax.set_title(label, fontsize=8)
            if c == 0 and rows[r]:
                ax.set_ylabel(rows[r], fontsize=8)
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)
    return path


def save_image(path: Path, img: torch.Tensor, title: str, polarity: str = "positive",
               score: dict | None = None) -> Path:
    """One reconstruction as a legible PNG: min-max normalised, a negative image (ungated
    depth buckets, paper §3.1) flipped by the physics rule the scoring uses and said so, a
    grey-level colour bar, the title wrapped to the figure, PSNR/SSIM when known.

    Args:
        path: the PNG to write (parent folders are created).
        img: ``(B, 1, H, W)``; the first image is shown.
        title: what it is (wrapped to the figure width).
        polarity: ``"positive"`` or ``"negative"`` (physics polarity of the buckets).
        score: optional ``{"psnr": dB, "ssim": float}``.

    Returns:
        ``path``.
    """
    import textwrap

    from .metrics import normalize_image

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    show = normalize_image(img[:1].detach().float())[0, 0]
    note = "min-max normalised"
    if polarity == "negative":
        show = 1.0 - show
        note += "; negative image (dark pixels read 5 m) shown flipped"
    if score is not None:
        note += f"\nPSNR {score['psnr']:.2f} dB, SSIM {score['ssim']:.3f} vs the simulated object"
    plt = pyplot()
    if plt is None:  # the plot extra is not installed: the image alone
        return save_montage(path, [[show]])

    fig, ax = plt.subplots(figsize=(5.0, 5.4))
    im = ax.imshow(show.numpy(), cmap="gray", vmin=0, vmax=1, interpolation="nearest")
    cb = fig.colorbar(im, ax=ax, fraction=0.046, pad=0.03)
    cb.set_label("normalised reflectance (0 = dark, 1 = object)", fontsize=7)
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_title("\n".join(textwrap.wrap(title, 48)), fontsize=9)
    ax.set_xlabel(note, fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)
    return path
