"""The report's experiments, each a function from settings to a frozen result; no I/O but the
benchmark logs they read. Seeds are explicit, so a rerun gives the same maps (times differ).

- :func:`area_sweep`: Table 3 and Fig. 19 (area error against cluster count, offline, §6.2.1);
- :func:`timing_runs`: Fig. 24 (time per step against step number, linemap and the EKF, same scans);
- :func:`sim_accuracy`: line accuracy and pose error on simulated worlds, linemap against the EKF;
- :func:`log_accuracy`: relation error on the SLAM benchmark logs, linemap against the EKF;
- :func:`noise_removal`: each noise-removal kernel on the same noisy scans, outliers removed / points kept.
"""

from __future__ import annotations

import functools
import itertools
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from shared.bench.table3 import Table3Row, offline_areas
from shared.kernels import REGISTRY
from shared.metrics import LineAccuracy, RelationError, line_accuracy, read_relations, relation_error
from shared.metrics.distance import nearest_segment
from shared.report.runs import MapRun, run_ekf, run_linemap, run_linemap_loop
from shared.report.worlds import CLUTTER_NOISE, cluttered_world
from shared.sim import RangeNoise, World, default_world, patrol_lap_steps, patrol_scans, simulate_run
from shared.types import Pose2D, Scan

__all__ = [
    "LOGS",
    "AccuracyRow",
    "LogRow",
    "LogSpec",
    "NoiseRow",
    "TimingRun",
    "area_sweep",
    "log_accuracy",
    "noise_removal",
    "sim_accuracy",
    "timing_runs",
]

Progress = Callable[[str], None]


def _quiet(_msg: str) -> None:
    return None


def _prefixed(progress: Progress, prefix: str, msg: str) -> None:
    progress(prefix + msg)


def area_sweep(
    seeds: tuple[int, ...],
    counts: tuple[int, ...] = (30, 40, 50, 60, 70),
    lines: tuple[str, ...] = ("centroid-join", "hough", "svd"),
    progress: Progress = _quiet,
) -> list[Table3Row]:
    """Area error of the default world mapped offline for every clustering x line method x cluster count
    x seed (the paper's Table 3 cells are the counts 50/60/70). O(configurations x scans x step)."""
    rows = []
    for seed in seeds:
        run = simulate_run(default_world(), seed=seed)
        configs = list(itertools.product(("kmeans", "fcm"), lines, counts))
        rows += offline_areas(run, configs, functools.partial(_prefixed, progress, f"area: seed {seed}, "))
    return rows


@dataclass(frozen=True)
class TimingRun:
    """Both mappers on the same ``steps`` scans of ``source``."""

    source: str
    steps: int
    linemap: MapRun
    ekf: MapRun
    lap_steps: int | None = None  # a patrol: steps of a later lap (step i is where step i - lap_steps was)


def timing_runs(
    steps: tuple[int, ...] = (400, 4000),
    seed: int = 0,
    log: Path | None = None,
    progress: Progress = _quiet,
) -> list[TimingRun]:
    """Time per step of linemap and the EKF on the same scans: ``steps`` scans of the simulated robot
    patrolling the default world out and back (long runs see the same walls again), and, when ``log`` is
    given, the first ``max(steps)`` scans of that benchmark log (a large building: the EKF keeps adding
    landmarks, as in the paper's Fig. 24). O(steps x step)."""
    world = default_world()
    offset = simulate_run(world, seed=seed).drive.laser_offset
    sources: list[tuple[str, list[Scan], Pose2D | None, int | None]] = []
    longest = list(itertools.islice(patrol_scans(world, seed=seed), max(steps)))
    lap = patrol_lap_steps(world)[1]
    for n in steps:
        sources.append(("simulated patrol", longest[:n], offset, lap))
    if log is not None and log.is_file():
        scans, log_offset = _log_scans(log, max(steps))
        sources.append((log.name.split(".")[0].upper(), scans, log_offset, None))
    out = []
    for source, scans, off, lap_steps in sources:
        progress(f"timing: {source}, {len(scans):,} steps, linemap")
        ours = run_linemap(scans, off)
        progress(f"timing: {source}, {len(scans):,} steps, EKF-SLAM")
        ekf = run_ekf(scans, off)
        out.append(TimingRun(source, len(scans), ours, ekf, lap_steps))
    return out


