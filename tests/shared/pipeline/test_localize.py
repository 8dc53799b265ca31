"""Scan-to-map refinement against known walls."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.pipeline.localize import refine_to_walls
from shared.sim import RangeNoise, default_world, simulate_scan
from shared.types import Pose2D

WORLD = default_world()
TRUE = Pose2D(4.5, 2.0, math.pi)


def scan_points(seed: int = 0) -> np.ndarray:
    scan = simulate_scan(WORLD, TRUE, np.random.default_rng(seed), RangeNoise(outlier_rate=0.05))
    return scan.to_points()[0]


def rms_to_walls(points: np.ndarray, pose: Pose2D, trim_m: float = 0.08) -> float:
    """RMS distance of the scan ``points`` at ``pose`` to the nearest true wall, within ``trim_m``."""
    world = pose.transform_points(points)
    a, b = WORLD.walls[:, :2], WORLD.walls[:, 2:]
    ab = b - a
    t = np.clip(np.einsum("pwk,wk->pw", world[:, None, :] - a, ab) / np.einsum("wk,wk->w", ab, ab), 0.0, 1.0)
    d = np.linalg.norm(world[:, None, :] - (a + t[..., None] * ab), axis=2).min(axis=1)
    return float(np.sqrt(np.mean(d[d <= trim_m] ** 2)))


@settings(max_examples=25, deadline=None)
@given(st.floats(-0.1, 0.1), st.floats(-0.1, 0.1), st.floats(-0.05, 0.05))
def test_recovers_true_pose_from_a_perturbed_guess(dx: float, dy: float, dth: float) -> None:
    guess = Pose2D(TRUE.x_m + dx, TRUE.y_m + dy, TRUE.theta_rad + dth)
    fit = refine_to_walls(scan_points(), guess, WORLD.walls)
    assert fit is not None
    err = TRUE.between(fit.pose)
    assert math.hypot(err.x_m, err.y_m) < 0.01 and abs(err.theta_rad) < math.radians(0.3)
    # the returned pose fits the walls (fit.rmse_m is that of the pose before the last step, which after
    # the iterations ran out from a far guess is still a few mm off: 3.6 cm there, 2.5 cm here)
    assert rms_to_walls(scan_points(), fit.pose) < 0.03


def test_corridor_keeps_the_along_wall_guess() -> None:
    walls = np.array([[-10.0, -1.0, 10.0, -1.0], [-10.0, 1.0, 10.0, 1.0]])
    x = np.linspace(-5, 5, 200)
    pts = np.vstack([np.column_stack([x, np.full_like(x, -1.0)]), np.column_stack([x, np.full_like(x, 1.0)])])
    guess = Pose2D(0.3, 0.05, 0.0)  # 30 cm along the corridor (unobservable), 5 cm across
    fit = refine_to_walls(pts, guess, walls)
    assert fit is not None
    assert fit.pose.y_m == pytest.approx(0.0, abs=1e-3), "across the corridor: corrected"
    assert fit.pose.x_m == pytest.approx(0.3, abs=1e-3), "along the corridor: left alone"


def test_corridor_axis_follows_the_prior_where_the_walls_are_blind() -> None:
    walls = np.array([[-10.0, -1.0, 10.0, -1.0], [-10.0, 1.0, 10.0, 1.0]])
    x = np.linspace(-5, 5, 200)
    pts = np.vstack([np.column_stack([x, np.full_like(x, -1.0)]), np.column_stack([x, np.full_like(x, 1.0)])])
    guess = Pose2D(0.3, 0.05, 0.0)  # a scan match that slid 30 cm along the corridor
    wheels = Pose2D(0.0, 0.04, 0.0)  # odometry: right along it, 4 cm off across it
    info = np.diag([1e4, 1e4, 1e4]) * 0.02**2  # 1 cm, 0.01 rad, in units of a 2 cm residual's variance
    fit = refine_to_walls(pts, guess, walls, degeneracy_ratio=0.05, prior=wheels, prior_information=info)
    assert fit is not None
    assert fit.pose.y_m == pytest.approx(0.0, abs=1e-3), "across the corridor: the walls"
    assert fit.pose.x_m == pytest.approx(0.0, abs=0.01), "along the corridor: odometry"


def test_too_few_matches_gives_none() -> None:
    assert refine_to_walls(scan_points(), Pose2D(50.0, 50.0, 0.0), WORLD.walls) is None
    assert refine_to_walls(np.zeros((0, 2)), TRUE, WORLD.walls) is None


@settings(max_examples=25, deadline=None)
@given(st.floats(2.0, 5.0), st.floats(0.01, 0.04))
def test_nearly_parallel_walls_do_not_slide_the_pose_along_the_corridor(
    tilt_deg: float, shift_m: float
) -> None:
    """Walls a few degrees off parallel barely fix the along-track position: a small inconsistency between
    scan and map (``shift_m`` across one wall) must not become a large along-track move."""
    t = math.tan(math.radians(tilt_deg))
    x = np.linspace(-6, 6, 240)
    pts = np.vstack([np.column_stack([x, np.full_like(x, -1.0)]), np.column_stack([x, 1.0 + t * x])])
    walls = np.array([[-10, -1.0, 10, -1.0], [-10, 1.0 - 10 * t + shift_m, 10, 1.0 + 10 * t + shift_m]])
    free = refine_to_walls(pts, Pose2D(), walls)
    kept = refine_to_walls(pts, Pose2D(), walls, degeneracy_ratio=0.05)
    assert free is not None and kept is not None
    assert abs(free.pose.x_m) > 0.1, "without the degeneracy test the across-wall residual slides the pose"
    assert abs(kept.pose.x_m) < 0.01
    assert abs(kept.pose.y_m) <= shift_m and abs(kept.pose.theta_rad) < math.radians(0.2)


def _reference_normal_equations(
    points: np.ndarray, pose: Pose2D, walls: np.ndarray, max_d: float, trim: float
) -> tuple[int, np.ndarray, np.ndarray, float, float]:
    """The same linearisation in plain numpy, point by wall, as the compiled loop's check."""
    world = pose.transform_points(points)
    a, ab = walls[:, :2], walls[:, 2:] - walls[:, :2]
    t = np.clip(np.einsum("pwk,wk->pw", world[:, None, :] - a, ab) / np.einsum("wk,wk->w", ab, ab), 0.0, 1.0)
    d = np.linalg.norm(world[:, None, :] - (a + t[..., None] * ab), axis=2)
    j = d.argmin(axis=1)
    normal = np.column_stack([-ab[:, 1], ab[:, 0]]) / np.hypot(ab[:, 0], ab[:, 1])[:, None]
    offset = (normal * a).sum(axis=1)
    r = (normal[j] * world).sum(axis=1) - offset[j]
    use = (d[np.arange(len(j)), j] <= max_d) & (np.abs(r) <= trim)
    n, r = normal[j][use], r[use]
    lever = world[use] - np.array([pose.x_m, pose.y_m])
    rows = np.column_stack([n, -n[:, 0] * lever[:, 1] + n[:, 1] * lever[:, 0]])
    return int(use.sum()), rows.T @ rows, rows.T @ r, float(r @ r), float((lever**2).sum())


