"""Where a benchmark writes the files beside its JSON table (figures, resumable case lists): the
folder that ``run_all.py --out`` names, passed on as ``METASENSOR_BENCH_OUT``, else
``benchmarks/results`` (the recorded figures). A run into another folder never overwrites the
recorded files."""

from __future__ import annotations

import os
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"
ENV = "METASENSOR_BENCH_OUT"


def output_path(name: str) -> Path:
    """``name`` inside the run's output folder (``METASENSOR_BENCH_OUT``, else
    ``benchmarks/results``), the folder created where missing."""
    folder = Path(os.environ.get(ENV) or RESULTS)
    folder.mkdir(parents=True, exist_ok=True)
    return folder / name
