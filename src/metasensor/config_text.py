"""Text of system configurations: one-line errors for TOML and JSON that do not parse, exact
one-line TOML values, and the note (said once) on optics a configuration file leaves to the
prototype's defaults."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from metasensor.config import SystemConfig

__all__ = ["ConfigError", "FALLBACK_FIELDS", "drop_fallbacks", "note_fallbacks", "parse_text",
           "say_fallbacks", "toml_value"]


# optics a TOML should set for its own system; missing ones fall back to the prototype's
FALLBACK_FIELDS = ("mla_pitch", "mla_focal", "wavelength", "na")
_PENDING: dict[str, str] = {}  # optical digest -> the note not said yet
_SAID: set[str] = set()


def note_fallbacks(path: Path, text: str, cfg: SystemConfig) -> None:
    """Remember which optics ``path`` leaves to the prototype's defaults (a reconstruction
    with another system's optics looks plausible); :func:`say_fallbacks` says it once."""
    table = tomllib.loads(text)
    table = table.get("system", table)
    missing = [k for k in FALLBACK_FIELDS if k not in table]
    key = str(Path(path).resolve())
    if missing and key not in _SAID:
        _SAID.add(key)
        from metasensor.config import SystemConfig

        proto = SystemConfig()
        values = ", ".join(f"{k} = {getattr(proto, k)!r}" for k in missing)
        _PENDING[cfg.optical_digest()] = (f"note: {path} does not set {', '.join(missing)}; "
                                          f"using the prototype's ({values})")


def say_fallbacks(cfg: SystemConfig | None = None) -> None:
    """Print, once, on stderr, the note of a configuration file read by
    :meth:`SystemConfig.from_toml` that left optics to the prototype: for ``cfg``'s optics
    (called where optics are used, e.g. PSF generation), or all pending ones (None; the CLI
    calls it when a command has finished)."""
    import sys

    keys = list(_PENDING) if cfg is None else [cfg.optical_digest()]
    for key in keys:
        note = _PENDING.pop(key, None)
        if note is not None:
            print(note, file=sys.stderr)


def drop_fallbacks() -> None:
    """Forget the notes not said yet: the CLI calls it when a command starts, so a command
    that failed before its optics were used does not leave its note to the next command run
    in the same process (the napari plugin, scripts calling ``main``)."""
    _PENDING.clear()


class ConfigError(ValueError):
    """An impossible or inconsistent system parameter (one line, naming the parameter)."""


def parse_text(loads, error: type[Exception], text: str, what: str) -> Any:
    """``loads(text)``, its syntax errors (and text nested thousands deep) as one ConfigError
    line ``invalid <what>: ...``."""
    try:
        return loads(text)
    except error as exc:
        raise ConfigError(f"invalid {what}: {exc}") from None
    except RecursionError:
        raise ConfigError(f"invalid {what}: nested too deeply") from None


def toml_value(value: Any) -> str:
    """One TOML value (bool, int, float with exact repr, str, list): scalars written by
    ``tomli_w``, arrays kept on one line (tomli_w puts every item on its own line);
    ConfigError for non-finite numbers and other types."""
    import tomli_w

    if isinstance(value, (tuple, list)):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    if isinstance(value, float) and not math.isfinite(value):
        raise ConfigError(f"cannot write non-finite value {value!r} to TOML")
    if not isinstance(value, (bool, int, float, str)):
        raise ConfigError(f"cannot write value of type {type(value).__name__} to TOML")
    return tomli_w.dumps({"v": value}).strip().removeprefix("v = ")
