"""Screenshot of the napari plugin on a small demo capture (``docs/images/napari.png``).

A real window, so run it under a display; headless, with a virtual one::

    xvfb-run -a -s "-screen 0 1600x1000x24" python scripts/napari_screenshot.py

Steps: simulate a capture the way ``metasensor demo`` does (the built-in chart through the
demo's single plastic lens, 30 dB; ``metasensor simulate --lens``) unless ``--capture`` names
one; open its views through the plugin's reader; run the Reconstruct widget (wave-optics DAO,
2 x 2 blocks) and wait for its worker; show the Explore dock's pupil map and an EPI along a line
on the image; save the whole window.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _capture(work: Path, size: int) -> Path:
    cap = work / "capture"
    if not (cap / "views.tif").is_file():
        subprocess.run([sys.executable, "-m", "metasensor.cli", "simulate", "--scene", "chart",
                        "--size", str(size), "--lens", "--snr", "30", "--out", str(cap)],
                       check=True)
    return cap


def _wait(app, widget, timeout: float) -> None:
    t0 = time.monotonic()
    while widget.outcome is None:
        app.processEvents()
        time.sleep(0.05)
        if time.monotonic() - t0 > timeout:
            widget.cancel()
            raise TimeoutError(f"{widget.command} did not finish in {timeout:.0f} s")


def main(argv=None) -> Path:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "images" / "napari.png")
    ap.add_argument("--capture", type=Path, help="a simulate output folder (default: simulate)")
    ap.add_argument("--work", type=Path, help="working folder (default: a temporary one)")
    ap.add_argument("--size", type=int, default=192, help="scene size of the simulated capture")
    ap.add_argument("--blocks", default="2x2")
    ap.add_argument("--timeout", type=float, default=3000.0)
    args = ap.parse_args(argv)

    import napari
    import npe2
    import numpy as np

    from metasensor.napari.explore import ExploreWidget

    work = args.work or Path(tempfile.mkdtemp(prefix="ms-napari-"))
    cap = args.capture or _capture(work, args.size)
    pm = npe2.PluginManager.instance()
    pm.discover()
    if "metasensor" not in pm:  # a checkout newer than its install: the manifest itself
        pm.register(npe2.PluginManifest.from_file(ROOT / "src/metasensor/napari/napari.yaml"))

    from napari.settings import get_settings
    from qtpy.QtCore import Qt

    get_settings().application.gui_notification_level = "error"  # no info/warning toasts
    viewer = napari.Viewer(title="metasensor in napari", show=True)
    viewer.window._qt_window.resize(1800, 1050)
    app = napari.qt.get_qapp()
    viewer.open(str(cap / "views.tif"), plugin="metasensor")
    views = viewer.layers["views"]
    c = views.data.shape[0] // 2
    viewer.dims.current_step = (c, c) + tuple(viewer.dims.current_step[2:])
    rec_dock, rec = viewer.window.add_plugin_dock_widget("metasensor", "Reconstruct")
    rec.set(views=cap / "views.tif", out=work / "result", method="wave", blocks=args.blocks)
    rec.start()
    _wait(app, rec, args.timeout)
    if rec.outcome.status != "done":
        raise SystemExit(f"reconstruct {rec.outcome.status}: {rec.outcome.error}")
    views.visible = False
    ex = ExploreWidget(viewer)
    ex_dock = viewer.window.add_dock_widget(ex, name="Explore", area="right")
    viewer.window._qt_window.resizeDocks([rec_dock, ex_dock], [560, 560], Qt.Horizontal)
    h, w = views.data.shape[-2:]
    ex.layer_box.value = views
    ex.start_line()
    ex.line_layer.add_lines(np.array([[0.4 * h, 0.15 * w], [0.4 * h, 0.85 * w]]))
    ex.show_pupil(int(0.5 * h), int(0.5 * w))
    viewer.layers.selection.active = viewer.layers["image"]
    viewer.reset_view()
    for _ in range(20):
        app.processEvents()
        time.sleep(0.05)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    viewer.screenshot(str(args.out), canvas_only=False)
    print(f"wrote {args.out} (result in {work / 'result'})")
    viewer.close()
    return args.out


if __name__ == "__main__":
    main()
