"""The multi-lap section of the report and of ``linemap bench laps``: the map after each lap, the
position error over time (the paper's Fig. 20) and the time of each optimisation, front end alone and with
loop closure (:mod:`shared.bench.laps`)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from shared.bench.laps import LapsRun
from shared.bench.tables import markdown_table

__all__ = [
    "LAPS_COLUMNS",
    "LAPS_PNG",
    "laps_markdown",
    "laps_rows",
    "laps_section",
    "laps_timing_line",
    "plot_position_error",
]

#: the report's picture of the position error over time
LAPS_PNG = "fig20_position_error.png"

LAPS_COLUMNS = (
    ("world", False),
    ("seed", True),
    ("mapped by", False),
    ("lap", True),
    ("mean cm", True),
    ("p95 cm", True),
    ("complete %", True),
    ("spurious %", True),
    ("walls / seen", True),
    ("ATE m", True),
    ("on target", False),
)


def _f(value: float, scale: float = 1.0, digits: int = 1) -> str:
    return "n/a" if not math.isfinite(value) else f"{value * scale:.{digits}f}"


def laps_rows(runs: Sequence[LapsRun]) -> list[list[str]]:
    """One row per run and lap (the map as the robot showed it at that lap's end)."""
    return [
        [
            r.kind,
            str(r.seed),
            r.variant,
            str(f.lap),
            _f(f.mean_error_m, 100, 2),
            _f(f.p95_error_m, 100, 2),
            _f(f.completeness, 100),
            _f(f.spurious_share, 100),
            f"{f.walls_mapped} / {f.walls_seen}",
            _f(f.ate_m, 1, 3),
            "yes" if f.meets_targets() else "no",
        ]
        for r in runs
        for f in r.laps
    ]


def _stats(values: Sequence[float]) -> str:
    if not values:
        return "none"
    a = np.asarray(values, dtype=np.float64)
    return f"{len(a)}, median {np.median(a):.1f} ms, p95 {np.percentile(a, 95):.1f} ms, max {a.max():.1f} ms"


def laps_timing_line(runs: Sequence[LapsRun]) -> str:
    """The optimisations' and redraws' times over every run with loop closure, and the steps'."""
    loop = [r for r in runs if r.variant == "loop closure"]
    front = [r for r in runs if r.variant == "front end"]
    opt = [t for r in loop for t in r.optimise_ms]
    redraw = [t for r in loop for t in r.redraw_ms]
    closures = sum(r.closures for r in loop)

    def step(rs: Sequence[LapsRun]) -> str:
        steps = [t for r in rs for t in r.step_ms]
        return f"{np.median(steps):.2f} ms" if steps else "n/a"

    return (
        f"loop closures {closures}; pose-graph optimisations {_stats(opt)}; map redraws {_stats(redraw)}; "
        f"step median {step(front)} front end alone, {step(loop)} with loop closure (search and redraws "
        "in the step here; on the robot they run on a worker thread)"
    )


def laps_markdown(runs: Sequence[LapsRun], picture: str | None = None) -> str:
    """The table, the timing line and the picture's link as Markdown."""
    lines = [markdown_table(LAPS_COLUMNS, laps_rows(runs)).rstrip("\n"), "", laps_timing_line(runs) + "."]
    if picture:
        lines += ["", f"![position error over time]({picture})"]
    return "\n".join(lines) + "\n"


def laps_section(runs: Sequence[LapsRun]) -> list[str]:
    """The report's section (lines of Markdown)."""
    if not runs:
        return []
    laps = len(runs[0].laps)
    return [
        "## Multi-lap worlds: loop closure over time",
        "",
        f"A loop of corridors round a block (42-62 m a lap) driven {laps} times with worn-wheel odometry (a "
        "scale and heading bias), mapped one scan at a time as the robot maps it: by the front end alone and "
        "under the keyframe pose graph (`linemap bench laps`). Each row is the map the robot showed at the "
        "end of that lap; ATE is the RMS error of the positions it believed at each step so far (Fig. 20 "
        "below: the same error over time).",
        "",
        laps_markdown(runs, LAPS_PNG).rstrip("\n"),
        "",
    ]


def plot_position_error(runs: Sequence[LapsRun], path: Path) -> Path:
    """Position error over time (Fig. 20): per world and seed, the distance between the position the robot
    believed at each step and the true one, front end alone and with loop closure, raw odometry's faint on a
    second axis; lap ends dotted."""
    from shared.report.plots import _plt

    plt = _plt()
    keys = sorted({(r.kind, r.seed) for r in runs})
    fig, axes = plt.subplots(len(keys), 1, figsize=(9, 2.8 * max(1, len(keys))), dpi=110, squeeze=False)
    colours = {"front end": "#1f77b4", "loop closure": "#2ca02c"}
    for ax, (kind, seed) in zip(axes[:, 0], keys, strict=True):
        mine = [r for r in runs if (r.kind, r.seed) == (kind, seed)]
        for r in mine:
            ax.plot(
                r.stamps_s,
                r.position_error_m * 100,
                color=colours.get(r.variant, "k"),
                lw=1.0,
                label=f"{r.variant} (ATE {r.laps[-1].ate_m * 100:.1f} cm)",
            )
        for t in mine[0].lap_end_s[:-1]:
            ax.axvline(t, color="grey", ls=":", lw=0.8)
        twin = ax.twinx()
        twin.plot(mine[0].stamps_s, mine[0].odometry_error_m, color="#d62728", alpha=0.35, lw=0.8)
        twin.set_ylabel("odometry error (m, red)", color="#d62728", fontsize=8)
        ax.set_ylabel("position error (cm)")
        ax.set_title(f"{kind} seed {seed}: {len(mine[0].laps)} laps (lap ends dotted)", fontsize=9)
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="upper left")
    axes[-1, 0].set_xlabel("time (s)")
    fig.suptitle("Position error over time (Fig. 20): the pose the robot believed at each step", fontsize=10)
    fig.tight_layout(rect=(0.0, 0.0, 1.0, 1.0 - 0.25 / max(1, len(keys))))
    fig.savefig(path)
    plt.close(fig)
    return path
