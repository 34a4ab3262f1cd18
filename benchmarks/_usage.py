"""``-h`` / ``--help`` for a benchmark script run directly: print the script's docstring and
exit, instead of starting the run (the scripts read their few flags, such as ``--quick``,
straight from ``sys.argv``, so an unknown flag would otherwise start a full run)."""

from __future__ import annotations

import sys


def exit_on_help(doc: str | None) -> None:
    """With ``-h`` or ``--help`` among the arguments: print ``doc`` and how to run the script,
    then exit with status 0; otherwise return."""
    if not any(a in ("-h", "--help") for a in sys.argv[1:]):
        return
    name = sys.argv[0].rsplit("/", 1)[-1]
    print((doc or "").strip())
    print(f"\nusage: python benchmarks/{name} [--quick], or python benchmarks/run_all.py "
          f"{name.removeprefix('bench_').removesuffix('.py')} [--quick] (table + JSON in "
          "benchmarks/results/)")
    raise SystemExit(0)
