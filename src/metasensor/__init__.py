"""metasensor: the meta-imaging sensor (Wu et al., Nature 2022) in Python.

A scanning, aperture-coded microlens array on a CMOS chip, and the software that turns its raw
frames into aberration-corrected, all-in-focus images and depth maps.

Public entry points are imported lazily, so ``import metasensor`` stays fast.
"""

from __future__ import annotations

import importlib  # no other import here: a Ctrl-C while the command starts is caught after it
import os  # loaded with the interpreter already

# OpenMP's threads (torch's intra-op pool) sleep at their barriers instead of spinning, unless
# the environment says otherwise: next to another busy process, spinning partners multiply the
# CPU time (docs/decisions.md, "the cost of the default reconstruction of the whole sensor").
# Read when torch loads, so set before it is imported.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

__version__ = "0.1.0"

# public name -> module that defines it
_EXPORTS = {
    "SystemConfig": "metasensor.config",
    "ConfigError": "metasensor.config",
    "view_psfs": "metasensor.optics.psf",
    "widefield_psf": "metasensor.optics.widefield",
    "realign": "metasensor.sensor.realign",
    "unrealign": "metasensor.sensor.realign",
    "scan_order": "metasensor.sensor.scan",
    "simulate": "metasensor.simulation.capture",
    "Capture": "metasensor.simulation.capture",
    "reconstruct": "metasensor.recon.api",
    "Reconstruction": "metasensor.recon.api",
    "correct_motion": "metasensor.motion.correct",
    "estimate_depth": "metasensor.depth.estimate",
    "DepthResult": "metasensor.depth.estimate",
    "read_views": "metasensor.io.views",
    "write_views": "metasensor.io.views",
    "read_raw": "metasensor.io.raw",
    "open_raw": "metasensor.io.raw",
    "write_raw": "metasensor.io.raw",
}
_SUBMODULES = ("optics", "sensor", "simulation", "recon", "motion", "depth", "metrics", "io",
               "report")

__all__ = sorted(_EXPORTS) + list(_SUBMODULES)


def __getattr__(name: str) -> object:
    if name in _EXPORTS:
        module = importlib.import_module(_EXPORTS[name])
        value = getattr(module, name)
        globals()[name] = value
        return value
    if name in _SUBMODULES:
        module = importlib.import_module(f"metasensor.{name}")
        globals()[name] = module
        return module
    raise AttributeError(f"module 'metasensor' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
