"""Graceful fallback of motion correction on the walking figure (articulated motion, occlusion,
motion blur, brightness drift), and its parts.

Acceptance: the scan-lattice artefact (``lattice_ratio``: energy at the scan-lattice
frequencies relative to the local spectrum, about 1 without an artefact) on the moving region
drops to <= 1.5 x that of a static capture of the same scene; the static region (more than
6 px from the moving region) is unchanged: correlation >= 0.99, detail (r.m.s. Laplacian)
within 10 %.
"""

import warnings

import numpy as np
import pytest
from scipy import ndimage

from metasensor.motion import FallbackOptions, correct_motion, plan_motion
from metasensor.motion.fallback import lattice_coherence, reference_upsample
from metasensor.motion.synthetic import lattice_ratio, natural_scene
from metasensor.simulation.walker import WalkerOptions, walker_view

ORDER = [(r, c) for r in range(5) for c in range(5)]


def _detail(img, mask):
    return float(np.sqrt(np.mean(ndimage.laplace(img.astype(np.float64))[mask] ** 2)))


def _check_walker(size, height, seed, **options):
    opt = WalkerOptions(height=height, seed=seed, **options)
    cap = walker_view((size, size), ORDER, 12, opt)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out, fmap = correct_motion(cap.view, ORDER, 12, return_fallback=True)
    moving = cap.moving
    ratio = lattice_ratio(out, 5, moving) / lattice_ratio(cap.static, 5, moving)
    assert ratio <= 1.5, (size, seed, ratio)
    assert lattice_ratio(cap.view, 5, moving) > 2 * lattice_ratio(out, 5, moving)
    still = ~ndimage.binary_dilation(moving, iterations=6)
    assert np.corrcoef(out[still], cap.view[still])[0, 1] >= 0.99
    detail = _detail(out, still) / _detail(cap.view, still)
    assert 0.9 <= detail <= 1.1, detail
    # the map says where the flow did not fit, and the warning says how much
    assert fmap.weight.shape == cap.view.shape and fmap.weight.dtype == np.float32
    assert 0 < fmap.fraction <= 1
    assert fmap.mask[moving].mean() > 5 * fmap.mask[still].mean()
    assert (len(caught) == 1) == (fmap.fraction > 0.5)
    return fmap


def test_walker_artefact_drops_to_the_static_level():
    _check_walker(300, 200.0, 2)


@pytest.mark.slow
@pytest.mark.parametrize("size,height,seed", [(300, 200.0, 0), (300, 200.0, 1),
                                              (300, 200.0, 3), (400, 300.0, 1),
                                              (400, 250.0, 3)])
def test_walker_artefact_more_scenes(size, height, seed):
    _check_walker(size, height, seed)


@pytest.mark.slow
@pytest.mark.parametrize("options", [dict(speed=6.0), dict(speed=-1.0), dict(exposure=0.0)])
def test_walker_faster_than_a_lenslet_reversed_unblurred(options):
    """6 view px per frame (more than a lenslet between frames), walking the other way, no
    motion blur."""
    _check_walker(400, 200.0 if options.get("speed") == 6.0 else 250.0, 2, **options)


def test_reference_upsample_is_the_cubic_spline_of_one_phase():
    view = np.random.default_rng(0).random((53, 47)).astype(np.float32)
    r, c = 2, 3
    yy, xx = np.mgrid[0:53, 0:47]
    want = ndimage.map_coordinates(view[r::5, c::5].astype(np.float64),
                                   [(yy - r) / 5, (xx - c) / 5], order=3, mode="mirror")
    got = reference_upsample(view, 5, (r, c))
    np.testing.assert_allclose(got, want, atol=1e-5)
    np.testing.assert_allclose(got[r::5, c::5], view[r::5, c::5], atol=1e-5)
    part = reference_upsample(np.stack([view, 2 * view]), 5, (r, c), slice(4, 30), slice(9, 40))
    np.testing.assert_allclose(part[1], 2 * want[4:30, 9:40], atol=1e-5)


