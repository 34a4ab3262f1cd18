"""A full disk is one line naming the file, never a traceback or a crash, and never a partial
output; a full PSF cache only costs the caching (the audit: h5py tracebacks and SIGSEGV for
psf and calibrate-aberration, "140625 requested and 25372 written" from the TIFF writers, and
psf broken by a full cache folder). Without root, the disk "fills" through a file-size limit
(RLIMIT_FSIZE, SIGXFSZ ignored: writes fail with EFBIG) in a subprocess, or through a writer
that raises ENOSPC."""

import errno
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import capped_cli_script

import metasensor as ms
from metasensor.io.raw import write_raw
from metasensor.io.views import write_views

SCRIPT = capped_cli_script(  # writes past 20,000 bytes fail with EFBIG, not a signal
    "import resource, signal; signal.signal(signal.SIGXFSZ, signal.SIG_IGN); "
    "resource.setrlimit(resource.RLIMIT_FSIZE, (20000, 20000))")


@pytest.mark.slow  # an interpreter computing a PSF bank under a file-size limit
def test_a_full_disk_is_one_line_naming_the_file(tmp_path):
    cfg = ms.SystemConfig(nnum=3, mla_pitch=3 * 4.6e-6, mla_focal=3 * 46e-6, scan=3)
    cfg.to_toml(tmp_path / "cfg.toml")
    frames = np.random.default_rng(0).integers(0, 4000, (9, 60, 60)).astype(np.uint16)
    write_raw(tmp_path / "raw.tif", frames, description=json.dumps(cfg.to_dict()))
    cache = tmp_path / "cache"
    cases = [["psf", "--config", str(tmp_path / "cfg.toml"), "--size", "41", "--out",
              str(tmp_path / "p.h5")],
             ["realign", str(tmp_path / "raw.tif"), "--config", str(tmp_path / "cfg.toml"),
              "--out", str(tmp_path / "v.tif")]]
    src = str(Path(__file__).resolve().parents[2] / "src")
    p = subprocess.run([sys.executable, "-c", SCRIPT, json.dumps(cases)], capture_output=True,
                       text=True, timeout=300, cwd=tmp_path,
                       env={"PYTHONPATH": src, "PATH": "", "METASENSOR_CACHE": str(cache),
                            "PYTHONDONTWRITEBYTECODE": "1",  # no .pyc cut short by the limit
                            "OMP_NUM_THREADS": "1"})
    assert p.returncode == 0, p.stderr[-2000:]
    for (code, err, _), args in zip(json.loads(p.stdout), cases, strict=True):
        lines = [ln for ln in err.splitlines() if ln.startswith("error:")]  # not the progress
        assert code == 2 and len(lines) == 1 and err.strip().endswith(lines[0]), (args, err)
        assert lines[0].startswith(f"error: cannot write {args[-1]}: "), err
        assert "file too large" in lines[0] or "file-size limit" in lines[0], err
    assert sorted(q.name for q in tmp_path.iterdir()) == ["cache", "cfg.toml", "raw.tif"]
    assert not list(cache.rglob("*.npy"))  # the cache entry did not fit: not kept, not fatal


def test_a_writer_hitting_enospc_names_the_file(tmp_path, monkeypatch):
    import tifffile

    from metasensor.optics import cache

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(tifffile, "imwrite", full)
    with pytest.raises(OSError, match=r"cannot write .*v\.tif: no space left on the device"):
        write_views(tmp_path / "v.tif", np.ones((3, 3, 4, 4), np.float32))
    monkeypatch.setattr(np, "save", full)
    assert cache.store("k", np.ones(3), folder=tmp_path) is None  # the caching only
    assert sorted(q.name for q in tmp_path.rglob("*")) == ["psf"]
