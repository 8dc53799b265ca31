"""The paper's Table 3 on the simulated world: the map closes and its area is within 1 %."""

from __future__ import annotations

import pytest

from shared.bench.table3 import PAPER_TABLE3, run_table3


@pytest.mark.parametrize(
    "config", [("kmeans", "centroid-join", 50), ("fcm", "svd", 60), ("kmeans", "hough", 70)]
)
def test_area_error_within_one_percent(config: tuple[str, str, int]) -> None:
    (row,) = run_table3(only=[config])
    assert row.paper_pct == PAPER_TABLE3[config]
    assert row.area_error_pct is not None, "the map must close around the trajectory"
    assert row.area_error_pct <= 1.0
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
