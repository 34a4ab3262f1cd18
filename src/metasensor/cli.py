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


def _fail(message: str, code: int) -> None:
    """Close progress bars a failing command left open (so the error starts its own line, not
    the bar's), print ``error: message`` to stderr and exit with ``code``."""
    import sys

    try:
        from tqdm import tqdm

        for bar in list(getattr(tqdm, "_instances", ())):
            bar.close()
    except Exception:  # pragma: no cover - tqdm missing or a bar already torn down
        pass
    typer.echo(f"error: {message}", err=True)
    sys.exit(code)


def main() -> None:
    """Entry point: run the app; bad input exits non-zero with one line naming the problem."""
    import sys

    try:  # typer >= 0.2x vendors click as typer._click; older ones use click itself
        from typer._click import exceptions as click
    except ImportError:  # pragma: no cover
        from click import exceptions as click

    try:
        code = app(standalone_mode=False)
    except click.NoArgsIsHelpError as exc:  # bare group call: the help, as asked
        typer.echo(exc.ctx.get_help() if exc.ctx is not None else str(exc))
        code = 0
    except click.UsageError as exc:  # missing/unknown option or command: one line, no box
        where = f"{exc.ctx.command_path}: " if exc.ctx is not None else ""
        _fail(f"{where}{exc.format_message()}", 2)
    except typer.Abort:
        _fail("aborted", 1)
    except (ValueError, TypeError, FileNotFoundError, OSError) as exc:
        _fail(str(exc), 2)
    except MemoryError as exc:  # e.g. an absurd --size or aberration: say so, in one line
        _fail(f"not enough memory for this request ({exc or 'MemoryError'})", 2)
    except RuntimeError as exc:  # corrupt chunks of a store, backend failures: one line
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        _fail(first, 1)
    sys.exit(code if isinstance(code, int) else 0)


if __name__ == "__main__":  # pragma: no cover
    main()
