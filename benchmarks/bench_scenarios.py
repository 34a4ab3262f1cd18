"""The paper's three remaining experiments as scenarios, and the mosaic stitcher at full size.

Rows:
- ``plastic-wrap``, ``telescope``, ``gigapixel``: each scenario's demo (``metasensor demo
  --scenario NAME``) with its acceptance figures and its run time on this machine;
  ``gigapixel-cold``: the gigapixel demo on an empty PSF cache (a new user's first run: every
  PSF bank computed), the ``gigapixel`` row then on the cache it filled, both with their CPU
  seconds per stage (PSF banks apart) and the load average.
- ``stitch``: the mosaic stitcher on full-sensor tiles (the prototype's 6,000 x 8,000 pixels,
  2 x 2 positions, 256-pixel overlaps: about 185 MP out; ``--quick``: 1,000 x 1,200 tiles).
  The tiles are a band-limited synthetic texture (24 seeded plane waves, evaluated exactly at
  every tile's true sub-pixel position, so the known offsets are exact) written to Zarr chunk by
  chunk; registration, blending and the pyramid run in a child process whose peak resident
  memory is measured. Seconds per megapixel and the extrapolated time for one gigapixel are
  the stitcher's alone (tile reconstruction: ``bench_stream``); per worker: the wall time times
  the cores used, per megapixel.
- ``stitch-cluster``: the same small mosaic through a ``dask.distributed`` LocalCluster (2
  processes x 1 thread) against local threads: max |difference|.
- ``telescope-simulation``: what the telescope's evolving turbulence costs the simulator (CPU
  seconds, this process, torch on one thread): one fine view bank (``subsample=3``) and one on
  the pixel grid (``subsample=1``) of a frame's wavefront, the per-frame fine-bank simulation
  extrapolated from the first (frames x field blocks x periods banks), and one scan period
  simulated with key frames every 1 (a bank per frame), 6 and 12 frames on the pixel grid, and
  with the screen held at the period's first frame; each one's relative r.m.s. difference of
  the clean views from the bank-per-frame simulation (the scene: the Moon, ``size`` px).
- ``telescope-truth``: the telescope's turbulence against Kolmogorov theory (Noll 1976), over
  12 seeded sequences (``--quick``: 4) at the demo's D/r0, three frames each (first, middle,
  last of a scan period): a frame's wavefront r.m.s. over the pupil (piston removed), its tip
  and tilt, its Noll 4-45; the Noll 4-45 r.m.s. of the period's mean wavefront (what one DAO
  estimate per window can find); and the largest true motion of any view between the
  period's frames (view px, :func:`metasensor.scenarios.truth.view_motion`).
- ``telescope-motion``: what the per-view motion correction could find in the demo's first
  scan period: the true motion of 12 seeded lit views between the period's frames and its
  reference frame (view px, from the screens), the non-rigid registration's raw estimate
  (mean flow per frame, before its evidence gate) against it (r.m.s. error, correlation), the
  fraction of samples the gated estimate moves, and the registration's CPU seconds per view.
- ``telescope-strong`` (``--telescope-strong`` alone): the telescope demo at D/r0 = 15.

The ``plastic-wrap`` row runs the demo on a 480-px field (:data:`WRAP_BENCH`; the demo's is
240 px): 4 x 4 regions of 112 px, whose spectra read down to 0.009 cycles/px (56-px regions:
0.018), and bar groups up to 12 px at every location (the chart's layout packs 40-px groups only
into fields of about 1,300 px, beyond this machine's time for the row).
``python benchmarks/bench_scenarios.py --plastic-wrap [--quick]`` runs it alone.

``python benchmarks/bench_scenarios.py --telescope [--quick] [--no-simulation]`` runs the four
telescope rows alone (``--no-simulation``: not the simulation's; ``--telescope-demo``: the
``telescope`` row alone), ``--gigapixel`` the gigapixel
demo (cold and warm), ``stitch`` and ``stitch-cluster`` rows, ``--gigapixel-demo`` the two
demo rows alone; each row goes into the results JSON in place of the old one (the other rows
kept).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "src"))
sys.path.insert(0, str(HERE))

from telescope_rows import telescope_motion, telescope_simulation, telescope_truth  # noqa: E402


def _waves(seed: int, k: int = 24):
    rng = np.random.default_rng(seed)
    f = rng.uniform(0.01, 0.2, k) * rng.choice([-1, 1], k)
    g = rng.uniform(0.01, 0.2, k) * rng.choice([-1, 1], k)
    return f, g, rng.uniform(0, 2 * np.pi, k), rng.uniform(0.5, 1.0, k)


def texture(y0: float, x0: float, h: int, w: int, seed: int = 0) -> np.ndarray:
    """(h, w) float32 texture at rows y0 + i, columns x0 + j (separable plane waves)."""
    f, g, ph, amp = _waves(seed)
    ay = 2 * np.pi * np.outer(f, y0 + np.arange(h)) + ph[:, None]
    ax = 2 * np.pi * np.outer(g, x0 + np.arange(w))
    img = (np.cos(ay) * amp[:, None]).T @ np.cos(ax) - (np.sin(ay) * amp[:, None]).T @ np.sin(ax)
    return (100.0 + 10.0 * img).astype(np.float32)


def _write_tiles(folder: Path, layout, jitter: float, seed: int):
    import zarr

    rng = np.random.default_rng(seed + 1)
    paths, true = {}, {}
    th, tw = layout.tile_shape
    for k in layout.indices:
        oy, ox = layout.origin(k)
        if k != (0, 0):
            oy, ox = oy + rng.uniform(-jitter, jitter), ox + rng.uniform(-jitter, jitter)
        true[k] = (float(oy), float(ox))
        z = zarr.open_array(str(folder / f"tile_{k[0]}_{k[1]}.zarr"), mode="w", shape=(th, tw),
                            chunks=(1024, 1024), dtype="f4", zarr_format=2)
        for y in range(0, th, 1024):
            z[y:y + 1024] = texture(oy + y, ox, min(1024, th - y), tw, seed)
        paths[k] = str(folder / f"tile_{k[0]}_{k[1]}.zarr")
    return paths, true


def stitch(tile_shape, grid, overlap: int, chunk: int, seed: int = 0, scheduler=None,
           folder: str | None = None) -> dict:
    """Write synthetic tiles, register, blend; returns timings and errors."""
    import zarr

    from metasensor.mosaic import MosaicLayout, blend_tiles, register_tiles, solve_positions

    layout = MosaicLayout(tuple(tile_shape), tuple(grid), overlap)
    work = Path(folder or tempfile.mkdtemp(prefix="stitch_"))
    paths, true = _write_tiles(work, layout, 2.0, seed)
    t0 = time.perf_counter()
    tiles = {k: zarr.open_array(p, mode="r") for k, p in paths.items()}
    pos = solve_positions(register_tiles(tiles, layout), layout)
    t_reg = time.perf_counter() - t0
    err = max(float(np.hypot(pos[k][0] - true[k][0], pos[k][1] - true[k][1]))
              for k in layout.indices)
    t1 = time.perf_counter()
    out = blend_tiles(paths, pos, layout.shape, work / "mosaic.ome.zarr", chunk=chunk,
                      ramp=overlap // 2, scheduler=scheduler, num_workers=os.cpu_count())
    t_blend = time.perf_counter() - t1
    mp = layout.shape[0] * layout.shape[1] / 1e6
    seam, truth_seam = _seams(out, layout, pos, seed)
    return {"tiles": len(paths), "tile_shape": list(tile_shape), "mosaic_mp": mp,
            "registration_error_px": err, "register_s": t_reg, "blend_s": t_blend,
            "s_per_mp": (t_reg + t_blend) / mp, "seam_ratio": seam,
            "truth_seam_ratio": truth_seam, "out": str(out), "folder": str(work)}


def _seams(out, layout, pos, seed: int, half: int = 40) -> tuple[float, float]:
    """Seam ratio (:func:`metasensor.mosaic.seams.seam_ratio`) at every tile edge inside the
    mosaic (where a later tile starts and an earlier one ends), read on strips of 2 x ``half``
    pixels across each edge, and the same on the exact texture: (mosaic, truth)."""
    from metasensor.mosaic import open_mosaic
    from metasensor.mosaic.seams import seam_ratio

    img = open_mosaic(out)
    (h, w), (th, tw) = layout.shape, layout.tile_shape
    rows = sorted({int(round(pos[(i, 0)][0])) for i in range(1, layout.grid[0])}
                  | {int(round(pos[(i, 0)][0] + th)) for i in range(layout.grid[0] - 1)})
    cols = sorted({int(round(pos[(0, j)][1])) for j in range(1, layout.grid[1])}
                  | {int(round(pos[(0, j)][1] + tw)) for j in range(layout.grid[1] - 1)})
    worst, worst_truth = 0.0, 0.0
    for y in (r for r in rows if half <= r <= h - half):
        a, t = np.asarray(img[y - half:y + half]), texture(y - half, 0, 2 * half, w, seed)
        worst = max(worst, seam_ratio(a, [half], []))
        worst_truth = max(worst_truth, seam_ratio(t, [half], []))
    for x in (c for c in cols if half <= c <= w - half):
        a, t = np.asarray(img[:, x - half:x + half]), texture(0, x - half, h, 2 * half, seed)
        worst = max(worst, seam_ratio(a, [], [half]))
        worst_truth = max(worst_truth, seam_ratio(t, [], [half]))
    return worst, worst_truth


def _child_stitch(tile_shape, grid, overlap, chunk) -> dict:
    """Run :func:`stitch` in a fresh process; add its own peak resident memory (GB: VmHWM,
    which the child's ``exec`` resets; ``RUSAGE_CHILDREN`` would give the largest of every
    child so far, and each child's ``ru_maxrss`` starts at this process's peak)."""
    call = f"b.stitch({list(tile_shape)!r}, {list(grid)!r}, {int(overlap)}, {int(chunk)})"
    code = (f"import json,sys; sys.path.insert(0, {str(HERE)!r}); import bench_scenarios as b; "
            f"from metasensor.io.memory import peak_resident_bytes as p; row = {call}; "
            f"row['peak_gb'] = p() / 1024**3; print(json.dumps(row))")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, env={**os.environ, "OMP_NUM_THREADS": "1"})
    return json.loads(res.stdout.strip().splitlines()[-1])


def _cluster_row() -> dict:
    import shutil

    from distributed import LocalCluster

    from metasensor.mosaic import open_mosaic

    a = stitch((400, 500), (2, 2), 64, 128)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster:
        b = stitch((400, 500), (2, 2), 64, 128, scheduler=cluster)
    diff = float(np.abs(open_mosaic(a["out"])[:] - open_mosaic(b["out"])[:]).max())
    for r in (a, b):
        shutil.rmtree(r["folder"], ignore_errors=True)
    return {"case": "stitch-cluster", "max_abs_diff": diff, "ok": diff <= 1e-5}


#: the plastic-wrap row's field (the demo's is 240 px): 112-px regions, whose spectra read down
#: to 0.009 cycles/px, and bar groups up to 12 px at every location
WRAP_BENCH = {"size": 480, "blocks": (4, 4), "grid": (4, 4)}


def _scenario_rows(quick: bool, names=("plastic-wrap", "telescope", "gigapixel")) -> list[dict]:
    """Each scenario's row (:func:`summary_row`) with the 1-minute load average and torch's
    thread count at its end (a one-thread run that ends on more threads computed on them)."""
    import torch

    from metasensor.scenarios import run_scenario

    settings = ({"plastic-wrap": {"size": 144, "blocks": (3, 3), "grid": (3, 3)},
                 "telescope": {"size": 192}, "gigapixel": {"tile": 120}} if quick
                else {"plastic-wrap": WRAP_BENCH})
    rows = []
    for name in names:
        with tempfile.TemporaryDirectory() as tmp:
            row = summary_row(run_scenario(name, tmp, progress=False, **settings.get(name, {})))
        rows.append({**row, "load_average": os.getloadavg()[0],
                     "torch_threads": torch.get_num_threads()})
    return rows


def summary_row(s: dict) -> dict:
    """A scenario's row from its summary (``summary.json`` of ``metasensor demo --scenario``)."""
    name = s["scenario"]
    row = {"case": name, "seconds": s["seconds"], "cpu_seconds": s["cpu_seconds"]}
    if name == "plastic-wrap":
        row.update({k: v for k, v in s["gains"].items() if not isinstance(v, dict)})
        row["bar_px"] = {r["sensor"]: r.get("bar_px") for r in s["table"]}
        row.update({"size": s["settings"]["size"], "blocks": s["settings"]["blocks"],
                    "maps_cpp": s["maps_cpp"],
                    "psnr_db": {r["sensor"]: r["psnr_db"] for r in s["table"]},
                    "ssim": {r["sensor"]: r["ssim"] for r in s["table"]},
                    "wrap_spread": s["wrap"]["spread_pupil_diameters"],
                    "block_variation_waves": s["wrap"]["block_variation_waves"],
                    "dao_error_waves_per_block": s.get("dao_error_waves_per_block"),
                    "stage_cpu_seconds": s.get("stage_cpu_seconds")})
    elif name == "telescope":
        row.update({"pupil_error": s["pupil"]["error"],
                    "residual_max_waves": s["residual_max_waves"],
                    "residual_over_true_max": float(np.max(s["residual_over_true"])),
                    "true_rms_waves": s["true_rms_waves"],
                    "true_frame_rms_waves": s["true_frame_rms_waves"],
                    "dao_gain_db": s["dao_gain_db"], "dao_over_2d_db": s["dao_over_2d_db"],
                    "kymo_lattice_ratio": s["kymograph"]["lattice_corrected_over_static"],
                    "motion": s.get("motion"),
                    "psnr_db": {r["sensor"]: r["psnr_db"] for r in s["table"]},
                    "stage_seconds": s["stage_seconds"]})
    else:
        row.update({"registration_error_px": s["registration_error_px"],
                    "psnr_db": {r["sensor"]: r["psnr_db"] for r in s["table"]},
                    "seam_ratio": {r["sensor"]: r["seam_ratio"] for r in s["table"]},
                    "truth_seam_ratio": s["table"][1]["truth_seam_ratio"],
                    "space_variant": s["settings"].get("space_variant"),
                    "stage_cpu_seconds": s.get("stage_cpu_seconds"),
                    "psf_banks": s.get("psf_banks"), "psfs_2d": s.get("psfs_2d")})
    return row


