"""The console command starts without importing the pipeline: ``--help`` lists every command
from cli.py's table, ``--version`` prints the package version, and the table agrees with what
each stage's ``register`` adds (so the lazy listing cannot drift from the real commands)."""

import subprocess
import sys
from importlib.metadata import version

from typer.testing import CliRunner

import metasensor
from metasensor import cli

_PROBE = ("import sys\n"
          "sys.argv = ['metasensor', *sys.argv[1:]]\n"
          "from metasensor.cli import main\n"
          "try:\n"
          "    main()\n"
          "except SystemExit:\n"
          "    pass\n"
          "heavy = sorted(m for m in ('torch', 'scipy', 'numpy', 'matplotlib', 'dask')\n"
          "               if m in sys.modules)\n"
          "print('HEAVY=' + ','.join(heavy), file=sys.stderr)\n")


def _heavy(*args: str) -> tuple[str, list[str]]:
    res = subprocess.run([sys.executable, "-c", _PROBE, *args], capture_output=True, text=True,
                         check=True)
    line = [ln for ln in res.stderr.splitlines() if ln.startswith("HEAVY=")][-1]
    return res.stdout, [m for m in line.removeprefix("HEAVY=").split(",") if m]


def test_help_and_version_import_no_numerical_library():
    out, heavy = _heavy("--help")
    assert heavy == [], heavy
    for name in cli._COMMANDS:
        assert name in out, name
    out, heavy = _heavy("--version")
    assert heavy == [] and out.strip() == f"metasensor {metasensor.__version__}"


def test_version_matches_the_installed_distribution():
    assert metasensor.__version__ == version("metasensor")
    res = CliRunner().invoke(cli.app, ["--version"])
    assert res.exit_code == 0 and res.output.strip() == f"metasensor {metasensor.__version__}"


def test_import_metasensor_is_light():
    code = ("import sys, metasensor\n"
            "assert 'torch' not in sys.modules and 'numpy' not in sys.modules, 'heavy'\n")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_table_matches_the_registered_commands():
    registered = {}
    for module in cli._COMMAND_MODULES:
        for name, cmd in cli.load_commands(module).items():
            registered[name] = (module, " ".join((cmd.help or "").split("\n\n")[0].split()))
    assert registered == cli._COMMANDS


def test_a_command_runs_through_the_lazy_group(tmp_path):
    res = CliRunner().invoke(cli.app, ["psf", "--help"])
    assert res.exit_code == 0 and "--zernike" in res.output
    res = CliRunner().invoke(cli.app, ["no-such-command"])
    assert res.exit_code == 2
