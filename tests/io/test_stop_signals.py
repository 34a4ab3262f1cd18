"""Ctrl-C and SIGTERM stop a real ``metasensor`` command with one line and exit 130 / 143 (the
shell's 128 + signal), remove its temporaries and its lock, leave the input byte-identical and
the output absent (a SIGTERM used to kill the command where it stood, temporaries and all).
The signal is sent once the command holds its output's lock (it is running, past start-up);
a signal inside the locking itself waits until the lock is registered for its release."""

import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import as_at_a_terminal

import metasensor as ms
from metasensor.io.raw import write_raw

CFG = ms.SystemConfig(nnum=3, mla_pitch=3 * 4.6e-6, mla_focal=3 * 46e-6, scan=3)


def _hidden(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


def test_sigterm_and_ctrl_c_stop_a_command_cleanly(tmp_path):
    frames = np.random.default_rng(0).integers(100, 4000, (9, 1200, 1200)).astype(np.uint16)
    write_raw(tmp_path / "raw.tif", frames, description=CFG.to_json())
    before = hashlib.sha256((tmp_path / "raw.tif").read_bytes()).hexdigest()
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2] / "src"),
           "OMP_NUM_THREADS": "1"}
    runs = []
    for sig, out in ((signal.SIGTERM, "v.zarr"), (signal.SIGINT, "w.zarr"),
                     (signal.SIGTERM, "x.tif")):
        (tmp_path / out).parent.mkdir(exist_ok=True)
        proc = subprocess.Popen([sys.executable, "-m", "metasensor.cli", "realign", "raw.tif",
                                 "--out", out], cwd=tmp_path, env=env, text=True,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                preexec_fn=as_at_a_terminal)  # not inherited as ignored
        runs.append((sig, out, proc))
    pending = list(runs)
    t0 = time.monotonic()
    while pending and time.monotonic() - t0 < 120:  # each run: its lock taken, then signalled
        for run in list(pending):
            sig, out, proc = run
            if (tmp_path / f".{out}.lock").exists() or proc.poll() is not None:
                proc.send_signal(sig)
                pending.remove(run)
        time.sleep(0.005)
    for sig, out, proc in runs:
        _, err = proc.communicate(timeout=120)
        lines = err.strip().splitlines()
        # 128 + signal; after Ctrl-C, CPython may instead end by SIGINT itself (a shell
        # reads both as 130) when the interrupt hit code run by an extension's PyRun_String
        codes = (130, -signal.SIGINT) if sig == signal.SIGINT else (143,)
        assert proc.returncode in codes, (out, proc.returncode, err[-2000:])
        assert lines[-1].startswith("error: stopped by") and "Traceback" not in err, err[-2000:]
        assert sum(line.startswith("error:") for line in lines) == 1, err[-2000:]
        assert not (tmp_path / out).exists(), out
    assert _hidden(tmp_path) == []  # no temporary, no lock
    assert hashlib.sha256((tmp_path / "raw.tif").read_bytes()).hexdigest() == before


def test_a_swallowed_ctrl_c_still_stops_the_write(tmp_path):
    """A KeyboardInterrupt that something swallows (a finaliser, a broad ``except``) is raised
    again before the output is put in place; a write begun after it is not affected."""
    from metasensor.io.atomic import atomic_path, staged_zarr

    previous = signal.getsignal(signal.SIGINT)
    signal.signal(signal.SIGINT, signal.default_int_handler)  # as in a plain interpreter
    try:
        for target, writer in ((tmp_path / "a.txt", atomic_path),
                               (tmp_path / "a.zarr", staged_zarr)):
            with pytest.raises(KeyboardInterrupt), writer(target) as tmp:
                (tmp / "x" if target.suffix == ".zarr" else tmp).parent.mkdir(exist_ok=True)
                try:
                    os.kill(os.getpid(), signal.SIGINT)  # Ctrl-C, then swallowed
                    time.sleep(1)
                except KeyboardInterrupt:
                    pass
            assert not target.exists() and _hidden(tmp_path) == []
        with atomic_path(tmp_path / "b.txt") as tmp:  # the interrupt was dealt with
            tmp.write_text("b")
        assert (tmp_path / "b.txt").read_text() == "b"
    finally:
        signal.signal(signal.SIGINT, previous)


