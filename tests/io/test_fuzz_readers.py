"""Property-based fuzzing of every reader: valid files with bytes overwritten, inserted or cut
off end in a valid result or a clean error (``ValueError``/``OSError``/``TypeError``, what the
command line turns into exit 2 and one line), within a time bound (hypothesis' deadline) and a
memory bound (readers are told only 256 MiB are available). A bounded budget runs in the default
suite; the ``slow`` variant runs many more examples."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import tifffile
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import metasensor as ms
from metasensor.dao.system_aberration import SystemAberration
from metasensor.io.raw import open_raw, write_raw
from metasensor.io.views import read_config_from_views, read_views, write_views
from metasensor.optics.psf_io import load_psf, read_npy, save_psf
from metasensor.sensor.calibration import Calibration

CFG = ms.SystemConfig(nnum=3, mla_pitch=3 * 4.6e-6, mla_focal=3 * 46e-6, scan=3)
CLEAN = (ValueError, OSError, TypeError)
_names = itertools.count()


def _read_frames(p):
    with open_raw(p) as raw:
        return [raw[t] for t in range(min(len(raw), 4))]


def _read_views(p):
    read_config_from_views(p, strict=False)
    return np.asarray(read_views(p))


def _read_zarr(p):
    return np.asarray(read_views(p)[:])


READERS = {
    "frames.tif": _read_frames,
    "views.tif": _read_views,
    "psf.h5": load_psf,
    "system.h5": SystemAberration.load,
    "cfg.toml": ms.SystemConfig.from_toml,
    "calib.toml": Calibration.from_toml,
    "vector.npy": lambda p: read_npy(p, "--zernike"),
}


@pytest.fixture(scope="module")
def originals(tmp_path_factory):
    root = tmp_path_factory.mktemp("fuzz")
    rng = np.random.default_rng(0)
    write_raw(root / "frames.tif", rng.integers(0, 4000, (9, 12, 12)).astype(np.uint16),
              description=CFG.to_json())
    write_views(root / "views.tif", rng.random((3, 3, 6, 6)).astype(np.float32), CFG,
                extra={"scan_order": [[0, 0]]})
    tifffile.imwrite(root / "deflate.tif", rng.random((3, 3, 6, 6)).astype(np.float32),
                     compression="zlib")
    save_psf(root / "psf.h5", np.full((3, 3, 5, 5), 0.04, np.float32), CFG, zernike=np.ones(4))
    SystemAberration(zernike=np.zeros((2, 2, 45)), shift_grid=np.zeros((3, 3, 2, 2, 2)),
                     view_shape=(6, 6), config=CFG).save(root / "system.h5")
    CFG.to_toml(root / "cfg.toml")
    Calibration(nnum=3, pitch=3.0, rotation=0.0, center=(1.0, 1.0), lenslets=(2, 2),
                sensor_shape=(9, 9)).to_toml(root / "calib.toml")
    np.save(root / "vector.npy", np.linspace(0, 1, 15))
    write_views(root / "views.zarr", rng.random((3, 3, 6, 6)).astype(np.float32), CFG)
    return root


def _mutate(data: bytes, edits, cut: int | None) -> bytes:
    buf = bytearray(data)
    for pos, chunk, insert in edits:
        pos %= max(1, len(buf))
        if insert:
            buf[pos:pos] = chunk
        else:
            buf[pos:pos + len(chunk)] = chunk
    return bytes(buf[:cut] if cut is not None else buf)


EDITS = st.lists(st.tuples(st.integers(0, 2**20), st.binary(min_size=1, max_size=16),
                           st.booleans()), min_size=1, max_size=4)
CUT = st.one_of(st.none(), st.integers(0, 4096))


def _check(originals, monkeypatch, name, edits, cut):
    from metasensor.io import tiff

    monkeypatch.setattr(tiff, "available_memory", lambda: 256 * 2**20)
    reader = READERS.get(name, _read_views)
    path = originals / f"{next(_names)}_{name}"
    path.write_bytes(_mutate((originals / name).read_bytes(), edits, cut))
    try:
        reader(path)
    except CLEAN:
        pass
    finally:
        path.unlink()


def _check_zarr(originals, edits, which: int, meta: bool):
    import shutil

    store = originals / f"{next(_names)}.zarr"
    shutil.copytree(originals / "views.zarr", store)
    files = sorted(p for p in store.rglob("*") if p.is_file() and (p.name == "zarr.json") == meta)
    target = files[which % len(files)]
    target.write_bytes(_mutate(target.read_bytes(), edits, None))
    try:
        _read_zarr(store)
    except CLEAN:
        pass
    finally:
        shutil.rmtree(store)


FILES = st.sampled_from([*READERS, "deflate.tif"])
QUICK = settings(max_examples=60, deadline=5000, derandomize=True,
                 suppress_health_check=[HealthCheck.function_scoped_fixture,
                                        HealthCheck.too_slow])
LONG = settings(max_examples=2000, deadline=5000,
                suppress_health_check=[HealthCheck.function_scoped_fixture,
                                       HealthCheck.too_slow])


@QUICK
@given(name=FILES, edits=EDITS, cut=CUT)
def test_fuzzed_files_end_cleanly(originals, monkeypatch, name, edits, cut):
    _check(originals, monkeypatch, name, edits, cut)


@settings(QUICK, max_examples=20)  # a store is copied per example
@given(edits=EDITS, which=st.integers(0, 100), meta=st.booleans())
def test_fuzzed_zarr_stores_end_cleanly(originals, edits, which, meta):
    _check_zarr(originals, edits, which, meta)


@pytest.mark.slow
@LONG
@given(name=FILES, edits=EDITS, cut=CUT)
def test_fuzzed_files_end_cleanly_long(originals, monkeypatch, name, edits, cut):
    _check(originals, monkeypatch, name, edits, cut)


@pytest.mark.slow
@settings(LONG, max_examples=400)
@given(edits=EDITS, which=st.integers(0, 100), meta=st.booleans())
def test_fuzzed_zarr_stores_end_cleanly_long(originals, edits, which, meta):
    _check_zarr(originals, edits, which, meta)
