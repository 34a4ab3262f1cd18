"""Fixtures of the napari plugin's tests: Qt offscreen, the plugin registered with npe2, and one
tiny simulated capture (nnum 5, 5 x 5 scan, 40-px chart) shared by the module's tests."""

import os

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")

import pytest  # noqa: E402

napari = pytest.importorskip("napari", reason="the napari extra is not installed")

from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from plugin_helpers import CFG  # noqa: E402

MANIFEST = Path(__file__).parents[2] / "src" / "metasensor" / "napari" / "napari.yaml"


@pytest.fixture(scope="session", autouse=True)
def _plugin_registered():
    """The plugin as napari sees it: from the installed ``napari.manifest`` entry point, or
    (a checkout newer than its editable install) from the manifest file itself."""
    import npe2

    pm = npe2.PluginManager.instance()
    pm.discover()
    if "metasensor" not in pm:
        pm.register(npe2.PluginManifest.from_file(MANIFEST))
    yield


@pytest.fixture(autouse=True)
def _gl_queries_without_a_display(monkeypatch):
    """Qt's offscreen platform gives vispy no OpenGL context, so napari's two capability queries
    (float textures, maximum texture sizes) fail; nothing is drawn in these tests, so where no
    context exists they answer what a basic OpenGL 2.1 driver would. With a display (e.g. under
    xvfb-run) the real queries run."""
    from napari._vispy import canvas
    from napari._vispy.layers import base, image, labels
    from napari._vispy.utils import gl

    try:
        gl.get_gl_extensions()
        gl.get_max_texture_sizes()
        return
    except (AttributeError, TypeError, RuntimeError):
        pass
    for module in (gl, image, base, labels, canvas):
        monkeypatch.setattr(module, "get_gl_extensions", lambda: "", raising=False)
        monkeypatch.setattr(module, "get_max_texture_sizes", lambda: (4096, 512), raising=False)


@pytest.fixture(scope="session")
def capture(tmp_path_factory):
    """A tiny simulated capture written by simulate's own writer: frames.tif, views.tif,
    truth.tif, config.toml ... (40-px chart, 30 dB, a little defocus)."""
    import metasensor as ms
    from metasensor.simulation.commands import write_capture

    out = tmp_path_factory.mktemp("napari") / "cap"
    scene = ms.simulation.scenes.load_scene("chart", 40)
    z = np.zeros(6, np.float32)
    z[3] = 0.3
    cap = ms.simulate(scene, CFG, zernike=z, snr_db=30, seed=0)
    write_capture(cap, out, figure=False)
    return out
