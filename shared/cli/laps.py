"""``linemap bench laps``: a world driven in laps, mapped with and without loop closure; the map after
each lap, the position error over time (Fig. 20) and the time of each optimisation."""

from __future__ import annotations

import json
import sys
from dataclasses import asdict
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from shared.cli.progress import case_progress
from shared.cli.report import parse_seeds
from shared.errors import LinemapError

__all__ = ["bench_laps_cmd"]


def bench_laps_cmd(
    seeds: Annotated[str, typer.Option(help="Seeds, comma-separated.")] = "0,1,2",
    laps: Annotated[int, typer.Option(min=1, max=20, help="Laps driven round the loop.")] = 3,
    world: Annotated[str, typer.Option(help="A world kind the suite drives in laps.")] = "loop-block",
    png: Annotated[
        Path | None, typer.Option("--png", help="Write the position error over time (Fig. 20) here.")
    ] = None,
    json_path: Annotated[
        Path | None, typer.Option("--json", help="Also write the figures to this JSON file.")
    ] = None,
    markdown: Annotated[bool, typer.Option("--markdown", help="Print a Markdown table instead.")] = False,
) -> None:
    """Drive a loop of corridors (worn-wheel odometry) several laps and map it as the robot does, front end
    alone and under the pose graph: per lap the map's wall error, completeness, spurious share, wall count
    and trajectory error; the time of every pose-graph optimisation and map redraw."""
    from shared.bench.laps import run_laps_suite
    from shared.report.laps import (
        LAPS_COLUMNS,
        laps_markdown,
        laps_rows,
        laps_timing_line,
        plot_position_error,
    )
    from shared.sim.worlds import KINDS

    console = Console(width=None if sys.stdout.isatty() else 200)
    err = Console(stderr=True, soft_wrap=True)
    try:
        if world not in KINDS:
            raise LinemapError(f"--world {world!r}: expected one of {', '.join(KINDS)}")
        seed_list = parse_seeds(seeds)
        for target in (png, json_path):
            if target is not None and not target.resolve().parent.is_dir():
                raise LinemapError(f"cannot write {target}: folder {target.parent} does not exist")
        with case_progress(err) as note:
            runs = run_laps_suite(seed_list, laps, kind=world, progress=note)
        if png is not None:
            plot_position_error(runs, png)
        if json_path is not None:
            data = [
                {
                    "world": r.kind,
                    "seed": r.seed,
                    "variant": r.variant,
                    "laps": [asdict(f) for f in r.laps],
                    "closures": r.closures,
                    "optimise_ms": list(r.optimise_ms),
                    "redraw_ms": list(r.redraw_ms),
                }
                for r in runs
            ]
            try:
                json_path.write_text(json.dumps(data, indent=2) + "\n", encoding="utf-8")
            except OSError as exc:
                raise LinemapError(f"cannot write {json_path}: {exc.strerror}") from None
    except LinemapError as exc:
        err.print(f"[red]error:[/red] {escape(str(exc))}")
        raise typer.Exit(2) from None
    if markdown:
        typer.echo(laps_markdown(runs, str(png) if png else None), nl=False)
    else:
        table = Table(
            title=f"{world}, {laps} laps: the map at each lap's end (targets: <= 2 cm, >= 95 %, <= 3 %, "
            "<= 1.5x)"
        )
        for name, right in LAPS_COLUMNS:
            table.add_column(name, justify="right" if right else "left")
        for row in laps_rows(runs):
            table.add_row(*row)
        console.print(table)
        console.print(laps_timing_line(runs))
    for target, what in ((png, "position error over time"), (json_path, "figures")):
        if target is not None:
            err.print(f"{what} written to {target}")
