"""Phase screens for the scenarios: Kolmogorov turbulence, plastic wrap, layered frozen flow.

All screens are wavefronts in **waves**. Pupil-plane screens are sampled on ``samples²`` points
covering ``rho ∈ [−1, 1]²`` (sample k at ``rho = −1 + (k + 0.5) · 2 / samples``, as
:mod:`metasensor.simulation.turbulence`); lengths are in pupil diameters D unless stated.

- :func:`kolmogorov_screen`: one Kolmogorov / von Kármán screen from aotools' FFT generator with
  sub-harmonics (``aotools.turbulence.ft_sh_phase_screen``; Lane et al., Waves Random Media 2,
  209 (1992)), whose phase structure function is ``D(r) = 6.88 (r / r0)^{5/3}`` rad² (Fried,
  JOSA 56, 1372 (1966)); :func:`structure_function` measures it, :func:`kolmogorov_structure`
  gives the theory.
- :class:`PlasticWrap`: sheets of plastic wrap a distance in front of the lens (Fig. 3 of the
  paper). Each sheet is a smooth random surface: white Gaussian noise convolved with a Gaussian
  of standard deviation ``correlation`` (pupil diameters), scaled to ``rms_waves / sqrt(layers)``
  r.m.s. over the screen, so its covariance is ``σ² exp(−r² / (4 s²))`` and its structure
  function ``2 σ² (1 − exp(−r² / (4 s²)))`` (hand-written: no library models plastic wrap).
  A sheet at distance z is crossed by the beam of field angle θ at an offset ``z θ``: the field
  point at normalised coordinates (yn, xn) sees the sheet's footprint shifted by
  ``spread · z_k / z_max · (yn, xn)`` pupil diameters, so every field point sees a different
  part of the sheets (anisoplanatic).
- :class:`LayeredTurbulence`: atmospheric layers, each a frozen-flow Kolmogorov screen blown
  across the pupil by its own wind (pupil diameters per frame) and seen by the field point
  (yn, xn) shifted by ``spread · (yn, xn)`` (its height times the field angle). Weights split
  ``(D / r0)^{5/3}`` between the layers (Roddier, Prog. Optics 19, 281 (1981)). It is a
  :class:`~metasensor.simulation.turbulence.Turbulence`, so ``simulate(turbulence=...)`` renders
  its on-axis screen frame by frame (the evolving, isoplanatic part) and
  :meth:`LayeredTurbulence.field_zernike` gives the field-dependent remainder at the scan centre.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from metasensor.optics.zernike import fit_zernike
from metasensor.simulation.turbulence import Turbulence

__all__ = ["kolmogorov_screen", "structure_function", "kolmogorov_structure",
           "gaussian_structure", "PlasticWrap", "Layer", "LayeredTurbulence", "fit_screen"]

FIT_MODES = range(4, 46)  # piston, tip and tilt are image motion, not blur
GENERATE_MIN = 1024


def _seed(seed) -> int:
    if isinstance(seed, np.random.SeedSequence):
        return int(seed.generate_state(1)[0])
    if not isinstance(seed, int | np.integer):
        raise TypeError(f"seed must be an int or a SeedSequence, got {type(seed).__name__}")
    return int(seed)


def kolmogorov_screen(n: int, r0_px: float, outer_scale_px: float | None = None,
                      seed: int | np.random.SeedSequence = 0,
                      generate: int = GENERATE_MIN) -> np.ndarray:
    """One (n, n) float64 Kolmogorov (von Kármán with ``outer_scale_px``) screen in waves.

    Parameters
    ----------
    n : screen side in samples (>= 8).
    r0_px : Fried parameter in samples (at the wavelength the waves refer to).
    outer_scale_px : L0 in samples; None: Kolmogorov (L0 = 1e4 n).
    seed : all randomness.
    generate : side of the screen generated (at least n, rounded up to a power of two).

    The screen is the centre of one generated on at least ``generate`` samples: the FFT
    method with aotools' three sub-harmonic levels still lacks low-frequency power on small
    grids (its structure function is 15-20 % low at lags 2-16 on a 64- or 256-sample grid,
    5-10 % on 1,024), and cropping keeps the large grid's statistics.
    """
    from aotools.turbulence import ft_sh_phase_screen

    if not (isinstance(n, int | np.integer) and n >= 8):
        raise ValueError(f"n must be an integer >= 8, got {n!r}")
    if not (r0_px > 0 and math.isfinite(r0_px)):
        raise ValueError(f"r0_px must be positive, got {r0_px!r}")
    m = 1 << int(math.ceil(math.log2(max(n, int(generate)))))
    l0 = 1e4 * m if outer_scale_px is None else float(outer_scale_px)
    if not l0 > 0:
        raise ValueError(f"outer_scale_px must be positive, got {outer_scale_px!r}")
    # aotools draws from NumPy's global generator when seeded: keep the caller's state intact
    state = np.random.get_state()  # noqa: NPY002 (restoring the legacy global state)
    try:
        scr = ft_sh_phase_screen(float(r0_px), m, 1.0, l0, 0.01, seed=_seed(seed))
    finally:
        np.random.set_state(state)  # noqa: NPY002
    o = (m - n) // 2
    return np.asarray(scr[o:o + n, o:o + n], dtype=np.float64) / (2 * math.pi)


def structure_function(screen: np.ndarray, lags) -> np.ndarray:
    """Measured ``D(r) = <(φ(x + r) − φ(x))²>`` (waves²) at integer ``lags`` (samples), averaged
    over rows and columns of a (n, n) screen (or a stack (..., n, n))."""
    s = np.asarray(screen, dtype=np.float64)
    out = []
    for r in lags:
        r = int(r)
        if not 0 < r < s.shape[-1]:
            raise ValueError(f"lag {r} outside 1 .. {s.shape[-1] - 1}")
        dy = (s[..., r:, :] - s[..., :-r, :]) ** 2
        dx = (s[..., :, r:] - s[..., :, :-r]) ** 2
        out.append(0.5 * (dy.mean() + dx.mean()))
    return np.asarray(out)


def kolmogorov_structure(r, r0) -> np.ndarray:
    """Theory: ``6.88 (r / r0)^{5/3}`` rad² in waves² (Fried 1966)."""
    return 6.88 * (np.asarray(r, float) / r0) ** (5.0 / 3.0) / (2 * math.pi) ** 2


def gaussian_structure(r, rms, correlation) -> np.ndarray:
    """Theory of a Gaussian-smoothed white-noise screen: ``2 σ² (1 − exp(−r² / (4 s²)))``."""
    r = np.asarray(r, float)
    return 2 * rms**2 * (1 - np.exp(-(r**2) / (4 * correlation**2)))


def _sample(big: np.ndarray, centre_yx, samples: int, px_per_d: float) -> np.ndarray:
    """(samples, samples) window of ``big`` covering one pupil (D = ``px_per_d`` big samples)
    centred at ``centre_yx`` (big samples), cubic interpolation."""
    k = (np.arange(samples) + 0.5 - samples / 2) * px_per_d / samples
    yy, xx = np.meshgrid(centre_yx[0] + k, centre_yx[1] + k, indexing="ij")
    return ndimage.map_coordinates(big, [yy, xx], order=3, mode="reflect")


def fit_screen(screen: np.ndarray, jmax: int = 45, modes=FIT_MODES) -> np.ndarray:
    """Noll vector (jmax,) in waves of a (s, s) pupil screen (modes 4..jmax by default: piston,
    tip and tilt excluded), least squares over the unit disk."""
    s = screen.shape[-1]
    k = -1.0 + (np.arange(s) + 0.5) * 2.0 / s
    x, y = np.meshgrid(k, k, indexing="xy")
    return fit_zernike(screen, x, y, jmax=jmax, modes=modes)


@dataclass(frozen=True)
class PlasticWrap:
    """Sheets of plastic wrap in front of the lens (model in the module docstring).

    layers : number of sheets; rms_waves : total r.m.s. over the screens (waves);
    correlation : Gaussian correlation length s (pupil diameters); spread : footprint shift of
    the farthest sheet between the field centre and the field edge (pupil diameters);
    distances : relative distances z_k / z_max of the sheets (default evenly up to 1);
    samples : pupil samples; seed : all randomness.
    """

    layers: int = 3
    rms_waves: float = 3.0
    correlation: float = 0.12
    spread: float = 0.6
    distances: tuple[float, ...] | None = None
    samples: int = 64
    seed: int = 0

    def __post_init__(self) -> None:
        if not (isinstance(self.layers, int) and self.layers >= 1):
            raise ValueError(f"layers must be a positive integer, got {self.layers!r}")
        for name in ("rms_waves", "correlation"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive number, got {v!r}")
        if not (math.isfinite(self.spread) and self.spread >= 0):
            raise ValueError(f"spread must be a non-negative number, got {self.spread!r}")
        if not (isinstance(self.samples, int) and self.samples >= 16):
            raise ValueError(f"samples must be an integer >= 16, got {self.samples!r}")
        dist = self.distances
        if dist is None:
            dist = tuple((k + 1) / self.layers for k in range(self.layers))
        dist = tuple(float(z) for z in dist)
        if len(dist) != self.layers or not all(0 <= z <= 1 for z in dist):
            raise ValueError(f"distances must be {self.layers} values in [0, 1], got {dist}")
        object.__setattr__(self, "distances", dist)

    @property
    def px_per_d(self) -> float:
        return float(self.samples)

    def sheets(self) -> np.ndarray:
        """(layers, n, n) float64 sheet surfaces in waves (big enough for every footprint)."""
        return _wrap_sheets(self)

    def wavefront(self, yn: float = 0.0, xn: float = 0.0) -> np.ndarray:
        """(samples, samples) pupil wavefront (waves) seen from normalised field point
        (yn, xn) ∈ [−1, 1]²: the sum of the sheets' footprints."""
        big = self.sheets()
        c = big.shape[-1] / 2.0 - 0.5
        out = np.zeros((self.samples, self.samples))
        for z, sheet in zip(self.distances, big, strict=True):
            shift = self.spread * z * self.px_per_d
            out += _sample(sheet, (c + shift * yn, c + shift * xn), self.samples, self.px_per_d)
        return out

    def field_zernike(self, jmax: int = 45):
        """Callable ``f(yn, xn) -> (..., jmax)`` Noll vectors (modes 4..jmax) of the footprints,
        the form ``simulate(field_zernike=...)`` takes."""

        @functools.lru_cache(maxsize=4096)
        def one(y: float, x: float) -> np.ndarray:
            return fit_screen(self.wavefront(y, x), jmax)

        def fz(yn, xn):
            yn, xn = np.broadcast_arrays(np.asarray(yn, float), np.asarray(xn, float))
            flat = [one(float(a), float(b)) for a, b in zip(yn.ravel(), xn.ravel(), strict=True)]
            return np.asarray(flat).reshape(*yn.shape, jmax)

        return fz

    def block_variation(self, blocks: tuple[int, int], jmax: int = 45) -> np.ndarray:
        """(by, bx) waves: for a ``blocks`` grid of equal blocks over the field, the r.m.s.
        (Noll 4..jmax) of the largest difference between the wavefront at a block's centre and
        at its four corners: how far the wrap is from uniform over one block, which multisite
        DAO assumes (Wu et al. 2022, Methods: "We assume the aberration is uniform in each
        block")."""
        by, bx = (int(b) for b in blocks)
        if by < 1 or bx < 1:
            raise ValueError(f"blocks must be two positive integers, got {blocks}")
        from metasensor.optics.field import block_centres_normalised

        fz = self.field_zernike(jmax)
        yc, xc = block_centres_normalised(by, bx)
        centre = fz(yc, xc)[..., 3:]
        worst = np.zeros((by, bx))
        for dy in (-1.0 / by, 1.0 / by):
            for dx in (-1.0 / bx, 1.0 / bx):
                diff = fz(yc + dy, xc + dx)[..., 3:] - centre
                worst = np.maximum(worst, np.sqrt((diff**2).sum(-1)))
        return worst


