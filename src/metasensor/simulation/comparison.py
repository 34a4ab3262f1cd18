"""Comparison sensors from the same scene, optics and photon budget.

- a conventional 2D sensor: the scene blurred by the widefield PSF of the same (aberrated) lens,
  integrated over the same pixels (the fine-grid model of :mod:`metasensor.simulation.kernels`);
- hardware adaptive optics: an N × N segmented tip-tilt(-piston) mirror conjugate to the pupil,
  its segments tiling the square around the pupil, measuring the wavefront perfectly. The residual
  is the wavefront minus its per-segment least-squares piston/tip/tilt fit (paper, Methods). The
  mirror corrects the on-axis (field-centre) wavefront; off-axis field points keep the difference.
- a plain light-field camera: :func:`metasensor.simulation.capture.plain_lightfield`, the same
  simulation with a 1 × 1 scan.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

__all__ = ["SegmentedMirror", "zernike_wavefront", "comparison_sensors"]


def zernike_wavefront(z) -> Callable[[np.ndarray, np.ndarray], np.ndarray] | None:
    """Callable ``W(rho_x, rho_y)`` [waves] of a Noll vector (None → None)."""
    if z is None:
        return None
    from metasensor.optics.zernike import wavefront

    z = np.asarray(z, dtype=np.float64)
    return lambda x, y: np.asarray(wavefront(z, np.asarray(x, float), np.asarray(y, float)))


class SegmentedMirror:
    """Least-squares per-segment piston/tip/tilt fit of a wavefront over an annular pupil.

    ``segments`` per axis tile the square [−1, 1]² of normalised pupil coordinates; the fit uses
    ``samples`` points per segment side, inside ``obstruction <= |rho| <= 1``. Segments holding
    fewer than 3 pupil samples fit piston only.
    """

    def __init__(self, segments: int = 15, obstruction: float = 0.0, samples: int = 12):
        if not (isinstance(segments, int) and segments >= 1):
            raise ValueError(f"segments must be a positive integer, got {segments!r}")
        self.segments, self.obstruction, self.samples = segments, float(obstruction), samples
        m = segments * samples
        g = -1.0 + (np.arange(m) + 0.5) * 2.0 / m
        self.x, self.y = np.meshgrid(g, g)  # x along columns, y along rows
        r = np.hypot(self.x, self.y)
        self.inside = (r <= 1.0) & (r >= self.obstruction)

    def segment_index(self, rho_x, rho_y) -> tuple[np.ndarray, np.ndarray]:
        n = self.segments
        sy = np.clip(np.floor((np.asarray(rho_y) + 1.0) * n / 2.0), 0, n - 1).astype(int)
        sx = np.clip(np.floor((np.asarray(rho_x) + 1.0) * n / 2.0), 0, n - 1).astype(int)
        return sy, sx

    def fit(self, wavefront: Callable) -> np.ndarray:
        """Per-segment coefficients (segments, segments, 3): piston, tip (x), tilt (y)."""
        n, s = self.segments, self.samples
        w = np.asarray(wavefront(self.x, self.y), dtype=np.float64)
        coef = np.zeros((n, n, 3))
        for i in range(n):
            for j in range(n):
                sl = (slice(i * s, (i + 1) * s), slice(j * s, (j + 1) * s))
                keep = self.inside[sl]
                if not keep.any():
                    continue
                xs, ys, ws = self.x[sl][keep], self.y[sl][keep], w[sl][keep]
                if keep.sum() < 3:
                    coef[i, j, 0] = ws.mean()
                    continue
                a = np.stack([np.ones_like(xs), xs, ys], axis=1)
                coef[i, j] = np.linalg.lstsq(a, ws, rcond=None)[0]
        return coef

    def correction(self, wavefront: Callable) -> Callable:
        """Callable ``D(rho_x, rho_y)``: the mirror's surface (in waves of wavefront)."""
        coef = self.fit(wavefront)

        def mirror(rho_x, rho_y):
            rx, ry = np.broadcast_arrays(np.asarray(rho_x, float), np.asarray(rho_y, float))
            sy, sx = self.segment_index(rx, ry)
            c = coef[sy, sx]
            return c[..., 0] + c[..., 1] * rx + c[..., 2] * ry

        return mirror

    def residual(self, wavefront: Callable, corrected: Callable | None = None) -> Callable:
        """Callable residual ``W − D`` where D is fitted to ``corrected`` (default: W itself)."""
        mirror = self.correction(wavefront if corrected is None else corrected)
        return lambda x, y: np.asarray(wavefront(x, y), dtype=np.float64) - mirror(x, y)

    def rms(self, wavefront: Callable) -> float:
        """R.m.s. [waves] of ``wavefront`` over the pupil (piston removed)."""
        w = np.asarray(wavefront(self.x, self.y), dtype=np.float64)[self.inside]
        return float(np.sqrt(np.mean((w - w.mean()) ** 2)))


