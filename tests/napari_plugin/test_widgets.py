"""The plugin's widgets on a tiny simulated capture: each runs its ``metasensor`` command in a
worker, shows the outputs as layers (shapes, axes, scales checked), writes what the CLI writes
on the same input (compared with the CLI run in-process from summary.json's replay line), and a
cancelled run leaves nothing behind."""

import json

import numpy as np
import tifffile
from plugin_helpers import CFG, P_UM
from typer.testing import CliRunner

from metasensor.cli import app
from metasensor.io.views import read_views, write_views
from metasensor.napari import panels

TIMEOUT_MS = 300_000  # the machine may be shared; a run takes 2-4 s of CPU


def _run(qtbot, widget, **values):
    widget.set(**values)
    widget.start()
    qtbot.waitUntil(lambda: widget.outcome is not None, timeout=TIMEOUT_MS)
    return widget.outcome


def _replay(result, out):
    """The CLI, in-process, on summary.json's recorded command line, writing to ``out``."""
    argv = json.loads((result.out / "summary.json").read_text())["replay"]["argv"]
    i = argv.index("--out")
    target = out / argv[i + 1].split("/")[-1] if argv[i + 1].endswith((".tif", ".toml")) else out
    res = CliRunner().invoke(app, argv[:i + 1] + [str(target)] + argv[i + 2:])
    assert res.exit_code == 0, res.output
    return target


def test_every_field_has_the_cli_help_as_tooltip(qtbot):
    from metasensor.napari.widgets import cli_params

    viewer = None  # the forms need no viewer until they show a result
    for factory in (panels.CalibrateWidget, panels.RealignWidget, panels.ReconstructWidget,
                    panels.MotionWidget, panels.DepthWidget, panels.EvaluateWidget):
        w = factory(viewer)
        helps = {p.name: p.help for p in cli_params(w.command)}
        assert w.fields, w.command
        for name, field in w.fields.items():
            assert field.tooltip == helps[name].strip(), (w.command, name)


def test_realign_and_reconstruct_widgets_match_the_cli(make_napari_viewer, qtbot, capture,
                                                       tmp_path):
    viewer = make_napari_viewer()
    realign = panels.RealignWidget(viewer)
    res = _run(qtbot, realign, raw_path=capture / "frames.tif", out=tmp_path / "realigned")
    assert res.status == "done", res.error
    views = read_views(tmp_path / "realigned" / "views.tif")
    np.testing.assert_array_equal(views, read_views(capture / "views.tif"))  # exact
    layer = viewer.layers["views"]
    assert layer.data.shape == (5, 5, 35, 35) and tuple(layer.axis_labels) == ("u", "v", "y", "x")
    np.testing.assert_allclose(layer.scale, (1, 1, P_UM, P_UM))
    cli_views = _replay(res, tmp_path / "cli_realign")
    np.testing.assert_array_equal(read_views(cli_views), views)

    rec = panels.ReconstructWidget(viewer)
    assert str(rec.fields["views"].value) == str(tmp_path / "realigned" / "views.tif")  # prefill
    res = _run(qtbot, rec, out=tmp_path / "result", blocks="2x2", overlap=6, solver="rl",
               iterations="2", zernike="4:0.3")
    assert res.status == "done", res.error
    image = tifffile.imread(tmp_path / "result" / "image.tif")
    kinds = {la.metadata["metasensor"]["kind"]: la for la in viewer.layers}
    np.testing.assert_array_equal(kinds["image"].data, image)
    assert image.shape == (35, 35)
    np.testing.assert_allclose(kinds["image"].scale, (P_UM, P_UM))
    wf = kinds["wavefront"]  # a 2 x 2 grid of pupil maps beside the image
    assert wf.metadata["metasensor"]["blocks"] == [2, 2]
    assert np.nanmax(wf.data) > 0.3  # 0.3 λ r.m.s. defocus peaks at sqrt(3) x 0.3 at the rim
    assert ".partial-" not in res.stdout + rec.status.value  # the final folder is named
    summary = json.loads((tmp_path / "result" / "summary.json").read_text())
    assert summary["blocks"] == [2, 2] and summary["replay"]["settings"]["blocks"] == "2x2"
    assert summary["replay"]["command"].startswith("metasensor reconstruct ")
    cli = _replay(res, tmp_path / "cli_result")
    np.testing.assert_array_equal(tifffile.imread(cli / "image.tif"), image)
    np.testing.assert_array_equal(np.load(cli / "zernike.npy"),
                                  np.load(tmp_path / "result" / "zernike.npy"))


