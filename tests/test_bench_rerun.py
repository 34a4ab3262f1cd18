"""benchmarks/rerun.py merges re-measured rows into committed ones; quality_photos' targets."""

from __future__ import annotations

import importlib.util
from pathlib import Path

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"


def _load(name: str):
    spec = importlib.util.spec_from_file_location(f"{name}_under_test", BENCH / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_merge_replaces_marks_and_keeps_the_rest():
    rerun = _load("rerun")
    old = [{"scene": "a", "scan": 1, "ssim": 0.5}, {"scene": "a", "scan": 3, "ssim": 0.6},
           {"summary": "old target", "holds": True}]
    new = [{"scene": "a", "scan": 3, "ssim": 0.7}, {"scene": "b", "scan": 1, "ssim": 0.1},
           {"summary": "new target", "holds": False}]
    rows = rerun.merge(old, new, ("scene", "scan"), ("ssim",))
    assert rows[0] == {"scene": "a", "scan": 1, "ssim": 0.5}
    assert rows[1] == {"scene": "a", "scan": 3, "ssim": 0.7, "remeasured": True,
                       "previous": {"ssim": 0.6}}
    assert rows[2] == {"scene": "b", "scan": 1, "ssim": 0.1, "remeasured": True}
    assert len(rows) == 3  # summaries are recomputed by the caller, not carried
    assert old[1]["ssim"] == 0.6 and "remeasured" not in new[0]  # inputs untouched


def test_photo_targets_read_each_reference():
    qp = _load("quality_photos")
    key = {"study": "photos-aberrated", "scene": "camera", "aberration_rms_waves": 1.0,
           "focus_offset_waves": 0.0}
    rows = [{**key, "image": "ISA (wave DAO)", "ssim": 0.75, "psnr_db": 25.0, "resolved": 0.17},
            {**key, "image": "2D sensor", "ssim": 0.42, "psnr_db": 17.0, "resolved": 0.03},
            {**key, "image": "2D+prior (true PSF)", "ssim": 0.51, "psnr_db": 17.0,
             "resolved": 0.11},
            {**key, "image": "2D+prior (DAO PSF)", "ssim": 0.62, "psnr_db": 21.0,
             "resolved": 0.05}]
    out = {r["reference"]: r for r in qp.targets(rows)}
    assert out["2D sensor"]["holds"] is True
    assert abs(out["2D sensor"]["resolved_ratio"] - 0.17 / 0.03) < 1e-12
    assert out["2D+prior (true PSF)"]["holds"] is False  # resolved 1.5x only
    assert out["2D+prior (DAO PSF)"]["holds"] is False  # SSIM +0.13, PSNR +4 dB
