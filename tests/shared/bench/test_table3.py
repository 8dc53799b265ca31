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
