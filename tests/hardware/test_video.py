"""The projector window (pygame, headless through SDL's dummy video driver) and the
placement of the bit-plane frame on the DMD."""

import numpy as np
import pytest

from torchtof.hardware.dlpc350 import pack_bitplanes, unpack_bitplane
from torchtof.hardware.errors import HardwareError
from torchtof.hardware.video import DMD_SHAPE, embed_patterns


def test_embed_patterns_known_answer():
    f = np.zeros((2, 3, 3), dtype=np.uint8)
    f[0, 1] = (1, 2, 3)
    out = embed_patterns(f, (10, 9), scale=2, row_scale=2)  # blocks of 2 columns x 4 rows
    assert out.shape == (10, 9, 3)
    # the 8x6 block image is centred: rows 1-8, columns 1-6
    want = np.zeros((10, 9, 3), dtype=np.uint8)
    want[1:5, 3:5] = (1, 2, 3)
    np.testing.assert_array_equal(out, want)
    with pytest.raises(ValueError, match=r"scale in \[1, 2\]"):
        embed_patterns(f, (10, 9), scale=3)
    with pytest.raises(ValueError, match="uint8"):
        embed_patterns(f.astype(np.float32), (10, 9))


def test_embedded_bit_planes_keep_every_pattern():
    pats = np.random.default_rng(0).integers(0, 2, size=(24, 32, 32)).astype(np.uint8)
    out = embed_patterns(pack_bitplanes(pats))
    s = min(DMD_SHAPE[1] // 32, DMD_SHAPE[0] // 64)  # 17 columns x 34 rows per pixel
    r0, c0 = (DMD_SHAPE[0] - 64 * s) // 2, (DMD_SHAPE[1] - 32 * s) // 2
    for k in (0, 9, 23):
        plane = unpack_bitplane(out, k)
        np.testing.assert_array_equal(plane[r0:r0 + 64 * s:2 * s, c0:c0 + 32 * s:s], pats[k])
        assert plane.sum() == pats[k].sum() * 2 * s * s


@pytest.fixture
def pygame(monkeypatch):
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")  # headless: a 1024x768 dummy display
    pg = pytest.importorskip("pygame")
    yield pg
    pg.display.quit()


def test_window_refuses_a_display_of_another_size(pygame):
    from torchtof.hardware.video import WindowVideoPort

    with pytest.raises(HardwareError, match="runs at 1024x768, the DMD needs 912x1140"):
        WindowVideoPort(display=0)
    with pytest.raises(HardwareError, match="no display 3"):
        WindowVideoPort(display=3)


def test_window_shows_the_frame_pixel_for_pixel(pygame):
    from torchtof.hardware.video import WindowVideoPort

    port = WindowVideoPort(display=0, shape=(768, 1024))
    frame = np.random.default_rng(1).integers(0, 256, size=(768, 1024, 3)).astype(np.uint8)
    port.show(frame)
    shown = pygame.surfarray.array3d(pygame.display.get_surface()).swapaxes(0, 1)
    np.testing.assert_array_equal(shown, frame)
    with pytest.raises(ValueError, match=r"\(768, 1024, 3\) uint8"):
        port.show(frame[..., :2])
    port.close()
