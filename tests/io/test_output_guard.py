"""No command replaces what it reads or deletes what it did not write: generated names, figures
and side files are checked against the inputs and each other (each case below reproduced a
loss: the command exited 0 having replaced or deleted the user's file)."""

import os

import numpy as np
import pytest
from cli_helpers import refused, run_cli, tree_digest

import metasensor as ms
from metasensor.io.atomic import atomic_write_text, sibling_name
from metasensor.io.guard import OutputLocked, guard
from metasensor.io.raw import write_raw
from metasensor.io.views import read_views, write_views
from metasensor.sensor.calibration import Calibration


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    root = tmp_path_factory.mktemp("guard")
    frames = np.random.default_rng(0).integers(0, 4000, (50, 30, 30)).astype(np.uint16)
    write_raw(root / "run_00001.tif", frames)  # 50 frames = two 5x5 scan periods
    write_raw(root / "win_00001.tif", frames[:26])  # --sliding: two windows
    ms.SystemConfig().to_toml(root / "cfg.toml")
    np.save(root / "z.npy", np.zeros(15))
    Calibration(nnum=15, pitch=15.0, rotation=0.0, center=(7.0, 7.0), lenslets=(2, 2),
                sensor_shape=(30, 30), flat="c.flat.tif").to_toml(root / "c.toml")
    write_raw(root / "c.flat.tif", np.ones((30, 30), np.float32))
    (root / "d.zarr").mkdir()
    write_raw(root / "d.zarr" / "frames.tif", frames[:25])
    (root / "mydata.zarr").mkdir()
    (root / "mydata.zarr" / "notes.txt").write_text("a user's file")
    (root / "r").mkdir()
    (root / "r2").mkdir()  # an image.zarr that is a link to the user's folder
    (root / "r2" / "image.zarr").symlink_to(root / "mydata.zarr")
    np.save(root / "r" / "zernike.npy", np.zeros(15))
    write_views(root / "views.tif", np.ones((15, 15, 4, 4), np.float32), ms.SystemConfig())
    (root / "ev").mkdir()
    np.save(root / "ev" / "evaluation.json", np.ones((8, 8)))
    return root


def test_every_command_refuses_outputs_over_inputs_or_each_other(files):
    f = files
    before = tree_digest(f)
    cases = [
        # generated names: 50 frames -> run_00000.tif, run_00001.tif (the input)
        (["realign", f / "run_00001.tif", "--out", f / "run.tif"], "would overwrite the input"),
        (["realign", f / "win_00001.tif", "--sliding", "--out", f / "win.tif", "--config",
          f / "cfg.toml"], "would overwrite"),
        (["realign", f / "d.zarr" / "frames.tif", "--out", f / "d.zarr"], "would overwrite"),
        (["realign", f / "run_00001.tif", "--out", f / "mydata.zarr"], "not a Zarr store"),
        (["realign", f / "d.zarr" / "frames.tif", "--calib", f / "c.toml", "--flat", "--out",
          f / "c.flat.tif"], "would overwrite the input"),
        (["psf", "--config", f / "cfg.toml", "--out", f / "p.h5", "--png", f / "p.h5"],
         "same file"),
        (["psf", "--config", f / "cfg.toml", "--zernike", f / "z.npy", "--out", f / "p.h5",
          "--png", f / "z.npy"], "would overwrite the input"),
        (["reconstruct", f / "views.tif", "--zernike", f / "r" / "zernike.npy", "--out",
          f / "r"], "would overwrite the input"),
        (["reconstruct", f / "views.tif", "--out", f / "r2"], "not a Zarr store"),
        (["calibrate", f / "run_00001.tif", "--config", f / "cfg.toml", "--out",
          f / "cfg.toml"], "would overwrite the input"),
        (["calibrate", f / "run_00001.tif", "--figure", f / "k.toml", "--out", f / "k.toml"],
         "same file"),
        (["evaluate", f / "ev" / "evaluation.json", "--out", f / "ev"], "would overwrite"),
        (["calibrate-aberration", f / "views.tif", "--out", f / "views.h5", "--figure"],
         "would overwrite the input"),  # views.h5's figure is views.png: allowed; the h5 is not
        (["motion", f / "views.tif", "--out", f / "views.tif"], "would overwrite the input"),
    ]
    (f / "views.h5").symlink_to(f / "views.tif")  # a link to an input is the input
    try:
        for args, match in cases:
            refused(*args, match=match)
    finally:
        (f / "views.h5").unlink()
    assert tree_digest(f) == before  # nothing written, replaced or removed
    assert not [p for p in f.rglob(".*")]  # no lock or temporary left behind
    assert (f / "mydata.zarr" / "notes.txt").read_text() == "a user's file"


