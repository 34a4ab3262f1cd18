"""One set of command-line conventions: ``--out``/``-o`` on every command that writes, one
scan-order option (``--scan-order``, old ``--order`` kept) with one syntax, defaults to the
prototype configuration, an explicit ``--data-range`` for ``evaluate``."""

import json

import numpy as np
import pytest
import tifffile
from typer.testing import CliRunner

from metasensor import cli
from metasensor.cli_options import SCAN_ORDER_SYNTAX, parse_scan_order
from metasensor.sensor.scan import scan_order


def _commands() -> dict:
    commands = {}
    for module in cli._COMMAND_MODULES:
        commands.update(cli.load_commands(module))
    return commands


def _option(cmd, name):
    return next((p for p in cmd.params if name in getattr(p, "opts", ())), None)


def test_every_output_option_is_out_or_o():
    for name, cmd in _commands().items():
        out = _option(cmd, "--out")
        assert out is not None, f"{name} has no --out"
        assert "-o" in out.opts, f"{name}: --out has no -o"


def test_one_scan_order_option_name_everywhere():
    for name, cmd in _commands().items():
        names = {o for p in cmd.params for o in p.opts if "order" in o}
        if names:
            assert names == {"--scan-order", "--order"}, (name, names)
            assert "0,0;0,1" in (_option(cmd, "--scan-order").help or ""), name
    for name in ("simulate", "realign", "calibrate", "motion"):
        assert _option(_commands()[name], "--scan-order") is not None, name


@pytest.mark.parametrize("text", ["0,0;0,1;1,1;1,0", "[(0,0),(0,1),(1,1),(1,0)]",
                                  " (0, 0), (0, 1), (1, 1), (1, 0) ", "0,0;0,1;1,1;1,0;"])
def test_scan_order_spellings_read_alike(text):
    assert parse_scan_order(text) == [(0, 0), (0, 1), (1, 1), (1, 0)]
    assert parse_scan_order(text, 2) == [(0, 0), (0, 1), (1, 1), (1, 0)]


def test_scan_order_presets_and_errors_show_the_syntax():
    assert parse_scan_order("serpentine", 3) == scan_order(3, "serpentine")
    assert parse_scan_order("Row-Major", None, default_period=3) == scan_order(3)
    assert parse_scan_order(None, 3) is None
    for bad in ("diagonal", "0,0;0", "[(0,0),(0,1)", "0,0;0,1;1,1", "0,0;0,0;1,1;1,0"):
        with pytest.raises(ValueError, match="--scan-order") as info:
            parse_scan_order(bad, 2)
        assert SCAN_ORDER_SYNTAX in str(info.value), bad


def test_realign_and_motion_accept_each_others_syntax(tmp_path):
    from metasensor.motion.commands import parse_scan_order as motion_order
    from metasensor.sensor.commands import _order as realign_order

    semi = "0,0;0,1;0,2;1,2;1,1;1,0;2,0;2,1;2,2"
    listed = str([tuple(p) for p in scan_order(3, "serpentine")])
    assert realign_order(listed, 3) == motion_order(semi, 3) == scan_order(3, "serpentine")
    res = CliRunner().invoke(cli.app, ["realign", str(tmp_path / "raw.tif"), "-o",
                                       str(tmp_path / "v.tif"), "--scan-order", "zigzag"])
    assert res.exit_code != 0


def test_psf_defaults_to_the_prototype(tmp_path):
    from metasensor.optics.psf_io import load_psf

    res = CliRunner().invoke(cli.app, ["psf", "-o", str(tmp_path / "p.h5"), "--size", "31"])
    assert res.exit_code == 0, res.output
    bank = load_psf(tmp_path / "p.h5")
    bank = bank[0] if isinstance(bank, tuple) else bank
    assert np.asarray(bank).shape == (15, 15, 31, 31)


def test_evaluate_takes_a_data_range(tmp_path):
    truth = np.full((32, 32), 0.5, np.float32)  # constant: no range to take from the truth
    image = truth + np.random.default_rng(0).normal(0, 0.01, truth.shape).astype(np.float32)
    tifffile.imwrite(tmp_path / "t.tif", truth)
    tifffile.imwrite(tmp_path / "r.tif", image)
    args = ["evaluate", str(tmp_path / "r.tif"), "--truth", str(tmp_path / "t.tif"), "-o",
            str(tmp_path / "e")]
    res = CliRunner().invoke(cli.app, args)
    assert res.exit_code != 0 and "data_range" in str(res.exception)
    res = CliRunner().invoke(cli.app, [*args, "--data-range", "1"])
    assert res.exit_code == 0, res.output
    got = json.loads((tmp_path / "e" / "evaluation.json").read_text())
    assert got["data_range"] == 1.0 and got["psnr_db"] == pytest.approx(40, abs=0.5)


def test_calibrate_aberration_writes_beside_its_input(tmp_path, monkeypatch):
    import metasensor as ms

    assert _option(_commands()["calibrate-aberration"], "--out").default is None
    monkeypatch.chdir(tmp_path)
    (tmp_path / "data").mkdir()
    views = np.random.default_rng(0).random((15, 15, 16, 16)).astype(np.float32)
    ms.write_views(tmp_path / "data" / "checker.tif", views, ms.SystemConfig())
    res = CliRunner().invoke(cli.app, ["calibrate-aberration", "data/checker.tif", "--blocks",
                                       "1x1", "--grid", "3x3", "--iterations", "1",
                                       "--no-figure"])
    assert res.exit_code == 0, res.output
    assert (tmp_path / "data" / "checker_system.h5").is_file()
    assert not (tmp_path / "system.h5").exists()


@pytest.mark.parametrize("command", [["reconstruct", "views.tif"], ["demo"],
                                     ["calibrate-aberration", "views.tif"]])
@pytest.mark.parametrize("text", ["4", "4x", "0x3", "3x-1"])
def test_one_grid_syntax_everywhere(tmp_path, command, text):
    """Every ``--blocks`` reads ``4x4`` through one parser, positivity included."""
    from metasensor.cli_options import parse_pair

    with pytest.raises(ValueError, match="--blocks must"):
        parse_pair(text, "--blocks")
    views = tmp_path / "views.tif"
    if len(command) > 1:
        from metasensor.config import SystemConfig
        from metasensor.io.views import write_views

        cfg = SystemConfig(nnum=5, scan=5)
        write_views(views, np.ones((5, 5, 8, 8), np.float32), cfg)
        command = [command[0], str(views)]
    res = CliRunner().invoke(cli.app, [*command, "--blocks", text, "--out",
                                       str(tmp_path / "out")])
    assert isinstance(res.exception, ValueError), res.output
    assert str(res.exception).startswith("--blocks must"), res.exception


def test_every_scheduler_option_says_it_trusts_the_scheduler():
    """dask.distributed exchanges pickles over unauthenticated TCP: each ``--scheduler`` help
    says so and names the remedy."""
    found = []
    for name, cmd in _commands().items():
        opt = _option(cmd, "--scheduler")
        if opt is not None:
            found.append(name)
            text = " ".join((opt.help or "").split())
            assert "unauthenticated TCP" in text and "tls://" in text, (name, text)
    assert sorted(found) == ["demo", "reconstruct"]
