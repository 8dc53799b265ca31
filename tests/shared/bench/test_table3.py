"""The paper's Table 3 on the simulated world: the map closes and its area is within 1 %."""

from __future__ import annotations

import numpy as np
import pytest

from shared.bench.table3 import PAPER_TABLE3, run_table3
from shared.sim import SimRun, default_world, simulate_run
from shared.sim.scans import ray_wall_hits
from shared.types import Pose2D


def _faces_seen(run: SimRun) -> np.ndarray:
    """Which true walls some beam of the run hits first (ray-cast from every true scanner pose, in range)."""
    walls = run.world.walls
    seen = np.zeros(len(walls), dtype=bool)
    offset = run.drive.laser_offset
    for (_, x, y, th), scan in zip(run.trajectory("true"), run.scans, strict=True):
        laser = Pose2D(x, y, th) @ offset
        angles = scan.angle_min_rad + scan.angle_increment_rad * np.arange(
            len(scan.ranges_m), dtype=np.float64
        )
        dist, _ = ray_wall_hits(walls, (laser.x_m, laser.y_m), angles + laser.theta_rad)
        first = dist.argmin(axis=1)
        seen[first[dist.min(axis=1) <= scan.range_max_m]] = True
    return seen


def test_the_default_drive_never_sees_the_underside_of_the_first_box() -> None:
    """Why the area error below is taken against the mappable floor: box A's face at y = 1.2 m faces the
    wall at y = 0 and the drive passes below it only at x = 9 m, 6.2 m away (the URG-04LX reaches
    5.6 m). No map can draw that face, so the box's 0.64 m^2 (1.4 % of the floor) is floor to any map;
    a map that closed the box would have drawn a wall it never saw."""
    run = simulate_run(default_world(), seed=0)
    seen = _faces_seen(run)
    assert seen.tolist() == [True] * 8 + [False] + [True] * 7  # wall 8: box A's face at y = 1.2 m


@pytest.mark.parametrize(
    "config", [("kmeans", "centroid-join", 50), ("fcm", "svd", 60), ("kmeans", "hough", 70)]
)
def test_area_error_within_one_percent(config: tuple[str, str, int]) -> None:
    (row,) = run_table3(only=[config])
    assert row.paper_pct == PAPER_TABLE3[config]
    assert row.area_error_pct is not None, "the map must close around the trajectory"
    # against the floor the drive lets a map enclose: the true floor plus box A, whose underside it never
    # sees (previous test); against the true floor alone the error is that box's 1.4 % plus the map's own
    assert row.map_area_m2 is not None
    mappable = default_world().floor_area_m2 + 0.8 * 0.8
    assert 100.0 * abs(row.map_area_m2 - mappable) / mappable <= 1.0
    assert row.completeness >= 0.95


def test_shared_steps_give_the_map_of_a_pipeline_built_for_the_configuration() -> None:
    """offline_areas steps once and copies the pipeline per configuration: the same map as a pipeline
    made for that configuration from the start (N_smax = every scan, as the paper's batch)."""
    import numpy as np

    from shared.bench.table3 import offline_areas
    from shared.metrics import area_error_pct
    from shared.pipeline import KernelChoice, Mode, Pipeline, PipelineConfig
    from shared.sim import default_world, simulate_run

    run = simulate_run(default_world(), seed=2)
    configs = [("fcm", "hough", 50), ("kmeans", "svd", 70)]
    rows = offline_areas(run, configs)
    for (clustering, lines, k), row in zip(configs, rows, strict=True):
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
        assert (row.clustering, row.lines, row.clusters) == (clustering, lines, k)
        assert row.paper_pct == PAPER_TABLE3[(clustering, lines, k)]
        assert np.isfinite(snap.segments).all() and len(snap.segments) > 0
        area = area_error_pct(snap.segments, run.world.floor_area_m2, snap.trajectory[:, 1:3])
        assert row.area_error_pct == area
