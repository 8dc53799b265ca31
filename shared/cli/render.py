"""Rich tables for the CLI: the kernel catalogue and the benchmark figures (with their targets)."""

from __future__ import annotations

from typing import Any

import numpy as np
from rich.table import Table

from shared.bench.kernels import BenchReport
from shared.kernels import KernelInfo
from shared.mapping import MapRun
from shared.pipeline import MapSnapshot
from shared.sim import World
from shared.types import FloatArray

__all__ = [
    "TARGETS",
    "accuracy_table",
    "bench_markdown",
    "bench_tables",
    "evaluation_table",
    "kernel_markdown",
    "kernel_table",
    "param_rows",
    "run_summary",
]

#: The kernel benchmark's targets: online step median/p99 (ms), speed-up over the library chain, offline
#: batch.
TARGETS: dict[str, Any] = {
    "online_step": {"median_ms": 2.0, "p99_ms": 5.0, "ratio": 40.0},
    "offline_batch": {"median_ms": 50.0},
    "clustering/fcm (batch)": {"ratio": 30.0},
}


def param_rows(info: KernelInfo) -> list[str]:
    """One ``name = default unit (range)`` string per parameter of a kernel."""
    schema = info.cls.param_schema()
    rows = []
    for name, prop in schema.get("properties", {}).items():
        unit = f" {prop['unit']}" if "unit" in prop else ""
        bounds = []
        if "minimum" in prop:
            bounds.append(f">= {prop['minimum']}")
        if "exclusiveMinimum" in prop:
            bounds.append(f"> {prop['exclusiveMinimum']}")
        if "maximum" in prop:
            bounds.append(f"<= {prop['maximum']}")
        if "exclusiveMaximum" in prop:
            bounds.append(f"< {prop['exclusiveMaximum']}")
        if "enum" in prop:
            bounds.append("one of " + "/".join(map(str, prop["enum"])))
        rng = f" ({', '.join(bounds)})" if bounds else ""
        rows.append(f"{name} = {prop.get('default')!r}{unit}{rng}")
    return rows


def kernel_table(infos: list[KernelInfo]) -> Table:
    """The catalogue: stage, name@version, summary, parameters."""
    table = Table(title="linemap kernels", show_lines=True)
    table.add_column("stage")
    table.add_column("kernel")
    table.add_column("what it does")
    table.add_column("parameters (default, unit, range)")
    for info in infos:
        table.add_row(
            str(info.stage), f"{info.name}@{info.version}", info.summary, "\n".join(param_rows(info))
        )
    return table


def kernel_markdown(infos: list[KernelInfo]) -> str:
    """The catalogue as a Markdown table (the README's kernel catalogue is this text)."""
    lines = ["| stage | kernel | what it does | parameters (default, unit, range) |", "|---|---|---|---|"]
    for info in infos:
        params = "<br>".join(f"`{p}`" for p in param_rows(info))
        lines.append(f"| {info.stage} | `{info.name}`@{info.version} | {info.summary} | {params} |")
    return "\n".join(lines) + "\n"


def _fmt(value: float | None, digits: int = 3) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def _verdict(key: str, median: float, p99: float, ratio: float | None) -> str:
    """Each target of ``key`` with a green check or a red cross."""
    target = TARGETS.get(key, {})
    checks = []
    if "median_ms" in target:
        checks.append((f"median <= {target['median_ms']:g} ms", median <= target["median_ms"]))
    if "p99_ms" in target:
        checks.append((f"p99 <= {target['p99_ms']:g} ms", p99 <= target["p99_ms"]))
    if "ratio" in target:
        checks.append((f">= {target['ratio']:g}x", ratio is not None and ratio >= target["ratio"]))
    return "\n".join(f"[green]yes[/green] {text}" if ok else f"[red]no[/red]  {text}" for text, ok in checks)


def bench_markdown(report: BenchReport) -> str:
    """The figures as Markdown (for the README and closing notes)."""
    out = [
        "| kernel | data | median ms | p99 ms | library (same run) | library median ms | x faster |",
        "|---|---|---:|---:|---|---:|---:|",
    ]
    for row in report.rows:
        base = row.baseline.median_ms if row.baseline else None
        out.append(
            f"| {row.key} | {row.data} | {_fmt(row.ours.median_ms)} | {_fmt(row.ours.p99_ms)} | "
            f"{row.library or '-'} | {_fmt(base, 2)} | {_fmt(row.ratio, 1)} |"
        )
    out += ["", "| quality check (batch data) | value | target |", "|---|---:|---:|"]
    for name, q in report.quality.items():
        value = q["value"]
        text = f"{value:+.2%}" if isinstance(value, float) else str(value)
        out.append(f"| {name} | {text} | {q['target']} |")
    return "\n".join(out) + "\n"


