"""Run one ``metasensor`` command for a widget: the CLI itself, in a child process.

The widgets add no second implementation: each run is the command line a user would type
(``python -m metasensor.cli <command> ...``), so its outputs are the CLI's by construction. A
child process keeps the viewer responsive (no shared interpreter lock), reports progress through
the command's own progress bars (tqdm on stderr, parsed here), and can be cancelled at any moment
by ending it.

Outputs go to a staging folder beside the chosen one (``.<name>.partial-<id>``) and are moved into
place only when the command succeeded: a cancelled or failed run leaves nothing behind, a
finished one leaves the command's files plus ``summary.json`` with the run's settings and its
command line (``replay``), so ``metasensor <replay.argv>`` repeats it. Only the standard library
is used here (no Qt), so the runner is testable on its own.
"""

from __future__ import annotations

import json
import os
import queue
import re
import shlex
import shutil
import signal
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["CommandRun", "Job", "JobResult", "Progress", "parse_progress"]

_BAR = re.compile(r"(?:(?P<desc>[^:\r\n|]+):\s*)?\d+%\|[^|]*\|\s*(?P<n>\d+)/(?P<total>\d+)")


@dataclass(frozen=True)
class Progress:
    """One progress report of the running command (its tqdm bar)."""

    n: int
    total: int
    desc: str = ""


@dataclass(frozen=True)
class CommandRun:
    """A command line to run for a widget.

    command : the ``metasensor`` command (``"reconstruct"``).
    inputs : its positional arguments (input files).
    options : ``(flag, value)`` pairs; value ``None`` = a bare flag, ``False``/``""`` = left out.
    out : the output folder the widget was given.
    out_name : the file inside ``out`` that ``--out`` names (``"views.tif"``), or ``None`` when
        ``--out`` is the folder itself.
    settings : the widget's values, recorded in ``summary.json``.
    """

    command: str
    inputs: tuple[str, ...]
    options: tuple[tuple[str, object], ...]
    out: Path
    out_name: str | None = None
    settings: dict = field(default_factory=dict)

    def argv(self, out: Path | None = None) -> list[str]:
        """The command's arguments (after ``metasensor``), writing to ``out`` (default: the
        chosen folder)."""
        target = Path(out if out is not None else self.out)
        target = target / self.out_name if self.out_name else target
        args = [self.command, *(str(i) for i in self.inputs), "--out", str(target)]
        for flag, value in self.options:
            if value is None:
                args.append(flag)
            elif value is not False and value != "":
                args += [flag, str(value)]
        return args


@dataclass
class JobResult:
    """What a run ended with: ``status`` is ``"done"``, ``"cancelled"`` or ``"failed"``."""

    status: str
    out: Path
    stdout: str = ""
    error: str = ""
    argv: list[str] = field(default_factory=list)


def parse_progress(text: str) -> Progress | None:
    """The last tqdm report in ``text`` (``"desc:  40%|####  | 4/10 [...]"``), or None."""
    found = None
    for m in _BAR.finditer(text):
        found = m
    if found is None:
        return None
    return Progress(int(found["n"]), int(found["total"]), (found["desc"] or "").strip())


def _one_line(stderr: str, code: int) -> str:
    """The command's ``error:`` line (the CLI's one-line message), else its last line."""
    lines = [ln.strip() for ln in re.split(r"[\r\n]+", stderr) if ln.strip()]
    errors = [ln for ln in lines if ln.startswith("error:")]
    if errors:
        return errors[-1][len("error:"):].strip()
    return lines[-1] if lines else f"the command exited with status {code}"


