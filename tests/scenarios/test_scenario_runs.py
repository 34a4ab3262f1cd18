"""Scenario entry points: the CLI's --scenario choice, the measurements, small end-to-end runs."""

import json
import subprocess
import sys

import numpy as np
import pytest
from scipy import ndimage

from metasensor.scenarios import run_scenario
from metasensor.scenarios.measure import lattice_energy, resolved_frequency


def test_resolved_frequency_falls_with_blur():
    rng = np.random.default_rng(0)
    truth = rng.random((64, 64))
    assert resolved_frequency(truth, truth) == 0.5
    sharp = resolved_frequency(ndimage.gaussian_filter(truth, 0.7), truth)
    blurred = resolved_frequency(ndimage.gaussian_filter(truth, 3.0), truth)
    assert 0 < blurred < sharp < 0.5
    with pytest.raises(ValueError, match="equal 2-D regions"):
        resolved_frequency(truth, truth[:32])


def test_lattice_energy_sees_a_scan_pattern():
    rng = np.random.default_rng(1)
    smooth = ndimage.gaussian_filter(rng.random((40, 30)), (3, 0))
    striped = smooth + 0.2 * (np.arange(40) % 5 == 0)[:, None]
    assert lattice_energy(striped, 5) > 3 * lattice_energy(smooth, 5)


def test_unknown_scenario_and_misplaced_scheduler_are_refused(tmp_path):
    with pytest.raises(ValueError, match="unknown scenario"):
        run_scenario("nope", tmp_path)
    with pytest.raises(ValueError, match="gigapixel"):
        run_scenario("telescope", tmp_path, scheduler="tcp://localhost:8786")
    res = subprocess.run([sys.executable, "-c", "from metasensor.cli import main; main()",
                          "demo", "--scenario", "nope", "--out", str(tmp_path / "x")],
                         capture_output=True, text=True)
    assert res.returncode == 2
    assert res.stderr.strip().startswith("error:") and len(res.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "x").exists()


@pytest.mark.slow
@pytest.mark.parametrize("name, settings", [
    ("plastic-wrap", {"size": 144, "blocks": (3, 3), "grid": (3, 3)}),
    ("telescope", {"size": 120}),
    ("gigapixel", {"tile": 120}),
])
def test_scenario_end_to_end_small(tmp_path, name, settings):
    summary = run_scenario(name, tmp_path, progress=False, **settings)
    assert (tmp_path / "index.html").is_file()
    saved = json.loads((tmp_path / "summary.json").read_text())
    assert saved["scenario"] == name and saved["table"]
    for fig in saved["figures"].values():
        assert (tmp_path / fig).is_file()
    assert summary["seconds"] > 0
