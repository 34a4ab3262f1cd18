"""Motion correction on simulated dynamic scenes (the motion stage's acceptance figures).

Truth: the scene at the reference time on the dense grid (motion.synthetic). Measures:
PSNR to the truth (images in [0, 1]); the scan artefact ``scan_artifact`` (excess spectral
energy at the lattice frequencies (k/5, l/5) over the image's own level around them).
Acceptance: artefact ÷ ≥ 10 and PSNR + ≥ 6 dB over plain realignment in the moving region;
static regions unchanged (bit-for-bit for a static scene; ≥ 60 dB to the truth away from the
object's path, i.e. a loss far below 0.3 dB of any realistic PSNR).
"""

import numpy as np
import pytest
from motion_helpers import ORDER, REF, SHAPE, P, psnr, scene

from metasensor.motion import correct_motion, correct_motion_views
from metasensor.motion.synthetic import (
    dynamic_view,
    rigid_motion,
    scan_artifact,
    smooth_random_motion,
)

YY, XX = np.mgrid[0:SHAPE[0], 0:SHAPE[1]]
INNER = np.zeros(SHAPE, bool)
INNER[12:-12, 12:-12] = True
CROP = (slice(30, 170), slice(30, 170))


def _assert_artifact_drop(view, out, truth, region, factor):
    """Lattice-frequency energy of the error (with truth) drops ≥ factor; so does the excess
    peak energy (without truth) wherever the plain view shows a clear peak (excess > 1)."""
    a_plain = scan_artifact(view, P, region, truth=truth)
    a_corr = scan_artifact(out, P, region, truth=truth)
    assert a_corr <= a_plain / factor, (a_plain, a_corr)
    e_plain, e_corr = scan_artifact(view, P, region), scan_artifact(out, P, region)
    if e_plain > 1.0:
        assert e_corr <= e_plain / factor, (e_plain, e_corr)


def test_static_scene_is_returned_bit_for_bit():
    for seed in range(3):
        view, truth = dynamic_view(scene(seed), 2, SHAPE, ORDER, rigid_motion((0, 0), REF))
        out = correct_motion(view, ORDER)
        assert out.dtype == np.float32 and out.shape == SHAPE
        np.testing.assert_array_equal(out, view)


@pytest.mark.parametrize("vel", [(0.3, 0.2), (1.0, 0.6), (3.0, -2.0)])
def test_rigid_translation(vel):
    view, truth = dynamic_view(scene(0), 2, SHAPE, ORDER, rigid_motion(vel, REF))
    view_in = view.copy()
    out = correct_motion(view, ORDER)
    np.testing.assert_array_equal(view, view_in)  # input untouched
    gain = psnr(out, truth, INNER) - psnr(view, truth, INNER)
    assert gain >= 6.0, gain
    _assert_artifact_drop(view, out, truth, CROP, 10.0)


def test_nonrigid_flow():
    """Rotation about the centre (0.4° per frame) plus a slow shear: a smooth non-rigid flow."""
    th = np.deg2rad(0.4)

    def motion(t, y, x):
        k = t - REF
        cy, cx = y - 100, x - 100
        dy = (np.cos(k * th) - 1) * cy + np.sin(k * th) * cx + 0.004 * k * cx
        dx = -np.sin(k * th) * cy + (np.cos(k * th) - 1) * cx
        return dy, dx

    view, truth = dynamic_view(scene(1), 2, SHAPE, ORDER, motion)
    out = correct_motion(view, ORDER)
    mask = INNER & (np.hypot(YY - 100, XX - 100) < 80)
    gain = psnr(out, truth, mask) - psnr(view, truth, mask)
    assert gain >= 6.0, gain
    _assert_artifact_drop(view, out, truth, CROP, 10.0)


@pytest.mark.parametrize("vel", [(1.0, 0.6), (2.0, -1.0)])
def test_moving_object_over_static_background(vel):
    cy, cx, r = 100, 100, 50

    def alpha(y, x):
        return np.clip(r + 0.5 - np.hypot(y - cy, x - cx), 0, 1)

    view, truth = dynamic_view(scene(2), 2, SHAPE, ORDER, rigid_motion(vel, REF),
                               background=scene(1), alpha=alpha)
    out = correct_motion(view, ORDER)
    dist = np.hypot(YY - cy, XX - cx)
    moving = dist < r - 8
    gain = psnr(out, truth, moving) - psnr(view, truth, moving)
    assert gain >= 6.0, gain
    crop = (slice(cy - 32, cy + 32), slice(cx - 32, cx + 32))
    _assert_artifact_drop(view, out, truth, crop, 10.0)
    # static background away from the object's path (+ one flow window) is unchanged
    path = r + 12 * max(abs(vel[0]), abs(vel[1])) + 15
    static = (dist > path) & INNER
    assert static.sum() > 4000
    assert psnr(out, truth, static) >= 60.0
    assert np.mean(out[static] == view[static]) >= 0.95


