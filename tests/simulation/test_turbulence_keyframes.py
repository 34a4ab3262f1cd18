"""The simulator's sampling of evolving turbulence: key frames interpolated in time, and banks on
the pixel grid (``Turbulence.key_every``, ``Turbulence.subsample``)."""

import dataclasses
from typing import Any

import numpy as np
import pytest

import metasensor as ms
from metasensor.simulation.capture import simulate
from metasensor.simulation.sampling import time_weights
from metasensor.simulation.turbulence import Turbulence

CFG = ms.SystemConfig(sensor_shape=(132, 132))


@dataclasses.dataclass(frozen=True)
class Given(Turbulence):
    """Turbulence whose screens are given (one per frame)."""

    stack: Any = None

    def screens(self, n_frames, seed=0):
        return np.asarray(self.stack, np.float32)[:n_frames]


def _tilts(n_frames: int, samples: int = 16) -> np.ndarray:
    rho = -1 + (np.arange(samples) + 0.5) * 2 / samples
    x, y = np.meshgrid(rho, rho)
    return np.stack([0.4 * np.sin(0.7 * t) * x + 0.3 * np.cos(0.5 * t) * y + 0.2 * x * y
                     for t in range(n_frames)])


def test_time_weights_are_linear_between_key_frames():
    assert time_weights(3, 9, 1) == [(3, 1.0)]
    assert time_weights(4, 9, 4) == [(4, 1.0)] and time_weights(8, 9, 4) == [(8, 1.0)]
    assert time_weights(1, 9, 4) == [(0, 0.75), (4, 0.25)]
    (k0, w0), (k1, w1) = time_weights(6, 8, 4)  # the period's last frame is a key frame
    assert (k0, k1) == (4, 7) and w0 == pytest.approx(1 / 3) and w0 + w1 == pytest.approx(1)


def test_key_frames_render_exactly_and_frames_between_interpolate(standin):
    scene = np.random.default_rng(0).random((70, 70)).astype(np.float32)
    scr = _tilts(9)
    run = lambda t: simulate(scene, CFG, scan=3, turbulence=t, comparison=False,  # noqa: E731
                             scale=1.0).views_clean
    every = run(Given(samples=16, stack=scr))
    keyed = run(Given(samples=16, stack=scr, key_every=4))
    order = [(t // 3, t % 3) for t in range(9)]  # row-major
    for t in (0, 4, 8):
        r, c = order[t]
        np.testing.assert_allclose(keyed[:, :, r::3, c::3], every[:, :, r::3, c::3], atol=1e-6)
    held0 = run(Given(samples=16, stack=np.repeat(scr[:1], 9, 0)))
    held4 = run(Given(samples=16, stack=np.repeat(scr[4:5], 9, 0)))
    r, c = order[1]
    mix = 0.75 * held0[:, :, r::3, c::3] + 0.25 * held4[:, :, r::3, c::3]
    np.testing.assert_allclose(keyed[:, :, r::3, c::3], mix, atol=1e-5 * mix.max())
    assert np.abs(keyed[:, :, r::3, c::3] - every[:, :, r::3, c::3]).max() > 1e-3 * mix.max()


def test_pixel_grid_banks_give_the_pixel_grid_forward_model(standin):
    # subsample 1: every frame is the pixel-pitch bank of its screen, sampled at the lenslets
    from metasensor.optics import psf
    from metasensor.simulation.turbulence import screen_phase

    scene = np.zeros((70, 70), np.float32)
    scene[30:40, 33:36] = 1
    scr = np.repeat(_tilts(1), 9, 0)
    cap = simulate(scene, CFG, scan=3, turbulence=Given(samples=16, stack=scr, subsample=1),
                   comparison=False, scale=1.0)
    bank = psf.view_psfs(CFG, None, 0.0, phase=screen_phase(scr[0]), subsample=1)
    from scipy.signal import fftconvolve

    u, v = 7, 5
    full = fftconvolve(scene, bank[u, v], mode="full")
    k = bank.shape[-1] // 2
    d, n = 5, 15
    h, w = cap.views_clean.shape[2:]
    expect = full[k + n // 2::d, k + n // 2::d][:h, :w]
    np.testing.assert_allclose(cap.views_clean[u, v], expect, atol=1e-5 * expect.max())


def test_sampling_options_are_validated():
    with pytest.raises(ValueError, match="key_every"):
        Turbulence(key_every=0)
    with pytest.raises(ValueError, match="subsample must be odd"):
        Turbulence(subsample=2)
