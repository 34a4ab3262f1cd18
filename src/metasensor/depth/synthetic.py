"""Geometric test scenes for depth estimation: layered scenes rendered into every view with the
light-field parallax (for tests and benchmarks; the wave-optics simulator is
``metasensor.simulation``).

Model (docs/conventions.md, geometric optics): view (u, v) at view sample (Y, X) records the scene
around image pixel ``P = (Y·d + d//2, X·d + d//2)``, ``d = nnum // scan``, shifted by the parallax
and integrated over one lenslet aperture (a disk of the lenslet's diameter, or a square lenslet):

    V_uv(P) = Σ_layers  [K ⊛ (T · α_l)](P − δ_l(P) · a_uv − s_uv(P))   (composited back to front)

with ``δ_l`` the layer's disparity in image pixels per view step, ``a_uv = (u − c, v − c)``,
``s_uv`` an optional aberration shift map, and occlusion by the blurred layer opacities
``K ⊛ α_l`` ("over" compositing). Layers are drawn in the centre view's coordinates and sampled
with cubic splines from the image-pixel grid, so the estimator (bilinear on the coarser view grid)
never meets its own discretisation. Noise: additive Gaussian at a given SNR (power ratio, dB).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from metasensor.config import SystemConfig

__all__ = ["Layer", "SyntheticViews", "random_texture", "render_views", "scene_planes",
           "scene_slanted", "scene_staircase", "aberration_shift_maps"]


@dataclass(frozen=True)
class Layer:
    """One scene layer: opacity ``alpha`` (H, W) in [0, 1] and disparity (scalar or (H, W)) in
    IMAGE pixels per view step, both on the image-pixel grid in centre-view coordinates;
    ``texture`` (H, W): the layer's own texture (None: the scene's common texture)."""

    alpha: np.ndarray
    disparity: float | np.ndarray
    texture: np.ndarray | None = None


@dataclass(frozen=True)
class SyntheticViews:
    """Rendered views and their truth (disparity in VIEW pixels per view step)."""

    views: np.ndarray          # (nnum, nnum, Hv, Wv) float32 (views outside the pupil: zero)
    views_clean: np.ndarray    # the same without noise
    disparity: np.ndarray      # (Hv, Wv) true disparity, view px per view step
    config: SystemConfig


def random_texture(shape: tuple[int, int], seed: int = 0, scale_px: float = 12.0) -> np.ndarray:
    """Band-limited random texture in [0.1, 1]: white noise with a spectrum falling as
    ``1 / (1 + (f · scale_px)^2)`` (features of about ``scale_px`` image pixels and larger)."""
    rng = np.random.default_rng(seed)
    noise = rng.standard_normal(shape)
    fy = np.fft.fftfreq(shape[0])[:, None]
    fx = np.fft.rfftfreq(shape[1])[None, :]
    f2 = (fy**2 + fx**2) * scale_px**2
    tex = np.fft.irfft2(np.fft.rfft2(noise) / (1.0 + f2), s=shape)
    tex = (tex - tex.min()) / (np.ptp(tex) + 1e-12)
    return (0.1 + 0.9 * tex).astype(np.float32)


def _aperture_kernel(cfg: SystemConfig) -> np.ndarray:
    diam = cfg.lenslet_diameter / cfg.pixel_pitch
    half = int(np.ceil(diam / 2))
    r = np.arange(-half, half + 1, dtype=np.float64)
    # 4 x 4 sub-samples per pixel for the disk's edge
    sub = (np.arange(4) + 0.5) / 4 - 0.5
    yy = (r[:, None, None, None] + sub[None, None, :, None])
    xx = (r[None, :, None, None] + sub[None, None, None, :])
    if cfg.lenslet_aperture == "square":
        inside = (np.abs(yy) <= diam / 2) & (np.abs(xx) <= diam / 2)
    else:
        inside = yy**2 + xx**2 <= (diam / 2) ** 2
    k = inside.mean(axis=(2, 3))
    return k / k.sum()


def aberration_shift_maps(cfg: SystemConfig, view_shape: tuple[int, int], curvature: float = 0.0,
                          astig: float = 0.0, coma: float = 0.0) -> np.ndarray:
    """Field-dependent per-view shift maps ``(nnum, nnum, 2, Hv, Wv)`` in VIEW pixels (dy, dx).

    Geometric ray shifts of a pupil aberration: ``s = (λ/NA) ∇_ρ W(ρ_uv)`` image metres at the
    view's pupil point ``ρ_uv = −((v−c), (u−c)) / R`` (conventions). ``W`` (waves, at normalised
    field ``r = (xn, yn)``): astigmatism ``astig · |r|² · √6 ρ² cos 2(θ − φ)`` with ``φ`` the field
    azimuth (tangential/sagittal), and coma ``coma · |r| · √8 (3ρ² − 2) ρ cos(θ − φ)``; both grow
    with field radius like a simple lens's. Returned in view pixels: ``s / (pixel_pitch · d)``.
    """
    n, c = cfg.nnum, cfg.center
    hv, wv = view_shape
    yn = (2 * (np.arange(hv) + 0.5) / hv - 1)[:, None] * np.ones((1, wv))
    xn = (2 * (np.arange(wv) + 0.5) / wv - 1)[None, :] * np.ones((hv, 1))
    phi = np.arctan2(yn, xn)
    rad = np.hypot(yn, xn)
    cos2, sin2 = np.cos(2 * phi), np.sin(2 * phi)
    cos1, sin1 = np.cos(phi), np.sin(phi)
    out = np.zeros((n, n, 2, hv, wv), dtype=np.float64)
    scale = cfg.wavelength / cfg.na / (cfg.pixel_pitch * cfg.scan_step_px)
    for u in range(n):
        for v in range(n):
            px = -(v - c) / cfg.pupil_radius_px
            py = -(u - c) / cfg.pupil_radius_px
            # astigmatism sqrt6 * rho^2 cos 2(theta - phi) = sqrt6 [(x²−y²) cos2φ + 2xy sin2φ]
            a = astig * rad**2 * np.sqrt(6)
            gx = a * (2 * px * cos2 + 2 * py * sin2)
            gy = a * (-2 * py * cos2 + 2 * px * sin2)
            # field curvature: defocus sqrt3 (2ρ² − 1) → gradient 4 sqrt3 ρ
            f = curvature * rad**2 * 4 * np.sqrt(3)
            gx = gx + f * px
            gy = gy + f * py
            # coma sqrt8 (3ρ² − 2) ρ cos(θ − φ) = sqrt8 (3ρ² − 2)(x cosφ + y sinφ)
            b = coma * rad * np.sqrt(8)
            r2 = px**2 + py**2
            lin = px * cos1 + py * sin1
            gx = gx + b * (6 * px * lin + (3 * r2 - 2) * cos1)
            gy = gy + b * (6 * py * lin + (3 * r2 - 2) * sin1)
            out[u, v, 0] = gy * scale
            out[u, v, 1] = gx * scale
    return out.astype(np.float32)


def render_views(texture: np.ndarray, layers: list[Layer], cfg: SystemConfig,
                 scan: int | None = None, *, shift_maps: np.ndarray | None = None,
                 snr_db: float | None = None, seed: int = 0,
                 view_mask: np.ndarray | None = None) -> SyntheticViews:
    """Render the views of a layered scene (layers back to front); see the module docstring.

    ``texture`` and the layers live on the image-pixel grid ``(H, W)``; the views have
    ``(H // d, W // d)`` samples. ``shift_maps``: ``(nnum, nnum, 2, Hv, Wv)`` aberration shifts
    in view pixels (view content at ``p + s`` shows the unaberrated view's content at ``p``).
    """
    scan = cfg.scan if scan is None else int(scan)
    cfg = cfg.replace(scan=scan)
    texture = np.asarray(texture, dtype=np.float64)
    if texture.ndim != 2:
        raise ValueError(f"texture must be 2-D, got shape {texture.shape}")
    if not layers:
        raise ValueError("layers must hold at least one Layer")
    n, c, d = cfg.nnum, cfg.center, cfg.scan_step_px
    hv, wv = texture.shape[0] // d, texture.shape[1] // d
    mask = cfg.view_mask() if view_mask is None else np.asarray(view_mask, bool)
    py = (np.arange(hv) * d + d // 2)[:, None] * np.ones((1, wv))
    px = (np.arange(wv) * d + d // 2)[None, :] * np.ones((hv, 1))
    prepared = _prepared_layers(texture, layers, _aperture_kernel(cfg))
    views = np.zeros((n, n, hv, wv), dtype=np.float64)
    for u in range(n):
        for v in range(n):
            if mask[u, v]:
                shift = None if shift_maps is None else shift_maps[u, v] * d
                views[u, v] = _composited(prepared, py, px, shift, u - c, v - c)
    truth = _front_disparity(layers, py, px)
    clean = views.astype(np.float32)
    noisy = clean.copy()
    if snr_db is not None:
        rng = np.random.default_rng(seed)
        power = float(np.mean(clean[mask] ** 2))
        sigma = np.sqrt(power / 10 ** (snr_db / 10))
        noisy[mask] += rng.normal(0, sigma, size=noisy[mask].shape).astype(np.float32)
    return SyntheticViews(noisy, clean, (truth / d).astype(np.float32), cfg)


def _prepared_layers(texture: np.ndarray, layers: list[Layer], kern: np.ndarray) -> list:
    """Each layer's colour and opacity blurred by the lenslet aperture and spline-prefiltered
    once (sampled by :func:`_composited` with the prefilter off).

    Parameters
    ----------
    texture : numpy.ndarray
        The scene's common texture ``(H, W)`` on the image-pixel grid.
    layers : list of Layer
        Back to front; checked against ``texture``'s shape (one-line ``ValueError``).
    kern : numpy.ndarray
        The aperture kernel (:func:`_aperture_kernel`).

    Returns
    -------
    list of tuple
        Per layer ``(colour, opacity, constant disparity or None, disparity map or None)``,
        disparities in image pixels per view step.
    """
    prepared = []
    for layer in layers:
        alpha = np.clip(np.asarray(layer.alpha, dtype=np.float64), 0, 1)
        if alpha.shape != texture.shape:
            raise ValueError(f"layer alpha shape {alpha.shape} != texture {texture.shape}")
        tex_l = texture if layer.texture is None else np.asarray(layer.texture, np.float64)
        if tex_l.shape != texture.shape:
            raise ValueError(f"layer texture shape {tex_l.shape} != texture {texture.shape}")
        col = ndimage.spline_filter(ndimage.convolve(tex_l * alpha, kern, mode="reflect"),
                                    order=3, mode="mirror")
        alp = ndimage.spline_filter(ndimage.convolve(alpha, kern, mode="reflect"), order=3,
                                    mode="mirror")
        disp = layer.disparity
        disp_map = None if np.isscalar(disp) else np.asarray(disp, dtype=np.float64)
        prepared.append((col, alp, float(disp) if disp_map is None else None, disp_map))
    return prepared


def _composited(prepared: list, py: np.ndarray, px: np.ndarray, shift, du: int,
                dv: int) -> np.ndarray:
    """One view: the prepared layers sampled at their parallax and composited back to front
    ("over").

    Parameters
    ----------
    prepared : list
        :func:`_prepared_layers`.
    py, px : numpy.ndarray
        The view samples' positions on the image-pixel grid ``(Hv, Wv)``.
    shift : numpy.ndarray or None
        The view's aberration shift ``(2, Hv, Wv)`` (dy, dx) in image pixels, or None.
    du, dv : int
        The view's offset from the centre view [view steps].

    Returns
    -------
    numpy.ndarray
        The view ``(Hv, Wv)`` float64.
    """
    hv, wv = py.shape
    sy, sx = (np.zeros((hv, wv)), np.zeros((hv, wv))) if shift is None else (shift[0], shift[1])
    out = np.zeros((hv, wv))
    for col, alp, dconst, dmap in prepared:
        qy, qx = py - sy, px - sx
        if dmap is None:
            qy, qx = qy - dconst * du, qx - dconst * dv
        else:  # fixed point Q = P − δ(Q) a, two iterations from δ(P)
            ey, ex = qy, qx
            for _ in range(3):
                dq = ndimage.map_coordinates(dmap, [ey, ex], order=1, mode="nearest")
                ey, ex = qy - dq * du, qx - dq * dv
            qy, qx = ey, ex
        cv = ndimage.map_coordinates(col, [qy, qx], order=3, mode="mirror", prefilter=False)
        av = ndimage.map_coordinates(alp, [qy, qx], order=3, mode="mirror", prefilter=False)
        out = out * (1 - np.clip(av, 0, 1)) + cv
    return out


def _front_disparity(layers: list[Layer], py: np.ndarray, px: np.ndarray) -> np.ndarray:
    """The true disparity: the front-most opaque (alpha > 0.5) layer's at each centre-view
    sample ``(py, px)`` [image pixels per view step], 0 where none is."""
    truth = np.zeros(py.shape)
    iy, ix = py.astype(int), px.astype(int)
    for layer in layers:
        a = np.asarray(layer.alpha)[iy, ix] > 0.5
        disp = layer.disparity
        val = disp if np.isscalar(disp) else np.asarray(disp)[iy, ix]
        truth = np.where(a, val, truth)
    return truth


def scene_planes(shape, near: float, far: float, seed: int = 0) -> tuple[np.ndarray, list[Layer]]:
    """Two fronto-parallel planes: a background at disparity ``far`` and a centred square
    (half the field) at ``near`` (both in image pixels per view step), one texture."""
    tex = random_texture(shape, seed)
    h, w = shape
    sq = np.zeros(shape)
    sq[h // 4: 3 * h // 4, w // 4: 3 * w // 4] = 1
    return tex, [Layer(np.ones(shape), far), Layer(sq, near)]


def scene_slanted(shape, d_left: float, d_right: float,
                  seed: int = 0) -> tuple[np.ndarray, list[Layer]]:
    """One slanted plane whose disparity runs linearly from ``d_left`` to ``d_right`` along x
    (image pixels per view step)."""
    tex = random_texture(shape, seed)
    ramp = np.linspace(d_left, d_right, shape[1])[None, :] * np.ones((shape[0], 1))
    return tex, [Layer(np.ones(shape), ramp)]


def scene_staircase(shape, steps: int, d_min: float, d_max: float,
                    seed: int = 0) -> tuple[np.ndarray, list[Layer]]:
    """A staircase: ``steps`` vertical bands at disparities from ``d_min`` (left) to ``d_max``
    (right). Layers are ordered back to front (largest disparity = farthest object first); each
    step continues under the nearer steps (a solid staircase: no holes at the occluding edges).
    With ``d_min > d_max`` the left steps are the far ones and each continues under the right."""
    tex = random_texture(shape, seed)
    edges = np.linspace(0, shape[1], steps + 1).round().astype(int)
    values = np.linspace(d_min, d_max, steps)
    layers = []
    for i in np.argsort(-values):
        a = np.zeros(shape)
        nearer_left = i > 0 and values[i - 1] < values[i]
        nearer_right = i < steps - 1 and values[i + 1] < values[i]
        a[:, 0 if nearer_left else edges[i]:shape[1] if nearer_right else edges[i + 1]] = 1
        layers.append(Layer(a, float(values[i])))
    return tex, layers
