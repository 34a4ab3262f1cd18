"""Disparity ↔ image-side depth ↔ object distance (docs/conventions.md, thin lens)."""

import numpy as np
import pytest

from metasensor.config import SystemConfig
from metasensor.depth import geometry as g


def test_disparity_to_image_depth_uses_view_sampling():
    # conventions: one view step of disparity is z / mla_focal IMAGE pixels; views are sampled
    # every d = nnum // scan image pixels, so z = δ_view · d · mla_focal (exact, rel 1e-12).
    for scan, d in ((5, 3), (1, 15), (3, 5), (15, 1)):
        cfg = SystemConfig(scan=scan)
        z = g.disparity_to_image_depth(0.5, cfg)
        assert z == pytest.approx(0.5 * d * 690e-6, rel=1e-12)
        assert g.image_depth_to_disparity(z, cfg) == pytest.approx(0.5, rel=1e-12)


def test_thin_lens_round_trip_and_sign():
    f, s0 = 0.135, 5.0
    s_i0 = 1 / (1 / f - 1 / s0)
    # in focus: z = 0 ↔ the focus distance
    assert g.image_depth_to_object_distance(0.0, f, s0) == pytest.approx(s0, rel=1e-12)
    # a farther object focuses closer to the lens, i.e. in front of the MLA: z > 0
    z_far = g.object_distance_to_image_depth(10.0, f, s0)
    assert z_far > 0
    assert z_far == pytest.approx(s_i0 - 1 / (1 / f - 1 / 10.0), rel=1e-12)
    assert g.object_distance_to_image_depth(2.0, f, s0) < 0
    s = np.array([0.5, 1.0, 3.0, 5.0, 20.0, 1e3])
    back = g.image_depth_to_object_distance(g.object_distance_to_image_depth(s, f, s0), f, s0)
    np.testing.assert_allclose(back, s, rtol=1e-9)
    # beyond infinity focus (s_i <= f): no real object → NaN
    assert np.isnan(g.image_depth_to_object_distance(s_i0 - f + 1e-6, f, s0))
    with pytest.raises(ValueError, match="exceed the focal length"):
        g.object_distance_to_image_depth(0.1, f, s0)


def test_main_lens_geometry_and_ranges():
    cfg = SystemConfig()
    assert g.main_lens_geometry(cfg) is None
    assert g.main_lens_geometry(cfg, 0.1, 2.0) == (0.1, 2.0)
    cfg2 = SystemConfig(focal_length=0.05, focus_distance=1.0)
    assert g.main_lens_geometry(cfg2) == (0.05, 1.0)
    with pytest.raises(ValueError, match="focus_distance"):
        g.main_lens_geometry(cfg, 0.1, 0.05)
    # default range: ±scan/2 view px = ±nnum/2 image px per view step for every scan period
    for scan in (1, 3, 5):
        lo, hi = g.default_disparity_range(SystemConfig(scan=scan))
        assert hi * SystemConfig(scan=scan).scan_step_px == pytest.approx(7.5)
        assert lo == -hi
    c = g.disparity_candidates((-1, 1), 5)
    np.testing.assert_allclose(c, [-1, -0.5, 0, 0.5, 1])
    with pytest.raises(ValueError, match="disparity_range"):
        g.disparity_candidates((1, -1), 5)
    with pytest.raises(ValueError, match="candidates"):
        g.disparity_candidates((-1, 1), 2)
    au, av = g.view_offsets(5)
    assert au[0, 3] == -2 and av[0, 3] == 1
