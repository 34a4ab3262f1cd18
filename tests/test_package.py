"""The public names of interface.md resolve to the right objects, whatever was imported first."""

import subprocess
import sys


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