@pytest.mark.slow
def test_turbulence_per_frame_smooth_distortions():
    """Per-frame random smooth distortion fields (1 px r.m.s., 25 px correlation length):
    smooth per-frame flows from non-rigid registration; residual artefact drops ≥ 5×."""
    motion, _ = smooth_random_motion(SHAPE, len(ORDER), 1.0, 25.0, seed=3)
    view, truth = dynamic_view(scene(0), 2, SHAPE, ORDER, motion)
    out = correct_motion_views(view[None, None], ORDER, mode="turbulence", progress=False)[0, 0]
    _assert_artifact_drop(view, out, truth, CROP, 5.0)
    assert psnr(out, truth, INNER) - psnr(view, truth, INNER) >= 6.0


def test_flow_engine_choice_dis_beats_farneback():
    """The default engine (DIS) is measured against Farneback on the moving-object scene:
    PSNR to the truth in the object after correction."""
    cy, cx, r = 100, 100, 50

    def alpha(y, x):
        return np.clip(r + 0.5 - np.hypot(y - cy, x - cx), 0, 1)

    view, truth = dynamic_view(scene(2), 2, SHAPE, ORDER, rigid_motion((1.0, 0.6), REF),
                               background=scene(1), alpha=alpha)
    obj = np.hypot(YY - cy, XX - cx) < r - 8
    res = {m: psnr(correct_motion(view, ORDER, method=m), truth, obj)
           for m in ("dis", "farneback")}
    assert res["dis"] > res["farneback"] + 1.0, res


def test_bad_input():
    view = np.zeros(SHAPE, np.float32)
    with pytest.raises(ValueError, match="view_image"):
        correct_motion(np.zeros((3, 4, 5)), ORDER)
    with pytest.raises(ValueError, match="reference"):
        correct_motion(view, ORDER, reference=25)
    with pytest.raises(ValueError, match="scan order"):
        correct_motion(view, ORDER[:-1])
    with pytest.raises(ValueError, match="NaN"):
        bad = view.copy()
        bad[3, 3] = np.nan
        correct_motion(bad, ORDER)
    with pytest.raises(ValueError, match="method"):
        correct_motion(view + np.arange(SHAPE[1], dtype=np.float32), ORDER, method="nope")


def test_linear_scatter_as_good_as_cubic_griddata():
    """The default scattered interpolation (linear, sparse weights reused for every view) is
    measured against the paper's cubic (Clough–Tocher, scipy griddata "cubic"): PSNR to the
    truth on a rigid translation of 1 px per frame must be at least as good (−0.5 dB)."""
    view, truth = dynamic_view(scene(0), 2, SHAPE, ORDER, rigid_motion((1.0, 0.6), REF))
    lin = psnr(correct_motion(view, ORDER, scatter="linear"), truth, INNER)
    cub = psnr(correct_motion(view, ORDER, scatter="cubic"), truth, INNER)
    assert lin >= cub - 0.5, (lin, cub)


@pytest.mark.parametrize("order_name,reference", [("serpentine", None), ("row-major", 0)])
def test_other_scan_order_and_reference(order_name, reference):
    """Serpentine acquisition order, and alignment to the first frame instead of the middle."""
    from metasensor.sensor.scan import scan_order

    order = scan_order(P, order_name)
    ref = len(order) // 2 if reference is None else reference
    view, truth = dynamic_view(scene(0), 2, SHAPE, order, rigid_motion((1.0, 0.6), ref),
                               reference=ref)
    out = correct_motion(view, order_name if reference is None else order, reference=reference)
    gain = psnr(out, truth, INNER) - psnr(view, truth, INNER)
    assert gain >= 6.0, gain
    _assert_artifact_drop(view, out, truth, CROP, 10.0)


def test_view_size_not_a_multiple_of_the_period():
    """Samples in the last rows/columns (beyond the common sub-image size) move too."""
    from metasensor.motion.synthetic import natural_scene

    shape = (203, 198)
    sc = natural_scene(shape, 2, 1.0, seed=0)
    view, truth = dynamic_view(sc, 2, shape, ORDER, rigid_motion((1.0, 0.6), REF))
    out = correct_motion(view, ORDER)
    edge = np.zeros(shape, bool)
    edge[185:195, 20:180] = True  # bottom rows, away from the border itself
    assert psnr(out, truth, edge) - psnr(view, truth, edge) >= 6.0
    static, _ = dynamic_view(sc, 2, shape, ORDER, rigid_motion((0, 0), REF))
    np.testing.assert_array_equal(correct_motion(static, ORDER), static)
