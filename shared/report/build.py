"""``linemap report``: run every experiment and write ``report.md`` with its tables and PNG figures.

:class:`ReportSettings` fixes everything a rerun needs (seeds, step counts, which logs); the report's
header states them with the versions of linemap and the libraries, so a reader can regenerate it with the
command it prints. ``quick`` is a small version for tests (one seed, few configurations, short runs; the
scenario suite's ``--quick`` subset). Beside ``report.md`` the scenario suite's section is also written as
``worlds.md`` (the file the README cites); :func:`run_worlds_report` writes only that (a few minutes).
"""

from __future__ import annotations

import platform
import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path
from typing import TypeVar

from shared.bench.laps import LapsRun, run_laps_suite
from shared.bench.table3 import Table3Row
from shared.report import experiments as ex
from shared.report.laps import LAPS_PNG, plot_position_error
from shared.report.markdown import write_markdown
from shared.report.plots import plot_area_sweep, plot_maps, plot_suite_grid, plot_timing
from shared.report.suite import GRID_PNG, SuiteRun, run_suite, suite_document
from shared.report.worlds import cluttered_world

__all__ = ["ReportResults", "ReportSettings", "run_report", "run_worlds_report"]

#: The scenario suite's section as a file of its own, beside the report.
WORLDS_MD = "worlds.md"

_T = TypeVar("_T")


@dataclass(frozen=True)
class ReportSettings:
    """What the report runs. ``data``: the benchmark logs' folder (skipped when missing)."""

    seeds: tuple[int, ...] = (0, 1, 2)
    counts: tuple[int, ...] = (30, 40, 50, 60, 70)
    lines: tuple[str, ...] = ("centroid-join", "hough", "svd")
    timing_steps: tuple[int, ...] = (400, 4000)
    timing_log: str | None = "aces"
    logs: tuple[str, ...] = ("aces", "fr079", "mit")
    ekf_log_max_scans: int | None = None
    noise_every: int = 5
    data: Path | None = None
    quick: bool = False

    @classmethod
    def quick_run(cls, data: Path | None = None) -> ReportSettings:
        """A minute-long version for tests: one seed, SVD only, short timing runs, the smallest log."""
        return cls(
            seeds=(0,),
            counts=(50, 70),
            lines=("svd",),
            timing_steps=(100, 400),
            timing_log=None,
            logs=("mit",),
            ekf_log_max_scans=0,
            noise_every=25,
            data=data,
            quick=True,
        )


@dataclass(frozen=True)
class ReportResults:
    settings: ReportSettings
    area: list[Table3Row]
    timing: list[ex.TimingRun]
    accuracy: list[ex.AccuracyRow]
    logs: list[ex.LogRow]
    noise: list[ex.NoiseRow]
    seconds: float
    versions: dict[str, str]
    started: str
    sections_s: dict[str, float]
    suite: SuiteRun | None = None
    laps: tuple[LapsRun, ...] = ()


def _versions() -> dict[str, str]:
    out = {"python": platform.python_version(), "machine": f"{platform.machine()}, {platform.system()}"}
    for dist in ("linemap", "numpy", "scipy", "scikit-learn", "numba", "matplotlib"):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist] = "not installed"
    out["commit"] = _commit()
    return out


def _commit() -> str:
    """The checkout's commit (short hash, ``+`` if it has local changes), or ``unknown`` outside git."""
    import subprocess

    here = Path(__file__).resolve().parent
    try:
        head = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=here, capture_output=True, text=True, timeout=10
        )
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=here, capture_output=True, text=True, timeout=10,
        )  # fmt: skip
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    if head.returncode != 0:
        return "unknown"
    return head.stdout.strip() + ("+" if dirty.stdout.strip() else "")


def run_report(out: Path, settings: ReportSettings, progress: Callable[[str], None] | None = None) -> Path:
    """Run the experiments of ``settings``, write ``out/report.md`` and its figures; returns the report's
    path. Several minutes for the full settings on a 2-core machine."""
    say = progress or (lambda _m: None)
    out.mkdir(parents=True, exist_ok=True)
    started = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    t0 = time.perf_counter()
    sections: dict[str, float] = {}

    def timed(name: str, fn: Callable[[], _T]) -> _T:
        start = time.perf_counter()
        result = fn()
        sections[name] = time.perf_counter() - start
        return result

    s = settings
    area = timed("Table 3 / Fig. 19", lambda: ex.area_sweep(s.seeds, s.counts, s.lines, say))
    timing_log = s.data / ex.LOGS[s.timing_log].log if s.data and s.timing_log else None
    timing = timed("Fig. 24", lambda: ex.timing_runs(s.timing_steps, s.seeds[0], timing_log, say))
    accuracy = timed("simulated accuracy", lambda: ex.sim_accuracy(s.seeds, say))
    suite = timed("scenario suite", lambda: run_suite(s.seeds, quick=s.quick, progress=say))
    data = s.data
    logs = (
        timed("benchmark logs", lambda: ex.log_accuracy(data, s.logs, s.ekf_log_max_scans, say))
        if data is not None and data.is_dir()
        else []
    )
    noise = timed("noise removal", lambda: ex.noise_removal(s.seeds[0], s.noise_every, say))
    laps = timed(
        "multi-lap worlds",
        lambda: run_laps_suite(
            s.seeds[:1] if s.quick else s.seeds,
            2 if s.quick else 3,
            progress=lambda label, _done, _total: say(f"multi-lap: {label}"),
        ),
    )
    say("figures")
    plot_area_sweep(area, out / "fig19_area_vs_clusters.png")
    plot_timing(timing, out / "fig24_time_per_step.png")
    plot_position_error(laps, out / LAPS_PNG)
    plot_maps(accuracy, cluttered_world().walls, "cluttered", settings.seeds[0], out / "maps_cluttered.png")
    _write_suite(out, suite, _command(s, worlds_only=False), started)
    results = ReportResults(
        settings,
        area,
        timing,
        accuracy,
        logs,
        noise,
        time.perf_counter() - t0,
        _versions(),
        started,
        sections,
        suite,
        tuple(laps),
    )
    path = out / "report.md"
    path.write_text(write_markdown(results), encoding="utf-8")
    return path


def _command(s: ReportSettings, *, worlds_only: bool) -> str:
    """The ``linemap report`` command line that reruns ``s``."""
    args = ["linemap report", *(["--worlds-only"] if worlds_only else [])]
    args.append("--quick" if s.quick else f"--seeds {','.join(map(str, s.seeds))}")
    return " ".join(args)


def _write_suite(out: Path, suite: SuiteRun, command: str, started: str) -> Path:
    """The suite's grid of maps and ``worlds.md`` in ``out``; returns the Markdown file's path."""
    plot_suite_grid(suite, out / GRID_PNG)
    path = out / WORLDS_MD
    path.write_text(suite_document(suite, command, started, _versions()), encoding="utf-8")
    return path


def run_worlds_report(
    out: Path, settings: ReportSettings, progress: Callable[[str], None] | None = None
) -> Path:
    """Only the scenario suite's section: ``out/worlds.md`` and its grid of maps (``report.md`` is left
    alone); returns the Markdown file's path. A few minutes for the whole suite on a 2-core machine."""
    out.mkdir(parents=True, exist_ok=True)
    started = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    suite = run_suite(settings.seeds, quick=settings.quick, progress=progress)
    (progress or (lambda _m: None))("figures")
    return _write_suite(out, suite, _command(settings, worlds_only=True), started)
