"""Whole view stacks (one flow for all views), the sliding window, and the CLI."""

import numpy as np
import pytest
from motion_helpers import ORDER, REF, psnr, scene
from typer.testing import CliRunner

from metasensor.io.views import read_views, write_views
from metasensor.motion import correct_motion, correct_motion_views
from metasensor.motion.synthetic import dynamic_view, rigid_motion

SHAPE = (150, 150)
INNER = np.zeros(SHAPE, bool)
INNER[12:-12, 12:-12] = True


def _stack(vel, nnum=3):
    """nnum² views of the same moving scene, each view with its own brightness and parallax-free
    content (object motion is shared by all views); view (1, 1) is the centre."""
    sc = scene(0)[:SHAPE[0] * 2, :SHAPE[1] * 2]
    view, truth = dynamic_view(sc, 2, SHAPE, ORDER, rigid_motion(vel, REF))
    gains = np.linspace(0.6, 1.0, nnum * nnum).reshape(nnum, nnum)
    return (gains[..., None, None] * view).astype(np.float32), gains[..., None, None] * truth


def test_views_one_flow_for_all():
    views, truth = _stack((1.0, 0.6))
    views[0, 0] = 0.0  # a dark view (outside the coded aperture) stays dark
    out = correct_motion_views(views, ORDER, progress=False)
    assert out.shape == views.shape and out.dtype == np.float32
    assert not out[0, 0].any()
    for u, v in [(1, 1), (2, 0), (0, 2)]:
        gain = psnr(out[u, v], truth[u, v], INNER) - psnr(views[u, v], truth[u, v], INNER)
        assert gain >= 6.0, (u, v, gain)
    # the centre view of the stack equals correct_motion on that view alone
    np.testing.assert_allclose(out[1, 1], correct_motion(views[1, 1], ORDER), atol=1e-6)


def test_views_sharpest_flow_view_and_bad_mode():
    views, _ = _stack((0.0, 0.0))
    out = correct_motion_views(views, ORDER, flow_view="sharpest", progress=False)
    np.testing.assert_array_equal(out, views)  # static: unchanged
    with pytest.raises(ValueError, match="mode"):
        correct_motion_views(views, ORDER, mode="wobble", progress=False)
    with pytest.raises(ValueError, match="views"):
        correct_motion_views(views[0], ORDER, progress=False)


def test_sliding_window_static_sequence_equals_realign():
    """A static scene: every window's corrected stack is the plain realignment."""
    from metasensor.config import SystemConfig
    from metasensor.motion import correct_motion_sequence
    from metasensor.sensor.realign import realign, unrealign

    cfg = SystemConfig()
    rng = np.random.default_rng(0)
    views = rng.random((cfg.nnum, cfg.nnum, 60, 60)).astype(np.float32)
    frames = unrealign(views, cfg)
    seq = np.concatenate([frames, frames[:3]])  # 28 frames: windows at t = 12 .. 15
    got = list(correct_motion_sequence(seq, cfg, times=[12, 14], progress=False,
                                       threshold=1e9))
    assert [t for t, _ in got] == [12, 14]
    for t, v in got:
        idx = list(range(t - 12, t + 13))
        order = [ORDER[i % 25] for i in idx]
        np.testing.assert_array_equal(v, realign(seq[idx], cfg, scan_order=order))
    with pytest.raises(ValueError, match="window"):
        list(correct_motion_sequence(seq, cfg, times=[3]))


def test_cli_motion(tmp_path):
    import typer

    from metasensor.motion.commands import register

    app = typer.Typer()

    @app.callback()
    def _group() -> None:  # keep "motion" a sub-command even when it is the only one
        pass

    register(app)
    views, truth = _stack((1.0, 0.6))
    src = write_views(tmp_path / "views.tif", views)
    before = src.read_bytes()
    res = CliRunner().invoke(app, ["motion", str(src), "--scan-order", "row-major",
                                   "--out", str(tmp_path / "corrected.tif")])
    # a stack without a configuration: a preset name cannot tell the scan period
    assert res.exit_code != 0 and "--period" in str(res.exception)
    assert not (tmp_path / "corrected.tif").exists()
    res = CliRunner().invoke(app, ["motion", str(src), "--scan-order", "row-major",
                                   "--period", "5", "--out", str(tmp_path / "corrected.tif")])
    assert res.exit_code == 0, res.output
    assert src.read_bytes() == before  # input untouched
    out = read_views(tmp_path / "corrected.tif")
    assert out.shape == views.shape
    assert (tmp_path / "corrected.png").stat().st_size > 1000  # before / after / difference
    assert psnr(out[1, 1], truth[1, 1], INNER) > psnr(views[1, 1], truth[1, 1], INNER) + 6
    res = CliRunner().invoke(app, ["motion", str(src), "--scan-order", "row-major",
                                   "--period", "5", "--no-fallback",
                                   "--out", str(tmp_path / "plain.tif")])
    assert res.exit_code == 0, res.output
    plain = correct_motion_views(views, ORDER, progress=False, fallback=False)
    np.testing.assert_allclose(read_views(tmp_path / "plain.tif"), plain, atol=1e-6)
    res = CliRunner().invoke(app, ["motion", "--help"])
    assert "Example" in res.output and "--no-fallback" in res.output
    res = CliRunner().invoke(app, ["motion", str(src), "--scan-order", "[(0,0),(0,1)]",
                                   "--out", str(tmp_path / "x.tif")])
    assert res.exit_code != 0 and "scan" in str(res.exception)


def test_parse_scan_order():
    from metasensor.motion.commands import parse_scan_order

    assert parse_scan_order("serpentine", 0)[5] == (1, 4)
    nine = str([(r, c) for r in range(3) for c in range(3)])
    assert len(parse_scan_order(nine, 0)) == 9
    with pytest.raises(ValueError, match="scan"):
        parse_scan_order("[(0, 0), (0, 1)]", 0)
    with pytest.raises(ValueError, match="scan-order"):
        parse_scan_order("[(0, 0), oops]", 5)


def test_cli_motion_uses_and_keeps_the_stored_scan_order(tmp_path):
    # a serpentine capture: without --scan-order the stack's stored order is used (a row-major
    # guess would misplace its samples), and it is written on with the other stored extras
    import typer

    from metasensor.io.views import stored_extras
    from metasensor.motion.commands import register
    from metasensor.sensor.scan import scan_order

    app = typer.Typer()

    @app.callback()
    def _group() -> None:
        pass

    register(app)
    serp = scan_order(5, "serpentine")
    sc = scene(0)[:SHAPE[0] * 2, :SHAPE[1] * 2]
    view, truth = dynamic_view(sc, 2, SHAPE, serp, rigid_motion((1.0, 0.6), REF))
    views = np.broadcast_to(view, (3, 3, *SHAPE)).astype(np.float32)
    src = write_views(tmp_path / "views.tif", views,
                      extra={"scan_order": [list(p) for p in serp], "scale": 2.0})
    res = CliRunner().invoke(app, ["motion", str(src), "--out", str(tmp_path / "c.tif")])
    assert res.exit_code == 0, res.output
    extras = stored_extras(tmp_path / "c.tif")
    assert [tuple(p) for p in extras["scan_order"]] == serp and extras["scale"] == 2.0
    out = read_views(tmp_path / "c.tif")
    expected = correct_motion(views[1, 1], serp)
    np.testing.assert_array_equal(out[1, 1], expected)
    assert psnr(out[1, 1], truth, INNER) > psnr(views[1, 1], truth, INNER) + 6
