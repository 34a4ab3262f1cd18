"""Run the ``metasensor`` entry point in this process (exit status and stderr as a user sees
them, without a new interpreter's start-up) and fingerprint files and folders."""

from __future__ import annotations

import hashlib
import io
import signal
import sys
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path


def run_cli(*args) -> tuple[int, str]:
    """(exit status, stderr) of ``metasensor ARGS`` run through :func:`metasensor.cli.main`."""
    from metasensor.cli import main

    err, out = io.StringIO(), io.StringIO()
    argv = sys.argv
    sys.argv = ["metasensor", *map(str, args)]
    try:
        with redirect_stderr(err), redirect_stdout(out):
            main()
        code = 0
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    finally:
        sys.argv = argv
    return code, err.getvalue()


_CHILD = r"""
import json, sys, time
sys.path.insert(0, {helpers!r})
{limit}
from cli_helpers import run_cli
results = []
for args in json.loads(sys.argv[1]):
    t0 = time.monotonic()
    code, err = run_cli(*args)
    results.append([code, err, time.monotonic() - t0])
print(json.dumps(results))
"""


def capped_cli_script(limit: str) -> str:
    """Source for ``python -c``: run the Python statements ``limit`` (a resource limit, set
    before the package is imported), then every ``metasensor ARGS`` of the JSON list in
    ``argv[1]`` through :func:`run_cli`; prints ``[[status, stderr, seconds], ...]`` as JSON."""
    return _CHILD.format(helpers=str(Path(__file__).resolve().parent), limit=limit)


def refused(*args, match: str) -> str:
    """Assert ``metasensor ARGS`` exits 2 with one ``error:`` line containing ``match``."""
    code, err = run_cli(*args)
    lines = err.strip().splitlines()
    assert code == 2, (args, code, err)
    assert len(lines) == 1 and lines[0].startswith("error:") and match in lines[0], (args, err)
    return lines[0]


def tree_digest(root: Path) -> dict[str, str]:
    """sha256 of every file under ``root`` (or of ``root`` itself), by relative path."""
    root = Path(root)
    if root.is_file():
        return {".": hashlib.sha256(root.read_bytes()).hexdigest()}
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def as_at_a_terminal() -> None:
    """``preexec_fn`` for a child a test stops with Ctrl-C: SIGINT and SIGTERM at their default
    disposition, as for a command typed at a terminal. A test run launched in the background of
    a non-interactive shell inherits SIGINT ignored, its children with it, and an interpreter
    started so keeps ignoring Ctrl-C (as POSIX shells expect)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
