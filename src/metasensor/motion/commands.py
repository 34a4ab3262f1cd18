"""Command-line commands of the motion stage (registered on the main app by metasensor.cli)."""

from __future__ import annotations

from pathlib import Path

import typer

from metasensor.cli_options import SCAN_ORDER_HELP, SCAN_ORDER_NAMES, SCAN_ORDER_PRESETS


def parse_scan_order(text: str, period: int) -> list[tuple[int, int]]:
    """``--scan-order`` (:func:`metasensor.cli_options.parse_scan_order`) → checked scan order.
    ``period`` 0: a list sets its own period (sqrt of its length); names use 5 (the command
    refuses a name without a period first, :func:`_scan_order`)."""
    from metasensor.cli_options import parse_scan_order as parse

    return parse(text or "row-major", period or None)


def _figure(before, after, path: Path) -> Path:
    """Centre view before and after motion correction, and what changed."""
    import numpy as np

    from metasensor.io.figures import new_figure, save_figure

    fig, axes = new_figure(1, 3, size=(12, 4.2))
    lo, hi = np.percentile(before, [0.5, 99.5])
    diff = after.astype(np.float32) - before.astype(np.float32)
    lim = float(np.abs(diff).max()) or 1.0
    for ax, img, title, kw in (
            (axes[0, 0], before, "centre view, realigned", dict(cmap="gray", vmin=lo, vmax=hi)),
            (axes[0, 1], after, "motion corrected", dict(cmap="gray", vmin=lo, vmax=hi)),
            (axes[0, 2], diff, "corrected − realigned", dict(cmap="RdBu_r", vmin=-lim,
                                                              vmax=lim))):
        ax.imshow(img, **kw)
        ax.set_title(title, fontsize=9)
        ax.axis("off")
    return save_figure(fig, path)


def _flow_view(text: str, nu: int, nv: int):
    """``--flow-view`` → None (centre), "sharpest" or a (u, v) view index, checked."""
    if text in ("centre", "center"):
        return None
    if text == "sharpest":
        return "sharpest"
    try:
        u, v = (int(a) for a in text.split(","))
    except ValueError:
        raise ValueError(f"--flow-view must be centre, sharpest or u,v; got {text!r}") from None
    if not (0 <= u < nu and 0 <= v < nv):
        raise ValueError(f"--flow-view {text} is outside the {nu}² views")
    return u, v


def _scan_order(text: str | None, stored: dict, period: int, views: Path):
    """The scan order: ``--scan-order`` if given, else the one stored with the views, else
    row-major. ``period`` 0 (neither ``--period`` nor a stored configuration): only an order
    that sets its own period (a list, stored or given) is accepted; a preset name or the
    default would have to guess the period, so that is a one-line error."""
    if text is None and isinstance(stored.get("scan_order"), list):
        from metasensor.sensor.scan import check_scan_order, period_of

        order = [tuple(q) for q in stored["scan_order"]]
        order = check_scan_order(order, period or period_of(order))
        typer.echo(f"using the scan order stored in {Path(views).name}")
        return order
    text = text or "row-major"
    if not period and text.strip().lower() in SCAN_ORDER_PRESETS:
        raise ValueError(f"{Path(views).name} carries no system configuration, so its scan "
                         f"period is unknown: pass --period (e.g. --period 5 for a 5 x 5 scan) "
                         f"or an explicit --scan-order list")
    return parse_scan_order(text, period)


def register(app: typer.Typer) -> None:
    """Add this stage's commands to app."""

    @app.command("motion")
    def motion_cmd(
        views: Path = typer.Argument(..., help="input view stack (.tif/.zarr, nnum² pages)"),
        out: Path = typer.Option(..., "--out", "-o", help="output view stack (.tif or .zarr)"),
        scan_order: str | None = typer.Option(
            None, *SCAN_ORDER_NAMES,
            help=f"{SCAN_ORDER_HELP} (default: the order stored in the stack, else row-major)"),
        period: int = typer.Option(
            0, "--period", help="scan period (default: from the stack's config; needed without "
                                "one unless --scan-order is a list)"),
        reference: int = typer.Option(-1, "--reference",
                                      help="index into the scan order to align to (-1: middle)"),
        mode: str = typer.Option("object", "--mode", help="object (one flow) or turbulence"),
        flow_view: str = typer.Option("centre", "--flow-view",
                                      help="centre, sharpest, or u,v (object mode)"),
        method: str = typer.Option("dis", "--method", help="dis or farneback (object mode)"),
        scatter: str = typer.Option("linear", "--scatter", help="linear or cubic"),
        fallback: bool = typer.Option(
            True, "--fallback/--no-fallback",
            help="object mode: where the corrected view still shows the scan artefact, blend "
                 "towards the reference frame alone (coarser, artefact-free)"),
    ) -> None:
        """Remove scan (grid) artefacts of moving objects or turbulence from a view stack.

        Example: metasensor motion views.tif --scan-order serpentine --out corrected.tif
        """
        import numpy as np

        from metasensor.io.guard import guard
        from metasensor.io.views import (
            read_config_from_views,
            read_views,
            stored_extras,
            write_views,
        )
        from metasensor.motion.correct import correct_motion_views

        guard([views], [out, out.with_suffix(".png")])
        cfg = read_config_from_views(views) if Path(views).exists() else None
        stack = np.asarray(read_views(views))
        if period < 0:
            raise ValueError(f"--period must be positive, got {period}")
        if cfg is not None and period and period != cfg.scan:
            raise ValueError(f"--period {period} differs from the stack's scan period {cfg.scan}")
        p = period or (cfg.scan if cfg is not None else 0)
        stored = stored_extras(views) if Path(views).exists() else {}
        order = _scan_order(scan_order, stored, p, views)
        fv = _flow_view(flow_view, stack.shape[0], stack.shape[1])
        if reference < -1:
            raise ValueError(f"--reference must be a scan-order index >= 0, or -1 for the "
                             f"middle one, got {reference}")
        ref = None if reference == -1 else reference
        result = correct_motion_views(stack, order, reference=ref, flow_view=fv, mode=mode,
                                      method=method, scatter=scatter, fallback=fallback)
        extra = {k: v for k, v in stored.items() if k not in ("kind", "view_shape")}
        extra.update(motion_corrected=True, scan_order=[list(q) for q in order])
        write_views(out, result, cfg, extra=extra)
        c = stack.shape[0] // 2
        changed = float(np.mean(result[c, c] != stack[c, c]))
        fig_path = _figure(stack[c, c], result[c, c], out.with_suffix(".png"))
        typer.echo(f"wrote {out} and {fig_path.name}: {100 * changed:.1f} % of the centre view's "
                   "samples moved (the rest, static, are unchanged)")
