"""Re-measure part of a full benchmark run and merge it into the committed JSON.

``python benchmarks/rerun.py scan_period`` (with ``SCAN_PERIOD_BUDGETS`` / ``SCAN_PERIOD_FOCUS``)
or ``python benchmarks/rerun.py stream`` (with ``STREAM_MODES``, e.g. ``default``) or
``python benchmarks/rerun.py ed_fig4`` (with ``ED_FIG4_LEVELS``; the cases are measured
afresh in a temporary cases file, or in ``ED_FIG4_CASES`` if set, which a repeated run
resumes) runs the benchmark's ``run()`` on the current code, replaces the committed rows it
re-measured (same key: every setting of the row), marks them ``"remeasured": True``, keeps the
old figures as ``"previous"`` ({metric: value}) for the comparison, recomputes the benchmark's
summary rows over the merged rows, redraws its figure and rewrites ``results/<name>.json``.
Rows the re-run did not reach stay as they were (unmarked).
"""

from __future__ import annotations

import importlib.util
import json
import os
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "src"))

#: Per benchmark: the settings that identify a row, the figures compared, summary and plot.
SPECS = {
    "scan_period": {"key": ("defocus_waves", "budget", "scene", "scan", "solver"),
                    "metrics": ("ssim", "psnr_db"), "summary": "_targets", "plot": "_plot",
                    "figure": "scan_period.png"},
    "ed_fig4": {"key": ("scene", "rms", "draw", "size", "mode"),
                "metrics": ("psnr", "ssim", "residual_rms"), "summary": "summary",
                "plot": "figure", "figure": "ed_fig4.png"},
    "stream": {"key": ("sensor_px", "solver"),
               "metrics": ("wall_s", "recon_s", "peak_rss_gb", "ssim_crop", "cpu_s"),
               "summary": None, "plot": None, "figure": None},
}


def _load(name: str):
    spec = importlib.util.spec_from_file_location(f"bench_{name}", HERE / f"bench_{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def merge(old_rows: list[dict], new_rows: list[dict], key: tuple, metrics: tuple) -> list[dict]:
    """``old_rows`` with every row of ``new_rows`` (same ``key``) replaced by the new one, marked
    and carrying the old ``metrics`` as ``previous``; new rows without an old one are appended."""
    def k(r):
        return tuple(r.get(c) for c in key)

    fresh = {k(r): r for r in new_rows if "summary" not in r}
    out, seen = [], set()
    for r in old_rows:
        if "summary" in r:
            continue
        if k(r) in fresh:
            new = dict(fresh[k(r)])
            new["remeasured"] = True
            new["previous"] = {m: r.get(m) for m in metrics if m in r}
            out.append(new)
            seen.add(k(r))
        else:
            out.append(r)
    out += [dict(r, remeasured=True) for kk, r in fresh.items() if kk not in seen]
    return out


def main(name: str) -> int:
    from metasensor.io.atomic import atomic_write_text

    spec = SPECS[name]
    module = _load(name)
    path = HERE / "results" / f"{name}.json"
    old = json.loads(path.read_text())
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        if name == "ed_fig4" and not os.environ.get("ED_FIG4_CASES"):  # else: resume that file
            os.environ["ED_FIG4_CASES"] = str(Path(tmp) / "cases.jsonl")
        new_rows = module.run(quick=False)
    rows = merge(old["rows"], new_rows, spec["key"], spec["metrics"])
    if spec["plot"] is not None:
        getattr(module, spec["plot"])(rows, HERE / "results" / spec["figure"])
    if spec["summary"] is not None:
        rows += getattr(module, spec["summary"])(rows)
    payload = dict(old, rows=rows, rerun={"date": time.strftime("%Y-%m-%d"),
                                          "seconds": time.perf_counter() - t0,
                                          "environment": {k: v for k, v in os.environ.items()
                                                          if k.startswith(("SCAN_PERIOD_",
                                                                           "ED_FIG4_LEVELS",
                                                                           "STREAM_MODES"))}})
    atomic_write_text(path, json.dumps(payload, indent=2, default=float))
    for r in rows:
        if r.get("remeasured") or "summary" in r:
            print(json.dumps(r, default=float))
    return 0


if __name__ == "__main__":
    if len(sys.argv) != 2 or sys.argv[1] not in SPECS:
        print(f"usage: rerun.py {{{','.join(SPECS)}}}", file=sys.stderr)
        raise SystemExit(2)
    raise SystemExit(main(sys.argv[1]))
