"""The ``metasensor`` console command (typer). Each pipeline stage registers its own commands
from ``metasensor.<stage>.commands.register(app)``; this file only assembles them.

A stage's module is imported only when one of its commands runs (or its ``--help`` is asked
for): ``metasensor --help`` lists the commands from the table below without importing torch,
so it answers in well under a second. ``tests/test_cli_startup.py`` checks that the table
matches the commands each module registers.
"""

from __future__ import annotations

import importlib
from typing import Any

import typer
from typer.core import TyperGroup

# command -> (module under metasensor that registers it, first paragraph of its help)
_COMMANDS: dict[str, tuple[str, str]] = {
    "psf": ("optics.commands", "Compute the phase-space PSF bank of every view and write it to "
            "HDF5 plus a figure."),
    "simulate": ("simulation.commands", "Simulate a raw meta-imaging capture with known truth "
                 "and comparison sensors."),
    "calibrate": ("sensor.commands", "Calibrate the lenslet grid (pitch, rotation, centre, flat "
                  "field, scan offsets)."),
    "realign": ("sensor.commands", "Realign raw frames into view stacks (page u*nnum + v = view "
                "(u, v))."),
    "calibrate-aberration": ("dao.commands", "Global system-aberration calibration from a "
                             "textured capture (e.g. a checkerboard)."),
    "reconstruct": ("recon.commands", "Reconstruct the all-in-focus image from views (ISA; "
                    "multisite blocks through Dask)."),
    "motion": ("motion.commands", "Remove scan (grid) artefacts of moving objects or turbulence "
               "from a view stack."),
    "depth": ("depth.commands", "Disparity, depth and confidence maps (TIFF) and a figure from a "
              "view stack."),
    "evaluate": ("metrics.commands", "PSNR, SSIM and slanted-edge MTF (ISO 12233) of a result "
                 "image."),
    "demo": ("report.commands", "Simulate the built-in resolution chart through a cheap single "
             "lens, reconstruct it, and write a report (PNG figures, index.html, summary.json); "
             "or run one of the paper's experiments with --scenario."),
    "info": ("io.info", "Print what a file holds: kind, shape, axes, units, configuration, "
             "provenance."),
}
_COMMAND_MODULES = tuple(dict.fromkeys(module for module, _ in _COMMANDS.values()))


def load_commands(module: str) -> dict[str, Any]:
    """Import ``metasensor.<module>`` and return the click commands its ``register`` adds."""
    stage = typer.Typer()
    importlib.import_module(f"metasensor.{module}").register(stage)

    @stage.command("-placeholder-")  # two commands or more: typer builds a group
    def _placeholder() -> None:  # pragma: no cover - never invoked
        """Placeholder."""

    group = typer.main.get_group(stage)
    return {name: cmd for name, cmd in group.commands.items() if name != "-placeholder-"}


class LazyGroup(TyperGroup):
    """A typer group whose commands are listed from ``_COMMANDS`` and imported on first use."""

    def list_commands(self, ctx: Any) -> list[str]:
        return list(_COMMANDS) + [n for n in super().list_commands(ctx) if n not in _COMMANDS]

    def _load(self, name: str) -> None:
        if name in _COMMANDS and name not in self.commands:
            for cmd_name, cmd in load_commands(_COMMANDS[name][0]).items():
                self.commands.setdefault(cmd_name, cmd)

    def get_command(self, ctx: Any, cmd_name: str) -> Any:
        if cmd_name in self.commands or cmd_name not in _COMMANDS:
            return super().get_command(ctx, cmd_name)
        import click  # a stand-in for the listing; resolve_command loads the real one

        return click.Command(cmd_name, help=_COMMANDS[cmd_name][1])

    def resolve_command(self, ctx: Any, args: list[str]) -> Any:
        if args:
            self._load(args[0])
        return super().resolve_command(ctx, args)


app = typer.Typer(
    name="metasensor",
    cls=LazyGroup,
    help="Meta-imaging sensor: simulate, realign, reconstruct, correct and evaluate captures.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def _print_version(value: bool) -> None:
    if value:
        from metasensor import __version__

        typer.echo(f"metasensor {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(False, "--version", is_eager=True, callback=_print_version,
                                 help="Print the version and exit."),
) -> None:
    """Meta-imaging sensor: simulate, realign, reconstruct, correct and evaluate captures."""


def _fail(message: str, code: int) -> None:
    """Print ``error: message`` to stderr and exit with ``code``. Every progress bar is a
    context manager (or an iteration) in the code that opened it, so a failing command has
    closed its bars, and the error starts its own line, before it gets here."""
    import sys

    typer.echo(f"error: {message}", err=True)
    sys.exit(code)


def main() -> None:
    """Entry point: run the app; bad input exits non-zero with one line naming the problem;
    Ctrl-C and SIGTERM exit 130 and 143 with one line, temporaries removed."""
    from metasensor.io.interrupt import handle_termination

    with handle_termination():  # SIGTERM as Ctrl-C: temporaries removed on the way out
        _run()


def _run() -> None:
    import signal
    import sys

    try:  # typer >= 0.2x vendors click as typer._click; older ones use click itself
        from typer._click import exceptions as click
    except ImportError:  # pragma: no cover
        from click import exceptions as click
    from metasensor.config_text import drop_fallbacks
    from metasensor.io.interrupt import received, taken

    drop_fallbacks()  # a note left by an earlier command of this process is not this one's
    since = taken()
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
    except KeyboardInterrupt:  # typer turns it into exit 130 itself; said below
        code = 130
    except (ValueError, TypeError, FileNotFoundError, OSError) as exc:
        _fail(str(exc), 2)
    except MemoryError as exc:  # e.g. an absurd --size or aberration: say so, in one line
        _fail(f"not enough memory for this request ({exc or 'MemoryError'})", 2)
    except RuntimeError as exc:  # corrupt chunks of a store, backend failures: one line
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        _fail(first, 1)
    signum = received(since)
    # the shell's convention: 128 + the signal; also when something swallowed the signal
    # and the command ran on (every commit after it was refused, see io.interrupt.check)
    if code in (0, 130) and signum is not None:
        name = "SIGTERM" if signum == signal.SIGTERM else "Ctrl-C (SIGINT)"
        _fail(f"stopped by {name}; unfinished outputs were removed", 128 + signum)
    from metasensor.config import say_fallbacks

    say_fallbacks()  # optics a configuration file left to the prototype: said once
    sys.exit(code if isinstance(code, int) else 0)


if __name__ == "__main__":  # pragma: no cover
    main()