def telescope_strong(d_over_r0: float = 15.0) -> dict:
    """The ``telescope-strong`` row: the telescope demo at a stronger turbulence (its other
    settings the defaults), where a frame's Noll 4-45 exceed the 0.3-wave residual line."""
    from metasensor.scenarios import run_scenario

    with tempfile.TemporaryDirectory() as tmp:
        row = summary_row(run_scenario("telescope", tmp, progress=False, d_over_r0=d_over_r0))
    return {**row, "case": "telescope-strong", "d_over_r0": d_over_r0}


def telescope_rows(quick: bool = False, save: bool = False, simulation: bool = True
                   ) -> list[dict]:
    """The truth's row, the simulation's (``simulation``) and the telescope demo's
    (:func:`_scenario_rows` for it alone); ``save``: each put into the results JSON as soon as
    it is measured (:func:`merge_rows`)."""
    rows = []
    makers = [lambda: [telescope_truth(quick)], lambda: [telescope_motion(quick)]]
    if simulation:
        makers.append(lambda: [telescope_simulation(quick)])
    makers.append(lambda: _scenario_rows(quick, names=("telescope",)))
    for make in makers:
        rows += make()
        if save:
            merge_rows(rows[-1:], quick)
    return rows


def merge_rows(rows: list[dict], quick: bool = False) -> Path:
    """Put ``rows`` into the results JSON in place of the rows of the same ``case``."""
    from metasensor.io.atomic import atomic_write_text
    from run_all import machine, result_name

    path = HERE / "results" / result_name("scenarios", quick)
    doc = json.loads(path.read_text()) if path.exists() else {
        "benchmark": "scenarios", "quick": quick, "machine": machine(), "rows": []}
    cases = {r["case"] for r in rows}
    doc["rows"] = [r for r in doc["rows"] if r.get("case") not in cases] + rows
    atomic_write_text(path, json.dumps(doc, indent=2) + "\n")
    return path


