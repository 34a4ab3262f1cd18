"""A short self-contained HTML page for a demo or evaluation summary (figures side by side)."""

from __future__ import annotations

import html
from pathlib import Path

from metasensor.io.atomic import atomic_write_text

__all__ = ["write_html_report"]


def _cell(value) -> str:
    if isinstance(value, float):
        return f"{value:.3f}"
    return html.escape(str(value))


def _table(rows: list[dict]) -> str:
    if not rows:
        return "<p>(no rows)</p>"
    cols = list(dict.fromkeys(k for r in rows for k in r))
    head = "".join(f"<th>{html.escape(c)}</th>" for c in cols)
    body = "".join(
        "<tr>" + "".join(f"<td>{_cell(r.get(c, ''))}</td>" for c in cols) + "</tr>" for r in rows
    )
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def write_html_report(path: str | Path, summary: dict, title: str = "metasensor demo") -> Path:
    """Write ``summary`` (``table``: list of row dicts; ``figures``: name -> PNG file name next to
    the page; anything else is listed as settings) as an HTML page, atomically."""
    figures = summary.get("figures", {})
    settings = {k: v for k, v in summary.items() if k not in ("table", "figures", "config")}
    figs = "".join(
        f'<figure><img src="{html.escape(str(f))}" alt="{html.escape(n)}">'
        f"<figcaption>{html.escape(n)}</figcaption></figure>"
        for n, f in figures.items()
    )
    settings_rows = "".join(
        f"<tr><th>{html.escape(str(k))}</th><td>{_cell(v)}</td></tr>" for k, v in settings.items()
    )
    page = f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<style>body{{font-family:sans-serif;max-width:1400px;margin:2em auto;}}
table{{border-collapse:collapse;margin:1em 0;}}td,th{{border:1px solid #bbb;padding:4px 8px;}}
figure{{margin:1em 0;}}img{{max-width:100%;}}</style></head>
<body><h1>{html.escape(title)}</h1>
<p>PSNR and SSIM against the ground truth; MTF50 in cycles per pixel from slanted edges near the
field centre and the field edge (ISO 12233).</p>
{_table(summary.get("table", []))}
{figs}
<h2>Settings</h2><table>{settings_rows}</table>
</body></html>
"""
    return atomic_write_text(path, page)