@dataclass(frozen=True)
class AccuracyRow:
    """One mapper on one simulated world and seed: line accuracy and pose error against the truth."""

    world: str
    seed: int
    method: str
    accuracy: LineAccuracy
    pose_error_mean_m: float
    pose_error_max_m: float
    step_ms_median: float
    run: MapRun


def sim_accuracy(seeds: tuple[int, ...], progress: Progress = _quiet) -> list[AccuracyRow]:
    """linemap and the EKF on the default world (5 % outliers) and the cluttered one (10 %)."""
    rows = []
    worlds: list[tuple[World, RangeNoise]] = [
        (default_world(), RangeNoise()),
        (cluttered_world(), CLUTTER_NOISE),
    ]
    for (world, noise), seed in itertools.product(worlds, seeds):
        run = simulate_run(world, seed=seed, noise=noise)
        truth = np.array([p.as_tuple() for p in run.true_poses])
        for method, mapper in (("linemap", run_linemap), ("ekf-slam", run_ekf)):
            progress(f"accuracy: {world.name} world, seed {seed}, {method}")
            mapped = mapper(run.scans, run.drive.laser_offset)
            err = np.hypot(*(mapped.poses[:, :2] - truth[:, :2]).T)
            rows.append(
                AccuracyRow(
                    world.name,
                    seed,
                    method,
                    line_accuracy(mapped.segments, world.walls),
                    float(err.mean()),
                    float(err.max()),
                    float(np.median(mapped.step_ms[1:])),
                    mapped,
                )
            )
    return rows


@dataclass(frozen=True, slots=True)
class LogSpec:
    """A benchmark log under the data folder, its relations, and the published figures (m, mean / std):
    incremental scan matching, RBPF (GMapping), graph mapping (Kümmerle et al. 2009)."""

    title: str
    log: str
    relations: str
    published: dict[str, tuple[float, float]]


LOGS: dict[str, LogSpec] = {
    "aces": LogSpec(
        "ACES", "aces/aces.clf.gz", "aces/aces.relations",
        {"scan matching": (0.173, 0.614), "RBPF": (0.060, 0.049), "graph mapping": (0.044, 0.044)},
    ),
    "fr079": LogSpec(
        "Freiburg 079", "fr079/fr079.clf.gz", "fr079/fr079.relations",
        {"scan matching": (0.258, 0.427), "RBPF": (0.061, 0.044), "graph mapping": (0.056, 0.042)},
    ),
    "mit": LogSpec(
        "MIT CSAIL", "mit-csail/mit-csail.clf.gz", "mit-csail/mit-csail.relations",
        {"scan matching": (0.106, 0.325), "RBPF": (0.049, 0.049), "graph mapping": (0.004, 0.009)},
    ),
}  # fmt: skip


@dataclass(frozen=True)
class LogRow:
    """One mapper on one log: relation error (None if it did not run), scans, median step time."""

    log: str
    method: str
    scans: int
    relation: RelationError | None
    step_ms_median: float
    note: str = ""


def _log_scans(path: Path, limit: int | None = None) -> tuple[list[Scan], Pose2D | None]:
    from shared.io import open_log

    with open_log(path) as reader:
        return list(itertools.islice(reader, limit)), reader.info.laser_offset


def log_accuracy(
    data: Path,
    logs: tuple[str, ...] = tuple(LOGS),
    ekf_max_scans: int | None = None,
    progress: Progress = _quiet,
) -> list[LogRow]:
    """Relation error of linemap and the EKF on each log present under ``data``; the EKF only if the log
    has at most ``ekf_max_scans`` scans (None: always). Logs that are missing are skipped."""
    rows = []
    for name in logs:
        spec = LOGS[name]
        if not (data / spec.log).is_file():
            continue
        scans, offset = _log_scans(data / spec.log)
        relations = read_relations(data / spec.relations)
        methods = (
            ("linemap", run_linemap),
            ("linemap + loop closure", run_linemap_loop),
            ("ekf-slam", run_ekf),
        )
        for method, mapper in methods:
            if method == "ekf-slam" and ekf_max_scans is not None and len(scans) > ekf_max_scans:
                rows.append(
                    LogRow(
                        spec.title, method, len(scans), None, math.nan, f"not run (> {ekf_max_scans} scans)"
                    )
                )
                continue
            progress(f"logs: {spec.title}, {method} ({len(scans):,} scans)")
            mapped = mapper(scans, offset)
            rel = relation_error(mapped.stamps_s, mapped.poses, relations)
            rows.append(LogRow(spec.title, method, len(scans), rel, float(np.median(mapped.step_ms[1:]))))
    return rows