def _with_turbulence(w, turb):
    """Wavefront callable ``w`` plus the turbulence phase ``turb`` (either may be None)."""
    if turb is None:
        return w
    if w is None:
        return turb
    return lambda x, y: np.asarray(w(x, y)) + turb(x, y)


def _on_axis(zernike, field_zernike, grid):
    """The field-centre Noll vector the hardware AO's mirror is fitted to."""
    from metasensor.optics.field import evaluate_field_zernike
    from metasensor.simulation.layers import add_zernike

    if field_zernike is None:
        return zernike
    local = evaluate_field_zernike(field_zernike if callable(field_zernike) else grid,
                                   np.zeros(1), np.zeros(1))[0]
    return add_zernike(zernike, local)


def comparison_sensors(cap, reference: np.ndarray, plan, zernike, field_zernike,
                       ao_segments: int, seeds) -> None:
    """Fill ``cap``'s ``sensor2d`` and ``hardware_ao`` (clean and noisy) in place: the scene
    ``reference`` through the widefield PSF of the same (aberrated) lens, and through it with
    an ``ao_segments``² mirror fitted to the on-axis wavefront (each field block keeps W_k − D);
    same scale, gain and noise model as the views (``seeds[1]``, ``seeds[2]``). ``ao_segments``
    0: the 2D sensor only (``hardware_ao`` stays None).

    ``plan``: :class:`metasensor.simulation.sampling.RenderPlan` of the capture."""
    import torch

    from metasensor.simulation.noise import apply_noise
    from metasensor.simulation.render import Lattice
    from metasensor.simulation.sampling import accumulate, prefetch_kernels
    from metasensor.simulation.turbulence import screen_phase

    banks, comps, dev = plan.banks, plan.comps, plan.banks.device
    ly, lx = cap.truth.shape
    rows, cols = Lattice(cap.offset, 1, ly), Lattice(cap.offset, 1, lx)
    screen = None if plan.screens is None else plan.screens[int(round(plan.tref))]
    turb = None if screen is None else screen_phase(screen)
    out = torch.zeros((1, ly, lx), dtype=torch.float32, device=dev)

    def kernel_of(cp):
        return banks.widefield(cp.zernike, cp.depth, turb, "t")

    prefetch_kernels(comps, kernel_of, dev)
    accumulate(reference, comps, kernel_of, rows, cols, out, dev)
    s2d = out[0].cpu().numpy() * np.float32(cap.scale)
    if ao_segments == 0:
        cap.sensor2d_clean = s2d
        cap.sensor2d = apply_noise(s2d, cap.noise, np.random.default_rng(seeds[1]))
        return
    mirror = SegmentedMirror(ao_segments, cap.config.obstruction)
    w_axis = _with_turbulence(zernike_wavefront(_on_axis(zernike, field_zernike, plan.grid)),
                              turb)
    if w_axis is None:
        ao = s2d.copy()
        cap.ao_residual_rms = 0.0
    else:
        fitted = mirror.correction(w_axis)
        residuals = {}

        def ao_kernel(cp):
            w_k = _with_turbulence(zernike_wavefront(cp.zernike), turb) or (lambda x, y: 0.0 * x)
            if cp.block not in residuals:
                residuals[cp.block] = lambda x, y, w=w_k: np.asarray(w(x, y)) - fitted(x, y)
            return banks.widefield(None, cp.depth, residuals[cp.block], ("ao", cp.block))

        out.zero_()
        accumulate(reference, comps, ao_kernel, rows, cols, out, dev)
        ao = out[0].cpu().numpy() * np.float32(cap.scale)
        cap.ao_residual_rms = mirror.rms(lambda x, y: np.asarray(w_axis(x, y)) - fitted(x, y))
    cap.sensor2d_clean, cap.hardware_ao_clean = s2d, ao
    cap.sensor2d = apply_noise(s2d, cap.noise, np.random.default_rng(seeds[1]))
    cap.hardware_ao = apply_noise(ao, cap.noise, np.random.default_rng(seeds[2]))
