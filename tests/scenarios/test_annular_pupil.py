"""The annular pupil's obstruction ratio, estimated from views of a uniform scene."""

import numpy as np
import pytest

import metasensor as ms
from metasensor.scenarios.pupil import estimate_annulus


@pytest.mark.parametrize("ratio", [0.0, 0.35, 0.5])
def test_obstruction_ratio_recovered_within_0_05(ratio):
    cfg = ms.SystemConfig(obstruction=ratio)
    light = ms.view_psfs(cfg).sum(axis=(2, 3))  # each view's share of a uniform scene
    rng = np.random.default_rng(0)
    views = light[:, :, None, None] * (1 + 0.01 * rng.standard_normal((1, 1, 12, 12)))
    views = views.astype(np.float32)
    before = views.copy()
    est = estimate_annulus(views, cfg)
    assert abs(est.obstruction - ratio) <= 0.05
    assert np.array_equal(views, before)
    centre = cfg.center
    assert est.amplitude[centre, centre] == (0.0 if ratio >= 0.35 else 1.0)
    assert est.amplitude.shape == (cfg.nnum, cfg.nnum)
