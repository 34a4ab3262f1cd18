"""The public names of interface.md resolve to the right objects, whatever was imported first."""

import subprocess
import sys

import pytest


def test_simulate_is_the_function_even_after_subpackage_imports():
    code = ("import metasensor.simulation.lens, metasensor.simulation.scenes\n"
            "import metasensor as ms\n"
            "assert callable(ms.simulate) and ms.simulate.__name__ == 'simulate'\n"
            "assert ms.simulation.load_scene is not None\n"
            "for name in ('SystemConfig', 'view_psfs', 'widefield_psf', 'realign', 'unrealign',\n"
            "             'reconstruct', 'correct_motion', 'estimate_depth'):\n"
            "    assert callable(getattr(ms, name)), name\n"
            "assert callable(ms.metrics.slanted_edge_mtf)\n")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_cli_lists_every_command():
    from typer.testing import CliRunner

    from metasensor.cli import app

    out = CliRunner().invoke(app, ["--help"]).output
    for cmd in ("psf", "simulate", "calibrate", "realign", "reconstruct", "calibrate-aberration",
                "motion", "depth", "evaluate", "demo"):
        assert cmd in out, cmd


def test_stage_submodules_resolve_as_attributes_in_a_fresh_process():
    # the README's ``ms.simulation.scenes.load_scene``: lazy packages also resolve submodules
    code = ("import metasensor as ms\n"
            "assert callable(ms.simulation.scenes.load_scene)\n"
            "assert callable(ms.sensor.scan.check_scan_order)\n"
            "try:\n"
            "    ms.simulation.no_such_name\n"
            "except AttributeError as exc:\n"
            "    assert 'no_such_name' in str(exc)\n"
            "else:\n"
            "    raise SystemExit('no AttributeError')\n")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_cli_usage_errors_are_one_line_and_exit_2():
    cases = (["psf"], ["no-such-command"], ["demo", "--size", "50"])  # psf: no --out
    for args in cases:
        res = subprocess.run([sys.executable, "-m", "metasensor.cli", *args],
                             capture_output=True, text=True)
        lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
        assert res.returncode == 2, (args, res.returncode)
        assert len(lines) == 1 and lines[0].startswith("error: "), (args, res.stderr)
    ok = subprocess.run([sys.executable, "-m", "metasensor.cli", "--help"], capture_output=True,
                        text=True)
    assert ok.returncode == 0 and "reconstruct" in ok.stdout


def test_cli_commands_refuse_to_overwrite_their_input(tmp_path):
    from metasensor.io.atomic import refuse_overwrite

    src = tmp_path / "in.tif"
    src.write_bytes(b"x")
    refuse_overwrite([tmp_path / "other.tif", None], [src, None])  # different paths: fine
    with pytest.raises(ValueError, match="would overwrite the input"):
        refuse_overwrite([tmp_path / "." / "in.tif"], [src])
    res = subprocess.run([sys.executable, "-m", "metasensor.cli", "motion", str(src), "--out",
                          str(src)], capture_output=True, text=True)
    assert res.returncode == 2 and "overwrite the input" in res.stderr
    assert src.read_bytes() == b"x"
    res = subprocess.run([sys.executable, "-m", "metasensor.cli", "psf", "--device", "tpu",
                          "--config", str(src), "--out", str(tmp_path / "p.h5")],
                         capture_output=True, text=True)
    assert res.returncode != 0 and len(res.stderr.strip().splitlines()) == 1


def test_cli_error_after_a_progress_bar_starts_its_own_line():
    # a command that fails mid-progress: its bar (a context, as every bar of the package) is
    # closed first, the error is its own line
    code = ("import sys\n"
            "from tqdm import tqdm\n"
            "import metasensor.cli as cli\n"
            "def boom(**_):\n"
            "    with tqdm(total=10, desc='work') as bar:\n"
            "        bar.update(3)\n"
            "        raise ValueError('views hold NaN')\n"
            "cli.app = boom\n"
            "cli.main()\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert res.returncode == 2
    lines = res.stderr.replace("\r", "\n").splitlines()
    assert "error: views hold NaN" in lines, res.stderr


def test_a_command_failing_inside_its_progress_bar_closes_it_before_the_error(tmp_path):
    # a real command's bar (a scenario's steps), closed by its context when the work fails
    code = ("import sys\n"
            "import metasensor as ms\n"
            "import metasensor.cli as cli\n"
            "def boom(*_, **__):\n"
            "    raise ValueError('views hold NaN')\n"
            "ms.simulate = boom\n"
            f"sys.argv = ['metasensor', 'demo', '--scenario', 'telescope', '--out', "
            f"{str(tmp_path / 'tel')!r}]\n"
            "cli.main()\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert res.returncode == 2, res.stderr
    assert "telescope:" in res.stderr  # the bar was shown
    lines = res.stderr.replace("\r", "\n").splitlines()
    assert "error: views hold NaN" in lines, res.stderr


def test_import_sets_passive_openmp_waiting_unless_the_environment_says_otherwise():
    import os
    from pathlib import Path

    src = str(Path(__file__).resolve().parents[1] / "src")
    probe = "import os, metasensor; print(os.environ['OMP_WAIT_POLICY'])"
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    env["PYTHONPATH"] = src
    for given, expected in ((None, "PASSIVE"), ("ACTIVE", "ACTIVE")):
        if given:
            env["OMP_WAIT_POLICY"] = given
        out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                             env=env, timeout=60)
        assert out.returncode == 0, out.stderr
        assert out.stdout.strip() == expected
