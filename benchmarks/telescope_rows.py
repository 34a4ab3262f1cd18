"""The telescope's measurement rows of ``bench_scenarios``: what its evolving turbulence costs the
simulator (``telescope-simulation``), its truth against Kolmogorov theory (``telescope-truth``)
and what the per-view motion correction could find (``telescope-motion``). Each row is
described in ``bench_scenarios``' docstring; this module holds their code so that file stays
one concept per file. Not a benchmark of its own (no ``bench_`` prefix).
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "src"))


def _sim_views(scene, cfg, turb, fz, blocks) -> tuple[np.ndarray, float]:
    """Clean views of one scan period (scale 1) and the CPU seconds they took."""
    import metasensor as ms

    c0 = time.process_time()
    cap = ms.simulate(scene, cfg, turbulence=turb, field_zernike=fz, field_blocks=blocks,
                      comparison=False, seed=0, scale=1.0)
    return cap.views_clean, time.process_time() - c0


def telescope_simulation(quick: bool = False) -> dict:
    """The ``telescope-simulation`` row (``bench_scenarios`` docstring)."""
    import dataclasses

    import torch

    import metasensor as ms
    from metasensor.optics.psf import view_psfs
    from metasensor.scenarios.screens import LayeredTurbulence
    from metasensor.scenarios.telescope import TelescopeSettings
    from metasensor.simulation.scenes import natural_image
    from metasensor.simulation.turbulence import screen_phase

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        st = TelescopeSettings()
        cfg = ms.SystemConfig(obstruction=st.obstruction)
        n = cfg.scan**2
        turb = LayeredTurbulence(d_over_r0=st.d_over_r0, samples=64, seed=st.seed,
                                 span=n * st.periods)
        fz = turb.field_zernike(n)
        screens = turb.screens(n)
        bank_s = {}
        for sub in (3, 1):
            c0 = time.process_time()
            view_psfs(cfg, fz(0.5, 0.5), 0.0, phase=screen_phase(screens[0]), subsample=sub,
                      cache=False)
            bank_s[sub] = time.process_time() - c0
        blocks = st.blocks[0] * st.blocks[1]
        scene = natural_image("moon", st.size).astype(np.float32)
        ref, cpu = _sim_views(scene, cfg, dataclasses.replace(turb, subsample=1), fz, st.blocks)
        periods = {"1": cpu}
        err = {}

        def rel(v):
            return float(np.sqrt(((v - ref) ** 2).mean() / (ref**2).mean()))

        for every in (6, 12):
            v, periods[str(every)] = _sim_views(
                scene, cfg, dataclasses.replace(turb, subsample=1, key_every=every), fz,
                st.blocks)
            err[str(every)] = rel(v)
        class Held(LayeredTurbulence):
            """The screen of the period's first frame, held for the whole period."""

            def screens(self, n_frames, seed=None):
                return np.repeat(super().screens(1), n_frames, axis=0)

        held = Held(**{f.name: getattr(turb, f.name) for f in dataclasses.fields(turb)})
        v, periods["held"] = _sim_views(scene, cfg, dataclasses.replace(
            held, subsample=1, key_every=10 * n), fz, st.blocks)
        err["held"] = rel(v)
    finally:
        torch.set_num_threads(threads)
    return {"case": "telescope-simulation", "size": st.size, "d_over_r0": st.d_over_r0,
            "bank_cpu_s_subsample3": bank_s[3], "bank_cpu_s_subsample1": bank_s[1],
            "per_frame_fine_banks": n * blocks * st.periods,
            "per_frame_fine_cpu_s_estimate": bank_s[3] * n * blocks * st.periods,
            "period_cpu_s_by_key_every": periods,
            "views_rel_rms_vs_per_frame": err,
            "demo_key_every": st.key_every, "demo_subsample": st.sim_subsample}


