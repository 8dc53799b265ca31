"""``linemap report``: regenerate the reproduction report into a folder."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated

import typer

from shared.errors import LinemapError

__all__ = ["DEFAULT_DATA", "parse_seeds", "report_cmd"]

#: The benchmark logs beside a checkout of the project (``../shared/data``), unless LINEMAP_DATA says.
DEFAULT_DATA = Path(__file__).resolve().parents[3] / "shared" / "data"


def parse_seeds(text: str) -> tuple[int, ...]:
    """Seeds from a `--seeds` option: comma-separated non-negative integers ("0,1,2")."""
    try:
        seeds = tuple(int(s) for s in text.split(",") if s.strip())
    except ValueError:
        raise LinemapError(f"--seeds {text!r}: expected comma-separated integers, e.g. 0,1,2") from None
    if not seeds or any(s < 0 for s in seeds):
        raise LinemapError(f"--seeds {text!r}: expected one or more non-negative integers")
    return seeds


def report_cmd(
    out: Annotated[Path, typer.Option("--out", help="Folder for report.md and its figures.")] = Path(
        "report"
    ),
    seeds: Annotated[str, typer.Option(help="Seeds of the simulated runs, comma-separated.")] = "0,1,2",
    data: Annotated[
        Path | None,
        typer.Option(help="Folder of the SLAM benchmark logs (default: $LINEMAP_DATA or ../shared/data)."),
    ] = None,
    quick: Annotated[
        bool, typer.Option(help="A small, fast version (one seed, few configurations).")
    ] = False,
    worlds_only: Annotated[
        bool,
        typer.Option(
            "--worlds-only",
            help="Only the scenario suite: OUT/worlds.md and its maps (report.md is left alone).",
        ),
    ] = False,
) -> None:
    """Reproduce the paper's Table 3, Fig. 19 and Fig. 24, compare linemap with a line-segment EKF-SLAM on
    simulated worlds and the benchmark logs, and run the scenario suite; writes OUT/report.md (and the
    suite's section as OUT/worlds.md) with PNG figures (several minutes)."""
    from rich.console import Console
    from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    from shared.report import ReportSettings, run_report, run_worlds_report

    folder = data or Path(os.environ.get("LINEMAP_DATA", DEFAULT_DATA))
    if data is not None and not data.is_dir():
        raise LinemapError(f"--data {data}: no such folder (expected the SLAM benchmark logs)")
    if quick:
        settings = ReportSettings.quick_run(folder)
    else:
        settings = ReportSettings(seeds=parse_seeds(seeds), data=folder)
    if not folder.is_dir() and not worlds_only:
        typer.echo(f"note: no benchmark logs at {folder}: the relation-error section is left out", err=True)
    console = Console(stderr=True)
    columns = [SpinnerColumn(), TextColumn("{task.description}"), TimeElapsedColumn()]
    with Progress(*columns, console=console, transient=True) as progress:
        task = progress.add_task("starting", total=None)
        run = run_worlds_report if worlds_only else run_report
        path = run(out, settings, lambda msg: progress.update(task, description=msg))
    typer.echo(f"wrote {path}")
