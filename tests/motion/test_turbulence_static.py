"""Turbulence mode leaves static data alone, on small sub-images too.

Defect: ``simulate --scene chart --size 210 --snr 30`` then ``motion --mode turbulence`` moved
65.9 % of the centre view's samples of that *static* capture (reconstruction SSIM 0.90 -> 0.33).
The registration flows between scan-phase sub-images (13 x 13 px there) fit aliasing and noise;
the gate now tests a flow in the dense view (metasensor.motion.consistency) and the control
grid is thinned on small sub-images (flow.registration_grid). Reference: a static scene must be
returned bit-for-bit (the module contract); real smooth turbulence (1 px r.m.s.) must still gain
>= 8 dB PSNR to the truth at the reference time (measured 11.6 dB here).
"""

import numpy as np
import pytest
from motion_helpers import ORDER, REF, psnr, scene

from metasensor.motion import correct_motion, correct_motion_views
from metasensor.motion.consistency import dense_confidence
from metasensor.motion.flow import registration_grid
from metasensor.motion.synthetic import dynamic_view, rigid_motion, smooth_random_motion

SMALL = (65, 65)  # 13 x 13 sub-images, as a 210-px simulated capture
INNER = np.zeros(SMALL, bool)
INNER[10:-10, 10:-10] = True


def _small_view(motion, seed=0):
    return dynamic_view(scene(seed)[:2 * SMALL[0], :2 * SMALL[1]], 2, SMALL, ORDER, motion)


def test_registration_grid_follows_sub_image_size():
    assert registration_grid((13, 13)) == (2, 2)
    assert registration_grid((27, 27)) == (4, 4)
    assert registration_grid((40, 40)) == (6, 6)  # the default, unchanged on the test scenes
    assert registration_grid((40, 13), (3, 8)) == (3, 2)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_static_small_view_unchanged_in_turbulence_mode(seed):
    """Static natural view, 13-px sub-images, noise 0.01 (scene in [0, 1]): before the fix
    49 % and 38 % of its samples moved for seeds 0 and 1 (PSNR to the input 34 dB); now
    bit-for-bit."""
    view, _ = _small_view(rigid_motion((0, 0), REF), seed)
    view = view + 0.01 * np.random.default_rng(seed).standard_normal(SMALL).astype(np.float32)
    out = correct_motion_views(view[None, None], ORDER, mode="turbulence", progress=False)
    np.testing.assert_array_equal(out[0, 0], view)


def test_small_view_turbulence_still_corrected():
    """Per-frame smooth distortions (1 px r.m.s., 25 px correlation) on 13-px sub-images:
    PSNR to the truth 22.6 -> 34.2 dB (before the fix: 31.9 dB)."""
    motion, _ = smooth_random_motion((200, 200), len(ORDER), 1.0, 25.0, seed=3)
    view, truth = _small_view(motion)
    out = correct_motion_views(view[None, None], ORDER, mode="turbulence", progress=False)[0, 0]
    assert psnr(out, truth, INNER) - psnr(view, truth, INNER) >= 8.0


def test_dense_confidence_rejects_pseudo_flow():
    """A random smooth 'flow' on a static view makes the dense view less consistent (ratio > 1
    almost everywhere); the true flow of a moving view makes it more consistent (< 0.5)."""
    view, _ = _small_view(rigid_motion((0, 0), REF))
    rng = np.random.default_rng(0)
    fake = np.repeat(rng.normal(0, 1.0, (2, 1, 1)), 65, 1).repeat(65, 2)
    fake = fake * (np.indices(SMALL).sum(0) % 2 == 0)  # every other sample displaced
    ratio = dense_confidence(view, ORDER, fake)
    assert np.median(ratio) > 1.0
    vel = (0.8, -0.5)
    moving, _ = _small_view(rigid_motion(vel, REF))
    tmap = np.array([[ORDER.index((y % 5, x % 5)) for x in range(65)] for y in range(65)])
    true = np.stack([vel[0] * (tmap - REF), vel[1] * (tmap - REF)]).astype(np.float32)
    ratio = dense_confidence(moving, ORDER, true)
    assert np.median(np.delete(ratio, REF, axis=0)[:, 2:-2, 2:-2]) < 0.5


@pytest.mark.slow
def test_simulated_static_chart_unchanged():
    """The audited case: simulated chart, 210 px, SNR 30 dB (views 65 x 65): three views
    corrected as turbulence are returned unchanged (before: 65.9 % of the centre view moved)."""
    from metasensor.config import SystemConfig
    from metasensor.simulation.capture import simulate
    from metasensor.simulation.scenes import load_scene

    cap = simulate(load_scene("chart", 210), SystemConfig(), snr_db=30, seed=0,
                   comparison=False)
    c = cap.views.shape[0] // 2
    for uv in [(c, c), (c, c + 4), (c - 5, c)]:
        view = cap.views[uv]
        out = correct_motion(view, cap.scan_order, method="registration")
        np.testing.assert_array_equal(out, view)


