"""The README's examples run as written: every ```python block, the command-line walk-through
(the ```bash block of ``metasensor`` lines), and the options of the command table exist."""

import re
import shlex
from pathlib import Path

import pytest
from typer.testing import CliRunner

from metasensor import cli

README = Path(__file__).resolve().parent.parent / "README.md"


def _blocks(lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", README.read_text(encoding="utf-8"), re.S)


def _cli_lines() -> list[list[str]]:
    lines = []
    for block in _blocks("bash"):
        cmds = [ln.split(" #")[0].strip() for ln in block.splitlines()]
        cmds = [c for c in cmds if c and not c.startswith("#")]
        if cmds and all(c.startswith("metasensor ") for c in cmds):
            lines += [shlex.split(c)[1:] for c in cmds]
    return lines


def test_python_examples_run(tmp_path, monkeypatch, capsys):
    blocks = _blocks("python")
    assert blocks, "README has no python block"
    monkeypatch.chdir(tmp_path)
    for block in blocks:
        exec(compile(block, str(README), "exec"), {"__name__": "__readme__"})  # noqa: S102
    out = capsys.readouterr().out
    assert "Capture(" in out and "array([" not in out  # shapes, not arrays


def test_command_line_walk_through_runs(tmp_path, monkeypatch):
    lines = _cli_lines()
    assert [a[0] for a in lines] == ["simulate", "realign", "reconstruct", "depth", "evaluate"]
    monkeypatch.chdir(tmp_path)
    for args in lines:
        res = CliRunner().invoke(cli.app, args)
        assert res.exit_code == 0, (args, res.output, res.exception)
    assert (tmp_path / "eval" / "evaluation.json").is_file()


def test_command_table_options_exist():
    rows = re.findall(r"^\| `metasensor ([^`]+)` \|", README.read_text(encoding="utf-8"), re.M)
    assert len(rows) >= 10
    commands = {}
    for module in cli._COMMAND_MODULES:
        commands.update(cli.load_commands(module))
    for row in rows:
        args = shlex.split(row)
        cmd = commands[args[0]]
        known = {opt for p in cmd.params for opt in (*p.opts, *p.secondary_opts)}
        for arg in args[1:]:
            if arg.startswith("-"):
                assert arg in known, f"README: metasensor {args[0]} has no option {arg}"


@pytest.mark.parametrize("name", ["Reconstruction", "Capture", "DepthResult"])
def test_result_types_document_every_field(name):
    import dataclasses

    import metasensor as ms

    cls = getattr(ms, name)
    doc = cls.__doc__ or ""
    missing = [f.name for f in dataclasses.fields(cls) if f.name not in doc]
    assert not missing, f"{name} does not document {missing}"
