"""The straight-line kernels' shared helpers: grouping, theta grid, span building, registration."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.errors import InvalidInputError
from shared.kernels import REGISTRY, Stage
from shared.kernels.lines import Hough, HoughCluster
from shared.kernels.lines._common import (
    MAX_COORDINATE_M,
    MIN_LENGTH_M,
    build_lines,
    empty_lines,
    group_points,
    theta_grid,
)
from tests.shared.kernels.lines.lines_helpers import assert_lines_valid


def test_all_four_kernels_are_registered() -> None:
    names = {info.name for info in REGISTRY.list(Stage.STRAIGHT_LINE)}
    assert {"centroid-join", "svd", "hough", "hough-cluster"} <= names


def test_group_points_sorts_stably_and_drops_bad_rows() -> None:
    pts = np.array([[0.0, 0.0], [1.0, 0.0], [np.nan, 0.0], [2.0, 0.0], [3.0, 0.0], [4.0, np.inf], [5.0, 0.0]])
    groups = np.array([2, 0, 0, -1, 2, 0, 0])
    g = group_points(pts, groups)
    np.testing.assert_array_equal(g.labels, [0, 2])
    np.testing.assert_array_equal(g.starts, [0, 2, 4])
    np.testing.assert_array_equal(g.points[:, 0], [1.0, 5.0, 0.0, 3.0])  # scan order kept in a group
    np.testing.assert_array_equal(g.group_index, [0, 0, 1, 1])
    np.testing.assert_array_equal(g.counts, [2, 2])


def test_group_points_defaults_and_empty() -> None:
    g = group_points(np.array([[0.0, 1.0], [2.0, 3.0]]), None)
    np.testing.assert_array_equal(g.labels, [0])
    assert g.n_groups == 1
    empty = group_points(np.zeros((0, 2)), np.zeros(0, dtype=int))
    assert empty.n_groups == 0
    assert empty.points.shape == (0, 2)
    np.testing.assert_array_equal(empty.starts, [0])


def test_group_points_does_not_touch_read_only_input() -> None:
    pts = np.array([[1.0, 2.0], [0.0, 0.0]])
    pts.setflags(write=False)
    g = group_points(pts, np.array([1, 0]))
    np.testing.assert_array_equal(g.points, [[0.0, 0.0], [1.0, 2.0]])


def test_group_labels_validation() -> None:
    pts = np.zeros((3, 2))
    np.testing.assert_array_equal(group_points(pts, np.array([1.0, np.nan, 0.0])).labels, [0, 1])
    with pytest.raises(InvalidInputError, match="shape"):
        group_points(pts, np.array([0, 1]))
    with pytest.raises(InvalidInputError, match="non-integer"):
        group_points(pts, np.array([0.5, 1.0, 2.0]))
    with pytest.raises(InvalidInputError, match="dtype"):
        group_points(pts, np.array(["a", "b", "c"]))
    with pytest.raises(InvalidInputError):
        group_points(np.zeros((3, 3)), None)


@pytest.mark.parametrize(("res_deg", "n"), [(1.0, 180), (0.5, 360), (7.0, 26), (10.0, 18)])
def test_theta_grid_closes_on_the_seam(res_deg: float, n: int) -> None:
    c, s = theta_grid(res_deg)
    assert c.shape == s.shape == (n,)
    theta = np.arctan2(s, c)
    np.testing.assert_allclose(theta, np.arange(n) * math.pi / n, atol=1e-12)


def test_build_lines_spans_filters_and_drops_degenerate() -> None:
    pts = np.array([[1.0, -1.0], [1.0, 0.5], [1.0, 2.0], [1.3, 9.0], [5.0, 5.0], [5.0, 5.0]])
    g = group_points(pts, np.array([0, 0, 0, 0, 1, 1]))
    # line 0: x = 1 written with theta = pi (rho = -1) -> made canonical; line 1: both points coincide
    lines = build_lines(
        g,
        np.arange(6),
        np.array([0, 0, 0, 0, 1, 1]),
        np.array([-1.0, 0.0]),
        np.array([math.pi, 0.7]),
        np.array([0, 1]),
        tolerance_m=0.1,
    )
    assert_lines_valid(lines)
    assert lines.n_lines == 1
    assert lines.theta_rad[0] == pytest.approx(0.0, abs=1e-12)
    assert lines.rho_m[0] == pytest.approx(1.0)
    assert lines.support[0] == 3  # the point 0.3 m off is beyond the tolerance
    np.testing.assert_allclose(lines.segments[0], [1.0, -1.0, 1.0, 2.0], atol=1e-12)
    assert lines.group[0] == 0
    assert MIN_LENGTH_M < 1e-6


def test_empty_lines_is_frozen() -> None:
    lines = empty_lines()
    assert lines.n_lines == 0
    assert_lines_valid(lines)


def test_absurd_coordinates_are_dropped_and_huge_groups_skipped() -> None:
    pts = np.array([[0.0, 0.0], [1.0, 0.0], [1e300, 1.0], [2.0, 0.0]])
    g = group_points(pts, None)
    np.testing.assert_array_equal(g.points[:, 0], [0.0, 1.0, 2.0])
    # a group spanning 500 km would need a 2.5e9-cell accumulator: the Hough kernels skip it
    wide = np.array([[0.0, 0.0], [1.0, 0.0], [5e5, 0.0], [2.0, 0.0]])
    for kernel in (Hough(), HoughCluster()):
        assert kernel.apply(wide).n_lines == 0
        assert kernel.apply(wide, np.array([0, 0, -1, 0])).n_lines == 1


def _numpy_grouping(points: np.ndarray, labels: np.ndarray) -> tuple[np.ndarray, ...]:
    """group_points' sort as plain numpy (its formulation before it was compiled): the reference."""
    sane = (np.abs(points) <= MAX_COORDINATE_M).all(axis=1)
    idx = np.flatnonzero(sane & (labels >= 0))
    order = idx[np.argsort(labels[idx], kind="stable")]
    sorted_lab = labels[order]
    first = np.flatnonzero(np.diff(sorted_lab)) + 1
    starts = (
        np.concatenate(([0], first, [order.size])).astype(np.intp) if order.size else np.zeros(1, np.intp)
    )
    kept = sorted_lab[starts[:-1]]
    return points[order], kept, starts, np.repeat(np.arange(kept.size, dtype=np.intp), np.diff(starts))


@settings(max_examples=300, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.floats(allow_nan=True, allow_infinity=True, width=64),
            st.floats(allow_nan=True, allow_infinity=True, width=64),
            st.integers(-2, 6),
        ),
        max_size=40,
    ),
    st.booleans(),
)
def test_group_points_matches_its_numpy_formulation(
    rows: list[tuple[float, float, int]], ascending: bool
) -> None:
    if ascending:
        rows = sorted(rows, key=lambda r: r[2])
    points = np.array([r[:2] for r in rows], dtype=np.float64).reshape(-1, 2)
    labels = np.array([r[2] for r in rows], dtype=np.intp)
    got = group_points(points, labels)
    for want, have in zip(
        _numpy_grouping(points, labels), (got.points, got.labels, got.starts, got.group_index), strict=True
    ):
        assert want.shape == have.shape
        np.testing.assert_array_equal(want, have)
