"""Clustering in the Hough domain (Algorithm 2, eq. 35): one averaged top-cell line per segment."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.kernels.lines import HoughCluster, Svd
from shared.types import FloatArray, IntArray, canonical_hesse
from tests.shared.kernels.lines.lines_helpers import angle_diff, assert_lines_valid, line_points, max_distance


def _top_cells(
    pts: FloatArray, delta: int, res_deg: float = 1.0, res: float = 0.02
) -> tuple[IntArray, IntArray, int, int, FloatArray]:
    """Reference accumulator in numpy (the documented layout).

    Returns the theta and rho cells of every cell with ``votes >= max(T - delta, 2)``, the peak's theta cell
    (row-major first), ``half`` and the centroid.
    """
    n_theta = round(180.0 / res_deg)
    theta = np.arange(n_theta) * math.pi / n_theta
    centre = pts.mean(axis=0)
    d = pts - centre
    half = math.ceil(float(np.sqrt((d**2).sum(axis=1).max())) / res) + 1
    j = np.floor(d[:, :1] * (np.cos(theta) / res) + d[:, 1:] * (np.sin(theta) / res) + half + 0.5).astype(int)
    acc = np.zeros((n_theta, 2 * half + 1), dtype=int)
    np.add.at(acc, (np.broadcast_to(np.arange(n_theta), j.shape), j), 1)
    k_peak = int(np.argmax(acc) // acc.shape[1])
    k_sel, j_sel = np.nonzero(acc >= max(int(acc.max()) - delta, 2))
    return k_sel, j_sel, k_peak, half, centre


def _reference_line(
    pts: FloatArray, delta: int, res_deg: float = 1.0, res: float = 0.02
) -> tuple[float, float]:
    """Algorithm 2 by hand: unweighted centroid of the top cells, moved across the seam to the peak's side."""
    k_sel, j_sel, k_peak, half, centre = _top_cells(pts, delta, res_deg, res)
    step = math.pi / round(180.0 / res_deg)
    theta = k_sel * step
    rho = (j_sel - half) * res
    theta_peak = k_peak * step
    above = theta - theta_peak > math.pi / 2
    below = theta_peak - theta > math.pi / 2
    theta = np.where(above, theta - math.pi, np.where(below, theta + math.pi, theta))
    rho = np.where(above | below, -rho, rho)
    t = float(theta.mean())
    r = float(rho.mean()) + centre[0] * math.cos(t) + centre[1] * math.sin(t)
    r_c, t_c = canonical_hesse(r, t)
    return float(r_c), float(t_c)


@pytest.mark.parametrize("theta_deg", [0.0, 30.0, 90.0, 135.0, 179.5, 0.4])
def test_recovers_noisy_walls(theta_deg: float) -> None:
    theta = math.radians(theta_deg)
    truth = line_points(2.0, theta, -1.0, 1.5, 2)
    pts = line_points(2.0, theta, -1.0, 1.5, 150, noise_m=0.01, seed=3)
    lines = HoughCluster().apply(pts)
    assert_lines_valid(lines)
    assert lines.n_lines == 1
    assert angle_diff(lines.theta_rad[0], theta) < math.radians(0.6)
    assert max_distance(truth, lines.rho_m[0], lines.theta_rad[0]) < 0.02
    assert lines.support[0] >= 145


def test_the_seam_vertical_wall_is_not_rotated() -> None:
    """A wall at 179.5 deg (x = -2): its top cells sit at theta = 0 and 179 deg; a plain average of the
    cells would be 89.5 deg, a line perpendicular to the wall."""
    theta = math.radians(179.5)
    pts = line_points(2.0, theta, -0.5, 0.5, 40, noise_m=0.01, seed=0)
    k_sel, _, _, _, _ = _top_cells(pts, delta=1)
    assert (k_sel == 0).any(), "the test needs top cells on both sides of the seam"
    assert (k_sel == 179).any(), "the test needs top cells on both sides of the seam"
    assert angle_diff(float(np.mean(k_sel)) * math.pi / 180, theta) > math.radians(80.0)
    lines = HoughCluster(delta=1).apply(pts)
    assert_lines_valid(lines)
    assert angle_diff(lines.theta_rad[0], theta) < math.radians(0.5)
    truth = line_points(2.0, theta, -0.5, 0.5, 2)
    assert max_distance(truth, lines.rho_m[0], lines.theta_rad[0]) < 0.02
    np.testing.assert_allclose(lines.segments[0, [0, 2]], -2.0, atol=0.03)