def test_lattice_coherence_separates_artefact_from_texture():
    """Static natural texture and a straight static edge stay below the region threshold;
    a pattern repeated in every lenslet does not."""
    opt = FallbackOptions()
    for seed in range(3):
        img = natural_scene((200, 200), 1, 1.0, seed=seed)
        assert np.percentile(lattice_coherence(img, 5), 99) < opt.region
    edge = natural_scene((200, 200), 1, 1.0, seed=0)
    edge[:, 102:] += 0.5  # a vertical edge at one lenslet phase, along the whole height
    assert lattice_coherence(edge, 5)[5:-5, 18:23].max() < opt.region
    striped = natural_scene((200, 200), 1, 1.0, seed=0)
    striped[::5] += 0.15  # a row and a column of every lenslet from another time
    striped[:, ::5] += 0.15
    assert np.percentile(lattice_coherence(striped, 5), 10) > opt.region


def test_fallback_leaves_static_scenes_and_good_corrections_alone():
    from motion_helpers import REF, SHAPE, psnr, scene

    from metasensor.motion.synthetic import dynamic_view, rigid_motion

    view, _ = dynamic_view(scene(0), 2, SHAPE, ORDER, rigid_motion((0, 0), REF))
    out, fmap = correct_motion(view, ORDER, return_fallback=True)
    np.testing.assert_array_equal(out, view)
    assert fmap.fraction == 0 and not fmap.weight.any()
    inner = np.zeros(SHAPE, bool)
    inner[12:-12, 12:-12] = True
    view, truth = dynamic_view(scene(0), 2, SHAPE, ORDER, rigid_motion((1.0, 0.6), REF))
    on = psnr(correct_motion(view, ORDER), truth, inner)
    off = psnr(correct_motion(view, ORDER, fallback=False), truth, inner)
    assert on >= off - 2.0, (on, off)


def test_plan_motion_applies_the_same_correction_to_every_view():
    cap = walker_view((300, 300), ORDER, 12, WalkerOptions(height=200.0, seed=2))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        plan = plan_motion(cap.view, ORDER, 12)
        single = correct_motion(cap.view, ORDER, 12)
    assert plan.fallback is not None and plan.fallback[0].weight.any()
    both = plan.apply(np.stack([cap.view, 0.5 * cap.view]))
    np.testing.assert_allclose(both[0], single, atol=1e-6)
    np.testing.assert_allclose(both[1], 0.5 * single, atol=1e-6)


def test_fallback_options_are_validated():
    with pytest.raises(ValueError, match="low < high"):
        FallbackOptions(low=0.3, high=0.2)
    with pytest.raises(ValueError, match="region"):
        FallbackOptions(region=0.0)
    with pytest.raises(ValueError, match="bridge"):
        FallbackOptions(bridge=-1)
    with pytest.raises(TypeError, match="fallback"):
        correct_motion(np.zeros((60, 60), np.float32), ORDER, fallback="yes")
    with pytest.raises(ValueError, match="optical flow"):
        plan_motion(np.zeros((60, 60), np.float32), ORDER, method="registration")


def test_the_fallback_warning_names_the_scan_period_used():
    """A 3 x 3 scan's view corrected as the default configuration's 5 x 5 (a preset name gives
    no period): the flow fits nowhere, and the one warning says which period was assumed."""
    from metasensor.motion.synthetic import dynamic_view, rigid_motion
    from metasensor.sensor.scan import scan_order

    shape = (210, 210)
    order = scan_order(3, "row-major")
    view, _ = dynamic_view(natural_scene(shape, 2, 1.0, seed=0), 2, shape, order,
                           rigid_motion((1.0, 0.6), len(order) // 2))
    with pytest.warns(UserWarning, match="fell back .* the scan period used is 5") as rec:
        correct_motion(view, "row-major")
    assert len(rec) == 1
