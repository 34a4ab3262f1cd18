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

_STAGES = ("optics", "simulate", "sensor", "recon", "motion", "depth", "metrics", "report")

for _stage in _STAGES:
    importlib.import_module(f"metasensor.{_stage}.commands").register(app)


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
