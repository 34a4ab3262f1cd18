"""Stand-in PSFs for the simulator's tests while ``metasensor.optics.psf`` is not available.

A geometric light-field model with the real functions' signatures and normalisation: a point
at displacement δ from a lenslet's centre sends its light through the lenslet's circular
aperture (radius nnum/2 px, edge softened by a Gaussian of 0.5 px) onto the pupil image behind
it; pixel (u, v) receives the share A_uv of the pupil disk it covers. Tilt (Noll 2, 3), defocus
(Noll 4, depth) and a ``phase`` callable shift each view by the local wavefront gradient
(λ/NA)∇W at the view's pupil point. The widefield PSF is a Gaussian (σ = 0.42 λ/NA) shifted by
the mean wavefront gradient. Only for tests: not physics.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import special


def _noll_nm(j):
    n = 0
    while j > (n + 1) * (n + 2) // 2:
        n += 1
    k = j - n * (n + 1) // 2 - 1
    ms = [m for m in range(-n, n + 1) if (n - m) % 2 == 0 and m >= 0]
    ms = sorted(set(ms))
    # Noll ordering within a radial order
    opts = []
    for m in ms:
        if m == 0:
            opts.append((0, 0))
        else:
            opts += [(m, 0), (m, 1)]
    m, _ = opts[k]
    # parity: even j -> cos, odd j -> sin (for m != 0)
    return n, m, ("cos" if j % 2 == 0 else "sin") if m else "none"


def wavefront(z, x, y):
    z = np.asarray(z, float)
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    r = np.hypot(x, y)
    t = np.arctan2(y, x)
    out = np.zeros(np.broadcast_shapes(x.shape, y.shape))
    for j, c in enumerate(z, start=1):
        if c == 0:
            continue
        n, m, kind = _noll_nm(j)
        rad = np.zeros_like(r)
        for s in range((n - m) // 2 + 1):
            rad += ((-1) ** s * math.factorial(n - s)
                    / (math.factorial(s) * math.factorial((n + m) // 2 - s)
                       * math.factorial((n - m) // 2 - s))) * r ** (n - 2 * s)
        if m == 0:
            out += c * math.sqrt(n + 1) * rad
        else:
            ang = np.cos(m * t) if kind == "cos" else np.sin(m * t)
            out += c * math.sqrt(2 * (n + 1)) * rad * ang
    return out


def _gradient(z, phase, rx, ry, depth, cfg):
    h = 1e-4
    def w(x, y):
        v = np.zeros(np.broadcast_shapes(np.shape(x), np.shape(y)))
        if z is not None:
            v = v + wavefront(z, x, y)
        if phase is not None:
            v = v + np.asarray(phase(x, y))
        return v
    gx = (w(rx + h, ry) - w(rx - h, ry)) / (2 * h)
    gy = (w(rx, ry + h) - w(rx, ry - h)) / (2 * h)
    scale = cfg.wavelength / cfg.na / cfg.pixel_pitch  # pixels per unit gradient (waves)
    dx, dy = gx * scale, gy * scale
    # parallax of defocus: +depth/mla_focal * (u - c, v - c) image pixels
    par = depth / cfg.mla_focal
    return dy, dx, par


def view_psfs(cfg, zernike=None, depth=0.0, *, phase=None, amplitude=None, subsample=1,
              size=None, device=None, cache=True, band_limited=False):
    if phase is None and amplitude is None:  # memoised (tests call it with few arguments)
        key = (cfg.to_json(), None if zernike is None else tuple(np.asarray(zernike, float)),
               float(depth), subsample, size)
        if key not in _MEMO:
            _MEMO[key] = _view_psfs(cfg, zernike, depth, None, subsample, size)
        return _MEMO[key].copy()
    return _view_psfs(cfg, zernike, depth, phase, subsample, size)


_MEMO: dict = {}


def _view_psfs(cfg, zernike, depth, phase, subsample, size):
    n = cfg.nnum
    c = n // 2
    rx, ry = cfg.pupil_coords()
    dy, dx, par = _gradient(zernike, phase, rx, ry, depth, cfg)
    u = np.arange(n) - c
    dy = dy + par * u[:, None]
    dx = dx + par * u[None, :]
    rp = cfg.pupil_radius_px
    # share of the pupil disk on each pixel (supersampled)
    ss = 8
    g = (np.arange(n * ss) + 0.5) / ss - n / 2
    yy, xx = np.meshgrid(g, g, indexing="ij")
    disk = ((yy**2 + xx**2) <= rp**2).astype(float)
    share = disk.reshape(n, ss, n, ss).sum((1, 3))
    share /= share.sum()
    shift = float(np.max(np.hypot(dy, dx)))
    k = size or (2 * int(math.ceil(n / 2 + shift + 3)) + 1)
    kf = k * subsample
    cf = kf // 2
    d = (np.arange(kf) - cf) / subsample
    out = np.zeros((n, n, kf, kf), np.float32)
    for a in range(n):
        for b in range(n):
            if share[a, b] == 0:
                continue
            yy2 = d[:, None] - dy[a, b]
            xx2 = d[None, :] - dx[a, b]
            rr = np.hypot(yy2, xx2)
            edge = 0.5 * (1 - special.erf((rr - n / 2) / (0.5 * math.sqrt(2))))
            out[a, b] = share[a, b] * edge / subsample**2  # view_psfs normalisation
    return out


def widefield_psf(cfg, zernike=None, depth=0.0, sampling=None, *, phase=None, amplitude=None,
                  size=None, device=None):
    pitch = cfg.pixel_pitch if sampling is None else sampling
    m = 64
    g = -1 + (np.arange(m) + 0.5) * 2 / m
    x, y = np.meshgrid(g, g)
    inside = np.hypot(x, y) <= 1
    dy, dx, _ = _gradient(zernike, phase, x, y, 0.0, cfg)
    sy = dy[inside].mean() * cfg.pixel_pitch / pitch
    sx = dx[inside].mean() * cfg.pixel_pitch / pitch
    sig = 0.42 * cfg.wavelength / cfg.na / pitch
    spread = math.hypot(float(dy[inside].std()), float(dx[inside].std())) * cfg.pixel_pitch / pitch
    sig = math.hypot(sig, spread)
    k = size or 2 * int(math.ceil(4 * sig + abs(sy) + abs(sx) + 2)) + 1
    d = np.arange(k) - k // 2
    ker = np.exp(-((d[:, None] - sy) ** 2 + (d[None, :] - sx) ** 2) / (2 * sig**2))
    return (ker / ker.sum()).astype(np.float32)


def random_zernike(rms, modes=range(4, 46), jmax=45, seed=0):
    rng = np.random.default_rng(seed)
    z = np.zeros(jmax)
    idx = np.array(list(modes)) - 1
    v = rng.normal(size=idx.size)
    z[idx] = v / np.linalg.norm(v) * rms
    return z
