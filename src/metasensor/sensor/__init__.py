"""Sensor geometry: scan orders, realign/unrealign, lenslet-grid calibration, rectification.

Names are imported lazily (scipy is loaded only when needed): ``unrealign``,
``realign_sequence``, ``scan_order``, ``Calibration``, ``find_grid``, ``flat_field``, ``adapt``,
``frame_offset``, ``rectify_frame``, ``rectify_frames``, ``flat_views``. The functions named like
their modules are reached through the module: ``metasensor.sensor.realign.realign`` (also
``metasensor.realign``) and ``metasensor.sensor.calibrate.calibrate``.
"""

from __future__ import annotations

import importlib
import importlib.util

_NAMES = {
    "unrealign": "realign", "realign_sequence": "realign",
    "lenslet_counts": "realign", "scan_order": "scan", "Calibration": "calibration",
    "find_grid": "calibrate", "flat_field": "calibrate",
    "adapt": "reuse", "frame_offset": "reuse", "rectify_frame": "rectify",
    "rectify_frames": "rectify", "flat_views": "rectify",
}

__all__ = sorted(_NAMES)


def __getattr__(name: str):
    if name in _NAMES:
        module = importlib.import_module(f"metasensor.sensor.{_NAMES[name]}")
        return getattr(module, name)
    if importlib.util.find_spec(f"metasensor.sensor.{name}") is not None:  # a submodule
        return importlib.import_module(f"metasensor.sensor.{name}")
    raise AttributeError(f"module 'metasensor.sensor' has no attribute {name!r}")
