"""SVD lines (eq. 27-32): total least squares per group, checked against numpy.linalg.svd and sklearn PCA."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from sklearn.decomposition import PCA

from shared.kernels.lines import Svd
from shared.types import FloatArray, canonical_hesse
from tests.shared.kernels.lines.lines_helpers import angle_diff, assert_lines_valid, line_points, max_distance


def _numpy_svd_line(pts: FloatArray) -> tuple[float, float, FloatArray]:
    """Reference: eq. 27-32 with numpy.linalg.svd on the centred matrix -> (rho, theta, A_new + mean)."""
    mean = pts.mean(axis=0)
    u, s, vt = np.linalg.svd(pts - mean, full_matrices=False)
    normal = vt[1]
    rho, theta = canonical_hesse(float(mean @ normal), math.atan2(normal[1], normal[0]))
    s_new = np.array([s[0], 0.0])  # the smaller singular value set to zero (eq. 32)
    a_new = (u * s_new) @ vt + mean
    return float(rho), float(theta), a_new


@pytest.mark.parametrize(
    ("rho", "theta"),
    [
        (2.0, 0.0),
        (1.5, math.pi / 2),
        (-0.7, math.pi / 2),
        (3.0, math.radians(179.7)),
        (2.5, math.radians(37.0)),
    ],
)
def test_recovers_noisy_known_lines(rho: float, theta: float) -> None:
    pts = line_points(rho, theta, -1.5, 1.5, 300, noise_m=0.01, seed=1)
    lines = Svd().apply(pts)
    assert_lines_valid(lines)
    assert lines.n_lines == 1
    assert angle_diff(lines.theta_rad[0], theta) < math.radians(0.5)
    assert max_distance(pts, lines.rho_m[0], lines.theta_rad[0]) < 0.05
    assert lines.support[0] == 300


def test_matches_numpy_svd_rank_one_reconstruction() -> None:
    rng = np.random.default_rng(2)
    pts = line_points(4.0, 1.1, 2.0, 5.0, 80, noise_m=0.03, seed=3) + rng.normal(0, 0.01, (80, 2))
    rho, theta, a_new = _numpy_svd_line(pts)
    lines = Svd().apply(pts)
    assert lines.theta_rad[0] == pytest.approx(theta, abs=1e-9)
    assert lines.rho_m[0] == pytest.approx(rho, abs=1e-9)
    # the segment's end points are the extreme rows of A_new (eq. 32)
    direction = np.array([-math.sin(theta), math.cos(theta)])
    t = a_new @ direction
    ends = a_new[[np.argmin(t), np.argmax(t)]].ravel()
    np.testing.assert_allclose(lines.segments[0], ends, atol=1e-9)


def test_matches_sklearn_pca_per_group() -> None:
    rng = np.random.default_rng(5)
    groups = np.repeat(np.arange(6), 40)
    pts = np.vstack([
        line_points(rng.uniform(-4, 4), rng.uniform(0, math.pi), -1.0, rng.uniform(0, 2), 40, 0.02, seed=g)
        for g in range(6)
    ])
    lines = Svd().apply(pts, groups)
    assert lines.n_lines == 6
    np.testing.assert_array_equal(lines.group, np.arange(6))
    for g in range(6):
        part = pts[groups == g]
        pca = PCA(n_components=2).fit(part)
        normal = pca.components_[1]
        rho, theta = canonical_hesse(float(pca.mean_ @ normal), math.atan2(normal[1], normal[0]))
        assert lines.theta_rad[g] == pytest.approx(float(theta), abs=1e-8)
        assert lines.rho_m[g] == pytest.approx(float(rho), abs=1e-8)


def test_corner_in_two_groups_gives_two_walls() -> None:
    wall_a = line_points(2.0, 0.0, -1.0, 1.0, 50)
    wall_b = line_points(1.0, math.pi / 2, -2.0, 0.0, 50)
    pts = np.vstack([wall_a, wall_b])
    lines = Svd().apply(pts, np.repeat([4, 7], 50))
    np.testing.assert_array_equal(lines.group, [4, 7])
    np.testing.assert_allclose(lines.theta_rad, [0.0, math.pi / 2], atol=1e-9)
    np.testing.assert_allclose(lines.rho_m, [2.0, 1.0], atol=1e-9)
    np.testing.assert_allclose(lines.segments, [[2.0, -1.0, 2.0, 1.0], [2.0, 1.0, 0.0, 1.0]], atol=1e-9)


def test_degenerate_groups_give_no_line() -> None:
    pts = np.array([[1.0, 1.0], [1.0, 1.0], [1.0, 1.0], [5.0, 0.0], [2.0, 2.0], [2.0, 3.0], [9.0, 9.0]])
    groups = np.array([0, 0, 0, 1, 2, 2, -1])  # duplicates, one point, a pair, ignored
    lines = Svd().apply(pts, groups)
    assert_lines_valid(lines)
    np.testing.assert_array_equal(lines.group, [2])
    assert lines.theta_rad[0] == pytest.approx(0.0, abs=1e-12)
    assert lines.rho_m[0] == pytest.approx(2.0)
    assert Svd(min_points=3).apply(pts, groups).n_lines == 0
    assert Svd().apply(np.zeros((0, 2))).n_lines == 0


def test_far_from_origin_is_accurate() -> None:
    pts = line_points(1.0e4, 0.3, 1.0e4, 1.0e4 + 2.0, 50)
    lines = Svd().apply(pts)
    assert lines.rho_m[0] == pytest.approx(1.0e4, abs=1e-6)
    assert lines.theta_rad[0] == pytest.approx(0.3, abs=1e-9)


@settings(max_examples=80, deadline=None)
@given(
    rho=st.floats(-5.0, 5.0),
    theta=st.floats(0.0, math.pi, exclude_max=True),
    t0=st.floats(-5.0, 5.0),
    length=st.floats(0.05, 6.0),
    n=st.integers(2, 60),
)
def test_property_noise_free_points_give_their_line(
    rho: float, theta: float, t0: float, length: float, n: int
) -> None:
    pts = line_points(rho, theta, t0, t0 + length, n)
    lines = Svd().apply(pts)
    assert_lines_valid(lines)
    assert lines.n_lines == 1
    assert angle_diff(lines.theta_rad[0], theta) < 1e-7
    assert max_distance(pts, lines.rho_m[0], lines.theta_rad[0]) < 1e-7
    seg_length = math.hypot(*(lines.segments[0, 2:] - lines.segments[0, :2]))
    assert seg_length == pytest.approx(length, abs=1e-7)
