"""A new user's first hour, scripted: simulate -> calibrate -> realign -> reconstruct -> depth
-> evaluate on a 256-px capture (``quick``: 128 px), each a ``metasensor`` command in its own
process, as a person would type them. Measures each command's wall time and its longest
*silent gap*: the longest time with nothing new on stdout or stderr (progress bars count),
from the start to the first output, between outputs, or from the last output to the exit.

Target: no gap over 10 s (a person waiting should see progress at least that often).
Rows: command, seconds, longest gap (s), the last output before that gap. ``FIRST_HOUR_LOGS``
names a folder that keeps each command's terminal output.
"""

from __future__ import annotations

import fcntl
import os
import pty
import select
import struct
import subprocess
import sys
import tempfile
import termios
import time
from pathlib import Path

SRC = str(Path(__file__).resolve().parent.parent / "src")
TARGET_GAP_S = 10.0


def steps(size: int) -> list[list[str]]:
    """The scripted session (file names relative to its folder)."""
    return [
        ["simulate", "--scene", "chart", "--size", str(size), "--zernike", "4:0.4,5:0.3,7:0.2",
         "--snr", "30", "-o", "cap"],
        ["calibrate", "cap/frames.tif", "-o", "calib.toml"],
        ["realign", "cap/frames.tif", "--calib", "calib.toml", "-o", "views.tif"],
        ["reconstruct", "views.tif", "--blocks", "2x2", "-o", "result"],  # DAO: the default
        ["depth", "views.tif", "-o", "depth"],
        ["evaluate", "result/image.tif", "--truth", "cap/truth.tif", "--chart", "-o", "eval"],
    ]


def watch(args: list[str], cwd: str) -> dict:
    """Run ``metasensor ARGS`` on a pseudo-terminal (progress bars draw as they do for a
    person) and time the silences in its output. The PSF cache is the session folder's own
    (``cwd/cache``): empty at the start, as on a first day."""
    env = {**os.environ, "PYTHONPATH": SRC + os.pathsep + os.environ.get("PYTHONPATH", ""),
           "OMP_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1",
           "METASENSOR_CACHE": str(Path(cwd) / "cache")}
    master, slave = pty.openpty()
    # a terminal of 100 x 30 characters: with no size set, progress bars draw nothing
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 30, 100, 0, 0))
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "metasensor.cli", *args], cwd=cwd, env=env,
                            stdin=subprocess.DEVNULL, stdout=slave, stderr=slave)
    os.close(slave)
    last, gap, before, text = t0, 0.0, "(start)", b""
    while True:
        ready, _, _ = select.select([master], [], [], 1.0)
        if not ready:
            if proc.poll() is not None:
                break
            continue
        try:
            chunk = os.read(master, 65536)
        except OSError:  # the child closed the terminal
            chunk = b""
        now = time.perf_counter()
        if not chunk:
            break
        if now - last > gap:
            gap, before = now - last, _tail(text)
        last, text = now, text + chunk
    proc.wait()
    os.close(master)
    end = time.perf_counter()
    if end - last > gap:
        gap, before = end - last, _tail(text)
    return {"command": "metasensor " + " ".join(args[:2]), "exit": proc.returncode,
            "seconds": end - t0, "longest_gap_s": gap, "before_gap": before,
            "gap_ok": gap <= TARGET_GAP_S, "output": text.decode(errors="replace")}


def _tail(text: bytes) -> str:
    line = text.decode(errors="replace").replace("\r", "\n").rstrip().rsplit("\n", 1)[-1]
    return line.strip()[-70:] or "(start)"


def run(quick: bool = False) -> list[dict]:
    import torch

    torch.set_num_threads(1)
    rows = []
    logs = os.environ.get("FIRST_HOUR_LOGS")  # a folder to keep each command's output in
    with tempfile.TemporaryDirectory() as tmp:
        for args in steps(128 if quick else 256):
            row = watch(args, tmp)
            output = row.pop("output")
            if logs:
                Path(logs).mkdir(parents=True, exist_ok=True)
                (Path(logs) / f"{args[0]}.txt").write_text(output)
            rows.append(row)
            if row["exit"] != 0:
                raise RuntimeError(f"{row['command']} failed: {output[-400:]}")
    rows.append({"command": "all", "exit": 0, "seconds": sum(r["seconds"] for r in rows),
                 "longest_gap_s": max(r["longest_gap_s"] for r in rows), "before_gap": "",
                 "gap_ok": all(r["gap_ok"] for r in rows)})
    return rows
