"""The lenslet-grid calibration of one sensor: a frozen dataclass saved as a small TOML file.

Geometry (sensor pixel centres at integer (row, column) coordinates). A rectified pixel ``q``
(rows, columns; lenslet (i, j) of phase (0, 0) covers ``q`` in ``[i*nnum, (i+1)*nnum)``) of the
frame of scan phase ``k`` sits on the sensor at

    p = center + offsets[k] + M (q - (h, h) - nominal_rect[k]),     M = (pitch / nnum) R(rotation)

with ``h = (nnum - 1) / 2``, ``R`` the rotation from +x towards +y (``R @ (0, 1) = (sin, cos)``),
``nominal_rect[k] = (r, c) * nnum // scan`` (``moving="mla"``; zero for ``"image"``) and
``offsets[k]`` the measured displacement [sensor px] of the whole lenslet grid at phase k from
its position at phase (0, 0) (nominal: ``M @ nominal_rect[k]``).
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from metasensor.config import toml_value

__all__ = ["Calibration"]


@dataclass(frozen=True)
class Calibration:
    """Lenslet grid of a sensor (all lengths in sensor pixels, angles in degrees).

    nnum : pixels per lenslet after rectification.
    pitch : lenslet pitch on the raw sensor [px] (exactly ``nnum`` for a perfect sensor).
    rotation : rotation of the lenslet grid [deg], from +x towards +y.
    center : (row, col) on the sensor of the centre of rectified lenslet (0, 0) at phase (0, 0).
    lenslets : (Ly, Lx) lenslets kept by rectification (on the sensor at every phase, within
        the border calibrate() allows).
    sensor_shape : (rows, cols) of the raw frames the calibration was made for.
    scan, moving, scan_order : the scan of the calibration frames.
    offsets : measured grid displacement [px] of every phase in ``scan_order`` (``None``: the
        nominal ones were assumed).
    contrast : strength of the lenslet pattern used (lattice-peak over mean, 0..1).
    peak_strength : the weaker lattice peak over the median of the spectrum around it (the
        fit's signal; below 8 no grid is found).
    fit_residual : r.m.s. distance [px] between the lattice points measured in tiles of a few
        lenslets across the field and the fitted lattice (``None``: too few tiles with lenslet
        contrast to measure it).
    flat : flat-field map file (TIFF, relative to the TOML file's folder) or ``None``.
    flat_origin : (row, col) lenslet index in the flat-field map of kept lenslet (0, 0).
    """

    nnum: int
    pitch: float
    rotation: float
    center: tuple[float, float]
    lenslets: tuple[int, int]
    sensor_shape: tuple[int, int]
    scan: int = 1
    moving: str = "mla"
    scan_order: tuple[tuple[int, int], ...] = ((0, 0),)
    offsets: tuple[tuple[float, float], ...] | None = None
    contrast: float = 0.0
    peak_strength: float = 0.0
    fit_residual: float | None = None
    flat: str | None = None
    flat_origin: tuple[int, int] = (0, 0)

    def __post_init__(self) -> None:
        fix = object.__setattr__
        fix(self, "flat_origin", tuple(int(v) for v in self.flat_origin))
        fix(self, "center", tuple(float(v) for v in self.center))
        fix(self, "lenslets", tuple(int(v) for v in self.lenslets))
        fix(self, "sensor_shape", tuple(int(v) for v in self.sensor_shape))
        fix(self, "scan_order", tuple((int(r), int(c)) for r, c in self.scan_order))
        if self.offsets is not None:
            fix(self, "offsets", tuple((float(a), float(b)) for a, b in self.offsets))
        if not (isinstance(self.nnum, int) and self.nnum >= 3 and self.nnum % 2):
            raise ValueError(f"calibration nnum must be odd and >= 3, got {self.nnum!r}")
        if not (math.isfinite(self.pitch) and self.pitch > 1):
            raise ValueError(f"calibration pitch must be a finite number > 1 px, got {self.pitch}")
        if not math.isfinite(self.rotation) or abs(self.rotation) > 45:
            raise ValueError(f"calibration rotation must lie in [-45, 45] deg, got "
                             f"{self.rotation}")
        if len(self.scan_order) != self.scan**2:
            raise ValueError(f"calibration scan_order has {len(self.scan_order)} phases, "
                             f"scan {self.scan} needs {self.scan**2}")
        if self.offsets is not None and len(self.offsets) != len(self.scan_order):
            raise ValueError(f"calibration has {len(self.offsets)} offsets for "
                             f"{len(self.scan_order)} scan phases")
        if self.moving not in ("mla", "image"):
            raise ValueError(f"calibration moving must be 'mla' or 'image', got {self.moving!r}")
        if min(self.lenslets) < 1:
            raise ValueError(f"calibration keeps no lenslets ({self.lenslets})")
        if not all(math.isfinite(v) for v in self.center):
            raise ValueError(f"calibration center must be finite, got {self.center}")
        if self.offsets is not None and not all(math.isfinite(v) for o in self.offsets
                                                for v in o):
            raise ValueError("calibration offsets must be finite")
        if min(self.sensor_shape) < 1:
            raise ValueError(f"calibration sensor_shape must be positive, got {self.sensor_shape}")
        if not (isinstance(self.scan, int) and self.scan >= 1):
            raise ValueError(f"calibration scan must be a positive integer, got {self.scan!r}")
        if len(set(self.scan_order)) != len(self.scan_order) or not all(
                0 <= r < self.scan and 0 <= c < self.scan for r, c in self.scan_order):
            raise ValueError(f"calibration scan_order must visit each of the {self.scan}x"
                             f"{self.scan} phases once, got {list(self.scan_order)}")

    # ------------------------------------------------------------------ geometry
    @property
    def scale(self) -> float:
        """Sensor pixels per rectified pixel, ``pitch / nnum``."""
        return self.pitch / self.nnum

    @property
    def matrix(self) -> np.ndarray:
        """``M`` (2 x 2, acting on (row, col) vectors): rectified → sensor displacement."""
        t = math.radians(self.rotation)
        return self.scale * np.array([[math.cos(t), math.sin(t)], [-math.sin(t), math.cos(t)]])

    @property
    def origin(self) -> tuple[float, float]:
        """(row, col) on the sensor of rectified pixel (0, 0): the first pixel of kept lenslet
        (0, 0) at phase (0, 0), ``center - M (h, h)`` (where the views' grid starts)."""
        h = (self.nnum - 1) / 2
        return tuple(float(v) for v in np.asarray(self.center) - self.matrix @ np.array([h, h]))

    def nominal_rect(self, phase: tuple[int, int]) -> tuple[int, int]:
        """Nominal block displacement of ``phase`` in rectified pixels."""
        if self.moving == "image":
            return (0, 0)
        d = self.nnum // self.scan
        return (phase[0] * d, phase[1] * d)

    @property
    def nominal_offsets(self) -> tuple[tuple[float, float], ...]:
        """Nominal grid displacement [sensor px] of every phase in ``scan_order``."""
        m = self.matrix
        return tuple(tuple(float(v) for v in m @ np.array(self.nominal_rect(ph), float))
                     for ph in self.scan_order)

    def offset(self, phase: tuple[int, int]) -> tuple[float, float]:
        """Grid displacement [sensor px] at ``phase`` (measured if known, else nominal)."""
        phase = (int(phase[0]), int(phase[1]))
        if phase not in self.scan_order:
            raise ValueError(f"phase {phase} is not in the calibration's scan order")
        k = self.scan_order.index(phase)
        return (self.offsets or self.nominal_offsets)[k]

    def offset_errors(self) -> np.ndarray:
        """Measured minus nominal offsets [px], ``(T, 2)`` (zeros when not measured)."""
        meas = np.array(self.offsets or self.nominal_offsets)
        return meas - np.array(self.nominal_offsets)

    def is_exact(self, tol: float = 1e-3) -> bool:
        """True when rectification is a pure integer crop (pitch = nnum, no rotation, integer
        centre and integer offsets equal to nominal)."""
        c = np.array(self.center)
        return (abs(self.pitch - self.nnum) < tol and abs(self.rotation) < tol
                and np.all(np.abs(c - np.round(c)) < tol)
                and np.all(np.abs(self.offset_errors()) < tol))

    def rect_shape(self) -> tuple[int, int]:
        """Shape of a rectified frame: the kept lenslets plus the scan margin."""
        d = self.nnum // self.scan
        margin = (self.scan - 1) * d if self.moving == "mla" else 0
        return (self.lenslets[0] * self.nnum + margin, self.lenslets[1] * self.nnum + margin)

    def replace(self, **changes) -> Calibration:
        return dataclasses.replace(self, **changes)

    # ------------------------------------------------------------------ TOML
    def to_toml_string(self) -> str:
        lines = ["# metasensor lenslet-grid calibration (lengths in sensor pixels, angles in deg)",
                 "[calibration]"]
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if value is None:
                continue
            lines.append(f"{f.name} = {toml_value(value)}")
        if self.offsets is not None:
            err = self.offset_errors()
            lines.append("# measured - nominal offsets [px]: " + ", ".join(
                f"{tuple(ph)}: ({e[0]:+.3f}, {e[1]:+.3f})"
                for ph, e in zip(self.scan_order, err, strict=True)))
        return "\n".join(lines) + "\n"

    def to_toml(self, path: str | Path) -> Path:
        """Write atomically; returns the path."""
        from metasensor.io.atomic import atomic_write_text

        return atomic_write_text(path, self.to_toml_string())

    @classmethod
    def from_toml(cls, path: str | Path) -> Calibration:
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"calibration file not found: {path}")
        try:
            data = tomllib.loads(path.read_text()).get("calibration")
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
            raise ValueError(f"{path}: invalid calibration TOML ({exc})") from None
        except RecursionError:
            raise ValueError(f"{path}: invalid calibration TOML (nested too deeply)") from None
        if not isinstance(data, dict):
            raise ValueError(f"{path}: no [calibration] table")
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - names)
        if unknown:
            raise ValueError(f"{path}: unknown calibration key(s): {', '.join(unknown)}")
        try:
            return cls(**data)
        except TypeError as exc:
            raise ValueError(f"{path}: incomplete calibration ({exc})") from None

    def flat_path(self, toml_path: str | Path) -> Path | None:
        """Absolute path of the flat-field map stored next to ``toml_path`` (or ``None``)."""
        return None if self.flat is None else Path(toml_path).parent / self.flat
