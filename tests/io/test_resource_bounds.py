"""Configurations and inputs that would allocate gigabytes or run for minutes end at once with
exit 2 and one line naming the value (the audit: ``wavelength = 1e-3``, ``na = 0.999999``,
``nnum = 101`` and ``depth --range -1e6,1e6`` allocated 4.8-7.1 GB and died in torch's
allocator; ``wavelength = 1e-15``, ``mla_pitch = 1e-300``, ``mla_focal = 1e300`` and a Zernike
vector of 10^6 terms ran for minutes). Configurations inside every range whose field grid would
not fit (4.7-12 GB index arrays, or minutes of widefield estimate, before) are sized before the
allocation. The commands run in one subprocess whose address space is capped (RLIMIT_AS), so a
regression fails fast with a memory error instead of swapping, and each case is timed."""

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
from cli_helpers import capped_cli_script

import metasensor as ms
from metasensor.io.views import write_views

CFG = ms.SystemConfig(nnum=3, mla_pitch=3 * 4.6e-6, mla_focal=3 * 46e-6, scan=3)


def _cap_bytes() -> int:
    """The address-space cap of the commands' process: 2.3 GiB over what the interpreter maps
    once torch and the package are imported (about 0.7 GB with a CPU build of torch; a CUDA
    build maps several GB of libraries, and under 3 GiB it cannot even be imported)."""
    probe = ("import re, torch, metasensor.cli; "
             "print(re.search(r'VmPeak:\\s+(\\d+) kB', open('/proc/self/status').read())[1])")
    src = str(Path(__file__).resolve().parents[2] / "src")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                         timeout=120, env={"PYTHONPATH": src, "PATH": "", "OMP_NUM_THREADS": "1"})
    assert out.returncode == 0, out.stderr[-2000:]
    return int(out.stdout.split()[-1]) * 1024 + int(2.3 * 2**30)


SCRIPT = capped_cli_script(
    "import resource; resource.setrlimit(resource.RLIMIT_AS, (int(sys.argv[2]),) * 2)")


def _toml(path: Path, **change) -> Path:
    CFG.to_toml(path)
    text = path.read_text()
    for key, value in change.items():
        line = f"{key} = {value}"
        text, n = re.subn(rf"^{key} = .*$", line, text, flags=re.M)
        if not n:
            text = text.replace("[system]\n", f"[system]\n{line}\n")
    path.write_text(text)
    return path


def test_huge_or_endless_requests_end_at_once_naming_the_value(tmp_path):
    views = 1 + np.random.default_rng(0).random((3, 3, 24, 24)).astype(np.float32)
    write_views(tmp_path / "views.tif", views, CFG)
    np.save(tmp_path / "z1e6.npy", np.full(10**6, 0.01))
    p = tmp_path / "p.h5"
    cases = []
    for key, value, name in (("wavelength", "1e-3", "wavelength"),
                             ("wavelength", "1e-15", "wavelength"),
                             ("na", "0.999999", "na"), ("nnum", "101", "nnum"),
                             ("mla_pitch", "1e-300", "mla_pitch"),
                             ("mla_focal", "1e300", "mla_focal"),
                             ("aperture_diameter", "1e-300", "aperture_diameter")):
        toml = _toml(tmp_path / f"{key}_{value}.toml", **{key: value})
        cases.append((["psf", "--config", str(toml), "--out", str(p)], name))
    cases += [
        (["psf", "--config", str(_toml(tmp_path / "c.toml")), "--zernike",
          str(tmp_path / "z1e6.npy"), "--out", str(p)], "--zernike"),
        (["psf", "--config", str(tmp_path / "c.toml"), "--zernike", "1000000:0.1", "--out",
          str(p)], "--zernike"),
        (["psf", "--config", str(tmp_path / "c.toml"), "--zernike", "4:1e300", "--out",
          str(p)], "--zernike"),
        (["depth", str(tmp_path / "views.tif"), "--range=-1e6,1e6", "--out",
          str(tmp_path / "d")], "range"),
    ]
    # within every range, yet the field grid would not fit: sized before allocating (and
    # before the widefield estimate of the window, which alone ran for minutes)
    for k, (change, name) in enumerate((
            ({"nnum": 63, "mla_pitch": 1e-2, "wavelength": 1e-7, "na": 0.95}, "the field grid"),
            ({"nnum": 63, "mla_pitch": 1e-2, "mla_focal": 1e-6}, "the field grid"),
            ({"wavelength": 2e-5, "na": 0.95, "mla_pitch": 1e-6, "mla_focal": 1.0},
             "the field grid"))):
        cases.append((["psf", "--config", str(_toml(tmp_path / f"big{k}.toml", **change)),
                       "--out", str(p)], name))
    src = str(Path(__file__).resolve().parents[2] / "src")
    run = subprocess.run([sys.executable, "-c", SCRIPT, json.dumps([c for c, _ in cases]),
                          str(_cap_bytes())], capture_output=True, text=True, timeout=300,
                         env={"PYTHONPATH": src, "PATH": "", "OMP_NUM_THREADS": "1",
                              "METASENSOR_CACHE": str(tmp_path / "cache")})
    assert run.returncode == 0, run.stderr[-2000:]
    for (code, err, seconds), (args, name) in zip(json.loads(run.stdout), cases, strict=True):
        lines = err.strip().splitlines()
        assert code == 2 and lines and lines[-1].startswith("error:"), (args, code, err[-1500:])
        assert name in lines[-1], (args, lines[-1])
        assert "Unable to allocate" not in lines[-1], (args, lines[-1])  # sized, not hit
        if not name.endswith("grid"):  # refused as out of range, before any sizing
            assert "memory" not in lines[-1], (args, lines[-1])
        assert seconds < 20, (args, seconds)  # refused before any work, not after it
    assert not p.exists() and not (tmp_path / "d").exists()
