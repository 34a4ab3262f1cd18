"""Command-line commands of the report stage: ``metasensor demo``."""

from __future__ import annotations

from pathlib import Path

import typer


def bar_lines(rows: list[dict]) -> list[str]:
    """The demo's bar-group rows as text: the finest resolved period [px] per image and
    location (``>P``: not even the coarsest group, of period P)."""
    if not rows:
        return []
    names = [k for k in rows[0] if k not in ("location", "coarsest_px", "gain_2d_over_meta",
                                             "gain_is_lower_bound")]
    lines = ["finest resolved bar group [px] per location: " + " | ".join(names)
             + " | 2D / meta"]
    for r in rows:
        cells = [f"{r[n]:g}" if r[n] is not None else f">{r['coarsest_px']:g}" for n in names]
        g = r["gain_2d_over_meta"]
        gain = "-" if g is None else (">" if r["gain_is_lower_bound"] else "") + f"{g:.1f}x"
        lines.append(f"  {r['location']:>12}: " + " | ".join(cells) + f" | {gain}")
    return lines

def register(app: typer.Typer) -> None:
    """Add this stage's commands to ``app``."""

    @app.command("demo")
    def demo(
        out: Path = typer.Option(Path("demo"), "--out", "-o", file_okay=False,
                                  help="folder for the report"),
        size: int = typer.Option(384, "--size", min=96, help="scene side in pixels"),
        scan: int = typer.Option(5, "--scan", help="scan period of the meta-imaging sensor"),
        snr: float = typer.Option(30.0, "--snr", help="SNR of the captures in dB"),
        blocks: str = typer.Option("4x4", "--blocks", help="multisite blocks, e.g. 3x3"),
        seed: int = typer.Option(0, "--seed", help="random seed"),
        chart: str = typer.Option("bars", "--chart",
                                  help="bars (three-bar groups at the centre, edge midpoints and "
                                       "corners), bars-field (the same, coarser groups towards "
                                       "the axis, symmetric about it) or chart (ISO 12233-style: "
                                       "slanted edges, a Siemens star)"),
        scenario: str = typer.Option("single-lens", "--scenario",
                                     help="single-lens (default), plastic-wrap, telescope or "
                                          "gigapixel (the paper's Figs. 3, 5 and ED Fig. 7)"),
        scheduler: str = typer.Option(None, "--scheduler",
                                      help="gigapixel: Dask scheduler address "
                                           "(tcp://host:8786); default local threads. "
                                           "Trusted: dask exchanges pickles over "
                                           "unauthenticated TCP; use a private network or "
                                           "tls://"),
    ) -> None:
        """Simulate the built-in resolution chart through a cheap single lens, reconstruct it,
        and write a report (PNG figures, index.html, summary.json); or run one of the paper's
        experiments with --scenario.

        Example: metasensor demo --out demo/ ; metasensor demo --scenario telescope --out tel/
        """
        import warnings

        from metasensor.report.demo import DemoSettings, run_demo
        from metasensor.scenarios import SCENARIOS, run_scenario

        if scenario not in SCENARIOS:
            raise typer.BadParameter(f"unknown scenario {scenario!r}; choose from "
                                     f"{', '.join(SCENARIOS)}", param_hint="--scenario")
        if scheduler is not None and scenario != "gigapixel":
            raise typer.BadParameter("applies to --scenario gigapixel only",
                                     param_hint="--scheduler")
        from metasensor.io.guard import guard

        guard([], [], folders=[out])  # a file in the way is refused; two runs do not interleave
        if scenario != "single-lens":
            summary = run_scenario(scenario, out, seed=seed, scheduler=scheduler)
            for row in summary["table"]:
                typer.echo("  ".join(f"{k}={v:.3f}" if isinstance(v, float) else f"{k}={v}"
                                     for k, v in row.items()))
            typer.echo(f"report: {Path(out) / 'index.html'} ({summary['seconds']:.0f} s)")
            return

        from metasensor.cli_options import parse_pair

        by, bx = parse_pair(blocks, "--blocks")

        def say(message, *_args, **_kwargs) -> None:  # a warning: one line, before the wait
            typer.echo(f"warning: {message}", err=True)

        with warnings.catch_warnings():
            warnings.showwarning = say
            warnings.simplefilter("always", UserWarning)
            summary = run_demo(out, DemoSettings(size=size, scan=scan, snr_db=snr,
                                                 blocks=(by, bx), seed=seed, scene=chart))
        for row in summary["table"]:
            typer.echo("  ".join(f"{k}={v:.3f}" if isinstance(v, float) else f"{k}={v}"
                                 for k, v in row.items()))
        for line in bar_lines(summary.get("bar_groups") or []):
            typer.echo(line)
        typer.echo(f"report: {Path(out) / 'index.html'} ({summary['seconds']:.0f} s)")
