"""benchmarks/run_all.py: quick runs keep off the full-run JSON; unknown names are an error."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

RUN_ALL = Path(__file__).resolve().parents[1] / "benchmarks" / "run_all.py"


@pytest.fixture()
def run_all(tmp_path, monkeypatch):
    spec = importlib.util.spec_from_file_location("run_all_under_test", RUN_ALL)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    bench = tmp_path / "bench"
    bench.mkdir()
    (bench / "bench_fake.py").write_text(
        "def run(quick=False):\n    return [{'quick': quick, 'value': 1.5}]\n")
    (bench / "bench_other.py").write_text("def run(quick=False):\n    return []\n")
    monkeypatch.setattr(module, "HERE", bench)
    monkeypatch.setattr(module, "machine", lambda: {"python": "test"})
    return module


def test_quick_run_writes_quick_json_and_keeps_full(run_all, tmp_path):
    out = tmp_path / "results"
    out.mkdir()
    full = out / "fake.json"
    full.write_text('{"rows": "full"}')
    assert run_all.main(["--quick", "fake", "--out", str(out)]) == 0
    assert full.read_text() == '{"rows": "full"}'
    quick = json.loads((out / "fake_quick.json").read_text())
    assert quick["quick"] is True and quick["rows"] == [{"quick": True, "value": 1.5}]
    assert not (out / "other_quick.json").exists()


def test_full_run_writes_plain_json(run_all, tmp_path):
    out = tmp_path / "results"
    assert run_all.main(["fake", "--out", str(out)]) == 0
    assert json.loads((out / "fake.json").read_text())["quick"] is False
    assert not (out / "fake_quick.json").exists()


def test_default_out_folder_is_results_next_to_the_benchmarks(run_all):
    assert run_all.main(["--quick", "fake"]) == 0
    assert (run_all.HERE / "results" / "fake_quick.json").is_file()
    assert not (run_all.HERE / "results" / "fake.json").exists()


def test_unknown_name_exits_nonzero_with_one_line(run_all, tmp_path, capsys):
    out = tmp_path / "results"
    assert run_all.main(["--quick", "nope", "fake", "--out", str(out)]) != 0
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1
    assert "nope" in lines[0] and "fake" in lines[0] and "other" in lines[0]
    assert "== fake ==" not in captured.out
    assert not out.exists()


def test_real_benchmark_names_are_accepted(tmp_path, capsys):
    spec = importlib.util.spec_from_file_location("run_all_real", RUN_ALL)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert module.main(["no_such_bench", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "psf" in err and "dao" in err


def test_every_runnable_benchmark_script_answers_help_before_it_runs():
    """A script run directly reads its flags from ``sys.argv``; ``--help`` must print its
    docstring and exit instead of starting a (possibly hour-long) run."""
    import ast

    bench = RUN_ALL.parent
    missing = []
    for path in sorted(bench.glob("bench_*.py")):
        tree = ast.parse(path.read_text())
        mains = [n for n in tree.body if isinstance(n, ast.If) and "__main__" in ast.unparse(
            n.test)]
        if not mains or "argparse" in path.read_text():
            continue  # nothing runs when executed, or argparse answers --help itself
        first = ast.unparse(mains[0].body[1]) if len(mains[0].body) > 1 else ""
        if "exit_on_help(__doc__)" not in first:
            missing.append(path.name)
    assert not missing, missing


def test_help_prints_the_docstring_and_exits():
    import subprocess
    import sys

    script = RUN_ALL.parent / "bench_metrics.py"
    out = subprocess.run([sys.executable, str(script), "--help"], capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.strip().splitlines()
    first = script.read_text().split('"""')[1].splitlines()[0]
    assert lines[0] == first  # the docstring, then the usage line, and no row of a run
    assert lines[-1].startswith("usage: python benchmarks/bench_metrics.py")
    assert not any(line.startswith("{") for line in lines)


def test_the_quality_table_merges_measured_rows_without_their_summaries(tmp_path):
    # the photographs' file carries summary rows (no "study"); merged as they were, they broke
    # the full quality run's figure
    path = RUN_ALL.parent / "bench_quality.py"
    spec = importlib.util.spec_from_file_location("bench_quality_under_test", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    results = tmp_path / "photos.json"
    results.write_text(json.dumps({"rows": [{"study": "photos-focus", "ssim": 0.8},
                                            {"summary": "a target", "holds": True}]}))
    assert module.measured_rows(results) == [{"study": "photos-focus", "ssim": 0.8}]
    assert module.measured_rows(tmp_path / "missing.json") == []


def test_figures_follow_the_out_folder_and_the_setting_is_restored(run_all, tmp_path,
                                                                    monkeypatch):
    monkeypatch.delenv("METASENSOR_BENCH_OUT", raising=False)
    (run_all.HERE / "bench_where.py").write_text(
        "import os\ndef run(quick=False):\n"
        "    return [{'out': os.environ.get('METASENSOR_BENCH_OUT')}]\n")
    out = tmp_path / "elsewhere"
    assert run_all.main(["where", "--out", str(out)]) == 0
    rows = json.loads((out / "where.json").read_text())["rows"]
    assert rows == [{"out": str(out.resolve())}]
    import os

    assert "METASENSOR_BENCH_OUT" not in os.environ


def test_output_path_reads_the_run_folder(tmp_path, monkeypatch):
    spec = importlib.util.spec_from_file_location("bench_paths", RUN_ALL.parent / "_paths.py")
    paths = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(paths)
    monkeypatch.setenv("METASENSOR_BENCH_OUT", str(tmp_path / "new"))
    assert paths.output_path("a.png") == tmp_path / "new" / "a.png"
    assert (tmp_path / "new").is_dir()
    monkeypatch.delenv("METASENSOR_BENCH_OUT")
    assert paths.output_path("a.png") == RUN_ALL.parent / "results" / "a.png"


def test_no_benchmark_writes_a_figure_into_the_recorded_results_directly():
    import re

    for script in sorted(RUN_ALL.parent.glob("*.py")):
        if script.name in ("rerun.py", "_paths.py"):  # rerun.py re-records on purpose
            continue
        text = script.read_text()
        hits = re.findall(r'HERE / "results" / [^\n]*\.(?:png|jsonl)', text)
        assert not hits, f"{script.name}: {hits} (use _paths.output_path)"
