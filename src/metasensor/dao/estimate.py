"""Digital adaptive optics in one block: wave-optics (and geometric) wavefront estimation.

Hand-written from the paper (Methods, "ISA with multisite DAO in wave optics"; system.md §4).
Alternate, starting from φ = ``init`` (or 0):

1. H = PSFs of every view from the pupil A·exp(i2πφ) (``view_psfs(cfg, zernike=φ,
   amplitude=A)``; "geometric" mode: the aberration-free PSFs translated by the accumulated view
   shifts, never reshaped);
2. I = Σ_uv e_uv Deconv(V_uv translated by −s_uv, H_uv) / Σ_uv e_uv — Krishnan–Fergus
   deconvolution (α = 2/3, λ = 5e4) of every view, up-sampled from its scan-step grid to the
   pixel grid; e_uv = Σ H_uv (the views' light, so the mean is weighted by signal): the
   paper's estimate (``estimator="views"``);

   Not in the paper (added here; the default, ``estimator="isa"``): once the last update is
   below ``isa_below`` (0.5 λ), I = the block's ISA, the phase-space Richardson–Lucy
   deconvolution of all views together with the current PSFs (:meth:`DaoBlock.estimate_isa`,
   5 iterations, 16 subsets), measured against once per update. The mean of separately
   deconvolved views lacks the detail only their combination resolves, and its predictions bias
   the shifts: started from the *true* 3 λ aberration (240-px block, 30 dB, draw 1), one update
   moved the estimate 0.172 / 0.181 λ away with the mean (astronaut / camera) and 0.035 /
   0.059 λ with the ISA. Far from the truth the ISA absorbs part of the error into I, so the
   shifts under-read it and the loop creeps: ISA from the first update ended camera draw 0 at
   0.322 λ (updates 0.17, 0.074 < tol, still 0.215 λ after 10 updates), and the six 3 λ draws at
   0.08-0.32 λ (mean-only: 0.12-0.31 λ); hence the mean for the coarse steps. With the switch
   at 0.5 λ (``benchmarks/bench_ed_fig4.py``, 2 scenes × 3 draws): 3 λ 0.083-0.147 λ in
   81-155 s per draw (mean-only 133-410 s); 1 λ 0.029-0.057 λ in 3 updates.
3. s_uv = shift of V_uv against the prediction S_d(I ⊛ H_uv) (sub-sample cross-correlation),
   in image pixels, clipped to ±50 px (the authors' limit);

   Not in the paper (added here): the shift measurement weights each view sample by how much
   of its predicted light comes from inside the block (``DaoBlock.reliability``: 0 below 95 %,
   1 at 100 %; one convolution of the block's indicator with each PSF). A view of a large
   aberration is displaced by a large part of the block (3 λ r.m.s.: 100-190 px), so part of
   its field records light from outside the block, where the estimate I is not known; the
   unweighted correlation is pulled by it. Measured (240-px block, 3 λ, camera, draw 0): with
   the *true* PSFs and the *true* image the shifts fitted to a 0.65 λ update without the
   weights and 0.16-0.19 λ with them (thresholds 0.97-0.9); wave DAO from φ = 0 ended at
   1.92 λ residual before and 0.61 λ after (``benchmarks/bench_ed_fig4.py`` has all draws).
4. every ``inner`` (3) iterations, fit the shifts by Zernike modes 4–45 plus a common offset
   (:mod:`metasensor.dao.wavefront`), add the fit to φ, regenerate the PSFs and restart the
   shifts from 0. Stop when the r.m.s. of the update is below ``tol`` (0.1 λ; 0 runs all) or
   after ``max_iter`` updates.

   Not in the paper (added here): the fit weights every view by the precision of its shift
   (:func:`metasensor.align.shifts.shift_precision`: the inverse variance of the shift under
   white noise, from the prediction's gradients and the residual; the paper's fit weighs all
   views alike; ``weigh_views=False`` restores that). At 3 λ the views' precisions span more
   than two orders of magnitude (few known samples, blurred or dim views); the plain fit let
   the poor ones set the low orders (radial orders 2–5 held 0.3–0.4 λ each of the remaining
   error). Measured (``benchmarks/bench_ed_fig4.py``, 2 scenes × 3 draws, wave DAO from φ = 0):
   3 λ on 240-px blocks, 0.33–0.93 → 0.12–0.31 λ residual; 1 λ on 150-px blocks after 3
   updates, 0.041–0.120 → 0.027–0.056 λ; 1 λ at SNR 10 dB (``tests/recon/test_dao.py``),
   0.149 → 0.112 λ.

``history`` holds the r.m.s. (waves, modes 4–45) of every update. Views used: ``cfg.view_mask()``
(113 for the prototype) and, when a pupil amplitude is given, its lit views. The mean in step 2
needs no visiting order (the authors' spiral order matters for their sequential RL updates,
not for this average).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch

from metasensor.backend import as_tensor, resolve_device, to_numpy
from metasensor.config import SystemConfig
from metasensor.dao.block import DaoBlock
from metasensor.dao.wavefront import (
    DAO_MODES,
    fit_shifts,
    gradient_matrix,
    zernike_rms,
)
from metasensor.dao.wavefront import predicted_shifts as _predicted
from metasensor.solvers.krishnan_fergus import DEFAULT_LAMBDA

__all__ = ["estimate_block_aberration", "DaoResult", "run_dao", "geometric_psfs", "block_psfs",
           "ray_reach_px", "psf_window"]

JMAX = 45


@dataclass
class DaoResult:
    """Everything one DAO run produced. zernike (45,) waves; history: r.m.s. of each update;
    shifts (nnum, nnum, 2): for "geometric", the accumulated absolute view shifts (pixels) the
    PSFs were translated by, for "wave" the last residual shifts; image: the last intermediate
    estimate I (pixel grid); fits: residual r.m.s. (px) of every shift fit."""

    zernike: np.ndarray
    history: list[float]
    shifts: np.ndarray
    method: str
    image: np.ndarray | None = None
    fits: list[float] = field(default_factory=list)
    psf_size: int | None = None  # K of the banks (None: view_psfs' default 99.5 % window)
    estimates: list[np.ndarray] = field(default_factory=list)  # φ (45,) after every update


# ----------------------------------------------------------------------------- PSF banks
def ray_reach_px(cfg: SystemConfig, zernike, mask=None, subsample: int = 5) -> float:
    """Largest geometric ray displacement (image pixels), ``k |∇W|`` with k = (λ/NA)/pitch, over
    the pupil footprints of the views in ``mask`` (default ``cfg.view_mask()``; each footprint a
    square of side 1/pupil_radius_px around the view's pupil point, sampled by ``subsample²``
    points, clipped to the pupil). Tip and tilt included. 0 for None / a zero vector."""
    from metasensor.dao.wavefront import shift_scale
    from metasensor.optics.zernike import zernike_gradients

    if zernike is None:
        return 0.0
    z = np.asarray(zernike, dtype=np.float64).ravel()
    if not np.isfinite(z).all():
        raise ValueError("zernike contains NaN or infinite values")
    if not np.any(z):
        return 0.0
    m = cfg.view_mask() if mask is None else np.asarray(mask, dtype=bool)
    rho_x, rho_y = cfg.pupil_coords()
    off = ((np.arange(subsample) + 0.5) / subsample - 0.5) / cfg.pupil_radius_px
    px = (rho_x[m][:, None, None] + off[None, None, :]).repeat(subsample, axis=1)
    py = (rho_y[m][:, None, None] + off[None, :, None]).repeat(subsample, axis=2)
    inside = px * px + py * py <= 1.0
    g = np.tensordot(z, zernike_gradients(px[inside], py[inside], jmax=max(z.size, 3))[:z.size],
                     axes=(0, 0))  # (2, P) waves per unit rho
    return float(shift_scale(cfg) * np.sqrt((g**2).sum(axis=0)).max()) if g.size else 0.0


def psf_window(cfg: SystemConfig, zernike=None, mask=None, margin: float | None = None) -> int:
    """Odd PSF window K (pixels) for DAO and ISA banks of the views in ``mask``:
    ``2·ceil(reach + margin) + 1``, reach = :func:`ray_reach_px`, margin (pixels; default one
    lenslet, ``nnum``, plus 10 λ/NA of sub-aperture diffraction). Much smaller than
    ``view_psfs``' default window (99.5 % of the light of *all* views, sized by the ray reach at
    the pupil rim, where high-order Zernike gradients peak), which the dark outer views need but
    the used ones do not; the light it drops is measured in ``tests/recon/test_dao.py``."""
    from metasensor.dao.wavefront import shift_scale

    if margin is None:
        margin = cfg.nnum + 10.0 * shift_scale(cfg)
    if not (np.isfinite(margin) and margin >= 0):
        raise ValueError(f"margin must be a non-negative number of pixels, got {margin!r}")
    return 2 * int(math.ceil(ray_reach_px(cfg, zernike, mask) + margin)) + 1


def _psf_bank(cfg: SystemConfig, zernike, amplitude, device, psf_kw) -> np.ndarray:
    from metasensor.optics.psf import view_psfs

    kw = dict(psf_kw or {})
    if amplitude is not None:
        kw["amplitude"] = amplitude
    return view_psfs(cfg, zernike=zernike, device=device, **kw)


def geometric_psfs(ideal: np.ndarray, shifts: np.ndarray) -> np.ndarray:
    """Aberration-free PSFs ``(n, n, K, K)`` translated by ``shifts (n, n, 2)`` pixels (y, x)
    (Fourier shift, after padding K to hold the largest shift; every view keeps its energy;
    :func:`metasensor.dao.bank_registration.translate_psfs`) → ``(n, n, K', K')``, K' odd."""
    from metasensor.dao.bank_registration import translate_psfs

    h = np.asarray(ideal, dtype=np.float32)
    s = np.asarray(shifts, dtype=np.float64)
    n, _, k, _ = h.shape
    if s.shape != (n, n, 2):
        raise ValueError(f"shifts must have shape ({n}, {n}, 2), got {s.shape}")
    out = translate_psfs(torch.tensor(h.reshape(n * n, k, k), device="cpu"),
                         torch.tensor(s.reshape(n * n, 2), device="cpu"))
    return to_numpy(out).reshape(n, n, *out.shape[-2:]).astype(np.float32)