def gigapixel_cold_warm(quick: bool = False) -> list[dict]:
    """The gigapixel demo twice on one new PSF cache folder (``METASENSOR_CACHE``):
    ``gigapixel-cold`` computes every PSF bank (a new user's first run), ``gigapixel`` is the
    same run on the filled cache; each row with the 1-minute load average at its end (the
    machine is shared: wall time stretches with it, CPU seconds much less)."""
    import torch

    from metasensor.scenarios import run_scenario

    settings = {"tile": 120} if quick else {}
    old = os.environ.get("METASENSOR_CACHE")
    rows = []
    with tempfile.TemporaryDirectory() as cache:
        os.environ["METASENSOR_CACHE"] = cache
        try:
            for case in ("gigapixel-cold", "gigapixel"):
                with tempfile.TemporaryDirectory() as tmp:
                    row = summary_row(run_scenario("gigapixel", tmp, progress=False,
                                                   **settings))
                rows.append({**row, "case": case, "load_average": os.getloadavg()[0],
                             "torch_threads": torch.get_num_threads()})
        finally:
            if old is None:
                os.environ.pop("METASENSOR_CACHE", None)
            else:
                os.environ["METASENSOR_CACHE"] = old
    return rows


def stitch_row(quick: bool = False) -> dict:
    """The ``stitch`` row (module docstring): the stitcher in a child process."""
    import shutil

    shape = (1000, 1200) if quick else (6000, 8000)
    st = _child_stitch(shape, (2, 2), 64 if quick else 256, 512 if quick else 2048)
    shutil.rmtree(st.pop("folder"), ignore_errors=True)
    st.pop("out")
    cores = os.cpu_count() or 1
    st.update({"case": "stitch", "gigapixel_s": st["s_per_mp"] * 1000,
               "s_per_mp_per_worker": st["s_per_mp"] * cores, "cores": cores,
               "gigapixel_s_per_worker": st["s_per_mp"] * cores * 1000})
    return st