def _tied(world: np.ndarray, walls: np.ndarray) -> np.ndarray:
    """Points as near (to 1e-9 m) to a second wall as to their nearest, e.g. at the corner two walls share:
    which one a point pairs with there is a matter of rounding."""
    a, ab = walls[:, :2], walls[:, 2:] - walls[:, :2]
    t = np.clip(np.einsum("pwk,wk->pw", world[:, None, :] - a, ab) / np.einsum("wk,wk->w", ab, ab), 0.0, 1.0)
    d = np.sort(np.linalg.norm(world[:, None, :] - (a + t[..., None] * ab), axis=2), axis=1)
    return np.asarray(d[:, 1] - d[:, 0] <= 1e-9)


@settings(max_examples=30, deadline=None)
@given(st.floats(-0.1, 0.1), st.floats(-0.1, 0.1), st.floats(-0.1, 0.1), st.integers(0, 5))
def test_the_compiled_linearisation_matches_a_numpy_reference(
    dx: float, dy: float, dth: float, seed: int
) -> None:
    from shared.pipeline.localize import _normal_equations

    pose = Pose2D(TRUE.x_m + dx, TRUE.y_m + dy, TRUE.theta_rad + dth)
    walls = np.ascontiguousarray(WORLD.walls, dtype=np.float64)
    pts = scan_points(seed)
    pts = np.ascontiguousarray(pts[~_tied(pose.transform_points(pts), walls)])
    got = _normal_equations(pts, pose.x_m, pose.y_m, pose.theta_rad, walls, 0.15, 0.08, np.ones(len(pts)))
    want = _reference_normal_equations(pts, pose, walls, 0.15, 0.08)
    assert got[0] == want[0] and want[0] > 30
    for g, w in zip(got[1:], want[1:], strict=True):
        np.testing.assert_allclose(np.asarray(g, dtype=np.float64), np.asarray(w), rtol=1e-9, atol=1e-9)
