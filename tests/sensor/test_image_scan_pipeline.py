"""Acceptance: a simulated 13 x 13, 3 x 3 image-scan capture (one-based order rows 3,2,1,1,1,2,
3,3,2, columns 1,1,1,2,3,3,3,2,2) through calibrate -> realign -> reconstruct by the CLI alone,
optics from a TOML, reconstructs about as well as the prototype geometry with a 3 x 3 scan on
the same scene (SSIM within 0.03; SNR 30 dB; benchmarks/bench_image_scan.py measures the same
at 10 lenslets), and realign of the raw frames equals the simulator's views exactly."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

import metasensor as ms

BENCH = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_image_scan.py"


def _bench():
    spec = importlib.util.spec_from_file_location("bench_image_scan", BENCH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.slow  # the 13-px fine PSF bank: ~20 s on one core without the cache
def test_uncalibrated_realign_of_the_simulated_scan_is_exact():
    from metasensor.sensor.scan import from_one_based
    from metasensor.simulation.image_scan import fine_factor, simulate_image_scan

    cfg = ms.SystemConfig(nnum=13, scan=3, moving="image")
    order = from_one_based([3, 2, 1, 1, 1, 2, 3, 3, 2], [1, 1, 1, 2, 3, 3, 3, 2, 2])
    scene = np.random.default_rng(0).random((4 * 13 * fine_factor(cfg),) * 2)
    cap = simulate_image_scan(scene.astype(np.float32), cfg, order, snr_db=30, seed=2)
    assert cap.frames.shape == (9, 52, 52) and cap.truth.shape == (60, 60)
    assert np.array_equal(ms.realign(cap.frames, cfg, order), cap.views)


@pytest.mark.slow
def test_cli_image_scan_reconstructs_as_well_as_the_prototype(tmp_path):
    bench = _bench()
    proto = bench.prototype(8)
    scan = bench.image_scan(8, tmp_path)
    assert scan["ssim"] >= proto["ssim"] - 0.03, (scan, proto)
    assert abs(scan["ssim"] - scan["exact_views_ssim"]) < 0.02
