"""Split-and-merge line extraction (the EKF baseline's front end): known answers, properties, bad input."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.baselines import (
    BaselineParameterError,
    LineObservations,
    SplitMergeParams,
    extract_lines,
    fit_line,
    line_difference,
    normalise_lines,
    split_and_merge,
)
from shared.errors import InvalidInputError, LinemapError
from shared.sim import RangeNoise, World, polygon_walls, simulate_scan
from shared.types import URG04LX, FloatArray, Pose2D, Scan, hesse_from_endpoints

GEOMETRY_ONLY = SplitMergeParams(min_incidence_deg=0.0)


def polyline_points(corners: FloatArray, spacing_m: float) -> FloatArray:
    """Points every ~``spacing_m`` along the polyline through ``corners``, corners included, in order."""
    out = [corners[:1]]
    for a, b in itertools.pairwise(corners):
        n = max(2, math.ceil(float(np.hypot(*(b - a))) / spacing_m))
        t = np.linspace(0.0, 1.0, n + 1)[1:]
        out.append(a + t[:, None] * (b - a))
    return np.vstack(out)


def expected_lines(corners: FloatArray) -> tuple[FloatArray, FloatArray]:
    seg = np.hstack([corners[:-1], corners[1:]])
    rho, theta = hesse_from_endpoints(seg)
    r, a, _ = normalise_lines(rho, theta)
    return r, a


@settings(max_examples=60, deadline=None)
@given(
    width=st.floats(0.8, 5.0),
    height=st.floats(0.8, 5.0),
    cx=st.floats(-3.0, 3.0),
    cy=st.floats(-3.0, 3.0),
    angle=st.floats(-math.pi, math.pi),
    start=st.integers(0, 3),
)
def test_noise_free_rectangle_gives_its_four_sides(
    width: float, height: float, cx: float, cy: float, angle: float, start: int
) -> None:
    c, s = math.cos(angle), math.sin(angle)
    local = np.array([[-width, -height], [width, -height], [width, height], [-width, height]]) / 2.0
    corners = local @ np.array([[c, s], [-s, c]]) + [cx, cy]
    corners = np.roll(corners, -start, axis=0)
    loop = np.vstack([corners, corners[:1]])  # closed: back to the first corner
    obs = split_and_merge(polyline_points(loop, 0.02), GEOMETRY_ONLY)
    assert len(obs) == 4
    rho, alpha = expected_lines(loop)
    d_rho, d_alpha, _ = line_difference(obs.rho_m, obs.alpha_rad, rho, alpha)
    assert np.abs(d_rho).max() < 1e-9
    assert np.abs(d_alpha).max() < 1e-9
    assert np.all(obs.rho_m >= 0.0)
    # end points are the corners (the corner point belongs to both sides)
    np.testing.assert_allclose(obs.endpoints[:, :2], loop[:-1], atol=1e-9)
    np.testing.assert_allclose(obs.endpoints[:, 2:], loop[1:], atol=1e-9)


def test_fit_line_known_answer_and_covariance_model() -> None:
    x = np.linspace(-1.0, 3.0, 41)
    pts = np.column_stack([x, np.full_like(x, -2.0)])  # y = -2: normal points down
    rho, alpha, cov, rms = fit_line(pts, sigma_floor_m=0.01)
    assert rho == pytest.approx(2.0)
    assert alpha == pytest.approx(-math.pi / 2)
    assert rms == pytest.approx(0.0, abs=1e-12)
    # var(alpha) = s^2 / sum (t - tc)^2, var(rho) = s^2 / N + tc^2 var(alpha), cov = tc var(alpha)
    t = x  # coordinate along d = (-sin alpha, cos alpha) = (1, 0) for alpha = -pi/2
    tc = t.mean()
    var_a = 0.01**2 / np.sum((t - tc) ** 2)
    np.testing.assert_allclose(cov, [[0.01**2 / 41 + tc**2 * var_a, tc * var_a], [tc * var_a, var_a]])
    assert np.all(np.linalg.eigvalsh(cov) > 0.0)


def test_noisy_residuals_set_the_covariance() -> None:
    rng = np.random.default_rng(3)
    x = np.linspace(0.0, 2.0, 201)
    pts = np.column_stack([x, 1.0 + rng.normal(0.0, 0.02, x.size)])
    rho, alpha, cov, rms = fit_line(pts, sigma_floor_m=0.001)
    assert rho == pytest.approx(1.0, abs=0.01)
    assert alpha == pytest.approx(math.pi / 2, abs=0.02)
    assert rms == pytest.approx(0.02, rel=0.2)
    assert math.sqrt(cov[0, 0]) > 0.02 / math.sqrt(201) * 0.8


def test_clutter_spikes_do_not_cut_a_wall() -> None:
    x = np.linspace(-2.0, 2.0, 300)
    pts = np.column_stack([x, np.full_like(x, 2.0)])
    pts[::25, 1] = 0.7  # isolated clutter returns well in front of the wall
    obs = split_and_merge(pts)
    assert len(obs) == 1
    assert obs.rho_m[0] == pytest.approx(2.0)
    assert obs.alpha_rad[0] == pytest.approx(math.pi / 2)
    assert obs.lengths_m[0] == pytest.approx(4.0, abs=0.05)


def test_a_simulated_room_scan_gives_its_walls() -> None:
    world = World(polygon_walls([(0, 0), (6, 0), (6, 6), (0, 6)]), 36.0, "square")
    pose = Pose2D(3.0, 3.0, 0.3)
    scan = simulate_scan(world, pose, np.random.default_rng(1), RangeNoise(outlier_rate=0.05))
    obs = extract_lines(scan)
    assert 3 <= len(obs) <= 6
    # every line lies on a wall: its end points in the world are within 10 cm of the wall's line
    ends = pose.transform_points(obs.endpoints.reshape(-1, 2)).reshape(-1, 4)
    for seg, n in zip(ends, obs.n_points, strict=True):
        xy = seg.reshape(2, 2)
        off = np.min(np.abs(np.column_stack([xy[:, 0], xy[:, 1], xy[:, 0] - 6, xy[:, 1] - 6])), axis=1)
        assert off.max() < 0.1
        assert n >= 10
    assert obs.covariance.shape == (len(obs), 2, 2)


@pytest.mark.parametrize(
    "points",
    [
        np.zeros((0, 2)),
        np.full((50, 2), np.nan),
        np.array([[1.0, 1.0]]),
        np.column_stack([np.linspace(0, 0.1, 5), np.ones(5)]),  # too few points
    ],
)
def test_degenerate_inputs_give_no_lines(points: FloatArray) -> None:
    obs = split_and_merge(points)
    assert len(obs) == 0
    assert obs.covariance.shape == (0, 2, 2)
    assert obs.endpoints.shape == (0, 4)


def test_empty_and_all_nan_scans_give_no_lines() -> None:
    for ranges in (np.full(URG04LX.beam_count, np.nan), np.full(URG04LX.beam_count, np.inf)):
        assert len(extract_lines(Scan.from_geometry(URG04LX, ranges))) == 0
    empty = Scan(0.0, 0.0, 0.01, 0.02, 5.6, np.zeros(0))
    assert len(extract_lines(empty)) == 0
    assert len(LineObservations.empty()) == 0


def test_bad_point_shape_is_refused() -> None:
    with pytest.raises(InvalidInputError):
        split_and_merge(np.zeros((4, 3)))


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("min_points", 2),
        ("min_points", 10.5),
        ("split_threshold_m", 0.0),
        ("break_distance_m", math.nan),
        ("merge_chi2", -1.0),
        ("split_range_ratio", -0.1),
        ("min_incidence_deg", 91.0),
        ("max_alpha_sigma_rad", True),
    ],
)
def test_params_errors_name_the_field(field: str, value: object) -> None:
    with pytest.raises(BaselineParameterError, match=f"SplitMergeParams.{field}") as info:
        SplitMergeParams(**{field: value})  # type: ignore[arg-type]
    assert info.value.parameter == field
    assert isinstance(info.value, LinemapError)
    assert isinstance(info.value, InvalidInputError)