def test_named_pipes_are_refused_not_read(files, tmp_path):
    fifo = tmp_path / "views.tif"
    os.mkfifo(fifo)
    for args in (["depth", fifo, "--out", tmp_path / "d"],
                 ["reconstruct", fifo, "--out", tmp_path / "r"],
                 ["motion", fifo, "--out", tmp_path / "m.tif"],
                 ["calibrate-aberration", fifo, "--out", tmp_path / "s.h5"],
                 ["psf", "--config", fifo, "--out", tmp_path / "p.h5"]):
        refused(*args, match="not a regular file")


def test_zarr_output_replaces_only_its_own_store(tmp_path):
    views = np.arange(15 * 15 * 4 * 4, dtype=np.float32).reshape(15, 15, 4, 4)
    user = tmp_path / "mydata.zarr"
    user.mkdir()
    (user / "notes.txt").write_text("keep me")
    with pytest.raises(ValueError, match="not a Zarr store written by metasensor"):
        write_views(user, views)
    assert (user / "notes.txt").read_text() == "keep me"
    own = write_views(tmp_path / "v.zarr", views)
    write_views(own, views + 1)  # an earlier store of ours: replaced
    assert float(np.asarray(read_views(own))[0, 0, 0, 0]) == 1.0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mydata.zarr", "v.zarr"]


def test_long_names_and_stale_temporaries(tmp_path):
    name = "a" * 247 + ".tif"  # 251 bytes: a valid name whose temporary must still fit
    assert len(sibling_name(tmp_path / name, "tmp", suffix=".tif").encode()) <= 255
    write_views(tmp_path / name, np.ones((3, 3, 4, 4), np.float32))
    assert (tmp_path / name).is_file()
    # a killed run's temporary (pid gone) is removed; a live run's is not
    dead = tmp_path / sibling_name(tmp_path / "x.txt", "tmp").replace(f".{os.getpid()}-",
                                                                      ".4194305-")
    live = tmp_path / sibling_name(tmp_path / "x.txt", "tmp").replace(f".{os.getpid()}-",
                                                                      f".{os.getppid()}-")
    dead.write_text("stale")
    live.write_text("in use")
    atomic_write_text(tmp_path / "x.txt", "new")
    assert not dead.exists() and live.exists()


def test_a_second_writer_of_the_same_output_is_refused(tmp_path, monkeypatch):
    from metasensor.io import guard as g

    monkeypatch.setattr(g, "command_context", lambda: object())  # as inside a command
    monkeypatch.setattr(g, "_on_exit", lambda cb: None)
    guard([], [tmp_path / "o.tif"])
    try:
        with pytest.raises(OutputLocked, match="another metasensor run is writing"):
            guard([], [tmp_path / "o.tif"])
    finally:
        for item in list(g._held):
            g._release(item)
    assert not list(tmp_path.iterdir())  # the lock file goes with the lock
    monkeypatch.undo()  # a real command, failing after its guard: its locks go too
    code, err = run_cli("psf", "--config", tmp_path / "missing.toml", "--out",
                        tmp_path / "new" / "p.h5")  # the folder made for its lock goes too
    assert code == 2 and not list(tmp_path.iterdir())


def test_result_folders_swap_whole_and_keep_the_users_files(tmp_path):
    from metasensor.io.atomic import StagedFolder

    def write(out, files):
        staged = StagedFolder(out, ["a.txt", "b.txt"])
        for name, text in files.items():
            (staged.path / name).write_text(text)
        return staged.commit()

    out = tmp_path / "res"
    write(out, {"a.txt": "1", "b.txt": "1"})
    write(out, {"a.txt": "2"})  # an earlier run's b.txt would contradict this one: gone
    assert sorted(p.name for p in out.iterdir()) == ["a.txt"]
    (out / "notes.txt").write_text("the user's")
    write(out, {"a.txt": "3", "b.txt": "3"})  # a folder holding the user's file keeps it
    assert {p.name: p.read_text() for p in out.iterdir()} == {"a.txt": "3", "b.txt": "3",
                                                              "notes.txt": "the user's"}
    staged = StagedFolder(out, ["a.txt"])
    (staged.path / "a.txt").write_text("never committed")
    staged.discard()  # what an error or Ctrl-C does: the folder as it was, no temporary
    assert (out / "a.txt").read_text() == "3" and sorted(os.listdir(tmp_path)) == ["res"]
    (tmp_path / "afile").write_text("x")
    with pytest.raises(ValueError, match="not a folder"):
        StagedFolder(tmp_path / "afile", ["a.txt"])
