"""Shared figure helpers: PNGs written atomically, readable, bad input rejected."""

import numpy as np
import pytest

from metasensor.io.figures import save_image, save_lines, save_panel

PNG = b"\x89PNG\r\n\x1a\n"


def check_png(path):
    import matplotlib.image as mpimg

    assert path.read_bytes()[:8] == PNG
    assert mpimg.imread(path).ndim == 3
    assert not [p for p in path.parent.iterdir() if p.name.startswith(".")]  # no temporaries


def test_save_image_panel_lines(tmp_path):
    img = np.random.default_rng(0).random((40, 60)).astype(np.float32)
    before = img.copy()
    check_png(save_image(tmp_path / "a.png", img, title="noise", colorbar=True))
    check_png(save_panel(tmp_path / "b.png", [("x", img), ("y", img * 2)],
                         boxes=[(5, 15, 5, 25)], suptitle="s"))
    check_png(save_panel(tmp_path / "c.png", {"x": img, "y": img, "z": img}, ncols=2,
                         shared_range=False))
    f = np.linspace(0, 1, 20)
    check_png(save_lines(tmp_path / "sub" / "d.png", [("a", f, 1 - f), ("b", f, f**2)],
                         xlabel="f", ylabel="m", hlines=(0.5,), ylim=(0, 1)))
    np.testing.assert_array_equal(img, before)


def test_bad_input(tmp_path):
    with pytest.raises(ValueError, match="2-D"):
        save_image(tmp_path / "a.png", np.zeros((2, 3, 4)))
    with pytest.raises(ValueError, match="empty"):
        save_panel(tmp_path / "b.png", [])
    with pytest.raises(ValueError, match="equal length"):
        save_lines(tmp_path / "c.png", [("a", np.arange(3), np.arange(4))])
    assert not list(tmp_path.iterdir())
