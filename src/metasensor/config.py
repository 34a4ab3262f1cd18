"""System description of a meta-imaging sensor: a frozen, validated dataclass with TOML in/out.

All lengths are in metres. The defaults describe the prototype of Wu et al. (Nature 2022):
a 15 x 15-pixel coded (circular-aperture) microlens array of 69 um pitch and 690 um focal length
on 4.6 um pixels, behind an f/10 (image-side NA 0.05) main lens, scanned 5 x 5, at 525 nm.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from metasensor.config_text import (
    ConfigError,
    note_fallbacks,
    parse_text,
    say_fallbacks,
    toml_value,
)

__all__ = ["SystemConfig", "ConfigError", "say_fallbacks", "toml_value"]

_APERTURES = ("circular", "square")
# physically meaningful ranges (lengths in metres): optical wavelengths from the UV to the
# thermal IR, microlens arrays from 1 µm to 10 mm pitch; values outside make the wave-optics
# grids explode or vanish (an all-zero PSF bank) rather than describe a sensor
RANGES = {"mla_pitch": (1e-6, 1e-2), "mla_focal": (1e-6, 1.0), "wavelength": (1e-7, 2e-5),
          "magnification": (1e-6, 1e6)}
MAX_NNUM = 63  # pixels per lenslet (the prototype: 15)
MAX_NA = 0.95  # image-side numerical aperture (the prototype: 0.05)
VIEW_RADIUS_FRACTION = 0.8  # the default view mask's radius over the pupil's (6 / 7.5 views)
_MOVING = ("mla", "image")
_APODIZATIONS = ("none", "aplanatic")


@dataclass(frozen=True)
class SystemConfig:
    """Optical and sensor geometry of a meta-imaging sensor.

    Parameters
    ----------
    nnum : pixels behind one lenslet per axis (odd, >= 3); also the number of views per axis.
    mla_pitch : lenslet pitch [m]. The sensor pixel pitch is ``mla_pitch / nnum``.
    mla_focal : lenslet focal length [m]; the sensor sits in its back focal plane.
    lenslet_aperture : ``"circular"`` (the coded aperture, default) or ``"square"``.
    aperture_diameter : diameter of the circular lenslet aperture [m] (``None``: ``mla_pitch``).
    wavelength : centre wavelength [m].
    na : image-side numerical aperture of the main lens, in (0, 1). The pupil's image behind a
        lenslet has diameter ``2 na mla_focal`` (:attr:`pupil_fill` pitches): above one pitch
        (a main lens faster than the lenslets) its rim spills onto the neighbours' edge pixels.
    obstruction : central obstruction ratio of the pupil (0: clear; e.g. 0.3 for a Cassegrain).
    scan : scan period per axis (1 = plain light-field camera); must divide ``nnum`` when the
        MLA moves (``moving="mla"``); any period when the image moves over a fixed MLA.
    magnification : lateral magnification of the main lens (object to image), for object-side
        conversions.
    apodization : pupil amplitude law: ``"none"`` (uniform, the paraxial model, default) or
        ``"aplanatic"`` (a lens obeying the sine condition imaging an isotropic point source,
        object-side NA ``na * magnification``: intensity per unit pupil area ``1 / cos θ``;
        :func:`metasensor.optics.pupil.aplanatic_amplitude`).
    focal_length, focus_distance : main-lens focal length and object focus distance [m]
        (optional; needed only for metric depth).
    sensor_shape : (rows, columns) of the full sensor.
    bit_depth : ADC bits of the raw frames (8, 10, 12, 14 or 16).
    moving : what moves during a scan: ``"mla"`` (the meta-imaging sensor: the MLA moves over a
        fixed sensor by ``nnum / scan`` px per step) or ``"image"`` (scanning light-field
        microscopes: the image moves over a fixed MLA and sensor by ``mla_pitch / scan`` per
        step, any period; docs/conventions.md). The default of ``realign``'s ``moving`` argument.

    Reconstruction grid: views are sampled every ``mla_pitch / scan`` on the image plane; the
    reconstruction grid subdivides that step into ``d = scan_step_px`` pixels, so its pitch is
    ``grid_pitch = mla_pitch / (scan·d)``: the sensor pitch when ``scan`` divides ``nnum``, else
    the coarsest pitch at most the sensor's with an odd ``scan·d`` (so that a grid pixel is
    centred on every lenslet centre; 13 px lenslets, 3 × 3 scan: d = 5, grid pitch 13/15 px).
    """

    nnum: int = 15
    mla_pitch: float = 69e-6
    mla_focal: float = 690e-6
    lenslet_aperture: str = "circular"
    aperture_diameter: float | None = None
    wavelength: float = 525e-9
    na: float = 0.05
    obstruction: float = 0.0
    scan: int = 5
    magnification: float = 10.0
    focal_length: float | None = None
    focus_distance: float | None = None
    sensor_shape: tuple[int, int] = field(default=(6004, 7920))
    bit_depth: int = 12
    moving: str = "mla"
    apodization: str = "none"

    def __post_init__(self) -> None:
        if isinstance(self.sensor_shape, list):
            object.__setattr__(self, "sensor_shape", tuple(self.sensor_shape))
        self.validate()

    # ------------------------------------------------------------------ validation
    def validate(self) -> None:
        """Raise :class:`ConfigError` naming the first impossible parameter."""

        def positive(name: str, lo: float = 0.0, hi: float = math.inf, unit: str = "") -> None:
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or isinstance(value, bool):
                raise ConfigError(f"{name} must be a number, got {value!r:.40}")
            try:
                finite = math.isfinite(value)
            except OverflowError:  # an int beyond any float
                finite = False
            if not finite or value <= 0:
                raise ConfigError(f"{name} must be positive and finite, got {value!r:.40}")
            if not lo <= value <= hi:  # physically meaningful (and computable) values only
                raise ConfigError(f"{name} must lie in [{lo:g}, {hi:g}]{unit}, got {value!r}")

        if not isinstance(self.nnum, int) or isinstance(self.nnum, bool):
            raise ConfigError(f"nnum must be an integer, got {self.nnum!r}")
        if self.nnum < 3 or self.nnum % 2 == 0:
            raise ConfigError(f"nnum must be odd and >= 3, got {self.nnum}")
        if self.nnum > MAX_NNUM:
            raise ConfigError(f"nnum must be at most {MAX_NNUM} pixels per lenslet, got "
                              f"{self.nnum}")
        for name, (lo, hi) in RANGES.items():
            positive(name, lo, hi, " m" if name != "magnification" else "")
        if not (isinstance(self.na, (int, float)) and 0.0 < self.na <= MAX_NA):
            raise ConfigError(f"na must lie in (0, {MAX_NA}], got {self.na!r:.40}")
        if self.lenslet_aperture not in _APERTURES:
            raise ConfigError(
                f"lenslet_aperture must be one of {_APERTURES}, got {self.lenslet_aperture!r}"
            )
        if self.aperture_diameter is not None:
            positive("aperture_diameter", self.mla_pitch / 100, math.inf, " m (1 % of the pitch "
                     "upwards)")
            if self.aperture_diameter > self.mla_pitch * math.sqrt(2) + 1e-12:
                raise ConfigError(
                    f"aperture_diameter {self.aperture_diameter!r} exceeds the lenslet's diagonal"
                )
        if not (isinstance(self.obstruction, (int, float)) and 0.0 <= self.obstruction < 1.0):
            raise ConfigError(f"obstruction must lie in [0, 1), got {self.obstruction!r}")
        if not isinstance(self.scan, int) or isinstance(self.scan, bool) or self.scan < 1:
            raise ConfigError(f"scan must be a positive integer, got {self.scan!r}")
        if self.apodization not in _APODIZATIONS:
            raise ConfigError(f"apodization must be 'none' or 'aplanatic', got "
                              f"{self.apodization!r:.40}")
        if self.apodization == "aplanatic" and not self.na * self.magnification < 1.0:
            raise ConfigError(f"apodization 'aplanatic' needs an object-side NA below 1, got "
                              f"na * magnification = {self.na * self.magnification:g}")
        if self.moving not in _MOVING:
            raise ConfigError(f"moving must be 'mla' or 'image', got {self.moving!r}")
        if self.moving == "mla" and self.nnum % self.scan != 0:
            raise ConfigError(f"scan period {self.scan} does not divide nnum {self.nnum}, as a "
                              f"moving MLA needs (set moving = \"image\" for a system whose "
                              f"image moves over a fixed MLA)")
        for name in ("focal_length", "focus_distance"):
            if getattr(self, name) is not None:
                positive(name)
        if self.focal_length is not None and self.focus_distance is not None:
            if self.focus_distance <= self.focal_length:
                raise ConfigError(
                    f"focus_distance {self.focus_distance!r} must exceed focal_length "
                    f"{self.focal_length!r} (a real image)"
                )
        shape = self.sensor_shape
        if (
            not isinstance(shape, tuple)
            or len(shape) != 2
            or not all(isinstance(s, int) and not isinstance(s, bool) and s > 0 for s in shape)
        ):
            raise ConfigError(f"sensor_shape must be two positive integers, got {shape!r}")
        if min(shape) < self.nnum:
            raise ConfigError(f"sensor_shape {shape} is smaller than one lenslet ({self.nnum} px)")
        if self.bit_depth not in (8, 10, 12, 14, 16):
            raise ConfigError(f"bit_depth must be 8, 10, 12, 14 or 16, got {self.bit_depth!r}")

    # ------------------------------------------------------------------ derived quantities
    @property
    def pixel_pitch(self) -> float:
        """Sensor pixel pitch [m] = mla_pitch / nnum (also the reconstruction grid)."""
        return self.mla_pitch / self.nnum

    @property
    def center(self) -> int:
        """Index of the centre view (and centre pixel behind a lenslet)."""
        return self.nnum // 2

    @property
    def lenslet_diameter(self) -> float:
        """Clear diameter of a lenslet's aperture [m] (the side for square lenslets)."""
        return self.mla_pitch if self.aperture_diameter is None else self.aperture_diameter

    @property
    def lenslet_fnumber(self) -> float:
        """f-number of one lenslet: focal length over aperture diameter."""
        return self.mla_focal / self.lenslet_diameter

    @property
    def image_fnumber(self) -> float:
        """Working f-number of the main lens on the image side, 1 / (2 NA)."""
        return 1.0 / (2.0 * self.na)

    @property
    def diffraction_limit(self) -> float:
        """Abbe diffraction limit at the MLA plane, λ / (2 NA) [m] (5.25 um for the prototype)."""
        return self.wavelength / (2.0 * self.na)

    @property
    def airy_radius(self) -> float:
        """Radius of the first dark ring of the Airy pattern, 0.61 λ / NA [m]."""
        return 0.6098 * self.wavelength / self.na

    @property
    def scan_step(self) -> float:
        """MLA displacement between scan phases [m] = mla_pitch / scan."""
        return self.mla_pitch / self.scan

    @property
    def scan_step_px(self) -> int:
        """Views' sample spacing in reconstruction-grid pixels, d: ``nnum // scan`` (the scan
        step in sensor pixels) when ``scan`` divides ``nnum``, else the smallest d with
        ``scan·d >= nnum`` and ``scan·d`` odd (an even scan period then has no such grid)."""
        if self.nnum % self.scan == 0:
            return self.nnum // self.scan
        d = -(-self.nnum // self.scan)
        return d if (self.scan * d) % 2 else d + 1

    @property
    def grid_points(self) -> int:
        """Reconstruction-grid pixels per lenslet pitch and axis, ``scan · d`` (= nnum when
        ``scan`` divides ``nnum``)."""
        return self.scan * self.scan_step_px

    @property
    def grid_pitch(self) -> float:
        """Pixel pitch of the reconstruction grid [m], ``mla_pitch / (scan · d)``; equals
        ``pixel_pitch`` when ``scan`` divides ``nnum``."""
        if self.grid_points == self.nnum:
            return self.pixel_pitch
        return self.mla_pitch / self.grid_points

    @property
    def pupil_fill(self) -> float:
        """Diameter of the pupil's image behind a lenslet over the pitch, ``2 NA f_ml / pitch``
        (1 for the prototype: the image just fills the lenslet; above 1: cross-talk)."""
        return 2.0 * self.na * self.mla_focal / self.mla_pitch

    @property
    def pupil_radius_px(self) -> float:
        """Radius of the main-lens pupil's image behind a lenslet, in pixels: NA·f_ml / pitch."""
        return self.na * self.mla_focal / self.pixel_pitch

    @property
    def field_offset_px(self) -> int:
        """Position of reconstruction pixel 0 in grid pixels from the first pixel of lenslet
        (0, 0) at phase (0, 0): ``(scan·d − d) // 2`` (= (nnum − d) // 2 when scan divides
        nnum; docs/conventions.md)."""
        return (self.grid_points - self.scan_step_px) // 2

    def view_mask(self, radius: float | None = None):
        """Boolean (nnum, nnum) mask of the views used for reconstruction.

        ``radius`` is in view units (default: ``VIEW_RADIUS_FRACTION`` of the pupil's radius
        ``pupil_radius_px``: the authors' 6 of 7.5 for nnum = 15, which keeps the 113 views the
        paper uses; a fraction rather than their 1.5-view margin, so that a smaller lenslet
        keeps the same share of its pupil, not a cross of 5 views at nnum = 5).
        """
        import numpy as np

        if radius is None:
            radius = VIEW_RADIUS_FRACTION * self.pupil_radius_px
        u = np.arange(self.nnum) - self.center
        return (u[:, None] ** 2 + u[None, :] ** 2) <= radius**2 + 1e-9

    def pupil_coords(self):
        """Normalised pupil coordinates (rho_x, rho_y) seen by every view, each (nnum, nnum)."""
        import numpy as np

        u = np.arange(self.nnum, dtype=np.float64) - self.center
        rho_y = -u[:, None] / self.pupil_radius_px * np.ones((1, self.nnum))
        rho_x = -u[None, :] / self.pupil_radius_px * np.ones((self.nnum, 1))
        return rho_x, rho_y

    # ------------------------------------------------------------------ (de)serialisation
    def replace(self, **changes: Any) -> SystemConfig:
        """A copy with some fields changed (validated)."""
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        out = dataclasses.asdict(self)
        out["sensor_shape"] = list(self.sensor_shape)
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> SystemConfig:
        names = {f.name for f in dataclasses.fields(cls)}
        # "metasensor": the extras a view stack's description or Zarr attributes add (io.views)
        unknown = sorted(set(data) - names - {"metasensor"})
        if unknown:
            raise ConfigError(f"unknown system parameter(s): {', '.join(unknown)}")
        data = {k: v for k, v in data.items() if k != "metasensor"}
        shape = data.get("sensor_shape")
        if isinstance(shape, (list, tuple)) and all(
            isinstance(s, (int, float)) and not isinstance(s, bool) and float(s).is_integer()
            for s in shape
        ):
            data["sensor_shape"] = tuple(int(s) for s in shape)
        # anything else reaches validate(), which names sensor_shape and the value
        return cls(**data)

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> SystemConfig:
        """Configuration from JSON: a config's own ``to_json`` or a view stack's description,
        whose extras under the ``"metasensor"`` key (io.views) are not system parameters."""
        data = parse_text(json.loads, json.JSONDecodeError, text, "JSON configuration")
        if not isinstance(data, dict):
            raise ConfigError(f"JSON configuration must be an object, got {type(data).__name__}")
        return cls.from_dict(data)

    def to_toml_string(self) -> str:
        lines = ["# metasensor system configuration (SI units: metres)", "[system]"]
        for key, value in self.to_dict().items():
            if value is None:
                continue
            lines.append(f"{key} = {toml_value(value)}")
        return "\n".join(lines) + "\n"

    @classmethod
    def from_toml_string(cls, text: str) -> SystemConfig:
        data = parse_text(tomllib.loads, tomllib.TOMLDecodeError, text, "TOML")
        table = data.get("system", data)
        if not isinstance(table, dict):
            raise ConfigError(f"'system' must be a TOML table, got {table!r:.40}")
        if "metasensor" in table:  # the extras key belongs to JSON descriptions only
            raise ConfigError("unknown system parameter(s): metasensor")
        return cls.from_dict(table)

    def to_toml(self, path: str | Path) -> Path:
        """Write the configuration as TOML (atomically); returns the path."""
        from metasensor.io.atomic import atomic_write_text

        return atomic_write_text(path, self.to_toml_string())

    @classmethod
    def from_toml(cls, path: str | Path) -> SystemConfig:
        path = Path(path)
        if not path.is_file():
            raise ConfigError(f"config file not found: {path}")
        try:
            text = path.read_bytes().decode("utf-8")
        except UnicodeDecodeError:
            raise ConfigError(f"config {path} is not a TOML text file (not UTF-8)") from None
        if not text.strip():
            raise ConfigError(f"config {path} is empty (a [system] table of parameters expected)")
        try:
            cfg = cls.from_toml_string(text)
        except ConfigError as exc:
            raise ConfigError(f"config {path}: {exc}") from None
        note_fallbacks(path, text, cfg)
        return cfg

    def digest(self) -> str:
        """Stable hash of every parameter (for cache keys)."""
        return hashlib.sha256(self.to_json().encode()).hexdigest()[:16]

    _OPTICAL_FIELDS = ("nnum", "mla_pitch", "mla_focal", "lenslet_aperture", "aperture_diameter",
                       "wavelength", "na", "obstruction")

    def optical_digest(self) -> str:
        """Hash of the parameters that shape the PSFs only (not scan, sensor size, bit depth,
        magnification or main-lens geometry), so PSF caches are shared across scan periods."""
        optical = {k: getattr(self, k) for k in self._OPTICAL_FIELDS}
        if self.apodization != "none":  # the object-side NA shapes the pupil too
            optical.update(apodization=self.apodization, magnification=self.magnification)
        return hashlib.sha256(json.dumps(optical, sort_keys=True).encode()).hexdigest()[:16]