def gigapixel_rows(quick: bool = False, save: bool = False) -> list[dict]:
    """The gigapixel demo's row, the ``stitch`` row and the ``stitch-cluster`` row; ``save``:
    each put into the results JSON as soon as it is measured (:func:`merge_rows`)."""
    rows = []
    for make in (lambda: gigapixel_cold_warm(quick),
                 lambda: [stitch_row(quick)], lambda: [_cluster_row()]):
        made = make()
        rows += made
        if save:
            merge_rows(made, quick)
    return rows


def run(quick: bool = False) -> list[dict]:
    rows = _scenario_rows(quick, names=("plastic-wrap", "telescope"))
    rows += gigapixel_cold_warm(quick)
    rows.append(stitch_row(quick))
    rows.append(_cluster_row())
    return rows


if __name__ == "__main__":
    from _usage import exit_on_help

    exit_on_help(__doc__)
    if "--plastic-wrap" in sys.argv or "--telescope-demo" in sys.argv:  # one demo's row alone,
        quick = "--quick" in sys.argv  # merged into the JSON
        rows = _scenario_rows(quick, names=("plastic-wrap" if "--plastic-wrap" in sys.argv
                                            else "telescope",))
        merge_rows(rows, quick)
        print(json.dumps(rows, indent=1))
    elif "--gigapixel-demo" in sys.argv:  # the gigapixel-cold and gigapixel rows alone
        quick = "--quick" in sys.argv
        rows = gigapixel_cold_warm(quick)
        merge_rows(rows, quick)
        print(json.dumps(rows, indent=1))
    elif any(a in sys.argv for a in ("--telescope", "--telescope-strong", "--gigapixel")):
        sys.path.insert(0, str(HERE))
        quick = "--quick" in sys.argv
        if "--telescope-strong" in sys.argv:
            rows = [telescope_strong()]
            merge_rows(rows, quick)
        elif "--telescope" in sys.argv:
            rows = telescope_rows(quick, save=True, simulation="--no-simulation" not in sys.argv)
        else:
            rows = gigapixel_rows(quick, save=True)
        print(json.dumps(rows, indent=1))
    else:
        print(json.dumps(run(quick="--quick" in sys.argv), indent=1))
