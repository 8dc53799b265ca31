"""The paper's Table 3 on the simulated world: area error of the map for CJ / HT / SVD x k-means / FCM x
50 / 60 / 70 clusters (spatial-domain clustering, §6.2.1).

The paper clusters the whole run's noise-free data; here each configuration runs the pipeline in offline
mode over the whole simulated run (N_smax = every scan), so DBSCAN, the clustering and the straight-line
kernel each see all the data once, with the poses the pipeline estimated.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

from shared.metrics import MapLeakError, line_accuracy
from shared.metrics.area import map_area_m2
from shared.pipeline import KernelChoice, Mode, Pipeline, PipelineConfig
from shared.sim import SimRun, default_world, simulate_run

__all__ = ["PAPER_TABLE3", "Table3Row", "offline_area", "offline_areas", "run_table3"]

#: Table 3 of the paper: area error in % (k-means / FCM rows, CJ / HT / SVD columns, 50 / 60 / 70 clusters).
PAPER_TABLE3: dict[tuple[str, str, int], float] = {
    ("kmeans", "centroid-join", 50): 2.917,
    ("kmeans", "hough", 50): 2.850,
    ("kmeans", "svd", 50): 2.813,
    ("kmeans", "centroid-join", 60): 2.571,
    ("kmeans", "hough", 60): 2.453,
    ("kmeans", "svd", 60): 2.438,
    ("kmeans", "centroid-join", 70): 2.176,
    ("kmeans", "hough", 70): 2.163,
    ("kmeans", "svd", 70): 2.138,
    ("fcm", "centroid-join", 50): 2.621,
    ("fcm", "hough", 50): 2.510,
    ("fcm", "svd", 50): 2.450,
    ("fcm", "centroid-join", 60): 2.240,
    ("fcm", "hough", 60): 2.215,
    ("fcm", "svd", 60): 2.188,
    ("fcm", "centroid-join", 70): 2.002,
    ("fcm", "hough", 70): 2.343,
    ("fcm", "svd", 70): 2.05,
}


@dataclass(frozen=True, slots=True)
class Table3Row:
    """One configuration: area error (None when the map does not close), line accuracy, the paper's value,
    and the area the map encloses (m^2; None when it does not close)."""

    clustering: str
    lines: str
    clusters: int
    area_error_pct: float | None
    mean_error_m: float
    completeness: float
    paper_pct: float
    map_area_m2: float | None = None


def run_table3(
    seed: int = 0,
    progress: Callable[[str], None] | None = None,
    only: list[tuple[str, str, int]] | None = None,
) -> list[Table3Row]:
    """Map the default simulated world once per configuration (18 runs, or the ``only`` ones)."""
    run = simulate_run(default_world(), seed=seed)
    configs = [c for c in PAPER_TABLE3 if only is None or c in only]
    return offline_areas(run, configs, progress)


def offline_area(run: SimRun, clustering: str, lines: str, k: int, paper: float = float("nan")) -> Table3Row:
    """One configuration of Table 3 on ``run`` (see :func:`offline_areas`); ``paper`` is carried along."""
    (row,) = offline_areas(run, [(clustering, lines, k)])
    return row if math.isnan(paper) else replace(row, paper_pct=paper)


def offline_areas(
    run: SimRun,
    configs: Sequence[tuple[str, str, int]],
    progress: Callable[[str], None] | None = None,
) -> list[Table3Row]:
    """Configurations ``(clustering, line method, clusters)`` of Table 3 on ``run``: offline over the whole
    run (one batch of every scan), then area error and line accuracy against ``run.world``.

    The steps (pose estimation, segmentation) do not depend on the clustering or the line method, so they
    run once; each configuration then takes a copy of that pipeline and runs the batch (noise removal,
    clustering, lines) under its own configuration. Gives the same map as a pipeline built for that
    configuration. O(scans x step + configurations x batch).
    """
    world = run.world
    n = len(run.scans)
    # n + 1: the batch never fills, so no stage runs until the flush, under each configuration's kernels
    base = Pipeline(
        PipelineConfig(mode=Mode.OFFLINE, n_smax=n + 1, heading_flush_deg=360.0),
        laser_offset=run.drive.laser_offset,
    )
    for scan in run.scans:
        base.step(scan)
    rows = []
    for clustering, lines, k in configs:
        if progress is not None:
            progress(f"{clustering} / {lines} / {k} clusters")
        pipe = copy.deepcopy(base)
        pipe.reconfigure(
            PipelineConfig(
                mode=Mode.OFFLINE,
                n_smax=n + 1,
                heading_flush_deg=360.0,
                clustering=KernelChoice(name=clustering, params={"n_clusters": k}),
                straight_line=KernelChoice(name=lines),
            )
        )
        pipe.flush()
        snap = pipe.snapshot()
        try:
            enclosed: float | None = map_area_m2(snap.segments, snap.trajectory[:, 1:3])
        except MapLeakError:
            enclosed = None
        area = None if enclosed is None else 100.0 * abs(enclosed - world.floor_area_m2) / world.floor_area_m2
        acc = line_accuracy(snap.segments, world.walls)
        paper = PAPER_TABLE3.get((clustering, lines, k), math.nan)
        rows.append(
            Table3Row(clustering, lines, k, area, acc.mean_distance_m, acc.completeness, paper, enclosed)
        )
    return rows
