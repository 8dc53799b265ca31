"""``linemap bench worlds``: run the scenario suite (docs/worlds.md) and print its table, per world and
seed."""

from __future__ import annotations

import json
import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from shared.bench.tables import WORLD_COLUMNS, worlds_markdown, worlds_rows
from shared.bench.worlds import WorldResult, summarize
from shared.cli.progress import case_progress
from shared.cli.report import parse_seeds
from shared.errors import LinemapError
from shared.slam import LoopClosureSettings

__all__ = ["bench_worlds_cmd", "worlds_table"]


def worlds_table(results: Sequence[WorldResult]) -> Table:
    """The suite's figures as a rich table."""
    table = Table(
        title="scenario suite: map against ground truth (targets: <= 2 cm, >= 95 %, <= 3 %, <= 1.5x)"
    )
    for name, right in WORLD_COLUMNS:
        table.add_column(name, justify="right" if right else "left")
    rows = worlds_rows(results)
    for i, row in enumerate(rows):
        table.add_row(*row, end_section=i == len(rows) - 2)
    return table


def _finite(value: object) -> object:
    """``value`` with every NaN or infinity replaced by ``None`` (JSON has no NaN)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_finite(v) for v in value]
    return value


def _kinds(text: str | None) -> list[str] | None:
    from shared.sim.worlds import KINDS

    if text is None:
        return None
    names = [k.strip() for k in text.split(",") if k.strip()]
    unknown = [k for k in names if k not in KINDS]
    if unknown or not names:
        raise LinemapError(
            f"--worlds {text!r}: unknown {unknown or 'empty'}; expected some of {', '.join(KINDS)}"
        )
    return names


def bench_worlds_cmd(
    worlds: Annotated[
        str | None, typer.Option("--worlds", help="World kinds, comma-separated (default: all; see --list).")
    ] = None,
    seeds: Annotated[str, typer.Option(help="Seeds, comma-separated.")] = "0,1,2",
    quick: Annotated[
        bool, typer.Option("--quick", help="A small subset: 3 kinds, seed 0 only, 150 scans each.")
    ] = False,
    odometry: Annotated[
        str | None, typer.Option(help="Odometry model for every world: perfect, slip, worn or bursts.")
    ] = None,
    drive: Annotated[
        str | None, typer.Option(help="Driving pattern for every world: single, out-back, laps.")
    ] = None,
    json_path: Annotated[
        Path | None, typer.Option("--json", help="Also write the figures to this JSON file.")
    ] = None,
    out: Annotated[
        Path | None, typer.Option("--out", help="Folder for one PNG per case (map over truth).")
    ] = None,
    markdown: Annotated[bool, typer.Option("--markdown", help="Print a Markdown table instead.")] = False,
    list_kinds: Annotated[bool, typer.Option("--list", help="List the world kinds and exit.")] = False,
    loop_closure: Annotated[
        bool,
        typer.Option(
            "--loop-closure/--no-loop-closure",
            help="Map under the keyframe pose graph with loop closure (the map drawn from its poses).",
        ),
    ] = False,
) -> None:
    """Map every world of the scenario suite (docs/worlds.md) offline and print, per world and seed, wall
    error, completeness, spurious share, wall count, trajectory error beside odometry's, and throughput."""
    from shared.bench.worlds import run_worlds
    from shared.sim.worlds import KINDS

    console = Console(width=None if sys.stdout.isatty() else 200)
    err = Console(stderr=True, soft_wrap=True)
    if list_kinds:
        table = Table(title="world kinds of the scenario suite")
        for col in ("kind", "odometry", "drive", "what"):
            table.add_column(col)
        for k in KINDS.values():
            table.add_row(k.name, k.odometry, k.drive, k.summary)
        console.print(table)
        return
    try:
        kinds = _kinds(worlds)
        seed_list = (0,) if quick and seeds == "0,1,2" else parse_seeds(seeds)
        if json_path is not None and not json_path.resolve().parent.is_dir():
            raise LinemapError(f"cannot write {json_path}: folder {json_path.parent} does not exist")
        with case_progress(err) as note:
            results = run_worlds(
                kinds,
                seed_list,
                quick=quick,
                odometry=odometry,
                drive=drive,
                pictures=out,
                progress=note,
                loop_closure=LoopClosureSettings() if loop_closure else None,
            )
        if json_path is not None:
            data = {
                "settings": {
                    "worlds": kinds or "all",
                    "seeds": list(seed_list),
                    "quick": quick,
                    "odometry": odometry,
                    "drive": drive,
                    "loop_closure": loop_closure,
                },
                "results": [r.as_dict() for r in results],
                "summary": summarize(results),
            }
            try:
                json_path.write_text(json.dumps(_finite(data), indent=2) + "\n", encoding="utf-8")
            except OSError as exc:
                raise LinemapError(f"cannot write {json_path}: {exc.strerror}") from None
    except LinemapError as exc:
        err.print(f"[red]error:[/red] {escape(str(exc))}")
        raise typer.Exit(2) from None
    if markdown:
        typer.echo(worlds_markdown(results), nl=False)
    else:
        console.print(worlds_table(results))
    if json_path is not None:
        err.print(f"figures written to {escape(str(json_path))}")
    if out is not None:
        err.print(f"pictures written to {out}")
