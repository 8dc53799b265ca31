"""Centroid joining (CJ): a polyline through each group's points in scan order."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from shared.errors import KernelParameterError
from shared.kernels.lines import CentroidJoin
from shared.types import hesse_from_endpoints
from tests.shared.kernels.lines.lines_helpers import assert_lines_valid


def _as_set(segments: np.ndarray) -> set[tuple[float, ...]]:
    """Segments as an order-free set of end-point pairs (rounded)."""
    out: set[tuple[float, ...]] = set()
    for x0, y0, x1, y1 in np.round(segments, 9):
        a, b = (float(x0), float(y0)), (float(x1), float(y1))
        out.add((*min(a, b), *max(a, b)))
    return out


def test_joins_consecutive_points_of_a_room_corner() -> None:
    pts = np.array([[2.0, -1.0], [2.0, 0.0], [2.0, 1.0], [1.0, 1.0], [0.0, 1.0]])
    lines = CentroidJoin().apply(pts)
    assert_lines_valid(lines)
    assert lines.n_lines == 4
    assert _as_set(lines.segments) == _as_set(np.hstack([pts[:-1], pts[1:]]))
    np.testing.assert_allclose(lines.theta_rad, [0.0, 0.0, math.pi / 2, math.pi / 2], atol=1e-12)
    np.testing.assert_allclose(lines.rho_m, [2.0, 2.0, 1.0, 1.0], atol=1e-12)
    np.testing.assert_array_equal(lines.support, [2, 2, 2, 2])


def test_hesse_matches_the_end_points() -> None:
    rng = np.random.default_rng(4)
    pts = np.cumsum(rng.normal(0.0, 0.5, (20, 2)), axis=0)
    lines = CentroidJoin(max_gap_m=100.0).apply(pts)
    rho, theta = hesse_from_endpoints(np.hstack([pts[:-1], pts[1:]]))
    np.testing.assert_allclose(lines.rho_m, rho, atol=1e-12)
    np.testing.assert_allclose(lines.theta_rad, theta, atol=1e-12)


def test_never_joins_across_groups_or_gaps() -> None:
    pts = np.array([[0.0, 0.0], [0.5, 0.0], [1.0, 0.0], [5.0, 0.0], [5.5, 0.0], [6.0, 1.0], [6.5, 1.0]])
    groups = np.array([0, 0, 0, 0, 0, 3, 3])
    lines = CentroidJoin(max_gap_m=1.0).apply(pts, groups)
    assert_lines_valid(lines)
    assert lines.n_lines == 4  # 0-1, 1-2, 3-4 in group 0; 5-6 in group 3; not 2-3 (gap), not 4-5 (groups)
    np.testing.assert_array_equal(lines.group, [0, 0, 0, 3])
    lines = CentroidJoin(max_gap_m=10.0).apply(pts, groups)
    assert lines.n_lines == 5
    np.testing.assert_array_equal(lines.group, [0, 0, 0, 0, 3])


def test_degenerate_groups() -> None:
    cj = CentroidJoin()
    assert cj.apply(np.array([[1.0, 2.0]])).n_lines == 0  # one point
    dup = np.array([[1.0, 2.0], [1.0, 2.0], [1.0, 2.0], [2.0, 2.0]])
    lines = cj.apply(dup)
    assert lines.n_lines == 1  # coincident neighbours give no segment
    np.testing.assert_allclose(lines.theta_rad, [math.pi / 2])
    assert cj.apply(np.zeros((0, 2))).n_lines == 0
    # a lone point in its own group, and a negative group, give nothing
    pts = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [3.0, 0.0]])
    lines = cj.apply(pts, np.array([0, 1, -1, -1]))
    assert lines.n_lines == 0


def test_nan_row_is_skipped_and_neighbours_joined() -> None:
    pts = np.array([[0.0, 0.0], [np.nan, 1.0], [1.0, 0.0]])
    lines = CentroidJoin().apply(pts)
    assert lines.n_lines == 1
    assert _as_set(lines.segments) == {(0.0, 0.0, 1.0, 0.0)}


@settings(max_examples=60, deadline=None)
@given(
    pts=arrays(np.float64, st.tuples(st.integers(0, 30), st.just(2)),
               elements=st.floats(-20.0, 20.0, allow_nan=False)),
    gap=st.floats(0.1, 50.0),
)
def test_property_every_segment_joins_two_consecutive_input_points(pts: np.ndarray, gap: float) -> None:
    lines = CentroidJoin(max_gap_m=gap).apply(pts)
    assert_lines_valid(lines)
    pairs = np.hstack([pts[:-1], pts[1:]]) if len(pts) > 1 else np.zeros((0, 4))
    length = np.hypot(pairs[:, 2] - pairs[:, 0], pairs[:, 3] - pairs[:, 1])
    expected = pairs[(length <= gap) & (length > 1e-9)]
    assert lines.n_lines == len(expected)
    for got, want in zip(lines.segments, expected, strict=True):
        same = np.allclose(got, want, atol=1e-9) or np.allclose(got, want[[2, 3, 0, 1]], atol=1e-9)
        assert same, (got, want)
    assert np.all(lines.support == 2)


@pytest.mark.parametrize("gap", [0.0, -1.0, 1001.0])
def test_bad_gap_is_rejected(gap: float) -> None:
    with pytest.raises(KernelParameterError, match="max_gap_m"):
        CentroidJoin(max_gap_m=gap)
