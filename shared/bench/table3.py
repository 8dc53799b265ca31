"""The paper's Table 3 on the simulated world: area error of the map for CJ / HT / SVD x k-means / FCM x
50 / 60 / 70 clusters (spatial-domain clustering, §6.2.1).

The paper clusters the whole run's noise-free data; here each configuration runs the pipeline in offline
mode over the whole simulated run (N_smax = every scan), so DBSCAN, the clustering and the straight-line
kernel each see all the data once, with the poses the pipeline estimated.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from shared.metrics import MapLeakError, area_error_pct, line_accuracy
from shared.pipeline import KernelChoice, Mode, Pipeline, PipelineConfig
from shared.sim import SimRun, default_world, simulate_run

__all__ = ["PAPER_TABLE3", "Table3Row", "offline_area", "run_table3"]

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
    """One configuration: area error (None when the map does not close), line accuracy, the paper's value."""

    clustering: str
    lines: str
    clusters: int
    area_error_pct: float | None
    mean_error_m: float
    completeness: float
    paper_pct: float


def run_table3(
    seed: int = 0,
    progress: Callable[[str], None] | None = None,
    only: list[tuple[str, str, int]] | None = None,
) -> list[Table3Row]:
    """Map the default simulated world once per configuration (18 runs, or the ``only`` ones)."""
    world = default_world()
    run = simulate_run(world, seed=seed)
    rows: list[Table3Row] = []
    for (clustering, lines, k), paper in PAPER_TABLE3.items():
        if only is not None and (clustering, lines, k) not in only:
            continue
        if progress is not None:
            progress(f"{clustering} / {lines} / {k} clusters")
        rows.append(offline_area(run, clustering, lines, k, paper))
    return rows


def offline_area(run: SimRun, clustering: str, lines: str, k: int, paper: float = float("nan")) -> Table3Row:
    """One configuration of Table 3 on ``run``: offline over the whole run, then area error and line
    accuracy against ``run.world``. O(scans x step)."""
    world = run.world
    cfg = PipelineConfig(
        mode=Mode.OFFLINE,
        n_smax=len(run.scans),
        heading_flush_deg=360.0,
        clustering=KernelChoice(name=clustering, params={"n_clusters": k}),
        straight_line=KernelChoice(name=lines),
    )
    pipe = Pipeline(cfg, laser_offset=run.drive.laser_offset)
    for scan in run.scans:
        pipe.step(scan)
    pipe.flush()
    snap = pipe.snapshot()
    try:
        area: float | None = area_error_pct(snap.segments, world.floor_area_m2, snap.trajectory[:, 1:3])
    except MapLeakError:
        area = None
    acc = line_accuracy(snap.segments, world.walls)
    return Table3Row(clustering, lines, k, area, acc.mean_distance_m, acc.completeness, paper)