@functools.lru_cache(maxsize=8)
def _wrap_sheets(wrap: PlasticWrap) -> np.ndarray:
    m = wrap.samples
    n = int(2 ** math.ceil(math.log2(m * (1 + 2 * wrap.spread) + 8 * wrap.correlation * m + 8)))
    rng = np.random.default_rng(wrap.seed)
    s_px = wrap.correlation * m
    out = np.empty((wrap.layers, n, n))
    for k in range(wrap.layers):
        sheet = ndimage.gaussian_filter(rng.standard_normal((n, n)), s_px, mode="wrap")
        sheet -= sheet.mean()
        out[k] = sheet * (wrap.rms_waves / math.sqrt(wrap.layers) / sheet.std())
    return out


@dataclass(frozen=True)
class Layer:
    """One turbulent layer: ``weight`` (share of (D/r0)^{5/3}), ``wind`` (pupil diameters per
    frame, (y, x)), ``spread`` (footprint shift between field centre and edge, pupil diameters:
    height × field angle / D)."""

    weight: float
    wind: tuple[float, float]
    spread: float


DEFAULT_LAYERS = (Layer(0.6, (0.0, 0.02), 0.0), Layer(0.4, (0.015, -0.01), 0.4))


@dataclass(frozen=True)
class LayeredTurbulence(Turbulence):
    """Layered frozen-flow turbulence (module docstring); ``d_over_r0`` is the total D / r0 at the
    wavelength, ``layers`` the :class:`Layer` s, ``seed`` all randomness (the ``seed`` of
    :meth:`screens` is ignored, so the simulator and the truth see the same screens).
    ``wind`` of the base class is unused. ``t0``: frame time of the first frame that
    :meth:`screens` returns (consecutive scan periods of one sequence: ``t0 = k · p²``);
    ``span``: frames the whole sequence lasts (the screens are made large enough for it and are
    the same for every ``t0``)."""

    layers: tuple[Layer, ...] = field(default=DEFAULT_LAYERS)
    seed: int = 0
    t0: int = 0
    span: int = 25

    def __post_init__(self) -> None:
        super().__post_init__()
        if not self.layers or not all(isinstance(x, Layer) for x in self.layers):
            raise ValueError("layers must be a non-empty tuple of Layer")
        if not all(x.weight > 0 and x.spread >= 0 for x in self.layers):
            raise ValueError("layer weights must be positive and spreads non-negative")
        if not (isinstance(self.t0, int) and self.t0 >= 0 and isinstance(self.span, int)
                and self.span >= 1):
            raise ValueError(f"t0 must be >= 0 and span >= 1 (integers), got {self.t0!r}, "
                             f"{self.span!r}")

    def at(self, t0: int) -> LayeredTurbulence:
        """The same turbulence, its :meth:`screens` starting at frame ``t0``."""
        import dataclasses

        return dataclasses.replace(self, t0=int(t0))

    def _big(self) -> tuple[np.ndarray, list[tuple[float, float]]]:
        import dataclasses

        base = dataclasses.replace(self, t0=0)  # one set of screens for the whole sequence
        return _layer_screens(base, self.span)

    def screen(self, t: float, yn: float = 0.0, xn: float = 0.0) -> np.ndarray:
        """(samples, samples) wavefront (waves, piston removed) at frame time ``t`` (0 ..
        span − 1) seen from normalised field point (yn, xn)."""
        bigs, starts = self._big()
        s = self.samples
        out = np.zeros((s, s))
        for big, start, layer in zip(bigs, starts, self.layers, strict=True):
            cy = start[0] + (layer.wind[0] * t + layer.spread * yn) * s
            cx = start[1] + (layer.wind[1] * t + layer.spread * xn) * s
            out += _sample(big, (cy, cx), s, float(s))
        return out - out.mean()

    def screens(self, n_frames: int, seed=None) -> np.ndarray:
        """(T, samples, samples) float32 on-axis screens in waves (simulate's interface)."""
        if n_frames < 1:
            raise ValueError(f"n_frames must be >= 1, got {n_frames}")
        return np.stack([self.screen(self.t0 + t) for t in range(n_frames)]).astype(np.float32)

    def field_zernike(self, n_frames: int, t: float | None = None, jmax: int = 45):
        """Callable ``f(yn, xn) -> (..., jmax)``: Noll vectors (modes 4..jmax) of the field
        point's wavefront minus the on-axis one at frame time ``t`` (default: the sequence's
        centre, after ``t0``), the anisoplanatic part that ``simulate(field_zernike=...)`` adds."""
        t = self.t0 + (n_frames - 1) / 2 if t is None else float(t)
        axis = fit_screen(self.screen(t), jmax)

        def fz(yn, xn):
            yn, xn = np.broadcast_arrays(np.asarray(yn, float), np.asarray(xn, float))
            flat = [fit_screen(self.screen(t, a, b), jmax) - axis
                    for a, b in zip(yn.ravel(), xn.ravel(), strict=True)]
            return np.asarray(flat).reshape(*yn.shape, jmax)

        return fz

    def mean_zernike(self, n_frames: int, yn: float = 0.0, xn: float = 0.0,
                     jmax: int = 45) -> np.ndarray:
        """Noll vector (modes 4..jmax) of the field point's wavefront averaged over the frames
        ``t0 .. t0 + n_frames − 1``."""
        return np.mean([fit_screen(self.screen(t, yn, xn), jmax)
                        for t in range(self.t0, self.t0 + n_frames)], axis=0)


@functools.lru_cache(maxsize=8)
def _layer_screens(turb: LayeredTurbulence, n_frames: int):
    s = turb.samples
    rng = np.random.SeedSequence(turb.seed).spawn(len(turb.layers))
    total = sum(x.weight for x in turb.layers)
    bigs, starts = [], []
    for layer, ss in zip(turb.layers, rng, strict=True):
        # layer r0: (D/r0_k)^{5/3} = weight_k / total · (D/r0)^{5/3}
        d_r0 = turb.d_over_r0 * (layer.weight / total) ** 0.6
        travel = [abs(w) * (n_frames - 1) * s for w in layer.wind]
        need = s * (1 + 2 * layer.spread) + max(travel) + 8
        n = 1 << max(int(math.ceil(math.log2(2 * need))), 6)
        l0 = None if turb.outer_scale is None else turb.outer_scale * s
        bigs.append(kolmogorov_screen(n, s / d_r0, l0, ss))
        starts.append(tuple(n / 2 - 0.5 - w * (n_frames - 1) * s / 2 for w in layer.wind))
    return bigs, starts
