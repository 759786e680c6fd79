"""The LightCrafter's video input: a borderless window on the projector's display that shows
24-bit frames pixel for pixel (pygame, ``pip install 'torchtof[hardware]'``).

In video pattern mode the DLPC350 takes its bit planes from the frames on its HDMI input,
so the frame must reach the DMD unchanged: the host's output for the projector must run at
the DMD's native 912 × 1140 with no scaling, colour management or dithering, and the window
must cover it exactly. :class:`WindowVideoPort` refuses a display of another size, draws the
frame 1:1 and reads its own back buffer to check that what it drew is the frame (what the
graphics driver does after that cannot be checked from the host: see the README's list of
what only a device can confirm).

:func:`embed_patterns` places an ``n × n`` bit-plane frame on the DMD: each pattern pixel
becomes a block of ``scale`` columns × ``row_scale · scale`` rows, centred, the rest black.
``row_scale = 2`` assumes the LightCrafter 4500's diamond mirror array, whose rows are half a
column pitch apart (to be confirmed on a device).
"""

from __future__ import annotations

import os

import numpy as np

from .dlpc350 import DMD_SHAPE, VideoPort
from .errors import HardwareError

__all__ = ["DMD_SHAPE", "embed_patterns", "WindowVideoPort"]

# DMD_SHAPE: (rows, columns) of the LightCrafter 4500's DMD and of its native video mode, 1140 x
# 912: pattern display mode "Assumes a 1-bit through 8-bit image with a pixel resolution of
# 912 x 1140" (TI's DLPC350 API, dlpc350_api.cpp, documentation of DLPC350_SetMode); defined in
# .dlpc350, whose check_video_input compares the video signal with it.