def test_cancel_and_errors_leave_nothing(make_napari_viewer, qtbot, capture, tmp_path,
                                        monkeypatch):
    """A reconstruction cancelled mid-solve, and a command that fails: no output folder, no
    staging folder; the failure is one notification line (the CLI's error line)."""
    import napari.utils.notifications as notes

    shown = []
    monkeypatch.setattr(notes, "show_error", shown.append)
    viewer = make_napari_viewer()
    rec = panels.ReconstructWidget(viewer)
    rec.set(views=capture / "views.tif", out=tmp_path / "result", blocks="2x2", overlap=6)
    progress = []
    rec.start()
    rec.worker.yielded.connect(lambda p: progress.append(p) if p is not None else None)
    qtbot.waitUntil(lambda: any(p.n >= 1 for p in progress), timeout=TIMEOUT_MS)
    rec.cancel()  # mid-solve: the HQS of the first block is running
    qtbot.waitUntil(lambda: rec.outcome is not None, timeout=TIMEOUT_MS)
    assert rec.outcome.status == "cancelled"
    assert rec.job._proc.poll() is not None  # the command was ended
    assert list(tmp_path.iterdir()) == []  # neither the folder nor the staging folder remains
    assert "image" not in [la.name for la in viewer.layers] and shown == []

    res = _run(qtbot, rec, blocks="0x2")
    assert res.status == "failed" and "\n" not in res.error
    assert shown == [f"reconstruct: {res.error}"] and "blocks" in res.error
    assert list(tmp_path.iterdir()) == []
    blank = panels.ReconstructWidget(viewer)
    blank.start()  # an incomplete form: named, nothing started
    assert blank.worker is None and shown[-1] == "choose the input (views)"


def test_calibrate_depth_motion_evaluate_widgets(make_napari_viewer, qtbot, capture, tmp_path):
    viewer = make_napari_viewer()
    cal = panels.CalibrateWidget(viewer)
    res = _run(qtbot, cal, white=capture / "frames.tif", out=tmp_path / "calib",
               config=capture / "config.toml")
    assert res.status == "done", res.error
    grid = viewer.layers["calib grid"]
    assert grid._type_string == "shapes" and set(grid.shape_type) == {"line"}
    np.testing.assert_allclose(grid.scale, (P_UM, P_UM))
    assert viewer.layers["frames"].data.shape == (25, 40, 40)
    assert "pitch" in cal.status.value and "contrast" in cal.status.value  # the fit quality
    cli = _replay(res, tmp_path / "cli_calib")
    assert cli.read_text() == (tmp_path / "calib" / "calib.toml").read_text()

    dep = panels.DepthWidget(viewer)
    res = _run(qtbot, dep, views=capture / "views.tif", out=tmp_path / "depth", candidates=8)
    assert res.status == "done", res.error
    disp = viewer.layers["disparity"]
    assert disp.data.shape == (35, 35)
    np.testing.assert_allclose(disp.scale, (CFG.scan_step_px * P_UM,) * 2)
    cli = _replay(res, tmp_path / "cli_depth")
    np.testing.assert_array_equal(tifffile.imread(cli / "disparity.tif"), disp.data)

    # motion needs 60 x 60 view samples at scan 5: a smooth moving-free stack
    rng = np.random.default_rng(3)
    base = rng.random((64, 64)).astype(np.float32)
    write_views(tmp_path / "v64.tif", np.broadcast_to(base, (5, 5, 64, 64)).copy(), CFG)
    mot = panels.MotionWidget(viewer)
    res = _run(qtbot, mot, views=tmp_path / "v64.tif", out=tmp_path / "motion")
    assert res.status == "done", res.error
    corrected = read_views(tmp_path / "motion" / "views.tif")
    assert viewer.layers["views"].data.shape == (5, 5, 64, 64)
    np.testing.assert_array_equal(read_views(_replay(res, tmp_path / "cli_motion")), corrected)

    # evaluate: a blurred slanted edge against the sharp one
    from scipy.ndimage import gaussian_filter

    yy, xx = np.mgrid[:80, :80]
    truth = (xx - 40 > 0.1 * (yy - 40)).astype(np.float32)
    tifffile.imwrite(tmp_path / "truth.tif", truth)
    tifffile.imwrite(tmp_path / "edge.tif", gaussian_filter(truth, 1.5).astype(np.float32))
    ev = panels.EvaluateWidget(viewer)
    res = _run(qtbot, ev, result=tmp_path / "edge.tif", truth=tmp_path / "truth.tif",
               roi="10,70,20,60", out=tmp_path / "eval")
    assert res.status == "done", res.error
    rows = dict(zip(ev.metric_rows["metric"], ev.metric_rows["value"], strict=True))
    assert ev.table.shape == (len(rows), 2)
    saved = json.loads((tmp_path / "eval" / "evaluation.json").read_text())
    assert rows["ssim"] == f"{saved['ssim']:.4f}" and rows["psnr_db"] == f"{saved['psnr_db']:.4f}"
    assert any(k.startswith("ROI 0 mtf50") for k in rows)
    assert len(ev.figure.axes[0].lines) == 2  # the ROI's MTF curve and the 0.5 line
    cli = _replay(res, tmp_path / "cli_eval")
    assert json.loads((cli / "evaluation.json").read_text())["mtf"] == saved["mtf"]


