"""What a run ended by force leaves beside its output is cleared by the napari plugin's runner
only when it is provably nobody's: a temporary whose process no longer exists, a lock no process
holds. A live run's lock and temporaries stay (the runner used to remove every file named like
its staging folder, a live lock included)."""

import fcntl
import os
import subprocess
import sys

from metasensor.io.atomic import sibling_name
from metasensor.napari.jobs import clear_leftovers


def _dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def test_only_a_dead_runs_leftovers_are_removed(tmp_path):
    out = tmp_path / ".result.partial-0123abcd"
    dead, alive = _dead_pid(), os.getpid()
    stale = tmp_path / f".{out.name}.{dead}-0badc0de.tmp"
    stale_store = tmp_path / f".{out.name}.{dead}-0badc0df.tmp.zarr"
    live = tmp_path / f".{out.name}.{alive}-00c0ffee.tmp"
    stale.write_text("x")
    stale_store.mkdir()
    (stale_store / "zarr.json").write_text("{}")
    live.write_text("y")
    lock = tmp_path / sibling_name(out, "lock", pid=False)
    fd = os.open(lock, os.O_RDWR | os.O_CREAT)
    fcntl.flock(fd, fcntl.LOCK_EX)  # a live run holds its output's lock
    try:
        assert sorted(p.name for p in clear_leftovers(out)) == sorted([stale.name,
                                                                       stale_store.name])
        assert lock.exists() and live.exists()
    finally:
        os.close(fd)  # that run ends by force: its lock file stays, held by no one
    assert clear_leftovers(out) == [lock] and not lock.exists() and live.exists()
    other = tmp_path / sibling_name(tmp_path / "result", "lock", pid=False)
    other.write_text("")  # another output's lock: never in this run's namespace
    clear_leftovers(out)
    assert other.exists()
