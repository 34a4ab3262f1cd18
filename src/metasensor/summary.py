"""Short ``repr`` for result dataclasses: arrays by shape and dtype, never their values.

A result such as :class:`metasensor.simulation.capture.Capture` holds many large arrays; the
dataclass default ``repr`` would print all of them. :func:`short_repr` prints each field on one
line: arrays as ``array(shape, dtype)``, long lists by length, a ``SystemConfig`` by its
sampling, everything else as its own short ``repr``.
"""

from __future__ import annotations

import dataclasses
from typing import Any

__all__ = ["short_repr", "describe"]


def describe(value: Any, limit: int = 60) -> str:
    """One short description of ``value`` (arrays and tensors by shape and dtype)."""
    shape = getattr(value, "shape", None)
    dtype = getattr(value, "dtype", None)
    if shape is not None and dtype is not None and not isinstance(value, (int, float, complex)):
        if len(shape) == 0:
            return repr(value.item()) if hasattr(value, "item") else repr(value)
        return f"{type(value).__name__}(shape={tuple(int(s) for s in shape)}, dtype={dtype})"
    if type(value).__name__ == "SystemConfig":
        return (f"SystemConfig(nnum={value.nnum}, scan={value.scan}, "
                f"pixel_pitch={value.pixel_pitch:g})")
    if isinstance(value, (list, tuple)) and len(repr(value)) > limit:
        return f"{type(value).__name__}[{len(value)}]"
    if isinstance(value, dict) and len(repr(value)) > limit:
        return f"dict[{len(value)} keys]"
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def short_repr(obj: Any) -> str:
    """``Name(field=description, ...)`` of a dataclass instance, one field per line."""
    fields = [f for f in dataclasses.fields(obj) if f.repr]
    body = ",\n".join(f"    {f.name}={describe(getattr(obj, f.name))}" for f in fields)
    return f"{type(obj).__name__}(\n{body},\n)"
