"""Hough lines (Algorithm 1): peak cell, inverse transform, inliers removed, repeated per group."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.kernels.lines import Hough, Svd
from tests.shared.kernels.lines.lines_helpers import angle_diff, assert_lines_valid, line_points, max_distance


@pytest.mark.parametrize(
    ("rho", "theta_deg"),
    [(2.0, 0.0), (-1.0, 0.0), (1.5, 90.0), (-0.5, 90.0), (1.2, 135.0), (3.0, 179.0), (0.0, 45.0)],
)
def test_on_grid_lines_are_exact(rho: float, theta_deg: float) -> None:
    """One line per group: rho is exact because the group votes relative to its centroid, on the line."""
    theta = math.radians(theta_deg)
    pts = line_points(rho, theta, -1.5, 2.0, 40)
    lines = Hough().apply(pts)
    assert_lines_valid(lines)
    assert lines.n_lines == 1
    assert lines.theta_rad[0] == pytest.approx(theta, abs=1e-12)
    assert lines.rho_m[0] == pytest.approx(rho, abs=1e-9)
    assert lines.support[0] == 40
    np.testing.assert_allclose(lines.segments[0], np.r_[pts[0], pts[-1]], atol=1e-9)


def test_near_pi_wall_lands_on_the_seam_cell() -> None:
    theta = math.radians(179.8)  # nearest cell is theta = 0 with rho negated
    pts = line_points(2.0, theta, -0.5, 0.5, 20)
    lines = Hough().apply(pts)
    assert_lines_valid(lines)
    assert lines.n_lines == 1
    assert angle_diff(lines.theta_rad[0], theta) <= math.radians(0.5)
    assert max_distance(pts, lines.rho_m[0], lines.theta_rad[0]) <= 0.02


def test_corner_in_one_group_gives_both_walls() -> None:
    wall_a = line_points(2.0, 0.0, -1.0, 1.0, 30)  # x = 2
    wall_b = line_points(1.0, math.pi / 2, -2.0, 0.0, 20)[1:]  # y = 1, without the corner point (2, 1)
    lines = Hough().apply(np.vstack([wall_a, wall_b]))
    assert_lines_valid(lines)
    assert lines.n_lines == 2
    np.testing.assert_allclose(lines.theta_rad, [0.0, math.pi / 2], atol=1e-12)
    np.testing.assert_allclose(lines.rho_m, [2.0, 1.0], atol=0.01)  # half a rho cell
    np.testing.assert_array_equal(lines.support, [30, 19])


def test_line_through_most_centroids_unlike_svd() -> None:
    """Fig. 13: Hough passes through the most centroids, SVD is the regression line."""
    on_line = line_points(1.0, math.pi / 2, -2.0, 2.0, 8)  # y = 1
    off = np.array([[-1.0, 1.3], [1.5, 1.25]])
    pts = np.vstack([on_line, off])
    first = Hough(min_votes=3).apply(pts)
    assert first.theta_rad[0] == pytest.approx(math.pi / 2)
    assert first.rho_m[0] == pytest.approx(1.0, abs=0.01)  # half a rho cell
    assert first.support[0] == 8
    svd = Svd().apply(pts)
    assert abs(svd.rho_m[0] - 1.0) > 0.02


def test_ties_go_to_the_smallest_theta() -> None:
    # two points 1 m apart on x = 0 fall in one rho cell for every theta within ~1 deg of 0 and of 180 deg
    lines = Hough().apply(np.array([[0.0, 0.0], [0.0, 1.0]]))
    assert lines.n_lines == 1
    assert lines.theta_rad[0] == 0.0
    assert lines.rho_m[0] == pytest.approx(0.0, abs=1e-12)


def test_min_votes_and_max_lines() -> None:
    angle = np.linspace(0.0, 2.0 * math.pi, 10, endpoint=False)
    circle = np.column_stack([np.cos(angle), np.sin(angle)])  # no three points near one line
    assert Hough(min_votes=3).apply(circle).n_lines == 0
    lines = Hough(min_votes=2, max_lines_per_group=3).apply(circle)
    assert lines.n_lines == 3
    assert np.all(lines.support == 2)
    assert Hough(min_votes=2).apply(circle).n_lines == 5  # pairs until fewer than min_points remain


def test_groups_are_separate_and_degenerate_ones_skipped() -> None:
    a = line_points(1.0, 0.0, 0.0, 1.0, 10)
    b = line_points(1.0, 0.0, 2.0, 3.0, 10)  # same infinite line, other group
    pts = np.vstack([a, b, [[5.0, 5.0]], [[7.0, 7.0], [7.0, 7.0]], [[0.0, 9.0]]])
    groups = np.r_[np.full(10, 2), np.full(10, 0), 5, 6, 6, -3]
    lines = Hough().apply(pts, groups)
    assert_lines_valid(lines)
    np.testing.assert_array_equal(lines.group, [0, 2])  # lone point and coincident pair give nothing
    np.testing.assert_allclose(lines.segments[:, [1, 3]], [[2.0, 3.0], [0.0, 1.0]], atol=1e-9)


def test_noisy_centroids_and_nan() -> None:
    pts = line_points(2.5, math.radians(60.0), -1.0, 1.0, 12, noise_m=0.003, seed=9)
    pts[4] = np.nan
    lines = Hough().apply(pts)
    assert_lines_valid(lines)
    assert lines.support.sum() <= 11
    assert angle_diff(lines.theta_rad[0], math.radians(60.0)) <= math.radians(2.0)


@settings(max_examples=60, deadline=None)
@given(
    rho=st.floats(-5.0, 5.0),
    theta=st.floats(0.0, math.pi, exclude_max=True),
    t0=st.floats(-5.0, 5.0),
    length=st.floats(0.3, 4.0),
    n=st.integers(8, 50),
)
def test_property_noise_free_points_give_their_line_within_resolution(
    rho: float, theta: float, t0: float, length: float, n: int
) -> None:
    pts = line_points(rho, theta, t0, t0 + length, n)
    kernel = Hough()
    lines = kernel.apply(pts)
    assert_lines_valid(lines)
    assert lines.n_lines >= 1
    res = kernel.params.rho_resolution_m
    bound = max(math.radians(kernel.params.theta_resolution_deg), res / length)
    assert angle_diff(lines.theta_rad[0], theta) <= 1.01 * bound
    assert max_distance(pts, lines.rho_m[0], lines.theta_rad[0]) <= 2.0 * res
    assert lines.support.sum() == n