def test_explore_epi_slope_and_pupil_map(make_napari_viewer, tmp_path):
    """Views of a scene at disparity δ (view (u, v) = the centre view moved δ·(v − c) along x):
    the EPI's rows are those views' profiles, shifted δ per view; the pupil map under the
    cursor is views[:, :, Y, X]."""
    from metasensor.napari.explore import ExploreWidget

    delta = -2
    rng = np.random.default_rng(4)
    base = rng.random((20, 40)).astype(np.float32)
    gain = 1 + np.arange(5, dtype=np.float32)[:, None, None, None]
    views = gain * np.stack([np.stack([np.roll(base, delta * (v - 2), axis=1)
                                       for v in range(5)]) for _ in range(5)])
    write_views(tmp_path / "shifted.tif", views, CFG)
    viewer = make_napari_viewer()
    viewer.open(str(tmp_path / "shifted.tif"), plugin="metasensor")
    # every dock of the manifest, as napari's Plugins menu makes it (the viewer handed over)
    for name, cls in (("Calibrate", panels.CalibrateWidget), ("Realign", panels.RealignWidget),
                      ("Reconstruct", panels.ReconstructWidget), ("Motion", panels.MotionWidget),
                      ("Depth", panels.DepthWidget), ("Evaluate", panels.EvaluateWidget),
                      ("Explore", ExploreWidget)):
        _, widget = viewer.window.add_plugin_dock_widget("metasensor", name)
        assert isinstance(widget, cls) and widget.viewer is not None
    ex = widget
    assert ex.views.name == "shifted"
    img = ex.show_epi((7, 10), (7, 30))
    assert img.shape == (5, 21)
    np.testing.assert_allclose(img, views[2, :, 7, 10:31], rtol=1e-6)
    np.testing.assert_allclose(img[3, 5:15], img[2, 5 - delta:15 - delta], rtol=1e-6)
    ex.start_line()  # the drawn line goes through the same code
    ex.line_layer.add_lines(np.array([[7.0, 10.0], [7.0, 30.0]]))
    np.testing.assert_allclose(ex.epi_image, img)
    layer = ex.views
    viewer.cursor.position = layer.data_to_world((0, 0, 11, 23))
    assert ex.pupil_at == (11, 23)
    np.testing.assert_array_equal(ex.pupil_image, views[:, :, 11, 23])