def test_flat_view_gives_no_evidence_either_way():
    # zero leave-one-out error with and without the motion (a flat background): ratio 1, not
    # 0/0 read as 0 (which passed meaningless registration flows there)
    from metasensor.motion.consistency import dense_confidence

    view = np.zeros((120, 120), np.float32)
    view[78:102, 78:102] = 1000.0  # sub-image px 26-34; the corner checked is 0-5
    order = [(r, c) for r in range(3) for c in range(3)]
    motion = np.random.default_rng(0).normal(0, 2, (2, 120, 120))
    ratio = dense_confidence(view, order, motion)
    assert np.all(ratio[:, :6, :6] == 1.0)


def test_resolved_fraction_of_noise_and_coarse_content():
    """White noise keeps about 1 / (π p²) of its energy through the sub-image-scale low-pass
    (measured 0.83x: the local mean takes a little); content 16 p wide keeps nearly all."""
    from metasensor.motion.consistency import resolved_fraction

    noise = np.random.default_rng(0).standard_normal((300, 300))
    yy, xx = np.mgrid[0:300, 0:300]
    for p in (3, 5):
        rn = np.median(resolved_fraction(noise, p)[30:-30, 30:-30])
        assert 0.6 / (np.pi * p * p) < rn < 1.2 / (np.pi * p * p)
        rs = np.median(resolved_fraction(np.sin(2 * np.pi * xx / (16 * p)), p)[30:-30, 30:-30])
        assert rs > 0.85


def test_static_star_field_unchanged_in_turbulence_mode():
    """Simulated static star grid (240 px, 30 dB): a star's view is a disk one lenslet wide, one
    sample per sub-image; the registration returned 2.4 view px flows there and 74.6 % of the
    capture was moved (reconstruction 30.09 -> 29.03 dB). Unresolved content gives no evidence
    now: views returned bit-for-bit."""
    from metasensor.config import SystemConfig
    from metasensor.simulation.capture import simulate
    from metasensor.simulation.scenes import load_scene

    cap = simulate(load_scene("points", 240), SystemConfig(), snr_db=30, seed=0,
                   comparison=False)
    c = cap.views.shape[0] // 2
    for uv in [(c, c), (c, c + 4)]:
        view = cap.views[uv]
        out = correct_motion(view, cap.scan_order, method="registration")
        np.testing.assert_array_equal(out, view)


def test_unresolved_content_gives_no_evidence_next_to_resolved_content():
    """One view, natural texture on the left and isolated one-sample spikes on the right, with
    a random flow everywhere: the spikes' half reads ratio 1 (no evidence either way), the
    natural half is tested (not all 1); flat views of any level read 0 resolved."""
    from metasensor.motion.consistency import resolved_fraction

    view, _ = _small_view(rigid_motion((0, 0), REF))
    view = view.copy()
    rng = np.random.default_rng(1)
    spikes = np.zeros((65, 33), np.float32)
    spikes[rng.integers(0, 65, 40), rng.integers(0, 33, 40)] = 1.0
    view[:, 32:] = spikes
    motion = rng.normal(0, 1.0, (2, 65, 65))
    ratio = dense_confidence(view, ORDER, motion)
    # sub-image columns >= 11: view columns >= 55, beyond the reach of the resolved-fraction
    # window (sigma 2p = 10 view px) from the natural half
    assert np.all(ratio[:, :, 11:] == 1.0)
    assert np.mean(ratio[:, :, :4] != 1.0) > 0.5
    ungated = dense_confidence(view, ORDER, motion, resolved_min=0.0)
    assert np.mean(ungated[:, :, 11:] != 1.0) > 0.1  # without the gate the spikes are tested
    for level in (0.0, 0.1, 1000.37):
        assert np.all(resolved_fraction(np.full((60, 60), level), 3) == 0.0)


def test_turbulence_mode_leaves_torchs_thread_setting_alone(monkeypatch):
    """The views' worker threads each run on one torch thread of their own: the process-wide
    ``torch.set_num_threads`` (which other callers' threads see change) is never called."""
    import torch

    motion, _ = smooth_random_motion((200, 200), len(ORDER), 1.0, 25.0, seed=3)
    view, truth = _small_view(motion)

    def refuse(n):
        raise AssertionError(f"torch.set_num_threads({n}) changes every thread's setting")

    with monkeypatch.context() as m:
        m.setattr(torch, "set_num_threads", refuse)
        out = correct_motion_views(view[None, None], ORDER, mode="turbulence", progress=False,
                                   workers=2)[0, 0]
    assert psnr(out, truth, INNER) - psnr(view, truth, INNER) >= 8.0  # corrected as before
