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
    ("telescope", {"size": 192}),
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
    if name == "gigapixel":  # the CPU split by stage, the PSF banks apart
        cpu = saved["stage_cpu_seconds"]
        assert {"simulation PSF banks", "reconstruction PSF banks", "registration",
                "blending"} <= set(cpu)
        assert all(v >= 0 for v in cpu.values())
        assert sum(saved["psf_banks"].values()) > 0  # the views' banks
        assert sum(saved["psfs_2d"].values()) > 0  # the 2D sensor's, counted apart


def test_bar_gains_count_finer_groups_and_flag_bounds():
    from metasensor.scenarios.measure import bar_gains, bar_periods
    from metasensor.simulation.bars import bar_chart, bar_groups

    chart = bar_chart(256).astype(np.float64)
    groups = bar_groups(256)
    sharp = bar_periods(chart, groups, exclude=(180, 256, 0, 90))
    assert "bottom-left" not in sharp and "centre" in sharp
    assert all(v["period_px"] is not None and v["period_px"] <= 2.5 for v in sharp.values())
    # a Gaussian of sigma s passes a bar period p with contrast exp(-2 pi^2 s^2 / p^2) (first
    # harmonic): sigma 1.2 px loses the 2-4 px groups, sigma 8 px every group of <= 7 px
    mid = bar_periods(ndimage.gaussian_filter(chart, 1.2), groups)
    lost = bar_periods(ndimage.gaussian_filter(chart, 8.0), groups)
    assert all(v["period_px"] is None for v in lost.values())
    g = bar_gains(mid, sharp)
    assert all(1.5 <= v["gain"] <= 3.5 and not v["bound"] for k, v in g.items())
    bound = bar_gains(lost, sharp)
    assert all(v["bound"] and v["gain"] == lost[k]["coarsest_px"] / sharp[k]["period_px"]
               for k, v in bound.items())
    assert bar_gains(sharp, lost)["centre"] == {"gain": 0.0, "bound": False}
    with pytest.raises(ValueError, match="no bar group"):
        bar_periods(chart, groups, exclude=(0, 256, 0, 256))


def test_telescope_settings_are_validated():
    from metasensor.scenarios.telescope import TelescopeSettings

    assert TelescopeSettings().size >= 192  # 12 lenslets: what the views' motion correction needs
    with pytest.raises(ValueError, match="size must be an integer >= 192"):
        TelescopeSettings(size=180)
    with pytest.raises(ValueError, match="check_iterations"):
        TelescopeSettings(check_iterations=0)
    assert TelescopeSettings(check_iterations=None).check_iterations is None


def test_gigapixel_settings_default_to_the_space_variant_model():
    from metasensor.scenarios.gigapixel import GigapixelSettings

    assert GigapixelSettings().space_variant is True
    with pytest.raises(TypeError, match="space_variant"):
        GigapixelSettings(space_variant=1)


def test_frequency_floor_is_the_lowest_bin_read():
    from metasensor.scenarios.measure import frequency_floor

    # 56-px regions are read in 14 bins over 0..0.5 cycles/px, 240-px regions in 60
    assert frequency_floor((56, 60)) == pytest.approx(0.25 / 14)
    assert frequency_floor((240, 240)) == pytest.approx(0.25 / 60)
    assert frequency_floor((16, 16)) == pytest.approx(0.25 / 8)
    rng = np.random.default_rng(2)
    truth = rng.random((56, 56))
    flat = np.full_like(truth, truth.mean())
    assert resolved_frequency(flat, truth) < frequency_floor(truth.shape)


def test_gigapixel_simulates_on_a_finer_field_grid_than_it_reconstructs():
    from metasensor.scenarios.gigapixel import GigapixelSettings

    s = GigapixelSettings()
    # the reconstruction's banks sit at the blocks' corners: blocks + 1 per axis
    assert all(sb > b + 1 for sb, b in zip(s.sim_blocks, s.blocks, strict=True))
    for bad in ((0, 4), (4,), [4, 4], (4.0, 4)):
        with pytest.raises(ValueError, match="sim_blocks"):
            GigapixelSettings(sim_blocks=bad)


def test_wrap_gains_floor_unresolved_regions_and_flag_the_bound():
    from metasensor.scenarios.plastic_wrap import _dao_error, _gains

    two_d = np.array([[0.0, 0.02], [0.03, 0.04]])
    meta = np.array([[0.18, 0.16], [0.15, 0.12]])
    rows = [{"sensor": "2D sensor", "resolved_near_object_cpp": 0.03,
             "resolved_chart_cpp": 0.03},
            {"sensor": "meta-imaging + DAO", "resolved_near_object_cpp": 0.1,
             "resolved_chart_cpp": 0.125}]
    g = _gains(rows, {"2D sensor": two_d, "meta-imaging + DAO": meta}, {}, floor=0.018)
    assert g["gain_at_2d_worst"] == pytest.approx(0.18 / 0.018)
    assert g["gain_at_2d_worst_is_lower_bound"] and g["floor_cpp"] == 0.018
    assert g["gain_mean"] == pytest.approx(np.mean([10.0, 8.0, 5.0, 3.0]))
    assert g["near_over_chart_meta"] == pytest.approx(0.8)
    measured = _gains(rows, {"2D sensor": two_d + 0.01, "meta-imaging + DAO": meta}, {}, 0.018)
    assert not measured["gain_at_2d_worst_is_lower_bound"]
    truth = np.zeros((2, 2, 45))
    truth[..., 3] = 1.0
    est = truth.copy()
    est[0, 0, 4] = 0.3
    assert np.allclose(_dao_error(truth, est), [[0.3, 0], [0, 0]])
    assert _dao_error(truth, est[:1]) is None
