"""The paper's experiments as runnable scenarios (``metasensor demo --scenario NAME``):
``plastic-wrap`` (Fig. 3), ``telescope`` (Fig. 5, Extended Data Fig. 8) and ``gigapixel``
(Extended Data Fig. 7), beside the default ``single-lens`` demo, and their pieces (phase screens,
the annular pupil's estimate, measurements). Every scenario writes ``index.html``, PNG figures and
``summary.json`` into its output folder.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["SCENARIOS", "run_scenario"]

SCENARIOS = ("single-lens", "plastic-wrap", "telescope", "gigapixel")


def run_scenario(name: str, out: str | Path, *, seed: int = 0, scheduler: str | None = None,
                 progress: bool = True, **settings) -> dict:
    """Run scenario ``name`` (one of :data:`SCENARIOS`) into folder ``out``; ``settings`` are
    fields of that scenario's settings dataclass; ``scheduler`` (Dask) applies to
    ``gigapixel``. Returns the summary that ``summary.json`` holds."""
    if name not in SCENARIOS:
        raise ValueError(f"unknown scenario {name!r}; choose from {', '.join(SCENARIOS)}")
    if scheduler is not None and name != "gigapixel":
        raise ValueError(f"scheduler applies to the gigapixel scenario only, not {name!r}")
    if name == "single-lens":
        from metasensor.report.demo import DemoSettings, run_demo

        return run_demo(out, DemoSettings(seed=seed, **settings), progress=progress)
    if name == "plastic-wrap":
        from metasensor.scenarios.plastic_wrap import PlasticWrapSettings, run_plastic_wrap

        return run_plastic_wrap(out, PlasticWrapSettings(seed=seed, **settings), progress)
    if name == "telescope":
        from metasensor.scenarios.telescope import TelescopeSettings, run_telescope

        return run_telescope(out, TelescopeSettings(seed=seed, **settings), progress)
    from metasensor.scenarios.gigapixel import GigapixelSettings, run_gigapixel

    return run_gigapixel(out, GigapixelSettings(seed=seed, scheduler=scheduler, **settings),
                         progress)