def telescope_truth(quick: bool = False) -> dict:
    """The ``telescope-truth`` row (``bench_scenarios`` docstring)."""
    import metasensor as ms
    from metasensor.scenarios.screens import LayeredTurbulence, fit_screen
    from metasensor.scenarios.telescope import TelescopeSettings
    from metasensor.scenarios.truth import kolmogorov_mode_rms, kolmogorov_residual, view_motion

    st = TelescopeSettings()
    cfg = ms.SystemConfig(obstruction=st.obstruction)
    n = cfg.scan**2
    s = 64
    k = -1.0 + (np.arange(s) + 0.5) * 2.0 / s
    x, y = np.meshgrid(k, k, indexing="xy")
    disk = x**2 + y**2 <= 1.0
    total, tilt, high, window, motion = [], [], [], [], []
    for seed in range(4 if quick else 12):
        turb = LayeredTurbulence(d_over_r0=st.d_over_r0, samples=s, seed=seed, span=n)
        scr = turb.screens(n).astype(np.float64)
        for t in (0, n // 2, n - 1):
            w = scr[t][disk]
            total.append(((w - w.mean()) ** 2).mean())
            z = fit_screen(scr[t], 45, modes=range(2, 46))
            tilt.append((z[1:3] ** 2).sum())
            high.append((z[3:45] ** 2).sum())
        window.append((turb.mean_zernike(n)[3:45] ** 2).sum())
        m = view_motion(scr, cfg, n // 2)
        motion.append(float(np.nanmax(np.hypot(m[..., 0], m[..., 1]))))
    d = st.d_over_r0
    return {"case": "telescope-truth", "d_over_r0": d, "screens": len(window),
            "frame_rms_waves": float(np.sqrt(np.mean(total))),
            "frame_rms_theory": math.sqrt(kolmogorov_residual(1) * d ** (5 / 3)) / (2 * math.pi),
            "tilt_rms_waves": float(np.sqrt(np.mean(tilt))),
            "tilt_rms_theory": kolmogorov_mode_rms(d, 2, 3),
            "noll4_45_rms_waves": float(np.sqrt(np.mean(high))),
            "noll4_45_rms_theory": kolmogorov_mode_rms(d, 4, 45),
            "window_mean_noll4_45_rms_waves": float(np.sqrt(np.mean(window))),
            "view_motion_max_px": {"median": float(np.median(motion)),
                                   "max": float(np.max(motion))}}


def telescope_motion(quick: bool = False, views_probed: int = 12) -> dict:
    """The ``telescope-motion`` row (``bench_scenarios`` docstring)."""
    import torch

    import metasensor as ms
    from metasensor.motion.correct import estimate_motion
    from metasensor.motion.flow import registration_flows
    from metasensor.scenarios.screens import LayeredTurbulence
    from metasensor.scenarios.telescope import TelescopeSettings
    from metasensor.scenarios.truth import view_motion
    from metasensor.simulation.scenes import natural_image

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        st = TelescopeSettings()
        cfg = ms.SystemConfig(obstruction=st.obstruction)
        n, ref = cfg.scan**2, cfg.scan**2 // 2
        turb = LayeredTurbulence(d_over_r0=st.d_over_r0, samples=64, seed=st.seed,
                                 span=n * st.periods, key_every=st.key_every,
                                 subsample=st.sim_subsample)
        cap = ms.simulate(natural_image("moon", st.size).astype(np.float32), cfg,
                          turbulence=turb, field_zernike=turb.field_zernike(n),
                          field_blocks=st.blocks, snr_db=st.snr_db, seed=st.seed,
                          comparison=False)
        views = ms.realign(cap.frames, cfg, cap.scan_order)
        order = [tuple(int(a) for a in x) for x in cap.scan_order]
        truth = view_motion(turb.screens(n), cfg, ref)  # (T, nnum, nnum, 2)
        lit = [(u, v) for u in range(cfg.nnum) for v in range(cfg.nnum)
               if views[u, v].any() and np.isfinite(truth[0, u, v, 0])]
        rng = np.random.default_rng(0)
        pick = [lit[i] for i in rng.choice(len(lit), min(views_probed, len(lit)), replace=False)]
        true_rms, err_rms, corr, moved, cpu = [], [], [], [], []
        for u, v in pick:
            c0 = time.process_time()
            raw = registration_flows(views[u, v], order, ref).mean(axis=(2, 3))  # (T, 2)
            cpu.append(time.process_time() - c0)
            t = truth[:, u, v]
            # the flow says where a sample's content sits at the reference time: minus the
            # content's motion
            true_rms.append(float(np.sqrt((t**2).mean())))
            err_rms.append(float(np.sqrt(((t + raw) ** 2).mean())))
            corr.append(float(np.corrcoef(t.ravel(), -raw.ravel())[0, 1]))
            moved.append(float(np.mean(estimate_motion(views[u, v], order, ref,
                                                       method="registration") != 0)))
    finally:
        torch.set_num_threads(threads)
    return {"case": "telescope-motion", "views": len(pick),
            "true_motion_rms_px": float(np.median(true_rms)),
            "true_motion_max_px": float(np.nanmax(np.hypot(truth[..., 0], truth[..., 1]))),
            "registration_error_rms_px": float(np.median(err_rms)),
            "registration_correlation": float(np.median(corr)),
            "gated_moving_fraction": float(np.mean(moved)),
            "registration_cpu_s_per_view": float(np.median(cpu))}
