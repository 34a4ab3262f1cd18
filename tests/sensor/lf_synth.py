"""Synthetic raw light-field frames on a known, misaligned lenslet grid (test helper).

A continuous model, evaluated pointwise at every sensor pixel centre: the frame of scan phase
k at sensor point p is ``S(q0) * A(local)``, with q0 the rectified (phase-0) coordinate of p,
``local`` the offset from the centre of the lenslet covering p at phase k and ``A`` a vignetted
disc (radius ~6.5 px, erf edge of width 0.5 px): the lenslet's pupil image. The truth
("views rendered directly on the exact grid") evaluates the same model at the integer rectified
pixels, so rectification is tested against the continuous model, not against its own inverse.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import erfc


def scene_fn(seed: int = 0, fmax: float = 0.06, terms: int = 12):
    """Smooth band-limited positive scene S(y, x) (rectified px), values in ~[0.3, 1]."""
    rng = np.random.default_rng(seed)
    f = rng.uniform(-fmax, fmax, (terms, 2))
    ph = rng.uniform(0, 2 * np.pi, terms)
    amp = rng.uniform(0.5, 1.0, terms)
    amp /= amp.sum()

    def s(y, x):
        val = np.zeros(np.broadcast(y, x).shape)
        for k in range(terms):
            val += amp[k] * np.cos(2 * np.pi * (f[k, 0] * y + f[k, 1] * x) + ph[k])
        return 0.65 + 0.35 * val

    return s


def pupil(dy, dx, radius: float = 6.5, edge: float = 0.5):
    r = np.hypot(dy, dx)
    return 0.5 * erfc((r - radius) / (math.sqrt(2) * edge)) * (1 - 0.25 * (r / radius) ** 2)


def matrix(pitch: float, rotation_deg: float, nnum: int) -> np.ndarray:
    t = math.radians(rotation_deg)
    return pitch / nnum * np.array([[math.cos(t), math.sin(t)], [-math.sin(t), math.cos(t)]])


def render(shape, nnum, pitch, rotation_deg, center, nominal_rect=(0, 0), jitter=(0.0, 0.0),
           scene=None, white=False):
    """Raw frame ``shape`` of the phase whose blocks sit ``nominal_rect`` rectified px from
    phase 0, with an extra grid displacement ``jitter`` [sensor px]. ``center``: sensor
    position of the centre of rectified lenslet (0, 0) at phase 0. Returns float64."""
    m = matrix(pitch, rotation_deg, nnum)
    minv = np.linalg.inv(m)
    h = (nnum - 1) / 2
    yy, xx = np.meshgrid(np.arange(shape[0]), np.arange(shape[1]), indexing="ij")
    p = np.stack([yy - center[0], xx - center[1]])  # sensor offset from lenslet (0,0) centre
    q0 = np.tensordot(minv, p, axes=1) + h  # rectified coordinate at phase 0
    off = m @ np.asarray(nominal_rect, float) + np.asarray(jitter, float)
    qk = np.tensordot(minv, p - off[:, None, None], axes=1)  # lenslet-grid coords at phase k
    local = qk - nnum * np.round(qk / nnum)
    s = 1.0 if white else (scene or scene_fn())(q0[0], q0[1])
    return s * pupil(local[0], local[1])


def render_truth(rect_shape, nnum, nominal_rect=(0, 0), delta=(0.0, 0.0), scene=None):
    """The exactly rectified frame of the same phase (lenslet (0, 0) at [0:nnum, 0:nnum]),
    the scene seen at ``q + delta`` (delta: the jitter in rectified px)."""
    h = (nnum - 1) / 2
    yy, xx = np.meshgrid(np.arange(rect_shape[0]), np.arange(rect_shape[1]), indexing="ij")
    qk = np.stack([yy - nominal_rect[0] - h, xx - nominal_rect[1] - h]).astype(float)
    local = qk - nnum * np.round(qk / nnum)
    s = (scene or scene_fn())(yy + delta[0], xx + delta[1])
    return s * pupil(local[0], local[1])


def true_views(calib, cfg, pitch, rotation_deg, center, phases, jitter, scene=None):
    """Views rendered directly on the exact grid that ``calib`` rectifies to: its lenslet
    (0, 0) is the true lattice point nearest ``calib.center``; phase k's scene is seen through
    the jittered lenslets (``jitter[k]`` sensor px)."""
    from metasensor.sensor.realign import realign

    nnum = calib.nnum
    m = matrix(pitch, rotation_deg, nnum)
    a = m * nnum
    k = np.round(np.linalg.solve(a, np.asarray(calib.center) - np.asarray(center)))
    q_origin = np.linalg.solve(m, a @ k)  # rectified coordinate of that lenslet's cell corner
    scene = scene or scene_fn()
    d = nnum // cfg.scan

    def shifted(y, x):
        return scene(y + q_origin[0], x + q_origin[1])

    truth = np.stack([render_truth(calib.rect_shape(), nnum, (r * d, c * d),
                                   np.linalg.solve(m, np.asarray(j, float)), shifted)
                      for (r, c), j in zip(phases, jitter, strict=True)])
    return realign(truth, cfg, phases)
