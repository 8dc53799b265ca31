"""Line accuracy against ground-truth walls (docs/design.md §5): known answers and properties."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.errors import InvalidInputError
from shared.metrics import LineAccuracy, MetricInputError, line_accuracy
from shared.metrics.lines import undirected_angle_diff
from shared.sim import default_world
from shared.types import FloatArray

WALL = np.array([[0.0, 0.0, 10.0, 0.0]])


def rect(x0: float, y0: float, x1: float, y1: float) -> FloatArray:
    v = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
    return np.hstack([v, np.roll(v, -1, axis=0)])


def rotate_about(segs: FloatArray, angle: float, centre: tuple[float, float]) -> FloatArray:
    c, s = math.cos(angle), math.sin(angle)
    p = segs.reshape(-1, 2) - centre
    q = np.stack([c * p[:, 0] - s * p[:, 1], s * p[:, 0] + c * p[:, 1]], axis=1) + centre
    return np.asarray(q.reshape(-1, 4))


def test_perfect_map_scores_perfectly() -> None:
    walls = default_world().walls
    acc = line_accuracy(walls, walls)
    assert acc.mean_distance_m == pytest.approx(0.0, abs=1e-12)
    assert acc.p95_distance_m == pytest.approx(0.0, abs=1e-12)
    assert acc.mean_angle_error_rad == 0.0
    assert acc.completeness == 1.0
    assert acc.spurious_share == 0.0
    assert acc.map_length_m == pytest.approx(acc.wall_length_m)
    assert (acc.n_segments, acc.n_walls) == (16, 16)


@pytest.mark.parametrize(("offset", "complete"), [(0.03, 1.0), (0.07, 0.0)])
def test_offset_map_has_that_distance(offset: float, complete: float) -> None:
    acc = line_accuracy([[0.0, offset, 10.0, offset]], WALL)
    assert acc.mean_distance_m == pytest.approx(offset, abs=1e-12)
    assert acc.p95_distance_m == pytest.approx(offset, abs=1e-12)
    assert acc.completeness == complete
    assert acc.spurious_share == 0.0
    assert acc.mean_angle_error_rad == pytest.approx(0.0, abs=1e-12)


def test_offset_beyond_spurious_limit_is_all_spurious() -> None:
    acc = line_accuracy([[0.0, -0.15, 10.0, -0.15]], WALL)
    assert acc.spurious_share == 1.0
    assert acc.completeness == 0.0
    assert acc.mean_distance_m == pytest.approx(0.15)


def test_trimmed_offset_rectangle() -> None:
    # each wall pushed out by 4 cm and trimmed 0.5 m at both ends: distance 4 cm everywhere
    d = 0.04
    segs = np.array(
        [[0.5, -d, 9.5, -d], [10 + d, 0.5, 10 + d, 3.5], [9.5, 4 + d, 0.5, 4 + d], [-d, 3.5, -d, 0.5]]
    )
    acc = line_accuracy(segs, rect(0, 0, 10, 4))
    assert acc.mean_distance_m == pytest.approx(d)
    assert acc.spurious_share == 0.0
    # covered: the trimmed spans plus sqrt(0.05^2 - 0.04^2) = 3 cm beyond each end (sampled every 1 cm)
    assert acc.completeness == pytest.approx((9 + 3 + 9 + 3 + 8 * 0.03) / 28, abs=8 * 0.01 / 28)


@pytest.mark.parametrize("angle_deg", [1.0, 5.0, 30.0])
def test_rotated_map_has_that_angle_error(angle_deg: float) -> None:
    a = math.radians(angle_deg)
    seg = rotate_about(WALL, a, (5.0, 0.0))
    acc = line_accuracy(seg, WALL)
    assert acc.mean_angle_error_rad == pytest.approx(a, abs=1e-12)
    assert acc.mean_angle_error_deg == pytest.approx(angle_deg, abs=1e-10)
    # a point s from the pivot is |s| sin(a) from the wall: mean 2.5 sin(a), p95 ~ 0.95 * 5 sin(a)
    assert acc.mean_distance_m == pytest.approx(2.5 * math.sin(a), rel=1e-6)
    assert acc.p95_distance_m == pytest.approx(0.95 * 5 * math.sin(a), abs=0.01 * math.sin(a) + 1e-9)


def test_reversed_segments_have_no_angle_error() -> None:
    acc = line_accuracy([[10.0, 0.0, 0.0, 0.0]], WALL)
    assert acc.mean_angle_error_rad == pytest.approx(0.0, abs=1e-12)


def test_spurious_segment_counts_by_length() -> None:
    walls = rect(0, 0, 10, 4)
    extra = np.array([[5.0, 1.0, 5.0, 3.0]])  # 2 m, perpendicular to the nearest wall, 1 m away
    acc = line_accuracy(np.vstack([walls, extra]), walls)
    assert acc.spurious_share == pytest.approx(2.0 / 30.0)
    assert acc.completeness == 1.0
    assert acc.mean_angle_error_rad == pytest.approx((math.pi / 2) * 2.0 / 30.0)
    assert acc.map_length_m == pytest.approx(30.0)
    # along the extra segment the distance runs 1 -> 2 -> 1 m (mean 1.5 m over 2 m of 30 m)
    assert acc.mean_distance_m == pytest.approx(1.5 * 2.0 / 30.0, rel=1e-6)
    # 95 % of 30 m = the 28 m of walls + 0.5 m of the extra, whose distances are uniform on [1, 2]: 1.25 m
    assert acc.p95_distance_m == pytest.approx(1.25, abs=0.01)


def test_missing_wall_lowers_completeness() -> None:
    walls = rect(0, 0, 10, 4)
    acc = line_accuracy(walls[:3], walls)  # the left wall (4 m) is missing
    # its first and last 5 cm lie within 5 cm of the neighbouring walls
    assert acc.completeness == pytest.approx((24.0 + 0.1) / 28.0, abs=1e-9)
    assert acc.spurious_share == 0.0
    assert acc.mean_distance_m == pytest.approx(0.0, abs=1e-12)


def test_split_walls_and_split_map_give_the_same_scores() -> None:
    walls = rect(0, 0, 10, 4)
    segs = rotate_about(walls, math.radians(2.0), (5.0, 2.0)) + 0.01
    t = np.linspace(0.0, 1.0, 5)
    split = np.vstack(
        [
            np.stack(
                [w[0] + t[:-1] * (w[2] - w[0]), w[1] + t[:-1] * (w[3] - w[1]),
                 w[0] + t[1:] * (w[2] - w[0]), w[1] + t[1:] * (w[3] - w[1])], axis=1,
            )
            for w in walls
        ]
    )  # fmt: skip
    a = line_accuracy(segs, walls, sample_m=0.05)
    b = line_accuracy(segs, split, sample_m=0.05)
    assert b.mean_distance_m == pytest.approx(a.mean_distance_m, rel=1e-9)
    assert b.completeness == pytest.approx(a.completeness, abs=0.02)


def test_empty_map() -> None:
    acc = line_accuracy(np.zeros((0, 4)), WALL)
    assert math.isnan(acc.mean_distance_m) and math.isnan(acc.mean_angle_error_rad)
    assert acc.completeness == 0.0 and acc.spurious_share == 0.0
    assert acc.n_segments == 0
    # zero-length segments carry no length and are ignored
    assert line_accuracy([[1.0, 1.0, 1.0, 1.0]], WALL).n_segments == 0


def test_large_map_is_exact_and_vectorised() -> None:
    # 2,000 segments vs 100 walls (the indexed search path): compare with a slow reference on a subset
    rng = np.random.default_rng(7)
    x, y = rng.uniform(0, 30, (2, 100))
    horizontal = rng.random(100) < 0.5
    length = rng.uniform(1, 5, 100)
    walls = np.stack([x, y, x + np.where(horizontal, length, 0), y + np.where(horizontal, 0, length)], axis=1)
    pick = walls[rng.integers(0, 100, 2000)]
    t0 = rng.uniform(0, 0.8, 2000)[:, None]
    t1 = t0 + rng.uniform(0.05, 0.2, 2000)[:, None]
    segs = np.hstack(
        [pick[:, :2] + t0 * (pick[:, 2:] - pick[:, :2]), pick[:, :2] + t1 * (pick[:, 2:] - pick[:, :2])]
    )
    segs = segs + rng.normal(0, 0.01, segs.shape)
    acc = line_accuracy(segs, walls)
    assert isinstance(acc, LineAccuracy)
    assert 0.0 < acc.mean_distance_m < 0.02
    assert 0.0 <= acc.spurious_share <= 1.0 and 0.0 < acc.completeness < 1.0
    assert set(acc.as_dict()) >= {"mean_distance_m", "completeness", "spurious_share"}


def test_bad_input_is_named() -> None:
    with pytest.raises(MetricInputError, match=r"walls has shape \(0, 4\)"):
        line_accuracy(WALL, np.zeros((0, 4)))
    with pytest.raises(InvalidInputError, match=r"segments has shape \(3,\)"):
        line_accuracy([1.0, 2.0, 3.0], WALL)
    with pytest.raises(MetricInputError, match="sample_m"):
        line_accuracy(WALL, WALL, sample_m=0.0)
    with pytest.raises(MetricInputError, match="zero length"):
        line_accuracy(WALL, [[1.0, 1.0, 1.0, 1.0]])


# --- properties --------------------------------------------------------------------------------------------

coord = st.floats(-5.0, 5.0)
segment = st.tuples(coord, coord, coord, coord).filter(lambda s: math.hypot(s[2] - s[0], s[3] - s[1]) > 0.05)
segment_sets = st.lists(segment, min_size=1, max_size=8).map(lambda rows: np.array(rows, dtype=np.float64))


@settings(max_examples=60, deadline=None)
@given(segment_sets, segment_sets, st.floats(-100, 100), st.floats(-100, 100))
def test_translating_map_and_walls_together_changes_nothing(
    segs: FloatArray, walls: FloatArray, dx: float, dy: float
) -> None:
    shift = np.array([dx, dy, dx, dy])
    a = line_accuracy(segs, walls, sample_m=0.05)
    b = line_accuracy(segs + shift, walls + shift, sample_m=0.05)
    assert b.mean_distance_m == pytest.approx(a.mean_distance_m, abs=1e-9)
    assert b.mean_angle_error_rad == pytest.approx(a.mean_angle_error_rad, abs=1e-9)
    assert b.completeness == pytest.approx(a.completeness, abs=0.02)
    assert b.spurious_share == pytest.approx(a.spurious_share, abs=0.02)


@settings(max_examples=60, deadline=None)
@given(segment_sets, segment_sets)
def test_scores_are_in_range(segs: FloatArray, walls: FloatArray) -> None:
    acc = line_accuracy(segs, walls, sample_m=0.05)
    assert acc.mean_distance_m >= 0.0 and acc.p95_distance_m >= 0.0
    assert 0.0 <= acc.mean_angle_error_rad <= math.pi / 2 + 1e-12
    assert 0.0 <= acc.completeness <= 1.0 and 0.0 <= acc.spurious_share <= 1.0
    # the map compared with itself is perfect
    self_acc = line_accuracy(segs, segs, sample_m=0.05)
    assert self_acc.mean_distance_m == pytest.approx(0.0, abs=1e-9)
    assert self_acc.completeness == 1.0


@given(st.floats(-10, 10), st.floats(-10, 10))
def test_undirected_angle_diff_is_symmetric_and_bounded(a: float, b: float) -> None:
    d = float(undirected_angle_diff(a, b))
    assert 0.0 <= d <= math.pi / 2 + 1e-12
    assert d == pytest.approx(float(undirected_angle_diff(b, a)), abs=1e-9)
    assert float(undirected_angle_diff(a, a + math.pi)) == pytest.approx(0.0, abs=1e-9)