def bench_tables(report: BenchReport) -> list[Table]:
    """The figures as two tables: timings, then quality against the libraries."""
    timings = Table(title="kernel benchmark: median / p99 ms on one core; library timed in the same run")
    for col in ("kernel", "data", "median ms", "p99 ms", "library", "lib median ms", "x faster", "target"):
        timings.add_column(col, justify="right" if "ms" in col or col == "x faster" else "left")
    for row in report.rows:
        timings.add_row(
            row.key,
            row.data,
            _fmt(row.ours.median_ms),
            _fmt(row.ours.p99_ms),
            row.library or "-",
            _fmt(row.baseline.median_ms if row.baseline else None, 2),
            _fmt(row.ratio, 1),
            _verdict(row.key, row.ours.median_ms, row.ours.p99_ms, row.ratio),
        )
    quality = Table(title="quality against the libraries (batch data)")
    quality.add_column("check")
    quality.add_column("value", justify="right")
    quality.add_column("target", justify="right")
    for name, q in report.quality.items():
        value = q["value"]
        text = f"{value:+.4%}" if isinstance(value, float) else str(value)
        quality.add_row(name, text, str(q["target"]))
    return [timings, quality]


def run_summary(name: str, run: MapRun) -> Table:
    """One mapping run in figures."""
    snap = run.snapshot
    table = Table(title=f"map of {name}", show_header=False)
    table.add_column("what")
    table.add_column("value", justify="right")
    length = float(
        np.hypot(snap.segments[:, 2] - snap.segments[:, 0], snap.segments[:, 3] - snap.segments[:, 1]).sum()
    )
    rows = [
        ("scans", f"{run.scans:,}"),
        ("throughput (reading included)", f"{run.scans_per_s:,.0f} scans/s"),
        ("step time median / p99", f"{run.step_median_ms:.2f} / {run.step_p99_ms:.2f} ms"),
        ("scans corrected by ICP", f"{run.icp_used:,} ({100 * run.icp_used / max(run.scans, 1):.0f} %)"),
        ("walls / total length", f"{len(snap.segments):,} / {length:,.1f} m"),
        ("centroids", f"{len(snap.centroids):,}"),
        ("loop closures", f"{run.loop_closures:,}"),
    ]
    for what, value in rows:
        table.add_row(what, value)
    return table


def accuracy_table(snapshot: MapSnapshot, world: World, true_trajectory: FloatArray | None) -> Table:
    """Map accuracy against the simulated ground truth (docs/design.md §5)."""
    from shared.metrics import line_accuracy

    acc = line_accuracy(snapshot.segments, world.walls)
    table = Table(title="accuracy against the ground truth")
    for col in ("metric", "value", "target"):
        table.add_column(col, justify="left" if col == "metric" else "right")
    table.add_row("mean orthogonal error", f"{acc.mean_distance_m * 100:.2f} cm", "<= 2 cm")
    table.add_row("95th percentile orthogonal error", f"{acc.p95_distance_m * 100:.2f} cm", "")
    table.add_row("mean angle error", f"{acc.mean_angle_error_deg:.2f} deg", "")
    table.add_row("completeness (walls within 5 cm)", f"{acc.completeness * 100:.1f} %", ">= 95 %")
    table.add_row("spurious (map farther than 10 cm)", f"{acc.spurious_share * 100:.1f} %", "<= 3 %")
    if len(snapshot.trajectory):
        from shared.metrics import MapLeakError, MetricError, area_error_pct

        try:
            area = area_error_pct(snapshot.segments, world.floor_area_m2, snapshot.trajectory[:, 1:3])
            table.add_row("area error (paper Table 3)", f"{area:.2f} %", "")
        except MapLeakError:
            table.add_row("area error (paper Table 3)", "map not closed", "")
        except MetricError as exc:
            table.add_row("area error (paper Table 3)", str(exc), "")
    if (
        true_trajectory is not None
        and len(true_trajectory) == len(snapshot.trajectory)
        and len(true_trajectory)
    ):
        err = np.hypot(*(true_trajectory[:, 1:3] - snapshot.trajectory[:, 1:3]).T)
        table.add_row("pose error mean / max", f"{err.mean() * 100:.1f} / {err.max() * 100:.1f} cm", "")
    return table


def evaluation_table(figures: dict[str, Any]) -> Table:
    """The figures of ``linemap eval``."""
    table = Table(title=f"evaluation of {figures['map']} ({figures['segments']} segments)")
    table.add_column("measure")
    table.add_column("value", justify="right")
    acc = figures.get("line_accuracy")
    if acc:
        table.add_row(
            "mean / p95 orthogonal error",
            f"{acc['mean_distance_m'] * 100:.2f} / {acc['p95_distance_m'] * 100:.2f} cm",
        )
        table.add_row("mean angle error", f"{acc['mean_angle_error_deg']:.2f} deg")
        table.add_row("completeness (within 5 cm)", f"{acc['completeness'] * 100:.1f} %")
        table.add_row("spurious (beyond 10 cm)", f"{acc['spurious_share'] * 100:.1f} %")
    if "area_error_pct" in figures:
        value = figures["area_error_pct"]
        table.add_row("area error", "map not closed" if value is None else f"{value:.2f} %")
    rel = figures.get("relation_error")
    if rel:
        table.add_row(
            "relation error, translation", f"{rel['trans_mean_m']:.3f} +- {rel['trans_std_m']:.3f} m"
        )
        table.add_row(
            "relation error, rotation", f"{rel['rot_mean_deg']:.2f} +- {rel['rot_std_deg']:.2f} deg"
        )
        table.add_row("relations used / unmatched", f"{rel['used']} / {rel['unmatched']}")
    return table
