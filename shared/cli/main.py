"""``linemap``, the one console command. Errors print one line and exit with code 2, never a traceback."""

from __future__ import annotations

import json
import logging
import math
import sys
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.markup import escape

from robot_agent.cli import agent_cmd
from server.cli import server_app
from shared.cli.demo import demo_cmd
from shared.cli.foxglove import foxglove_cmd
from shared.cli.keys import keys_app
from shared.cli.laps import bench_laps_cmd
from shared.cli.report import report_cmd
from shared.cli.worlds import bench_worlds_cmd
from shared.errors import LinemapError

__all__ = ["app", "interrupted", "main"]

app = typer.Typer(
    name="linemap",
    help="Indoor line mapping with a 2D laser scanner: kernels, benchmarks, robot agent and server.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
bench_app = typer.Typer(help="Benchmarks (figures, not tests).", no_args_is_help=True)
app.add_typer(bench_app, name="bench")
bench_app.command("worlds")(bench_worlds_cmd)
bench_app.command("laps")(bench_laps_cmd)
app.add_typer(keys_app, name="keys")
app.add_typer(server_app, name="server")
app.command("agent")(agent_cmd)
app.command("demo")(demo_cmd)
app.command("foxglove")(foxglove_cmd)
app.command("report")(report_cmd)

# Wide enough for the benchmark table when the output goes to a file or a pipe (rich assumes 80 columns).
console = Console(width=None if sys.stdout.isatty() else 160)
err_console = Console(stderr=True, soft_wrap=True)  # an error line is never cut in two


@app.callback()
def _main(
    verbose: Annotated[bool, typer.Option("--verbose", "-v", help="Log debug messages.")] = False,
) -> None:
    logging.basicConfig(
        level=logging.DEBUG if verbose else logging.WARNING, format="%(levelname)s %(name)s: %(message)s"
    )


@app.command("kernels")
def kernels_cmd(
    as_json: Annotated[bool, typer.Option("--json", help="Print the catalogue with JSON Schemas.")] = False,
    markdown: Annotated[
        bool, typer.Option("--markdown", help="Print the catalogue as a Markdown table.")
    ] = False,
    describe: Annotated[
        Path | None,
        typer.Option(
            "--describe",
            help="Print the parameter JSON Schema of the kernel defined in this module (your own file: it is "
            "imported here), for the `parameters` field of its upload.",
        ),
    ] = None,
) -> None:
    """List the registered kernels with their parameters, units, ranges and defaults."""
    from shared.cli.render import kernel_markdown, kernel_table
    from shared.kernels import REGISTRY

    if describe is not None:
        from shared.cli.kernelfile import describe_kernel_file

        try:
            info = describe_kernel_file(describe)
        except LinemapError as exc:
            err_console.print(f"[red]error:[/red] {escape(str(exc))}")
            raise typer.Exit(2) from None
        what = f"{info['name']} {info['version']} ({info['stage']})"
        err_console.print(f"{what}: its parameters as JSON Schema")
        typer.echo(json.dumps(info["parameters"], indent=2))
        return
    if markdown:
        typer.echo(kernel_markdown(REGISTRY.list()), nl=False)
        return
    if as_json:
        typer.echo(json.dumps(REGISTRY.describe(), indent=2))
        return
    console.print(kernel_table(REGISTRY.list()))


@bench_app.command("kernels")
def bench_kernels(
    json_path: Annotated[
        Path | None, typer.Option("--json", help="Also write the figures to this JSON file.")
    ] = None,
    runs: Annotated[
        int, typer.Option(min=5, max=10_000, help="Timed runs per kernel (after warm-up).")
    ] = 200,
    seed: Annotated[int, typer.Option(min=0, help="Seed of the simulated data.")] = 0,
    markdown: Annotated[bool, typer.Option("--markdown", help="Print Markdown tables instead.")] = False,
) -> None:
    """Time each kernel and one whole online step against scikit-learn/scikit-fuzzy/scipy on the same data."""
    from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    from shared.bench.kernels import run_kernel_bench
    from shared.cli.render import bench_markdown, bench_tables

    if json_path is not None and not json_path.resolve().parent.is_dir():
        err_console.print(
            "[red]error:[/red] "
            + escape(f"cannot write {json_path}: folder {json_path.parent} does not exist")
        )
        raise typer.Exit(2)
    try:
        with Progress(
            SpinnerColumn(),
            TextColumn("{task.description}"),
            TimeElapsedColumn(),
            console=err_console,
            transient=True,
        ) as progress:
            task = progress.add_task("compiling kernels (first run only)...", total=None)

            def note(label: str) -> None:
                progress.update(task, description=f"timing {label}")

            report = run_kernel_bench(runs=runs, seed=seed, progress=note)
    except LinemapError as exc:
        err_console.print(f"[red]error:[/red] {escape(str(exc))}")
        raise typer.Exit(2) from None
    if markdown:
        typer.echo(bench_markdown(report), nl=False)
    else:
        for table in bench_tables(report):
            console.print(table)
    if json_path is not None:
        try:
            json_path.write_text(json.dumps(report.as_dict(), indent=2) + "\n", encoding="utf-8")
        except OSError as exc:
            err_console.print(f"[red]error:[/red] cannot write {escape(f'{json_path}: {exc.strerror}')}")
            raise typer.Exit(2) from None
        err_console.print(f"figures written to {escape(str(json_path))}")


@bench_app.command("area")
def bench_area(seed: Annotated[int, typer.Option(min=0, help="Seed of the simulated run.")] = 0) -> None:
    """The paper's Table 3: area error for CJ/HT/SVD x k-means/FCM x 50/60/70 clusters, simulated world."""
    from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn
    from rich.table import Table

    from shared.bench.table3 import run_table3

    with Progress(
        SpinnerColumn(),
        TextColumn("{task.description}"),
        TimeElapsedColumn(),
        console=err_console,
        transient=True,
    ) as progress:
        task = progress.add_task("simulating", total=None)
        rows = run_table3(seed, progress=lambda label: progress.update(task, description=f"mapping: {label}"))
    table = Table(title="area error of the map, simulated world (paper Table 3 beside)")
    for col in (
        "clustering",
        "lines",
        "clusters",
        "area error %",
        "paper %",
        "mean error cm",
        "completeness %",
    ):
        table.add_column(col, justify="left" if col in ("clustering", "lines") else "right")
    for r in rows:
        area = "not closed" if r.area_error_pct is None else f"{r.area_error_pct:.2f}"
        table.add_row(
            r.clustering,
            r.lines,
            str(r.clusters),
            area,
            f"{r.paper_pct:.3f}",
            f"{r.mean_error_m * 100:.1f}",
            f"{r.completeness * 100:.0f}",
        )
    console.print(table)


@app.command("map")
def map_cmd(
    source: Annotated[
        str,
        typer.Argument(help="sim, sim:WORLD_FILE, a log (.clf/.log/.dat[.gz]) or a ROS bag (.bag/.mcap/dir)"),
    ] = "sim",
    out: Annotated[Path, typer.Option("--out", help="GeoJSON map (segments, centroids, trajectory).")] = Path(
        "map.geojson"
    ),
    svg: Annotated[Path | None, typer.Option(help="Also draw the map as SVG.")] = None,
    png: Annotated[Path | None, typer.Option(help="Also draw the map as PNG.")] = None,
    dxf: Annotated[
        Path | None, typer.Option(help="Also write the map as DXF (walls, centroids, trajectory; metres).")
    ] = None,
    pgm: Annotated[
        Path | None,
        typer.Option(
            help="Also write a ROS map_server occupancy map: PATH.pgm + PATH.yaml (or a .yaml path)."
        ),
    ] = None,
    resolution: Annotated[float, typer.Option(help="Metres per pixel of the --pgm occupancy map.")] = 0.05,
    mcap: Annotated[
        Path | None,
        typer.Option(help="Also write walls, centroids and trajectory as ROS 2 messages in MCAP (Foxglove)."),
    ] = None,
    topic: Annotated[
        str | None, typer.Option(help="ROS bag input: the LaserScan topic (default: the only one).")
    ] = None,
    odom_topic: Annotated[
        str | None, typer.Option(help="ROS bag input: the nav_msgs/Odometry topic (default: /odom, else tf).")
    ] = None,
    trajectory_out: Annotated[
        Path | None, typer.Option("--trajectory-out", help="CSV of poses: stamp,x,y,theta.")
    ] = None,
    config: Annotated[Path | None, typer.Option(help="Pipeline configuration (.json or .toml).")] = None,
    log_format: Annotated[
        str | None, typer.Option("--format", help="carmen, breezyslam or rosbag (default: detect).")
    ] = None,
    seed: Annotated[int, typer.Option(min=0, help="Seed of the simulated run.")] = 0,
    limit: Annotated[int | None, typer.Option(min=1, help="Stop after this many scans.")] = None,
    loop_closure: Annotated[
        bool,
        typer.Option(
            "--loop-closure/--no-loop-closure",
            help="Close loops with a keyframe pose graph and draw the map from its corrected poses.",
        ),
    ] = True,
    loop_radius: Annotated[
        float | None,
        typer.Option("--loop-radius", help="Loop closure: search radius round the current pose (m; 4)."),
    ] = None,
    loop_min_inliers: Annotated[
        float | None,
        typer.Option(
            "--loop-min-inliers", help="Loop closure: least share of returns a match explains (0.5)."
        ),
    ] = None,
) -> None:
    """Map a simulated world or a laser log into straight walls; print the accuracy when truth is known."""
    from shared.cli.progress import mapping_progress
    from shared.cli.render import accuracy_table, run_summary
    from shared.control import load_config
    from shared.mapping import MappingStoppedError, loop_settings, map_scans, open_source, write_outputs

    stopped: MappingStoppedError | None = None
    if pgm is not None and not (math.isfinite(resolution) and resolution > 0.0):
        err_console.print(f"[red]error:[/red] --resolution {resolution}: expected metres per pixel > 0")
        raise typer.Exit(2)
    try:
        cfg = load_config(config)
        loop = loop_settings(loop_closure, loop_radius, loop_min_inliers)
        src = open_source(source, log_format=log_format, seed=seed, scan_topic=topic, odom_topic=odom_topic)
        with mapping_progress(err_console, src.name, limit or src.total, src.progress) as on_step:
            try:
                run = map_scans(src, cfg, limit=limit, on_step=on_step, loop_closure=loop)
            except MappingStoppedError as stop:
                run, stopped = stop.run, stop
        walls = src.world.walls if src.world is not None else None
        written = write_outputs(
            run.snapshot,
            geojson=out,
            svg=svg,
            png=png,
            trajectory=trajectory_out,
            walls=walls,
            title=f"linemap: {src.name}",
            dxf=dxf,
            occupancy=pgm,
            resolution_m=resolution,
            mcap=mcap,
        )
    except LinemapError as exc:
        err_console.print(f"[red]error:[/red] {escape(str(exc))}")
        raise typer.Exit(2) from None
    console.print(run_summary(src.name, run))
    if run.scans and len(run.snapshot.segments) == 0:
        err_console.print(
            "[yellow]warning:[/yellow] the map has no walls. Erosion and opening on single scans remove "
            "every point (a scan is one point thick): use them in offline mode, or DBSCAN online."
        )
    if src.world is not None:
        console.print(accuracy_table(run.snapshot, src.world, src.true_trajectory))
    for path in written:
        console.print(f"wrote {escape(str(path))}")
    if stopped is not None:
        err_console.print(f"[red]error:[/red] {escape(str(stopped))}")
        raise typer.Exit(2)


@app.command("eval")
def eval_cmd(
    map_path: Annotated[Path, typer.Argument(help="The GeoJSON map written by `linemap map`.")],
    walls: Annotated[
        str | None, typer.Option(help="Ground-truth walls: 'sim' (the default world) or a world file.")
    ] = None,
    trajectory: Annotated[Path | None, typer.Option(help="Trajectory CSV from `linemap map`.")] = None,
    relations: Annotated[Path | None, typer.Option(help="Kümmerle et al. .relations file.")] = None,
    json_path: Annotated[Path | None, typer.Option("--json", help="Also write the figures as JSON.")] = None,
) -> None:
    """Measure a map (docs/design.md §5): line accuracy and area error against true walls, relation error."""
    from shared.cli.evaluate import evaluate
    from shared.cli.render import evaluation_table

    try:
        figures = evaluate(map_path, walls=walls, trajectory=trajectory, relations=relations)
        if json_path is not None:
            json_path.write_text(json.dumps(figures, indent=2) + "\n", encoding="utf-8")
    except LinemapError as exc:
        err_console.print(f"[red]error:[/red] {escape(str(exc))}")
        raise typer.Exit(2) from None
    except OSError as exc:
        err_console.print(f"[red]error:[/red] cannot write {escape(f'{json_path}: {exc.strerror}')}")
        raise typer.Exit(2) from None
    console.print(evaluation_table(figures))


def interrupted(exc: BaseException) -> bool:
    """Whether ``exc`` is, or was raised while handling or because of, a ``KeyboardInterrupt`` (O(chain))."""
    seen: set[int] = set()
    cur: BaseException | None = exc
    while cur is not None and id(cur) not in seen:
        if isinstance(cur, KeyboardInterrupt):
            return True
        seen.add(id(cur))
        cur = cur.__cause__ or cur.__context__
    return False


def main() -> None:
    """Entry point of the ``linemap`` command: an unexpected failure prints one line, not a traceback (run
    with ``--verbose`` to log it in full)."""
    try:
        app()
    except LinemapError as exc:  # expected errors of commands that let them through
        err_console.print(f"[red]error:[/red] {escape(str(exc))}")  # text in [brackets] shown as is
        raise SystemExit(2) from None
    except Exception as exc:  # the last line of defence; expected errors are handled per command
        if interrupted(exc):  # Ctrl-C that landed in compiled code (numba: "returned a result with an
            err_console.print("interrupted")  # exception set") comes out wrapped: still Ctrl-C, not a bug
            raise SystemExit(130) from None
        logging.getLogger(__name__).debug("unexpected failure", exc_info=True)
        err_console.print(
            f"[red]internal error:[/red] {type(exc).__name__}: {escape(str(exc))} "
            "(this is a bug in linemap: please report it with the command you ran; --verbose shows details)"
        )
        raise SystemExit(3) from None


if __name__ == "__main__":
    main()
