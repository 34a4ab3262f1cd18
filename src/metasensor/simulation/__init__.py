"""Simulator: raw meta-imaging captures with known truth, built-in scenes, comparison sensors.

``simulate(scene, cfg, ...) -> Capture`` and the plain light-field camera of a capture,
``plain_lightfield`` (capture.py); scene dynamics ``Motion`` (motion.py) and ``Turbulence``
(turbulence.py); built-in scenes ``load_scene`` (scenes.py); the hardware-AO mirror
``SegmentedMirror`` (comparison.py); a single-lens field-aberration model ``SingleLens`` (lens.py).
"""

from __future__ import annotations

import importlib
import importlib.util

_EXPORTS = {
    "simulate": "capture", "Capture": "capture", "Motion": "motion", "Turbulence": "turbulence",
    "load_scene": "scenes", "resolution_chart": "scenes", "checkerboard": "scenes",
    "SegmentedMirror": "comparison", "plain_lightfield": "capture", "SingleLens": "lens",
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        value = getattr(importlib.import_module(f"metasensor.simulation.{_EXPORTS[name]}"), name)
        globals()[name] = value
        return value
    if importlib.util.find_spec(f"metasensor.simulation.{name}") is not None:  # a submodule
        return importlib.import_module(f"metasensor.simulation.{name}")
    raise AttributeError(f"module 'metasensor.simulation' has no attribute {name!r}")