def embed_patterns(frame: np.ndarray, shape: tuple[int, int] = DMD_SHAPE,
                   scale: int | None = None, row_scale: int = 2) -> np.ndarray:
    """An ``(H, W, 3)`` uint8 bit-plane frame (``dlpc350.pack_bitplanes``) enlarged by whole
    blocks and centred on a black ``shape`` frame.

    Args:
        frame: ``(h, w, 3)`` uint8.
        shape: ``(rows, columns)`` of the output (the DMD's native mode).
        scale: columns per pattern pixel (default: the largest that fits).
        row_scale: rows per column of a pattern pixel.

    Raises:
        ValueError: a frame that is not ``(h, w, 3)`` uint8, or does not fit.

    Example:
        >>> # largest scale that fits 8x6: 2 columns (4 rows) per pixel, centred
        >>> embed_patterns(np.ones((2, 2, 3), np.uint8), (8, 6), row_scale=2)[:, :, 0]
        array([[0, 1, 1, 1, 1, 0],
               [0, 1, 1, 1, 1, 0],
               [0, 1, 1, 1, 1, 0],
               [0, 1, 1, 1, 1, 0],
               [0, 1, 1, 1, 1, 0],
               [0, 1, 1, 1, 1, 0],
               [0, 1, 1, 1, 1, 0],
               [0, 1, 1, 1, 1, 0]], dtype=uint8)
    """
    f = np.asarray(frame)
    if f.ndim != 3 or f.shape[2] != 3 or f.dtype != np.uint8:
        raise ValueError(f"embed_patterns: expected an (h, w, 3) uint8 frame, got "
                         f"{f.shape} {f.dtype}")
    rows, cols = (int(v) for v in shape)
    h, w = f.shape[:2]
    if isinstance(row_scale, bool) or not isinstance(row_scale, int) or row_scale < 1:
        raise ValueError(f"embed_patterns: expected row_scale a positive int, got {row_scale!r}")
    fit = min(cols // w, rows // (row_scale * h))
    s = fit if scale is None else scale
    if isinstance(s, bool) or not isinstance(s, (int, np.integer)) or not 1 <= s <= fit:
        raise ValueError(f"embed_patterns: a {w}x{h} frame needs a scale in [1, {fit}] to fit "
                         f"{cols}x{rows} (row_scale {row_scale}), got {scale!r}")
    big = np.repeat(np.repeat(f, row_scale * s, axis=0), s, axis=1)
    out = np.zeros((rows, cols, 3), dtype=np.uint8)
    r0, c0 = (rows - big.shape[0]) // 2, (cols - big.shape[1]) // 2
    out[r0:r0 + big.shape[0], c0:c0 + big.shape[1]] = big
    return out


class WindowVideoPort(VideoPort):
    """A borderless full-screen window on display ``display`` (the projector's HDMI output)
    that shows each frame pixel for pixel (module docstring).

    Args:
        display: pygame display index of the projector's output.
        shape: ``(rows, columns)`` expected of that display and of every frame.
        settle_flips: buffer swaps after drawing a frame before :meth:`show` returns (with
            vsync, each swap waits for the next VSYNC, so the frame is on the output).
        embed: enlarge smaller bit-plane frames onto the DMD (:func:`embed_patterns`).

    Raises:
        ImportError: pygame is missing (``pip install 'torchtof[hardware]'``).
        HardwareError: no such display, or it does not run at ``shape``.
    """

    def __init__(self, display: int = 1, shape: tuple[int, int] = DMD_SHAPE,
                 settle_flips: int = 2, embed: bool = True) -> None:
        os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
        try:
            import pygame
        except ImportError as exc:
            raise ImportError("WindowVideoPort needs pygame: pip install 'torchtof[hardware]' "
                              "(or pip install pygame)") from exc
        self.pg, self.shape = pygame, (int(shape[0]), int(shape[1]))
        self.settle_flips, self.embed = int(settle_flips), bool(embed)
        pygame.display.init()
        sizes = pygame.display.get_desktop_sizes()
        if not 0 <= int(display) < len(sizes):
            raise HardwareError(f"WindowVideoPort: no display {display}; pygame sees "
                                f"{len(sizes)}: {sizes}. Connect the LightCrafter's HDMI input "
                                "and extend the desktop onto it")
        cols, rows = sizes[int(display)]
        if (rows, cols) != self.shape:
            raise HardwareError(
                f"WindowVideoPort: display {display} runs at {cols}x{rows}, the DMD needs "
                f"{self.shape[1]}x{self.shape[0]}: set that output to the projector's native "
                "mode with no scaling")
        flags = pygame.NOFRAME | pygame.FULLSCREEN
        try:
            self.screen = pygame.display.set_mode((cols, rows), flags, display=int(display),
                                                  vsync=1)
        except pygame.error:  # vsync needs a GL-backed renderer; not every driver has one
            self.screen = pygame.display.set_mode((cols, rows), flags, display=int(display))
        pygame.mouse.set_visible(False)

    def show(self, frame: np.ndarray) -> None:
        """Draw ``frame`` ``(rows, columns, 3)`` uint8 (or a smaller bit-plane frame, embedded),
        check the back buffer holds exactly it, and swap ``settle_flips`` times."""
        f = np.asarray(frame)
        if self.embed and f.ndim == 3 and f.shape[:2] != self.shape:
            f = embed_patterns(f, self.shape)
        if f.shape != (*self.shape, 3) or f.dtype != np.uint8:
            raise ValueError(f"WindowVideoPort.show: expected a {self.shape + (3,)} uint8 frame, "
                             f"got {f.shape} {f.dtype}")
        pg = self.pg
        pg.event.pump()
        pg.surfarray.blit_array(self.screen, np.ascontiguousarray(f.swapaxes(0, 1)))
        drawn = pg.surfarray.array3d(self.screen).swapaxes(0, 1)
        if not np.array_equal(drawn, f):
            raise HardwareError("WindowVideoPort: the window does not hold the frame pixel for "
                                "pixel (a colour depth below 24 bits?)")
        for _ in range(max(1, self.settle_flips)):
            pg.display.flip()

    def close(self) -> None:
        try:
            self.pg.display.quit()
        except Exception:  # noqa: BLE001 - already closed
            pass
