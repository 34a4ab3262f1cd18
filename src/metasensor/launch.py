"""The ``metasensor`` console command's first step.

Loading the command line (typer, the package's command modules) takes a fraction of a second
before :func:`metasensor.cli.main` installs its Ctrl-C handling; a Ctrl-C inside that window
ends the command with the same one line and exit status 130 as a later one, not a traceback.
"""

from __future__ import annotations

import sys

__all__ = ["main"]


def main() -> None:
    """Entry point of the ``metasensor`` command: load the command line, then run it."""
    try:
        from metasensor.cli import main as run
    except KeyboardInterrupt:  # nothing was written yet
        sys.stderr.write("error: stopped by Ctrl-C (SIGINT) while starting; nothing was "
                         "written\n")
        sys.exit(130)
    run()
