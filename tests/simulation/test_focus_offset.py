"""simulate(focus_offset=): the meta-imaging sensor defocused, the comparison sensors in focus."""

import numpy as np
import pytest

import metasensor as ms
from metasensor.simulation.capture import OPERATING_FOCUS_OFFSET
from metasensor.simulation.scenes import load_scene


def test_focus_offset_defocuses_the_views_only():
    scene, cfg = load_scene("chart", 48), ms.SystemConfig()
    off = ms.simulate(scene, cfg, seed=0, focus_offset=OPERATING_FOCUS_OFFSET)
    z4 = ms.simulate(scene, cfg, seed=0, zernike=[0, 0, 0, OPERATING_FOCUS_OFFSET],
                     comparison=False)
    focused = ms.simulate(scene, cfg, seed=0)
    np.testing.assert_array_equal(off.views, z4.views)  # views: as a Z4 aberration
    # 2D sensor: in focus (at the capture's own intensity scale, set by its brightest view)
    np.testing.assert_allclose(off.sensor2d_clean / off.scale,
                               focused.sensor2d_clean / focused.scale, rtol=1e-5, atol=1e-6)
    assert not np.array_equal(off.views, focused.views)
    np.testing.assert_allclose(off.zernike, [0, 0, 0, OPERATING_FOCUS_OFFSET])
    with pytest.raises(ValueError, match="focus_offset"):
        ms.simulate(scene, cfg, focus_offset=float("nan"))
