"""The suite's measurement: a perfect map scores perfectly on every kind; a real run gives sane figures."""

from __future__ import annotations

import math

import numpy as np
import pytest

from shared.bench.worlds import WorldResult, measure_map, run_case, summarize
from shared.sim.worlds import KINDS, simulate_case


@pytest.mark.parametrize("kind", list(KINDS))
def test_the_ground_truth_fed_as_the_map_scores_perfectly(kind: str) -> None:
    case = simulate_case(kind, 1, max_scans=60)
    figures = measure_map(case, case.truth.walls, case.run.trajectory("true"))
    assert figures["mean_error_m"] == pytest.approx(0.0, abs=1e-12)
    assert figures["p95_error_m"] == pytest.approx(0.0, abs=1e-12)
    assert figures["completeness"] == 1.0
    assert figures["spurious_share"] == 0.0
    assert figures["ate_m"] == 0.0
    assert figures["walls_mapped"] == len(case.truth.walls) >= figures["walls_seen"]


def test_a_map_off_by_a_known_shift_scores_that_shift() -> None:
    case = simulate_case("corridor-long", 0, max_scans=30)
    walls = case.truth.walls
    long_walls = walls[np.abs(walls[:, 1] - walls[:, 3]) < 1e-9]  # the two along the corridor
    shifted = long_walls + np.array([0.0, 0.03, 0.0, 0.03])
    figures = measure_map(case, shifted, case.run.trajectory("true")[:10])
    # 3 cm, less a little near the end walls, which are nearer than 3 cm there
    assert figures["mean_error_m"] == pytest.approx(0.03, abs=1e-4)
    assert figures["spurious_share"] == 0.0 and math.isnan(figures["ate_m"])  # 10 poses of 30: no ATE
    far = measure_map(case, long_walls + np.array([0.0, 0.2, 0.0, 0.2]), case.run.trajectory("true"))
    assert far["spurious_share"] > 0.95 and far["completeness"] < 0.5  # but the ends, near the end walls


def test_mapping_a_short_case_gives_figures_in_range() -> None:
    result, mapped = run_case(simulate_case("lab-clutter", 0, odometry="perfect", max_scans=60))
    assert result.scans == 60 == len(mapped.snapshot.trajectory)
    assert 0.0 <= result.completeness <= 1.0 and 0.0 <= result.spurious_share <= 1.0
    assert result.mean_error_m < 0.05 and result.odometry_ate_m < 0.01
    assert result.walls_mapped == len(mapped.snapshot.segments) and result.scans_per_s > 0


def _result(kind: str, mean: float, complete: float, spurious: float, mapped: int) -> WorldResult:
    return WorldResult(
        kind, 0, "slip", "single", 100, mean, 2 * mean, complete, spurious, mapped, 10, 0.1, 0.2, 300.0, 2.0
    )


def test_the_summary_row_averages_and_counts_cases_on_target() -> None:
    rows = [_result("a", 0.01, 0.97, 0.01, 12), _result("b", 0.03, 0.90, 0.05, 30)]
    s = summarize(rows)
    assert s["cases"] == 2 and s["cases_meeting_targets"] == 1
    assert s["mean_error_m"] == pytest.approx(0.02) and s["worst_mean_error_m"] == pytest.approx(0.03)
    assert s["worst_completeness"] == pytest.approx(0.90) and s["wall_ratio"] == pytest.approx(2.1)
    assert summarize([]) == {"cases": 0}
