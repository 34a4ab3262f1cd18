"""Scenario ``telescope`` (Fig. 5, Extended Data Fig. 8 of the paper): multisite DAO against
dynamic turbulence on a Cassegrain telescope.

The pupil is an annulus (central obstruction ``obstruction``); the scene is scikit-image's
photograph of the Moon; the turbulence is :class:`~metasensor.scenarios.screens.LayeredTurbulence`
(two frozen-flow Kolmogorov layers, total D/r0 = ``d_over_r0``, each blown by its own wind, so
every frame of the scan has its own wavefront; the upper layer's footprint moves across the
field, so the field sees different aberrations). ``periods`` scan periods are simulated as one
sequence. Processing uses the public API only: the first scan window is realigned
(``ms.realign``) and every view motion-corrected by non-rigid registration
(:func:`metasensor.motion.correct.correct_motion_views`, mode "turbulence") if a probe of the
sharpest views finds measurable motion (:func:`correct_if_moving`); the pupil's
obstruction is estimated from those views
(:func:`~metasensor.scenarios.pupil.estimate_annulus`) and used for the PSFs; the image is
reconstructed without DAO (ISA with the ideal annular PSFs) and with multisite wave DAO
(``ms.reconstruct(method="wave")``); the 2D sensor
shares the photon budget. A kymograph (a line through the full-aperture image on the views' grid,
the sum of the views inside the estimated pupil, one row per sliding window of one scan period
every ``stride`` frames, motion-corrected by non-rigid registration) shows whether scan
artefacts remain: its power at the scan lattice's spatial frequencies relative to the same
line of a turbulence-free capture (the static reference). The per-block wavefront residual
compares the DAO estimate with the true wavefront averaged over the window's frames (and, as a
second figure, at its reference frame; Noll 4-45: piston, tip and tilt are image motion).
The truth's size is Kolmogorov theory's (:mod:`metasensor.scenarios.truth`): at D/r0 = 5 a
frame's wavefront is 0.62 λ r.m.s. with piston removed, 87 % of its variance tip and tilt, and
Noll 4-45 carry 0.21 λ; the window's mean carries less, as the screens move during the scan.
The summary gives the truths beside the residual (``true_rms_waves``, ``true_frame_rms_waves``,
``theory_frame_rms_waves``, ``residual_over_true``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from metasensor.scenarios.report import ScenarioSettings

__all__ = ["TelescopeSettings", "run_telescope", "correct_if_moving"]


@dataclass(frozen=True)
class TelescopeSettings(ScenarioSettings):
    """:class:`~metasensor.scenarios.report.ScenarioSettings` (``seed``: turbulence and noise)
    and size : scene side (pixels, >= 192: 12 lenslets); obstruction : central obstruction
    ratio; d_over_r0 : total D / r0; periods : scan periods simulated; stride : frames
    between kymograph windows; check_iterations : also reconstruct without and with DAO by
    Richardson–Lucy with this many iterations (a second solver beside ``iterations``'s, so a
    gain that one solver's artefacts make is seen; None: not);
    key_every, sim_subsample : the simulator's sampling of the evolving turbulence
    (:class:`~metasensor.simulation.turbulence.Turbulence` ``key_every`` and ``subsample``);
    motion_probe : views registered first to see whether the views move measurably (0: every
    view is motion-corrected without a probe; :func:`correct_if_moving`)."""

    size: int = 192
    obstruction: float = 0.35
    d_over_r0: float = 5.0
    periods: int = 2
    stride: int = 2
    key_every: int = 6
    sim_subsample: int = 1
    check_iterations: int | None = 8
    motion_probe: int = 8

    def __post_init__(self) -> None:
        if isinstance(self.motion_probe, bool) or not (
                isinstance(self.motion_probe, int) and self.motion_probe >= 0):
            raise ValueError(f"motion_probe must be an integer >= 0, got {self.motion_probe!r}")
        if not (isinstance(self.size, int) and self.size >= 192):  # 12 lenslets: the views'
            # motion correction needs 12 samples per scan period and axis
            raise ValueError(f"size must be an integer >= 192, got {self.size!r}")
        if not 0.0 <= self.obstruction < 0.9:
            raise ValueError(f"obstruction must lie in [0, 0.9), got {self.obstruction!r}")
        if not self.d_over_r0 > 0:
            raise ValueError(f"d_over_r0 must be positive, got {self.d_over_r0!r}")
        it = self.check_iterations
        if it is not None and not (isinstance(it, int) and it >= 1):
            raise ValueError(f"check_iterations must be None or a positive integer, got {it!r}")
        if self.periods < 2 or self.stride < 1 or min(self.blocks) < 1:
            raise ValueError("periods must be >= 2, stride and blocks >= 1")


def correct_if_moving(views: np.ndarray, order, reference: int, probe: int = 8
                      ) -> tuple[np.ndarray, dict]:
    """Per-view non-rigid motion correction of a view stack
    (:func:`~metasensor.motion.correct.correct_motion_views`, mode "turbulence") where the views
    move measurably.

    The ``probe`` views that resolve the most of their content on the scan's sub-image grid
    (mean :func:`~metasensor.motion.consistency.resolved_fraction`, the registration's own
    evidence measure) are registered first (:func:`~metasensor.motion.correct.estimate_motion`,
    method "registration", its defaults: motion below 0.5 view px, or that does not make the
    dense view more consistent, is zero). If none of them moves, the other views are not
    registered either and the stack is returned as float32, unchanged; else every view is
    corrected. ``probe`` 0: every view is corrected without a probe.

    Returns
    -------
    (views, info)
        The (corrected) stack, and ``info``: ``probe_views`` (count), ``probe_moving_fraction``
        (mean fraction of the probed views' samples with a motion; None without a probe),
        ``corrected`` (whether every view went through the correction).
    """
    from metasensor.motion.consistency import resolved_fraction
    from metasensor.motion.correct import correct_motion_views, estimate_motion

    n = views.shape[0]
    info = {"probe_views": 0, "probe_moving_fraction": None, "corrected": True}
    if probe > 0:
        period = int(round(len(order) ** 0.5))
        live = [(u, v) for u in range(n) for v in range(n) if np.any(views[u, v])]
        score = {uv: float(resolved_fraction(views[uv], period).mean()) for uv in live}
        chosen = sorted(live, key=lambda uv: -score[uv])[:probe]
        moving = [float(np.mean(estimate_motion(views[uv], order, reference,
                                                method="registration") != 0))
                  for uv in chosen]
        info.update(probe_views=len(chosen), probe_moving_fraction=float(np.mean(moving)))
        if not any(moving):
            info["corrected"] = False
            return np.asarray(views, dtype=np.float32).copy(), info
    return correct_motion_views(views, order, reference=reference, mode="turbulence",
                                progress=False), info


class _Clock:
    """Wall and CPU seconds (``time.perf_counter``, ``time.process_time``) of named stages."""

    def __init__(self) -> None:
        self.laps: dict[str, dict[str, float]] = {}
        self._t, self._c = time.perf_counter(), time.process_time()

    def lap(self, name: str) -> None:
        t, c = time.perf_counter(), time.process_time()
        self.laps[name] = {"wall": t - self._t, "cpu": c - self._c}
        self._t, self._c = t, c


def _kymograph(frames, cfg, order, stride: int, correct: bool, pupil) -> np.ndarray:
    """(windows, W) middle row of the sum of the views inside ``pupil`` ((nnum, nnum) bool:
    the full-aperture image on the views' grid) of sliding windows of one scan period every
    ``stride`` frames, motion-corrected by non-rigid registration when ``correct``."""
    import metasensor as ms

    n = len(order)
    half = n // 2
    rows = []
    for t in range(half, frames.shape[0] - (n - 1 - half), stride):
        idx = list(range(t - half, t - half + n))
        worder = [order[i % n] for i in idx]
        image = ms.realign(frames[idx], cfg, scan_order=worder)[pupil].sum(axis=0)
        if correct:
            image = ms.correct_motion(image, worder, reference=half, method="registration")
        rows.append(np.asarray(image)[image.shape[0] // 2])
    return np.stack(rows)


def _lattice(kymo: np.ndarray, period: int) -> float:
    """Power at the scan lattice's spatial frequencies along each window's line, relative to
    the line's mean power (:func:`~metasensor.scenarios.measure.lattice_energy` along x)."""
    from metasensor.scenarios.measure import lattice_energy

    return lattice_energy(kymo.T, period)


def _residuals(rec, turb, n: int, blocks) -> dict[str, np.ndarray]:
    """Per block, r.m.s. (waves, Noll 4-45) of the DAO estimate minus the true wavefront at
    the block's centre, averaged over the window's frames (``mean``) and at its reference
    frame (``reference``), and of the true wavefronts themselves (``true_mean``; at the
    reference frame ``true_frame``)."""
    from metasensor.recon.blocks import block_centre_normalised
    from metasensor.scenarios.screens import fit_screen

    out = {k: np.zeros(tuple(blocks)) for k in ("mean", "reference", "true_mean", "true_frame")}
    for b in rec.blocks:
        yn, xn = (float(a) for a in block_centre_normalised(b, rec.image.shape))
        mean = turb.mean_zernike(n, yn, xn)
        ref = fit_screen(turb.screen(turb.t0 + n // 2, yn, xn))
        est = np.zeros(45)
        z = np.asarray(rec.zernike[b.index], float).ravel()[:45]
        est[:z.size] = z
        out["mean"][b.index] = np.sqrt(((est[3:45] - mean[3:45]) ** 2).sum())
        out["reference"][b.index] = np.sqrt(((est[3:45] - ref[3:45]) ** 2).sum())
        out["true_mean"][b.index] = np.sqrt((mean[3:45] ** 2).sum())
        out["true_frame"][b.index] = np.sqrt((ref[3:45] ** 2).sum())
    return out


def _true_motion(turb, cfg, views) -> dict:
    """R.m.s. and largest true motion (view px) of the lit views between the first scan
    period's frames and its reference frame (:func:`~metasensor.scenarios.truth.view_motion`
    of the on-axis screens; the field's remainder is fixed during a period)."""
    from metasensor.scenarios.truth import view_motion

    n = cfg.scan**2
    m = view_motion(turb.screens(n), cfg, n // 2)
    lit = np.any(views, axis=(2, 3))
    mag = np.hypot(m[..., 0], m[..., 1])[:, lit & np.isfinite(m[0, ..., 0])]
    return {"rms": float(np.sqrt((mag**2).mean())), "max": float(mag.max())}


def _simulate(s: TelescopeSettings, cfg, turb, scene) -> tuple[list, object]:
    """The captures of ``s.periods`` consecutive scan periods (the first with the 2D sensor)
    and a turbulence-free one (the kymograph's static reference), one intensity scale."""
    import metasensor as ms

    n = cfg.scan**2
    caps = []
    for k in range(s.periods):
        tk = turb.at(k * n)
        caps.append(ms.simulate(scene, cfg, turbulence=tk, field_zernike=tk.field_zernike(n),
                                field_blocks=s.blocks, snr_db=s.snr_db, seed=s.seed + k,
                                comparison=k == 0, scale=caps[0].scale if caps else None))
    static = ms.simulate(scene, cfg, snr_db=s.snr_db, seed=s.seed + 99, comparison=False,
                         scale=caps[0].scale)
    return caps, static


def _figures(out: Path, s: TelescopeSettings, truth, images: dict, kymos: dict, est) -> dict:
    from metasensor.io.figures import save_panel

    lo, hi = float(truth.min()), float(truth.max())
    panel = [("ground truth", truth)] + [(k, np.clip(v, lo, hi)) for k, v in images.items()]
    return {
        "full field": save_panel(out / "full_field.png", panel, ncols=3,
                                 suptitle=f"Moon through turbulence, D/r0 = {s.d_over_r0}"),
        "kymographs": save_panel(out / "kymographs.png", list(kymos.items()), ncols=3,
                                 suptitle="kymographs of the full-aperture image (time down, "
                                          "position across)"),
        "pupil": save_panel(out / "pupil.png", [("angular intensity", est.intensity),
                                                ("binary pupil", est.amplitude)], ncols=2,
                            suptitle=f"estimated obstruction {est.obstruction:.3f} "
                                     f"(true {s.obstruction})")}


def _reconstructions(corrected, cfg_est, s: TelescopeSettings) -> dict:
    """The meta-imaging images without and with DAO (and with the check solver, if set)."""
    import metasensor as ms
    from metasensor.recon.parallel import local_workers

    recs, workers = {}, local_workers(s.blocks[0] * s.blocks[1])
    for tag, it in (("", s.iterations), (f" (RL {s.check_iterations})", s.check_iterations)):
        if tag and it is None:
            continue
        recs[f"meta-imaging, no DAO{tag}"] = ms.reconstruct(
            corrected, cfg_est, blocks=s.blocks, iterations=it, num_workers=workers)
        recs[f"meta-imaging + DAO{tag}"] = ms.reconstruct(
            corrected, cfg_est, method="wave", blocks=s.blocks, iterations=it,
            num_workers=workers)
    return recs


def _kymographs(caps, static, cfg, s: TelescopeSettings, ring) -> dict:
    """Kymographs of the static reference, and of the turbulent sequence without and with
    motion correction."""
    frames, order = np.concatenate([c.frames for c in caps]), caps[0].scan_order
    return {"static reference": _kymograph(np.concatenate([static.frames] * s.periods), cfg,
                                           order, s.stride, False, ring),
            "no motion correction": _kymograph(frames, cfg, order, s.stride, False, ring),
            "motion-corrected": _kymograph(frames, cfg, order, s.stride, True, ring)}


def _check_solver(db: dict, iterations: int | None) -> dict | None:
    """The DAO gains measured again with the check solver (Richardson–Lucy ``iterations``)."""
    if iterations is None:
        return None
    tag = f" (RL {iterations})"
    return {"iterations": iterations,
            "dao_gain_db": db[f"meta-imaging + DAO{tag}"] - db[f"meta-imaging, no DAO{tag}"],
            "dao_over_2d_db": db[f"meta-imaging + DAO{tag}"] - db["2D sensor"]}


def run_telescope(out: str | Path, settings: TelescopeSettings | None = None,
                  progress: bool = True) -> dict:
    """Run the scenario and write its report into ``out``; returns the summary."""
    import metasensor as ms
    from metasensor.metrics import psnr
    from metasensor.scenarios.pupil import estimate_annulus
    from metasensor.scenarios.report import scenario_run
    from metasensor.scenarios.screens import LayeredTurbulence
    from metasensor.scenarios.truth import kolmogorov_mode_rms
    from metasensor.simulation.scenes import natural_image

    s = settings or TelescopeSettings()
    with scenario_run(out, "telescope", 5, progress) as run:
        out, steps, clock = run.out, run.steps, _Clock()
        cfg = ms.SystemConfig(obstruction=s.obstruction)
        n = cfg.scan**2
        turb = LayeredTurbulence(d_over_r0=s.d_over_r0, samples=64, seed=s.seed,
                                 span=n * s.periods, key_every=s.key_every,
                                 subsample=s.sim_subsample)
        caps, static = _simulate(s, cfg, turb, natural_image("moon", s.size).astype(np.float32))
        cap = caps[0]
        clock.lap("simulate")
        steps.update()
        views = ms.realign(cap.frames, cfg, cap.scan_order)
        corrected, moved = correct_if_moving(views, cap.scan_order, n // 2, s.motion_probe)
        est = estimate_annulus(corrected, cfg)
        cfg_est = cfg.replace(obstruction=round(est.obstruction, 3))
        clock.lap("motion_and_pupil")
        steps.update()
        recs = _reconstructions(corrected, cfg_est, s)
        dao = recs["meta-imaging + DAO"]
        clock.lap("reconstruct")
        steps.update()
        kymos = _kymographs(caps, static, cfg, s, est.amplitude > 0)
        clock.lap("kymographs")
        steps.update()
        truth = cap.truth
        images = {"2D sensor": cap.sensor2d} | {k: np.asarray(r.image) for k, r in recs.items()}
        span = float(np.ptp(truth))
        rows = [{"sensor": k, "psnr_db": psnr(truth=truth, image=v, data_range=span),
                 "max_error_over_range": float(np.abs(v - truth).max() / span)}
                for k, v in images.items()]
        db = {r["sensor"]: r["psnr_db"] for r in rows}
        resid = _residuals(dao, turb, n, s.blocks)
        lat = {k: _lattice(v, cfg.scan) for k, v in kymos.items()}
        summary = {
            "scenario": "telescope", "table": rows,
            "dao_gain_db": db["meta-imaging + DAO"] - db["meta-imaging, no DAO"],
            "dao_over_2d_db": db["meta-imaging + DAO"] - db["2D sensor"],
            "check_solver": _check_solver(db, s.check_iterations),
            "pupil": {"true_obstruction": s.obstruction, "estimated_obstruction": est.obstruction,
                      "error": abs(est.obstruction - s.obstruction), "blur_views": est.blur},
            "motion_corrected_fraction": float(np.mean(corrected != views)),
            "motion": {**moved, "true_view_motion_px": _true_motion(turb, cfg, views)},
            "wavefront_residual_rms_waves": resid["mean"],
            "residual_max_waves": float(resid["mean"].max()),
            "residual_reference_frame_waves": resid["reference"],
            "true_rms_waves": resid["true_mean"],
            "true_frame_rms_waves": resid["true_frame"],
            "residual_over_true": resid["mean"] / resid["true_mean"],
            "theory_frame_rms_waves": {
                "piston_removed": kolmogorov_mode_rms(s.d_over_r0, 2, 10**6),
                "noll_4_45": kolmogorov_mode_rms(s.d_over_r0, 4, 45)},
            "kymograph": {"lattice_static": lat["static reference"],
                          "lattice_corrected_over_static":
                              lat["motion-corrected"] / lat["static reference"],
                          "lattice_uncorrected_over_static":
                              lat["no motion correction"] / lat["static reference"]},
            "turbulence": {"d_over_r0": s.d_over_r0, "layers": [
                {"weight": x.weight, "wind_d_per_frame": x.wind, "spread_d": x.spread}
                for x in turb.layers], "outer_scale": turb.outer_scale, "seed": s.seed},
            "settings": {"size": s.size, "blocks": s.blocks, "periods": s.periods,
                         "stride": s.stride, "snr_db": s.snr_db, "key_every": s.key_every,
                         "sim_subsample": s.sim_subsample,
                         "check_iterations": s.check_iterations},
            "stage_seconds": clock.laps,
        }
        figs = _figures(out, s, truth, images, kymos, est)
        return run.finish(summary, figs, "metasensor scenario: telescope (Fig. 5)")
