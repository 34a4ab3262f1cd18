"""Start-up of the console command: ``metasensor --help`` and ``--version`` in a fresh
interpreter (what a person waits for before the first screen), against a bare
``python -c pass`` and against the eager start-up this package had before (every stage's
command module imported before the help is drawn), in the same run.

Each case runs ``repeat`` times (``quick``: 3, else 15) with ``OMP_NUM_THREADS=1``; rows give
the median wall time, the slowest run, the median CPU time (user + system of the child: on a
machine shared with other jobs the wall time measures the load, the CPU time what the command
costs; on an idle 2-core machine they agree), and whether torch was imported on the way.
The target is a help screen in under 1 s on 2 cores.
"""

from __future__ import annotations

import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

SRC = str(Path(__file__).resolve().parent.parent / "src")

_PROBE = ("import sys\n"
          "sys.argv = ['metasensor', *sys.argv[1:]]\n"
          "from metasensor.cli import main\n"
          "try:\n"
          "    main()\n"
          "except SystemExit:\n"
          "    pass\n"
          "print('TORCH' if 'torch' in sys.modules else 'NOTORCH', file=sys.stderr)\n")
# the start-up before stages were loaded lazily: every command module imported first
_EAGER = ("import importlib, sys\n"
          "import metasensor.cli as cli\n"
          "for m in cli._COMMAND_MODULES:\n"
          "    importlib.import_module('metasensor.' + m)\n") + _PROBE


def _time(args: list[str], repeat: int) -> tuple[list[float], list[float], bool]:
    env = {**os.environ, "PYTHONPATH": SRC + os.pathsep + os.environ.get("PYTHONPATH", ""),
           "OMP_NUM_THREADS": "1"}
    wall, cpu, torch = [], [], False
    for _ in range(repeat):
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        res = subprocess.run([sys.executable, *args], capture_output=True, text=True, env=env,
                             check=True)
        wall.append(time.perf_counter() - t0)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu.append(after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime)
        torch = torch or "TORCH" in res.stderr.split()
    return wall, cpu, torch


def run(quick: bool = False) -> list[dict]:
    repeat = 3 if quick else 15
    cases = {
        "python -c pass": ["-c", "pass"],
        "metasensor --help": ["-c", _PROBE, "--help"],
        "metasensor --version": ["-c", _PROBE, "--version"],
        "metasensor reconstruct --help": ["-c", _PROBE, "reconstruct", "--help"],
        "eager start-up (before): --help": ["-c", _EAGER, "--help"],
    }
    rows = []
    for name, args in cases.items():
        wall, cpu, torch = _time(args, repeat)
        rows.append({"case": name, "runs": repeat, "median_s": statistics.median(wall),
                     "max_s": max(wall), "median_cpu_s": statistics.median(cpu),
                     "imports_torch": torch,
                     "load_1min": os.getloadavg()[0],
                     "target_s": 1.0 if name in ("metasensor --help",
                                                 "metasensor --version") else None})
    return rows
