"""The benchmarks' GPU rows: the device-bound rows of ``psf``, ``isa`` and ``dao`` on CUDA.

Usage: ``python benchmarks/gpu_rows.py OUT_DIR [STAGE ...]`` on a machine with CUDA. Stages (in
this order by default): ``psf`` (every ``bench_psf`` case), ``isa`` (the speed rows at 300 and
2,010 px and the HQS rows; the CPU-bound quality-per-iteration rows are left to ``run_all``),
``dao`` (every ``bench_dao`` row). Each stage writes ``OUT_DIR/<name>_cuda.json`` as soon as it
ends, in ``run_all``'s format, so a run stopped part way keeps the stages it finished. The rows
are the same functions ``run_all`` calls; only the device differs (``resolve_device(None)`` is
CUDA here). Ratios (wall time / the FFTs needed) are timed on the same device in the same run.
"""

from __future__ import annotations

import importlib.util
import json
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "src"))
sys.path.insert(0, str(HERE))

from metasensor.io.atomic import atomic_write_text  # noqa: E402
from run_all import _table, machine  # noqa: E402


def _module(name: str):
    spec = importlib.util.spec_from_file_location(f"bench_{name}", HERE / f"bench_{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _isa_rows(module) -> list[dict]:
    from metasensor.backend import resolve_device

    device = str(resolve_device(None))
    rows = module._speed_rows(20, 2, (1, 16, 113), device)
    rows.append(module._hqs_row(20, device))
    rows += module._speed_rows(134, 5, (16,), device)
    rows.append(module._hqs_row(134, device))
    return rows


STAGES = {
    "psf": lambda m: m.run(quick=False),
    "isa": _isa_rows,
    "dao": lambda m: m.run(quick=False),
}


def main(argv: list[str]) -> int:
    import torch

    if not argv:
        print(__doc__.splitlines()[2], file=sys.stderr)
        return 2
    if not torch.cuda.is_available():
        print("gpu_rows.py: CUDA is not available on this machine", file=sys.stderr)
        return 2
    out, names = Path(argv[0]), argv[1:] or list(STAGES)
    unknown = [n for n in names if n not in STAGES]
    if unknown:
        print(f"gpu_rows.py: unknown stage {', '.join(unknown)}; valid: {', '.join(STAGES)}",
              file=sys.stderr)
        return 2
    out.mkdir(parents=True, exist_ok=True)
    failed = 0
    for name in names:
        print(f"\n== {name} (cuda) ==", flush=True)
        t0 = time.perf_counter()
        try:
            rows = STAGES[name](_module(name))
        except Exception as exc:  # report and go on with the others
            print(f"FAILED: {type(exc).__name__}: {exc}", flush=True)
            failed += 1
            continue
        print(_table(rows), flush=True)
        payload = {"benchmark": name, "quick": False, "machine": machine(),
                   "seconds_total": time.perf_counter() - t0, "rows": rows}
        atomic_write_text(out / f"{name}_cuda.json", json.dumps(payload, indent=2, default=float))
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
