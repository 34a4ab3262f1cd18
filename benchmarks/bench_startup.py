"""Start-up of the console command: wall time of ``metasensor --help`` and ``--version`` in a
fresh interpreter (what a person waits for before the first screen), against a bare
``python -c pass`` in the same run, and whether torch was imported on the way.

Each case runs ``repeat`` times (``quick``: 3, else 15) with ``OMP_NUM_THREADS=1``; rows give
the median and the slowest run. The target is a help screen in under 1 s on 2 cores.
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

SRC = str(Path(__file__).resolve().parent.parent / "src")

_PROBE = ("import sys\n"
          "sys.argv = ['metasensor', *sys.argv[1:]]\n"
          "try:\n"
          "    from metasensor.cli import main\n"
          "    main()\n"
          "except SystemExit:\n"
          "    pass\n"
          "print('TORCH' if 'torch' in sys.modules else 'NOTORCH', file=sys.stderr)\n")


def _time(args: list[str], repeat: int) -> tuple[list[float], bool]:
    env = {**os.environ, "PYTHONPATH": SRC + os.pathsep + os.environ.get("PYTHONPATH", ""),
           "OMP_NUM_THREADS": "1"}
    times, torch = [], False
    for _ in range(repeat):
        t0 = time.perf_counter()
        res = subprocess.run([sys.executable, *args], capture_output=True, text=True, env=env,
                             check=True)
        times.append(time.perf_counter() - t0)
        torch = torch or "TORCH" in res.stderr.split()
    return times, torch


def run(quick: bool = False) -> list[dict]:
    repeat = 3 if quick else 15
    cases = {
        "python -c pass": ["-c", "pass"],
        "metasensor --help": ["-c", _PROBE, "--help"],
        "metasensor --version": ["-c", _PROBE, "--version"],
        "metasensor reconstruct --help": ["-c", _PROBE, "reconstruct", "--help"],
    }
    rows = []
    for name, args in cases.items():
        times, torch = _time(args, repeat)
        rows.append({"case": name, "runs": repeat, "median_s": statistics.median(times),
                     "max_s": max(times), "imports_torch": torch,
                     "target_s": 1.0 if name in ("metasensor --help",
                                                 "metasensor --version") else None})
    return rows