def block_psfs(cfg: SystemConfig, result: DaoResult, amplitude=None, device=None,
               **psf_kw) -> np.ndarray:
    """The PSF bank to reconstruct a block with after DAO: wave → ``view_psfs`` of the estimate;
    geometric → the ideal bank translated by the estimated view shifts (never reshaped).
    The window is ``result.psf_size`` unless ``psf_kw`` gives ``size``."""
    if result.psf_size is not None:
        psf_kw.setdefault("size", result.psf_size)
    if result.method == "geometric":
        return geometric_psfs(_psf_bank(cfg, None, amplitude, device, psf_kw), result.shifts)
    return _psf_bank(cfg, result.zernike, amplitude, device, psf_kw)


# ----------------------------------------------------------------------------- the loop
def gradient_shifts(phi: np.ndarray, matrix) -> np.ndarray:
    """Modelled view shifts (pixels) of the modes 4–45 of a Noll vector."""
    z = np.array(phi, dtype=np.float64)
    z[:3] = 0.0
    return _predicted(z, None, matrix=matrix)


def run_dao(block_views, cfg: SystemConfig, method: str = "wave", init=None, device=None, *,
            amplitude=None, max_iter: int = 5, inner: int = 3, tol: float = 0.1,
            lam: float = DEFAULT_LAMBDA, max_shift_px: float = 50.0, modes=DAO_MODES,
            view_mask=None, chunk: int = 16, psf_kw: dict | None = None,
            psf_size: int | str | None = "auto", weigh_views: bool = True,
            estimator: str = "isa", isa_below: float = 0.5,
            progress: bool = False) -> DaoResult:
    """Wavefront estimation in one block (module docstring); returns a :class:`DaoResult`.

    block_views : (nnum, nnum, h, w) the block's views (scan-step grid, any intensity scale).
    method : "wave" (PSFs regenerated from the estimated pupil) or "geometric" (ideal PSFs
        translated by the measured shifts).
    init : initial Noll vector (waves), e.g. the local system aberration; None = 0.
    amplitude : (nnum, nnum) pupil amplitude (:mod:`metasensor.dao.pupil`) or None.
    psf_kw : extra keyword arguments for ``view_psfs`` (e.g. ``{"cache": False}``).
    psf_size : PSF window K: "auto" (default) :func:`psf_window` of the current estimate over
        the used views, recomputed at every update (geometric: of the ideal bank, then padded by
        the shifts); None: ``view_psfs``' default (99.5 % of all views' light, several times
        larger and slower); or an odd int. ``psf_kw["size"]`` overrides it.
    weigh_views : weight every view's shift in the Zernike fit by its precision (step 4;
        default); False: all views alike (the paper's plain least squares).
    estimator : the intermediate image I of step 2: "isa" (default) uses the paper's mean (as
        "views") for the first update and while the last update's r.m.s. exceeds ``isa_below``
        (waves), then the block's phase-space Richardson–Lucy with the current PSFs
        (:meth:`DaoBlock.estimate_isa`; one estimate and one measurement per update);
        ``isa_below=inf`` uses it from the first update. "views": always the paper's mean of
        the views' Krishnan–Fergus deconvolutions (``inner`` estimate/measure rounds per update).
    """
    if method not in ("wave", "geometric"):
        raise ValueError(f"method must be 'wave' or 'geometric', got {method!r}")
    n = cfg.nnum
    v = np.asarray(block_views)
    if v.ndim != 4 or v.shape[:2] != (n, n):
        raise ValueError(f"block_views must have shape ({n}, {n}, h, w), got {v.shape}")
    if min(v.shape[2:]) < 8:
        raise ValueError(f"block too small for DAO: views of {v.shape[2:]} samples")
    if not np.isfinite(v).all():
        raise ValueError("block_views contain NaN or infinite values")
    if estimator not in ("isa", "views"):
        raise ValueError(f"estimator must be 'isa' or 'views', got {estimator!r}")
    if not isa_below >= 0:
        raise ValueError(f"isa_below must be a non-negative number of waves, got {isa_below!r}")
    if max_iter < 1 or inner < 1:
        raise ValueError(f"max_iter and inner must be >= 1, got {max_iter}, {inner}")
    for name, value in (("lam", lam), ("max_shift_px", max_shift_px)):
        if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a positive number, got {value!r}")
    if not (isinstance(tol, int | float) and math.isfinite(tol) and tol >= 0):  # 0: all updates
        raise ValueError(f"tol must be a non-negative number of waves, got {tol!r}")
    if not (isinstance(chunk, int | np.integer) and chunk >= 1):
        raise ValueError(f"chunk must be a positive integer, got {chunk!r}")
    if np.iscomplexobj(v):
        raise ValueError(f"block_views must be real, got dtype {v.dtype}")
    if not (psf_size is None or psf_size == "auto"
            or (isinstance(psf_size, int | np.integer) and psf_size > 0 and psf_size % 2)):
        raise ValueError(f"psf_size must be 'auto', None or a positive odd int, got {psf_size!r}")
    phi = np.zeros(JMAX)
    if init is not None:
        z0 = np.asarray(init, dtype=np.float64).ravel()
        if not np.isfinite(z0).all():
            raise ValueError("init contains NaN or infinite values")
        phi[: min(z0.size, JMAX)] = z0[:JMAX]
    used = cfg.view_mask() if view_mask is None else np.asarray(view_mask, dtype=bool)
    if amplitude is not None:
        amp = np.asarray(amplitude, dtype=np.float64)
        if amp.shape != (n, n):
            raise ValueError(f"amplitude must have shape ({n}, {n}), got {amp.shape}")
        used = used & (amp > 0)
    matrix = gradient_matrix(cfg, jmax=JMAX)
    used = used & (matrix[1] >= 0.5)
    if used.sum() < 8:
        raise ValueError(f"only {int(used.sum())} usable views: cannot estimate a wavefront")
    dev = resolve_device(device)
    views = as_tensor(v.reshape(n * n, *v.shape[2:])[used.ravel()], dev)
    blk = DaoBlock(views, cfg, used, lam, chunk)

    def size_for(phi_):
        if psf_kw and "size" in psf_kw:
            return psf_kw["size"]
        if psf_size == "auto":
            return psf_window(cfg, phi_ if method == "wave" else None, used)
        return None if psf_size is None else int(psf_size)

    def kw_for(phi_):
        return {**(psf_kw or {}), "size": size_for(phi_)}

    ideal = _psf_bank(cfg, None, amplitude, device, kw_for(None)) if method == "geometric" \
        else None
    # geometric: accumulated absolute view shifts (pixels), starting from those of init
    total = np.where(used[..., None], gradient_shifts(phi, matrix), 0.0)

    def bank_for(phi_):
        if method == "wave":
            return _psf_bank(cfg, phi_, amplitude, device, kw_for(phi_))
        return geometric_psfs(ideal, total)

    history: list[float] = []
    fits: list[float] = []
    estimates: list[np.ndarray] = []
    s_full = np.zeros((n, n, 2))
    image = None
    from tqdm.auto import tqdm

    bar = tqdm(total=max_iter, desc=f"DAO ({method})", disable=not progress, leave=False)
    for _ in range(max_iter):
        blk.set_psfs(bank_for(phi))
        last = history[-1] if history else math.inf  # inf <= isa_below only for isa_below=inf
        if estimator == "isa" and last <= isa_below:
            image = blk.estimate_isa()
        else:
            s = torch.zeros((views.shape[0], 2), device=dev, dtype=torch.float64)
            for _k in range(inner - 1):
                s = blk.measure(blk.estimate(s.to(views.dtype)), max_shift_px)
            image = blk.estimate(s.to(views.dtype))
        s, prec = blk.measure(image, max_shift_px, precision=True)
        s_full = np.full((n, n, 2), np.nan)
        s_full[used] = to_numpy(s)
        clipped = np.abs(s_full).max(axis=-1) >= max_shift_px - 1e-6
        wts = None
        if weigh_views:
            wts = np.zeros((n, n))
            wts[used] = np.nan_to_num(to_numpy(prec), nan=0.0, posinf=0.0)
            mean_w = float(wts[used & ~clipped].mean()) if (used & ~clipped).any() else 0.0
            wts = wts / mean_w if mean_w > 0 else None
        fit = fit_shifts(np.nan_to_num(s_full), cfg, mask=used & ~clipped, modes=modes,
                         weights=wts, jmax=JMAX, matrix=matrix)
        dz = fit.zernike
        fits.append(fit.residual_rms)
        history.append(zernike_rms(dz, modes))
        phi = phi + dz
        estimates.append(phi.copy())
        if method == "geometric":
            total = total + np.where(used[..., None], np.nan_to_num(s_full) - fit.tilt, 0.0)
        bar.set_postfix_str(f"update {history[-1]:.3f} λ, wavefront "
                            f"{zernike_rms(phi, modes):.3f} λ r.m.s.", refresh=False)
        bar.update(1)
        if history[-1] < tol:
            break
    bar.close()
    return DaoResult(zernike=phi, history=history,
                     shifts=total if method == "geometric" else np.nan_to_num(s_full),
                     method=method, image=None if image is None else to_numpy(image) * blk.scale,
                     fits=fits, psf_size=size_for(phi), estimates=estimates)


def estimate_block_aberration(block_views, cfg: SystemConfig, method: str = "wave", init=None,
                              device=None, **kw) -> tuple[np.ndarray, list[float]]:
    """Estimate one block's aberration (the contract used by ``reconstruct``): returns the Noll
    vector ``(45,)`` in waves and the r.m.s. of every phase update. ``kw`` go to
    :func:`run_dao`. For ``method="geometric"`` reconstruct with :func:`block_psfs` (ideal PSFs
    translated by the measured shifts), not with PSFs regenerated from this vector."""
    res = run_dao(block_views, cfg, method=method, init=init, device=device, **kw)
    return res.zernike.astype(np.float64), list(res.history)
