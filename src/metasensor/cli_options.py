"""Conventions shared by every ``metasensor`` command: one scan-order syntax (and one option
name, ``--scan-order``, with ``--order`` kept as an alias), one grid syntax (``4x4``),
``--out``/``-o`` for outputs, and commands declared as one frozen dataclass of their options
(:func:`typed_command`).

``tests/test_cli_conventions.py`` checks every registered command against them.
"""

from __future__ import annotations

import inspect
import re
from collections.abc import Callable
from typing import Any

__all__ = ["SCAN_ORDER_SYNTAX", "SCAN_ORDER_HELP", "SCAN_ORDER_NAMES", "SCAN_ORDER_PRESETS",
           "parse_scan_order", "parse_pair", "typed_command"]

SCAN_ORDER_NAMES = ("--scan-order", "--order")
SCAN_ORDER_SYNTAX = ("row-major, serpentine, spiral, or the (row,col) phases in acquisition "
                     "order as '0,0;0,1;0,2;...' ('[(0,0),(0,1),...]' is read too; "
                     "'one-based:1,1;1,2;...' for one-based phases), or a scan-pattern PNG "
                     "whose pixel (r,c) holds the acquisition index of phase (r,c)")
SCAN_ORDER_HELP = f"scan order: {SCAN_ORDER_SYNTAX}"
SCAN_ORDER_PRESETS = ("row-major", "rowmajor", "raster", "serpentine", "snake",
                      "boustrophedon", "spiral")
"""The preset names of ``--scan-order`` (each needs the scan period from elsewhere)."""
_PAIR = re.compile(r"\(\s*(-?\d+)\s*,\s*(-?\d+)\s*\)")


def _pairs(text: str) -> list[tuple[int, int]]:
    if "(" in text:  # the Python-list spelling
        if _PAIR.sub("", text).strip("[] ,;\t"):
            raise ValueError("unreadable")
        return [(int(r), int(c)) for r, c in _PAIR.findall(text)]
    pairs = []
    for item in text.split(";"):
        if item.strip():
            r, c = item.split(",")  # ValueError unless exactly two numbers
            pairs.append((int(r), int(c)))
    return pairs


def parse_scan_order(text: str | None, period: int | None = None, *,
                     default_period: int = 5) -> list[tuple[int, int]] | None:
    """Read a ``--scan-order`` value into a checked list of (row, col) phases.

    Parameters
    ----------
    text : str or None
        A preset name (``row-major``, ``serpentine``, ``spiral``), ``'r,c;r,c;...'`` or
        ``'[(r,c),(r,c),...]'`` (zero-based; prefixed ``one-based:`` for one-based phases), or
        a scan-pattern PNG path (:func:`metasensor.sensor.scan.read_order_png`). None or
        empty: None (the caller's default).
    period : int or None
        The scan period the order must cover; None or 0: an explicit list sets its own
        (the square root of its length) and a preset name uses ``default_period``.

    Returns
    -------
    list of (int, int) or None

    Raises
    ------
    ValueError
        One line naming ``--scan-order``, what is wrong and the accepted syntax.
    """
    from metasensor.sensor.scan import check_scan_order, period_of

    if text is None or not text.strip():
        return None
    text = text.strip()
    try:
        if text.lower() in SCAN_ORDER_PRESETS:
            return check_scan_order(text.lower(), period or default_period)
        if text.lower().endswith(".png"):  # the authors' scan-pattern image
            from pathlib import Path

            from metasensor.sensor.scan import read_order_png

            if not Path(text).is_file():
                raise ValueError(f"scan-pattern file not found: {text}")
            order = read_order_png(text)
            return check_scan_order(order, period or period_of(order))
        base = 0
        if text.lower().startswith("one-based:"):
            text, base = text[len("one-based:"):], 1
        try:
            pairs = [(r - base, c - base) for r, c in _pairs(text)]
        except ValueError:
            raise ValueError(f"cannot read {text!r}") from None
        if not pairs:
            raise ValueError(f"no phases in {text!r}")
        return check_scan_order(pairs, period or period_of(pairs))
    except ValueError as exc:
        raise ValueError(f"--scan-order: {exc}; use {SCAN_ORDER_SYNTAX}") from None


def parse_pair(text: str, name: str) -> tuple[int, int]:
    """A grid option's ``"4x4"`` → (4, 4), both positive integers.

    Parameters
    ----------
    text : str
        ``"<rows>x<cols>"`` (case-insensitive ``x``).
    name : str
        The option, named in the error (e.g. ``"--blocks"``).

    Returns
    -------
    (int, int)

    Raises
    ------
    ValueError
        One line naming ``name`` when the text is not two integers or one is below 1.
    """
    try:
        a, b = (int(t) for t in str(text).lower().split("x"))
    except ValueError:
        raise ValueError(f"{name} must look like 4x4, got {text!r}") from None
    if a < 1 or b < 1:
        raise ValueError(f"{name} must be positive, got {text!r}")
    return a, b


def typed_command(args_type: type, run: Callable[[Any], None]) -> Callable[..., None]:
    """A typer command whose options are the fields of the frozen dataclass ``args_type``.

    Each field is declared as ``name: Annotated[type, typer.Option(...)] = default`` (or
    ``typer.Argument``); the command's signature is the dataclass's, so typer (and the napari
    forms built from the click parameters) see one parameter per field, and the command's
    body is ``run(args_type(**given))``: the options arrive parsed and validated in one
    object. ``run``'s docstring is the command's help.
    """

    def command(**given: Any) -> None:
        run(args_type(**given))

    command.__signature__ = inspect.signature(args_type, eval_str=True)  # type: ignore[attr-defined]
    command.__doc__ = run.__doc__
    command.__name__ = run.__name__
    return command
