"""Any scan geometry: a 13 x 13-pixel, 3 x 3 image-scan capture against the prototype geometry.

Scene: the built-in chart over the same physical field for both systems (the same 69 µm / 690 µm
lenslets and NA 0.05, 525 nm; 13 px of 5.31 µm vs 15 px of 4.6 µm behind each lenslet), SNR
30 dB, aberration-free. The prototype (15 x 15, 3 x 3 MLA scan) is simulated by
``metasensor.simulate`` and reconstructed from its exact views; the 13 x 13 system (image moved
over a fixed MLA by 13/3 px per step, the spiral order, one-based rows 3,2,1,1,1,2,3,3,2) by
``simulation.image_scan.simulate_image_scan``, written as raw frames without metadata, and taken
through the command line alone: ``calibrate`` (all 9 frames) -> ``realign --calib`` ->
``reconstruct``, with the optics from a TOML. Both reconstructions: ISA with the default solver,
one block; SSIM / PSNR against each system's own truth on its own reconstruction grid (15 grid
pixels per lenslet for both, so the same 4.6 µm grid: the prototype's sensor pixels, 13/15 of
the 13-px system's), with its data range, cropping one lenslet at the border. The chart is
rendered over the same physical field for both (the 13-px sensor has 13/15 as many pixels).
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

TARGET_GAP = 0.03  # the 13 x 13 system's SSIM within this of the prototype's
ONE_BASED = "one-based:3,1;2,1;1,1;1,2;1,3;2,3;3,3;3,2;2,2"


def _cli(*args) -> None:
    res = subprocess.run([sys.executable, "-m", "metasensor.cli", *map(str, args)],
                         capture_output=True, text=True)
    if res.returncode:
        raise RuntimeError(f"metasensor {args[0]} failed: {res.stderr.strip()[-400:]}")


def _scores(image, truth) -> dict:
    from metasensor.metrics import psnr, ssim

    rng = float(truth.max() - truth.min())
    return {"ssim": ssim(truth=truth, image=image, data_range=rng),
            "psnr_db": psnr(truth=truth, image=image, data_range=rng)}


def prototype(lenslets: int) -> dict:
    import metasensor as ms
    from metasensor.simulation.scenes import load_scene

    cfg = ms.SystemConfig(scan=3)
    cap = ms.simulate(load_scene("chart", lenslets * 15 + 10), cfg, snr_db=30, seed=1,
                      comparison=False)
    t0 = time.perf_counter()
    rec = ms.reconstruct(cap.views, cap.config, method="isa", blocks=(1, 1))
    c = 15
    out = _scores(rec.image[c:-c, c:-c], cap.truth[c:-c, c:-c])
    return {"system": "prototype 15x15, MLA scan 3x3", **out, "truth_px": cap.truth.shape[0],
            "seconds": time.perf_counter() - t0}


def image_scan(lenslets: int, folder: Path) -> dict:
    import tifffile

    import metasensor as ms
    from metasensor.io.raw import write_raw
    from metasensor.sensor.scan import scan_order
    from metasensor.simulation.image_scan import fine_factor, simulate_image_scan
    from metasensor.simulation.scenes import load_scene

    cfg = ms.SystemConfig(nnum=13, scan=3, moving="image", mla_pitch=69e-6, mla_focal=690e-6,
                          wavelength=525e-9, na=0.05)
    s = fine_factor(cfg)
    size = int(round((lenslets * 15 + 10) * 13 / 15 * s))  # the prototype's field
    cap = simulate_image_scan(load_scene("chart", size), cfg, scan_order(3, "spiral"),
                              snr_db=30, seed=1)
    cfg.to_toml(folder / "cfg.toml")
    write_raw(folder / "raw.tif", cap.frames)
    t0 = time.perf_counter()
    _cli("calibrate", folder / "raw.tif", "--config", folder / "cfg.toml", "--order", ONE_BASED,
         "--no-flat", "--out", folder / "calib.toml")
    _cli("realign", folder / "raw.tif", "--config", folder / "cfg.toml", "--calib",
         folder / "calib.toml", "--order", ONE_BASED, "--out", folder / "views.tif")
    _cli("reconstruct", folder / "views.tif", "--out", folder / "result")
    with tifffile.TiffFile(folder / "result" / "image.tif") as tif:
        image = tif.asarray()
        meta = json.loads(tif.pages[0].description)
    origin = meta.get("metasensor", {}).get("origin", [0.0, 0.0])
    k = [int(round(v / cfg.nnum)) for v in origin]  # lenslets the calibration left out
    g = cfg.grid_points
    truth = cap.truth[k[0] * g:k[0] * g + image.shape[0], k[1] * g:k[1] * g + image.shape[1]]
    c = g
    exact = ms.reconstruct(cap.views, cfg, method="isa", blocks=(1, 1)).image
    return {"system": "13x13, image scan 3x3 (CLI)",
            **_scores(image[c:-c, c:-c], truth[c:-c, c:-c]),
            "exact_views_ssim": _scores(exact[c:-c, c:-c], cap.truth[c:-c, c:-c])["ssim"],
            "truth_px": truth.shape[0], "origin": origin,
            "seconds": time.perf_counter() - t0}


def run(quick: bool) -> list[dict]:
    import torch

    torch.set_num_threads(1)
    lenslets = 10 if quick else 16
    rows = [prototype(lenslets)]
    with tempfile.TemporaryDirectory() as tmp:
        rows.append(image_scan(lenslets, Path(tmp)))
    gap = rows[0]["ssim"] - rows[1]["ssim"]
    for r in rows:
        r.update(lenslets=lenslets, snr_db=30, ssim_gap=gap, meets=bool(gap <= TARGET_GAP))
    return rows


if __name__ == "__main__":
    from _usage import exit_on_help

    exit_on_help(__doc__)
    for row in run("--quick" in sys.argv):
        print(row)