@pytest.mark.parametrize("delta", [0, 1, 2])
@pytest.mark.parametrize(("rho", "theta_deg", "seed"), [(2.0, 0.3, 1), (1.0, 179.6, 2), (3.0, 61.3, 3)])
def test_matches_a_numpy_reference(delta: int, rho: float, theta_deg: float, seed: int) -> None:
    pts = line_points(rho, math.radians(theta_deg), -0.8, 1.2, 60, noise_m=0.015, seed=seed)
    want_rho, want_theta = _reference_line(pts, delta)
    lines = HoughCluster(delta=delta).apply(pts)
    assert lines.theta_rad[0] == pytest.approx(want_theta, abs=1e-9)
    assert lines.rho_m[0] == pytest.approx(want_rho, abs=1e-9)


def test_delta_zero_on_grid_is_the_peak_cell() -> None:
    pts = line_points(1.7, math.radians(30.0), -1.0, 1.0, 50)
    lines = HoughCluster(delta=0).apply(pts)
    assert lines.theta_rad[0] == pytest.approx(math.radians(30.0), abs=1e-12)
    assert lines.rho_m[0] == pytest.approx(1.7, abs=1e-9)


def test_one_line_per_group_and_degenerate_groups() -> None:
    a = line_points(2.0, 0.0, -1.0, 1.0, 30, noise_m=0.005, seed=1)
    b = line_points(1.0, math.pi / 2, -2.0, 0.0, 30, noise_m=0.005, seed=2)
    pts = np.vstack([a, b, [[9.0, 9.0]], [[4.0, 4.0]] * 3, [[0.0, 0.0], [5.0, 5.0]]])
    groups = np.r_[np.full(30, 3), np.full(30, 1), 7, 8, 8, 8, -1, -1]
    lines = HoughCluster().apply(pts, groups)
    assert_lines_valid(lines)
    np.testing.assert_array_equal(lines.group, [1, 3])  # lone point and coincident points give nothing
    assert angle_diff(lines.theta_rad[0], math.pi / 2) < math.radians(1.0)
    assert angle_diff(lines.theta_rad[1], 0.0) < math.radians(1.0)
    assert HoughCluster().apply(np.zeros((0, 2))).n_lines == 0
    assert HoughCluster(min_points=40).apply(pts, groups).n_lines == 0


def test_span_ignores_points_far_from_the_line() -> None:
    wall = line_points(2.0, 0.0, -1.0, 1.0, 60, noise_m=0.005, seed=4)
    clutter = np.array([[1.2, 3.0], [0.5, -2.5]])
    lines = HoughCluster().apply(np.vstack([wall, clutter]))
    assert lines.support[0] == 60
    assert np.abs(lines.segments[0, [1, 3]]).max() < 1.05


def test_agrees_with_svd_on_noisy_walls() -> None:
    rng = np.random.default_rng(8)
    for seed in range(5):
        theta = rng.uniform(0.0, math.pi)
        pts = line_points(rng.uniform(-4, 4), theta, -1.0, 1.0, 100, noise_m=0.01, seed=seed)
        hc = HoughCluster().apply(pts)
        svd = Svd().apply(pts)
        assert angle_diff(hc.theta_rad[0], svd.theta_rad[0]) < math.radians(1.0)


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
    kernel = HoughCluster()
    lines = kernel.apply(pts)
    assert_lines_valid(lines)
    assert lines.n_lines == 1
    res = kernel.params.rho_resolution_m
    bound = max(math.radians(kernel.params.theta_resolution_deg), res / length)
    assert angle_diff(lines.theta_rad[0], theta) <= bound
    assert max_distance(pts, lines.rho_m[0], lines.theta_rad[0]) <= 1.5 * res
