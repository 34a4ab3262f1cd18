"""Any scan geometry: an image scanned over a fixed MLA with a period that does not divide nnum
(13-px lenslets, 3 x 3 scan), scan orders (presets, one-based lists, scan-pattern PNGs) and the
reconstruction grid of such a scan. References: interface.md (realign is pure indexing for
moving="image") and the authors' scan-pattern format (pixel (r, c) = acquisition index)."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

import metasensor as ms
from metasensor.cli import app
from metasensor.config import ConfigError, SystemConfig
from metasensor.io.raw import write_raw
from metasensor.io.views import read_views
from metasensor.sensor.realign import unrealign
from metasensor.sensor.scan import from_one_based, read_order_png, scan_order, write_order_png

# the 3 x 3 order of a scanning light-field microscope, one-based (issue text)
ROWS1 = [3, 2, 1, 1, 1, 2, 3, 3, 2]
COLS1 = [1, 1, 1, 2, 3, 3, 3, 2, 2]
runner = CliRunner()


def cfg13(**kw) -> SystemConfig:
    return SystemConfig(nnum=13, scan=3, moving="image", **kw)


def test_config_carries_what_moves():
    with pytest.raises(ConfigError, match="does not divide nnum 13.*moving"):
        SystemConfig(nnum=13, scan=3)
    with pytest.raises(ConfigError, match="moving must be"):
        SystemConfig(moving="sensor")
    cfg = cfg13()
    assert SystemConfig.from_toml_string(cfg.to_toml_string()) == cfg
    assert SystemConfig().moving == "mla"
    # reconstruction grid: the view step 13/3 px split into d = 5 grid px (odd scan·d >= nnum)
    assert (cfg.scan_step_px, cfg.grid_points) == (5, 15)
    assert cfg.grid_pitch == pytest.approx(cfg.mla_pitch / 15)
    proto = SystemConfig()
    assert (proto.scan_step_px, proto.grid_points, proto.grid_pitch) == (3, 15, proto.pixel_pitch)


def test_realign_image_scan_is_pure_indexing():
    cfg = cfg13()
    order = from_one_based(ROWS1, COLS1)
    rng = np.random.default_rng(1)
    frames = rng.integers(0, 4096, (9, 3 * 13 + 5, 4 * 13 + 2)).astype(np.uint16)
    views = ms.realign(frames, cfg, order)  # moving from the configuration
    assert views.shape == (13, 13, 9, 12)
    assert np.array_equal(views, ms.realign(frames, cfg, order, moving="image"))
    for t, (r, c) in enumerate(order):
        for ly in range(3):
            for lx in range(4):
                block = frames[t, ly * 13:(ly + 1) * 13, lx * 13:(lx + 1) * 13]
                assert np.array_equal(views[:, :, ly * 3 + r, lx * 3 + c], block)
    back = unrealign(views, cfg, order, frame_shape=frames.shape[1:])
    assert np.array_equal(back[:, :39, :52], frames[:, :39, :52].astype(np.float32))
    with pytest.raises(ValueError, match="does not divide nnum 13"):
        ms.realign(frames, cfg, order, moving="mla")


def test_scan_order_presets_and_one_based_lists():
    order = from_one_based(ROWS1, COLS1)
    assert order[0] == (2, 0) and order[-1] == (1, 1)
    assert scan_order(3, "spiral") == order
    spiral5 = scan_order(5, "spiral")
    assert sorted(spiral5) == scan_order(5) and spiral5[0] == (4, 0) and spiral5[-1] == (2, 2)
    with pytest.raises(ValueError, match="below 1"):
        from_one_based([0, 1], [1, 1])


def _pattern(order, n):
    img = np.zeros((n, n), np.uint16)
    for k, (r, c) in enumerate(order):
        img[r, c] = k
    return img


def test_scan_pattern_png(tmp_path):
    order = scan_order(5, "spiral")
    img = _pattern(order, 5)
    assert img[4, 0] == 0  # frame 0 at the bottom-left, as in the authors' 5x5.conf.sk.png
    Image.fromarray(img).save(tmp_path / "5x5.conf.sk.png")
    assert Image.open(tmp_path / "5x5.conf.sk.png").mode.startswith("I;16")
    assert read_order_png(tmp_path / "5x5.conf.sk.png") == order
    # the rot180 variant: frame 0 at the top-right, read by the same rule
    Image.fromarray(img[::-1, ::-1].copy()).save(tmp_path / "5x5.conf.sk.rot180.png")
    assert read_order_png(tmp_path / "5x5.conf.sk.rot180.png") == [(4 - r, 4 - c)
                                                                  for r, c in order]
    write_order_png(tmp_path / "w.png", order)
    assert read_order_png(tmp_path / "w.png") == order
    bad = img.copy()
    bad[0, 0] = bad[0, 1]
    Image.fromarray(bad).save(tmp_path / "bad.png")
    with pytest.raises(ValueError, match="each acquisition index"):
        read_order_png(tmp_path / "bad.png")


def test_realign_cli_png_order_equals_explicit_order(tmp_path):
    cfg = cfg13()
    cfg.to_toml(tmp_path / "cfg.toml")
    order = scan_order(3, "spiral")
    rng = np.random.default_rng(2)
    frames = rng.integers(0, 4000, (9, 52, 65)).astype(np.uint16)
    write_raw(tmp_path / "raw.tif", frames)
    Image.fromarray(_pattern(order, 3)).save(tmp_path / "3x3.conf.sk.png")
    one_based = ";".join(f"{r},{c}" for r, c in zip(ROWS1, COLS1, strict=True))
    outs = {}
    for name, arg in (("png", tmp_path / "3x3.conf.sk.png"), ("one", f"one-based:{one_based}"),
                      ("zero", ";".join(f"{r},{c}" for r, c in order)), ("preset", "spiral")):
        out = tmp_path / f"{name}.tif"
        res = runner.invoke(app, ["realign", str(tmp_path / "raw.tif"), "--config",
                                  str(tmp_path / "cfg.toml"), "--order", str(arg), "--out",
                                  str(out)])
        assert res.exit_code == 0, res.output
        outs[name] = read_views(out)
    expect = ms.realign(frames, cfg, order)
    for name, views in outs.items():
        assert np.array_equal(views, expect), name


def test_grid_bank_on_a_commensurate_grid_equals_the_pixel_bank():
    """points = nnum is the pixel grid: the same bank (integer-step path)."""
    from metasensor.optics.psf import view_psfs

    cfg = SystemConfig(nnum=7, mla_pitch=32.2e-6, mla_focal=322e-6, scan=7)
    a = view_psfs(cfg, size=15, cache=False, device="cpu")
    b = view_psfs(cfg, size=15, points=7, cache=False, device="cpu")
    assert np.array_equal(a, b)


def test_grid_bank_of_a_non_dividing_scan_keeps_the_light():
    """The bank on the 15-per-lenslet grid of a 13-px lenslet (Fourier-shifted points) holds
    the same light as the pixel-grid bank (sum over a lenslet's point positions, normalised
    per sensor-pixel flux): within 0.5 %; its centre view peaks at zero displacement."""
    from metasensor.optics.psf import view_psfs

    cfg = SystemConfig(nnum=7, mla_pitch=32.2e-6, mla_focal=322e-6, scan=3, moving="image")
    assert cfg.grid_points == 9
    a = view_psfs(cfg, size=15, cache=False, device="cpu")
    b = view_psfs(cfg, size=19, points=9, cache=False, device="cpu")
    assert b.shape == (7, 7, 19, 19)
    assert b.sum() == pytest.approx(a.sum(), rel=5e-3)
    c = b[3, 3]
    assert np.unravel_index(np.argmax(c), c.shape) == (9, 9)
    with pytest.raises(ValueError, match="points must be an odd"):
        view_psfs(cfg, points=8, cache=False)