class Job:
    """One run of a :class:`CommandRun`. :meth:`steps` (in a worker thread) starts the process,
    yields :class:`Progress` and returns a :class:`JobResult`; :meth:`cancel` (from any thread)
    ends the process."""

    def __init__(self, run: CommandRun, python: str | None = None) -> None:
        self.run = run
        self.python = python or sys.executable
        self._proc: subprocess.Popen | None = None
        self._cancelled = threading.Event()
        self._cancel_time = 0.0
        self.staging = run.out.parent / f".{run.out.name}.partial-{uuid.uuid4().hex[:8]}"

    @property
    def cancelled(self) -> bool:
        return self._cancelled.is_set()

    def cancel(self) -> None:
        """Stop the running command (SIGTERM, which commands take as Ctrl-C: it cleans up after
        itself; unlike Ctrl-C it is not ignored when the viewer was started as a background job;
        :meth:`steps` ends it if it has not stopped 5 s later and removes the partial output)."""
        self._cancelled.set()
        self._cancel_time = time.monotonic()
        proc = self._proc
        if proc is not None and proc.poll() is None:
            proc.send_signal(signal.SIGTERM)

    def steps(self) -> Iterator[Progress]:
        """Generator: run the command; yields progress; returns the JobResult."""
        run = self.run
        argv = run.argv(self.staging)
        if self.cancelled:
            return JobResult("cancelled", run.out, argv=run.argv())
        self.staging.mkdir(parents=True)
        chunks: queue.Queue[str | None] = queue.Queue()
        try:
            self._proc = subprocess.Popen(
                [self.python, "-m", "metasensor.cli", *argv], stdout=subprocess.PIPE,
                stderr=subprocess.PIPE, stdin=subprocess.DEVNULL)
            if self.cancelled:  # cancelled while the process started
                self._proc.send_signal(signal.SIGTERM)
            out_text: list[str] = []
            readers = [threading.Thread(target=_pump, args=(self._proc.stderr, chunks),
                                        daemon=True),
                       threading.Thread(target=_collect, args=(self._proc.stdout, out_text),
                                        daemon=True)]
            for t in readers:
                t.start()
            err_text = ""
            while True:
                try:
                    chunk = chunks.get(timeout=0.1)
                except queue.Empty:
                    if self.cancelled and time.monotonic() - self._cancel_time > 5.0:
                        self._proc.kill()  # did not stop on SIGTERM
                    yield None  # a chance to quit for the worker; no news
                    continue
                if chunk is None:
                    break
                err_text += chunk
                report = parse_progress(chunk)
                if report is not None:
                    yield report
            code = self._proc.wait()
            for t in readers:
                t.join()
            if self.cancelled:
                return JobResult("cancelled", run.out, argv=run.argv())
            if code != 0:
                return JobResult("failed", run.out, "".join(out_text), _one_line(err_text, code),
                                 run.argv())
            stdout = "".join(out_text).replace(str(self.staging), str(run.out))
            self._publish(stdout)
            return JobResult("done", run.out, stdout, argv=run.argv())
        finally:
            if self._proc is not None and self._proc.poll() is None:  # generator closed early
                self._proc.kill()
                self._proc.wait()
            shutil.rmtree(self.staging, ignore_errors=True)
            clear_leftovers(self.staging)

    def _publish(self, stdout: str) -> None:
        """Record the run in summary.json, then move the staged outputs into the chosen folder
        (one rename if it does not exist yet; else file by file, summary.json last)."""
        run = self.run
        staged = str(self.staging)
        for path in self.staging.rglob("*"):  # text outputs that name the staging folder
            if path.is_file() and path.suffix in (".json", ".txt", ".toml", ".csv"):
                text = path.read_text(errors="replace")
                if staged in text:
                    path.write_text(text.replace(staged, str(run.out)))
        summary_path = self.staging / "summary.json"
        summary = {}
        if summary_path.is_file():  # reconstruct writes its own: the run is added to it
            summary = json.loads(summary_path.read_text())
        argv = run.argv()
        summary["replay"] = {"argv": argv, "command": "metasensor " + shlex.join(argv),
                             "widget": run.command, "settings": run.settings,
                             "stdout": stdout.strip().splitlines()[-20:]}
        tmp = summary_path.with_name(".summary.json.tmp")
        tmp.write_text(json.dumps(summary, indent=1, default=str))
        os.replace(tmp, summary_path)
        out = run.out
        if not out.exists():
            os.replace(self.staging, out)
            return
        out.mkdir(parents=True, exist_ok=True)
        names = sorted(p.name for p in self.staging.iterdir())
        names.sort(key=lambda n: n == "summary.json")
        for name in names:
            target = out / name
            if target.is_dir() and not (self.staging / name).is_dir():
                raise ValueError(f"{target} is a folder; the run wrote a file of that name")
            if target.is_dir():
                shutil.rmtree(target)
            os.replace(self.staging / name, target)


def clear_leftovers(out: Path) -> list[Path]:
    """Remove what a command ended by force left beside its output ``out``: temporaries of a
    process that no longer exists (:func:`metasensor.io.atomic.remove_stale`) and a lock no
    process holds (:func:`metasensor.io.guard.remove_free_lock`). A live run's lock or
    temporary is never removed. Returns the paths removed."""
    from metasensor.io.atomic import remove_stale, sibling_name
    from metasensor.io.guard import remove_free_lock

    removed = remove_stale(out)
    if remove_free_lock(out):
        removed.append(out.parent / sibling_name(out, "lock", pid=False))
    return removed


def _pump(stream, chunks: queue.Queue) -> None:
    """Pass on what arrives on the byte ``stream`` as it arrives (tqdm ends its updates with a
    carriage return, not a newline), decoded; ``None`` at the end."""
    import codecs

    decoder = codecs.getincrementaldecoder("utf-8")(errors="replace")
    try:
        while True:
            piece = stream.read1(4096)
            if not piece:
                break
            chunks.put(decoder.decode(piece))
    finally:
        chunks.put(None)


def _collect(stream, sink: list[str]) -> None:
    sink.append(stream.read().decode("utf-8", errors="replace"))
