"""Run every benchmark (``benchmarks/bench_*.py``), print one table each, write JSON.

Each module defines ``run(quick: bool = False) -> list[dict]``; every dict is one row.
Usage: ``python benchmarks/run_all.py [--quick] [NAME ...]`` (names without ``bench_``).
A full run writes ``results/<name>.json``; a ``--quick`` run writes ``results/<name>_quick.json``
(so a smoke run never replaces the committed full-run rows). An unknown NAME is an error.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import platform
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "src"))
sys.path.insert(0, str(HERE))  # _paths

from metasensor.io.atomic import atomic_write_text  # noqa: E402
from metasensor.io.memory import reset_peak_resident  # noqa: E402


def _table(rows: list[dict]) -> str:
    if not rows:
        return "(no rows)"
    cols = list(dict.fromkeys(k for r in rows for k in r))

    def fmt(v):
        if isinstance(v, float):
            return f"{v:.4g}"
        return str(v)

    cells = [[fmt(r.get(c, "")) for c in cols] for r in rows]
    widths = [max(len(c), *(len(row[i]) for row in cells)) for i, c in enumerate(cols)]
    line = "  ".join(c.ljust(w) for c, w in zip(cols, widths, strict=True))
    sep = "  ".join("-" * w for w in widths)
    body = ["  ".join(v.ljust(w) for v, w in zip(row, widths, strict=True)) for row in cells]
    return "\n".join([line, sep, *body])


def machine() -> dict:
    import torch

    return {
        "python": platform.python_version(),
        "torch": torch.__version__,
        "threads": torch.get_num_threads(),
        "cuda": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
        "platform": platform.platform(),
    }


def result_name(name: str, quick: bool) -> str:
    """The JSON file a run of benchmark ``name`` writes: quick rows never replace full ones."""
    return f"{name}_quick.json" if quick else f"{name}.json"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("names", nargs="*", help="benchmarks to run (default: all)")
    parser.add_argument("--quick", action="store_true", help="small sizes, for a smoke run")
    parser.add_argument("--out", default=str(HERE / "results"), help="folder for the JSON files")
    args = parser.parse_args(argv)
    files = sorted(HERE.glob("bench_*.py"))
    known = [f.stem.removeprefix("bench_") for f in files]
    unknown = [n for n in dict.fromkeys(args.names) if n not in known]
    if unknown:
        print(f"run_all.py: unknown benchmark{'s' if len(unknown) > 1 else ''} "
              f"{', '.join(unknown)}; valid names: {', '.join(known)}", file=sys.stderr)
        return 2
    if args.names:
        files = [f for f in files if f.stem.removeprefix("bench_") in args.names]
    from _paths import ENV  # figures and case lists go beside the JSON (benchmarks/_paths.py)

    previous = os.environ.get(ENV)
    os.environ[ENV] = str(Path(args.out).resolve())
    try:
        return _run(files, args)
    finally:
        if previous is None:
            os.environ.pop(ENV, None)
        else:
            os.environ[ENV] = previous


def _run(files: list[Path], args) -> int:
    """Run each benchmark file, writing its JSON table into ``args.out``; 1 if any failed."""
    failed = 0
    for file in files:
        name = file.stem.removeprefix("bench_")
        spec = importlib.util.spec_from_file_location(file.stem, file)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        print(f"\n== {name} ==", flush=True)
        t0 = time.perf_counter()
        reset_peak_resident()  # a benchmark's in-process peak is its own, not its predecessors'
        try:
            rows = module.run(quick=args.quick)
        except Exception as exc:  # report and go on with the others
            print(f"FAILED: {type(exc).__name__}: {exc}")
            failed += 1
            continue
        print(_table(rows))
        payload = {"benchmark": name, "quick": args.quick, "machine": machine(),
                   "seconds_total": time.perf_counter() - t0, "rows": rows}
        out = Path(args.out) / result_name(name, args.quick)
        atomic_write_text(out, json.dumps(payload, indent=2, default=float))
        print(f"-> {out}")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