MASKS = r"""
import json, sys, threading
from pathlib import Path
import numpy as np
from metasensor.io.views import write_views
from zarr.core import sync
write_views(Path(sys.argv[1]) / "v.zarr", np.ones((3, 3, 8, 8), np.float32))
def blocked(tid):
    status = Path(f"/proc/self/task/{tid}/status").read_text().splitlines()
    return int(next(x for x in status if x.startswith("SigBlk:")).split()[1], 16)
print(json.dumps([blocked(threading.main_thread().native_id),
                  blocked(sync.iothread[0].native_id)]))
"""


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="reads Linux /proc")
def test_zarr_threads_leave_ctrl_c_to_the_main_thread(tmp_path):
    """zarr's I/O thread blocks SIGINT and SIGTERM, so the kernel interrupts the main thread's
    wait in zarr's sync() instead of marking the signal in a thread that does not handle it
    (a fresh interpreter: the test process may have started zarr's loop itself)."""
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2] / "src")}
    out = subprocess.run([sys.executable, "-c", MASKS, str(tmp_path)], capture_output=True,
                         text=True, env=env, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    main, zarr_io = json.loads(out.stdout)
    stop = (1 << (signal.SIGINT - 1)) | (1 << (signal.SIGTERM - 1))
    assert main & stop == 0 and zarr_io & stop == stop, (main, zarr_io)


def test_a_command_started_with_ctrl_c_ignored_keeps_ignoring_it():
    """A command started in the background of a script (or under nohup) inherits SIGINT
    ignored and keeps it so; SIGTERM still stops it cleanly."""
    from metasensor.io.interrupt import handle_termination

    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        with handle_termination():
            assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
            assert callable(signal.getsignal(signal.SIGTERM))  # the clean stop
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, previous)


def test_ctrl_c_while_the_command_loads_is_one_line(monkeypatch, capsys):
    """A Ctrl-C before the command line has loaded (its handler not yet installed) ends the
    command with one line and exit 130, not a traceback."""
    from metasensor import launch

    class Interrupted:  # the import of the command line is where the Ctrl-C lands
        def find_spec(self, name, path=None, target=None):
            if name == "metasensor.cli":
                raise KeyboardInterrupt
            return None

    monkeypatch.delitem(sys.modules, "metasensor.cli", raising=False)
    monkeypatch.setattr(sys, "meta_path", [Interrupted(), *sys.meta_path])
    with pytest.raises(SystemExit) as stop:
        launch.main()
    assert stop.value.code == 130
    err = capsys.readouterr().err
    assert err.startswith("error: stopped by Ctrl-C") and err.count("\n") == 1, err


def test_a_signal_swallowed_before_a_write_began_stops_it_inside_a_command(tmp_path):
    """Inside a command, a SIGTERM that something swallowed before the output's write began
    (a finaliser, the import system's lock callback) still stops that write; outside the
    command a later write goes ahead."""
    from metasensor.io.atomic import atomic_path
    from metasensor.io.interrupt import Terminated, handle_termination

    with handle_termination():
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(1)
        except Terminated:
            pass  # swallowed
        with pytest.raises(Terminated), atomic_path(tmp_path / "a.txt") as tmp:
            tmp.write_text("a")
    assert not (tmp_path / "a.txt").exists() and _hidden(tmp_path) == []
    with atomic_path(tmp_path / "b.txt") as tmp:
        tmp.write_text("b")
    assert (tmp_path / "b.txt").read_text() == "b"
