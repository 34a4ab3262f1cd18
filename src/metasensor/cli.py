"""The ``metasensor`` console command (typer). Each pipeline stage registers its own commands
from ``metasensor.<stage>.commands.register(app)``; this file only assembles them."""

from __future__ import annotations

import importlib

import typer

app = typer.Typer(
    name="metasensor",
    help="Meta-imaging sensor: simulate, realign, reconstruct, correct and evaluate captures.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

_COMMAND_MODULES = (
    "optics.commands", "simulation.commands", "sensor.commands", "recon.commands",
    "recon.dao_commands", "motion.commands", "depth.commands", "metrics.commands",
    "report.commands",
)

for _module in _COMMAND_MODULES:
    importlib.import_module(f"metasensor.{_module}").register(app)


def main() -> None:
    """Entry point: run the app; bad input exits non-zero with one line naming the problem."""
    import sys

    try:
        app()
    except (ValueError, TypeError, FileNotFoundError, OSError) as exc:
        typer.echo(f"error: {exc}", err=True)
        sys.exit(2)


if __name__ == "__main__":  # pragma: no cover
    main()
