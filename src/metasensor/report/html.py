"""A short self-contained HTML page for a demo or evaluation summary (figures side by side)."""

from __future__ import annotations

import html
import math
from pathlib import Path

from metasensor.io.atomic import atomic_write_text

__all__ = ["write_html_report", "settings_rows"]

_MISSING = "—"


def _cell(value) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return _MISSING
    if isinstance(value, float):
        return f"{value:.3f}"
    if isinstance(value, (list, tuple)):
        return ", ".join(_cell(v) for v in value)
    return html.escape(str(value))


def _table(rows: list[dict]) -> str:
    if not rows:
        return "<p>(no rows)</p>"
    cols = list(dict.fromkeys(k for r in rows for k in r))
    head = "".join(f"<th>{html.escape(c)}</th>" for c in cols)
    body = "".join(
        "<tr>" + "".join(f"<td>{_cell(r.get(c))}</td>" for c in cols) + "</tr>" for r in rows
    )
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def settings_rows(settings: dict, prefix: str = "") -> list[tuple[str, str]]:
    """(name, value) rows of a settings mapping, nested mappings flattened to ``a / b`` names,
    values as plain text (never a Python ``repr`` of a dict)."""
    rows = []
    for key, value in settings.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            rows += settings_rows(value, f"{name} / ") if value else [(name, _MISSING)]
        else:
            rows.append((name, _cell(value)))
    return rows


def _mtf_notes(rows: list[dict]) -> str:
    """A note for every row whose MTF50 cells are blank: why nothing was measured there."""
    notes = []
    for r in rows:
        cells = [r.get(k) for k in ("centre_mtf50", "edge_mtf50")]
        if any(v is None or (isinstance(v, float) and not math.isfinite(v)) for v in cells):
            why = r.get("mtf_note") or ("no slanted edge near that position gave an MTF50 "
                                        "(the edge response never fell to half contrast, or "
                                        "no edge was found)")
            notes.append(f"<li>{html.escape(str(r.get('sensor', '')))}: {html.escape(why)}</li>")
    if not notes:
        return ""
    return f"<p>{_MISSING} in an MTF50 column: not measured.</p><ul>{''.join(notes)}</ul>"


def write_html_report(path: str | Path, summary: dict, title: str = "metasensor demo") -> Path:
    """Write ``summary`` (``table``: list of row dicts; ``figures``: name -> PNG file name next to
    the page; ``warnings``: lines shown above everything; anything else is listed as settings,
    one row per value) as an HTML page, atomically."""
    figures = summary.get("figures", {})
    settings = {k: v for k, v in summary.items()
                if k not in ("table", "figures", "config", "warnings", "bar_groups")}
    bars = summary.get("bar_groups")
    bar_table = ("<p>Finest resolved three-bar group (period in pixels; coarser than the "
                 "coarsest group: &gt; that period) at each chart location.</p>"
                 + _table(bars)) if bars else ""
    table = [{k: v for k, v in r.items() if k != "mtf_note"} for r in summary.get("table", [])]
    warnings = "".join(f'<p class="warn">warning: {html.escape(str(w))}</p>'
                       for w in summary.get("warnings", []))
    figs = "".join(
        f'<figure><img src="{html.escape(str(f))}" alt="{html.escape(n)}">'
        f"<figcaption>{html.escape(n)}</figcaption></figure>"
        for n, f in figures.items()
    )
    rows = "".join(f"<tr><th>{html.escape(k)}</th><td>{v}</td></tr>"
                   for k, v in settings_rows(settings))
    page = f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<style>body{{font-family:sans-serif;max-width:1400px;margin:2em auto;}}
table{{border-collapse:collapse;margin:1em 0;}}td,th{{border:1px solid #bbb;padding:4px 8px;}}
th{{text-align:left;}}figure{{margin:1em 0;}}img{{max-width:100%;}}
.warn{{background:#fff3cd;border:1px solid #e0b252;padding:6px 10px;}}</style></head>
<body><h1>{html.escape(title)}</h1>
{warnings}
<p>PSNR (dB) and SSIM against the ground truth; MTF50 in cycles per pixel from slanted edges near
the field centre and the field edge (ISO 12233).</p>
{_table(table)}
{_mtf_notes(summary.get("table", []))}
{bar_table}
{figs}
<h2>Settings</h2><table>{rows}</table>
</body></html>
"""
    return atomic_write_text(path, page)