#: The noise-removal kernels compared: (label, kernel, parameters).
ELEMENTS = ("DENSEx3", "PLUSx4", "PLUSx8", "STARx8")
NOISE_KERNELS: tuple[tuple[str, str, dict[str, Any]], ...] = (
    ("DBSCAN (eps 5 cm, minpts 3)", "dbscan", {}),
    *((f"erosion {e}", "erosion", {"element": e}) for e in ELEMENTS),
    *((f"opening {e}", "opening", {"element": e}) for e in ELEMENTS),
)


@dataclass(frozen=True, slots=True)
class NoiseRow:
    """A noise-removal kernel on the same points: share of outlier points removed, of true points kept.
    ``scans``: how many consecutive scans were stacked (world frame) before the kernel ran."""

    world: str
    scans: int
    label: str
    outliers_removed: float
    true_kept: float
    outliers: int
    true_points: int


def _labelled_batches(
    world: World, noise: RangeNoise, seed: int, batch: int, every: int
) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Points of ``batch`` consecutive scans stacked in the world frame (from the true laser poses), one
    stack every ``every`` scans, and whether each point is a true wall return (within 10 cm of a wall)."""
    run = simulate_run(world, seed=seed, noise=noise)
    seg: Any = REGISTRY.create("segmentation", "abd-iepf", {"max_skip": 0, "min_points": 1})
    for start in range(0, len(run.scans) - batch + 1, every):
        stack = []
        for scan, pose in zip(
            run.scans[start : start + batch], run.true_poses[start : start + batch], strict=True
        ):
            points = seg.apply(scan).points
            laser = run.drive.laser_pose(pose)
            c, s = math.cos(laser.theta_rad), math.sin(laser.theta_rad)
            stack.append(points @ np.array([[c, s], [-s, c]]) + np.array([laser.x_m, laser.y_m]))
        xy = np.vstack(stack)
        if len(xy) == 0:
            continue
        dist, _ = nearest_segment(xy, world.walls)
        yield xy, dist <= 0.10


def noise_removal(seed: int = 0, every: int = 5, progress: Progress = _quiet) -> list[NoiseRow]:
    """Each kernel of :data:`NOISE_KERNELS` on single scans and on stacks of 9 consecutive scans (the
    paper's offline batch, N_smax = 9), every ``every``-th scan, on the default (5 % outliers) and the
    cluttered (10 %) world. O(scans x kernels)."""
    rows = []
    for world, noise in ((default_world(), RangeNoise()), (cluttered_world(), CLUTTER_NOISE)):
        for batch in (1, 9):
            progress(f"noise removal: {world.name} world, {batch} scan(s) at a time")
            data = list(
                _labelled_batches(world, noise, seed, batch, every if batch == 1 else max(every, batch))
            )
            for label, name, params in NOISE_KERNELS:
                kernel: Any = REGISTRY.create("noise-removal", name, params)
                removed = kept = n_out = n_true = 0
                for points, true in data:
                    keep = np.asarray(kernel.apply(points).keep).astype(np.bool_)
                    removed += int(np.sum(~keep & ~true))
                    kept += int(np.sum(keep & true))
                    n_out += int(np.sum(~true))
                    n_true += int(np.sum(true))
                rows.append(
                    NoiseRow(
                        world.name,
                        batch,
                        label,
                        removed / max(n_out, 1),
                        kept / max(n_true, 1),
                        n_out,
                        n_true,
                    )
                )
    return rows
