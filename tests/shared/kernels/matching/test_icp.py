"""Tests of the ``icp`` scan-matching kernel (paper §6.2.2)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray

from shared.errors import InvalidInputError, KernelParameterError
from shared.kernels import REGISTRY
from shared.kernels.matching import Icp
from shared.types import URG04LX, Pose2D

F = NDArray[np.float64]

#: a 6 x 4.5 m room with a box and a door alcove, walls x0, y0, x1, y1
ROOM = np.array(
    [[0, 0, 6, 0], [6, 0, 6, 4.5], [6, 4.5, 3.2, 4.5], [2.3, 4.5, 0, 4.5], [0, 4.5, 0, 0],
     [4.2, 1.0, 4.8, 1.0], [4.8, 1.0, 4.8, 1.6], [4.8, 1.6, 4.2, 1.6], [4.2, 1.6, 4.2, 1.0],
     [2.3, 4.5, 2.3, 5.5], [3.2, 4.5, 3.2, 5.5], [2.3, 5.5, 3.2, 5.5]],
    dtype=np.float64,
)
SENSOR = Pose2D(2.5, 1.8, 0.3)


def scan_points(pose: Pose2D, sigma: float = 0.0, seed: int = 0) -> F:
    """URG-04LX points (scanner frame) of ``ROOM`` seen from ``pose``; beams that hit nothing are dropped."""
    a = URG04LX.angles_rad() + pose.theta_rad
    d = np.stack([np.cos(a), np.sin(a)], axis=1)
    p0 = ROOM[:, :2]
    e = ROOM[:, 2:] - p0
    w = p0[None] - np.array([pose.x_m, pose.y_m])
    den = d[:, None, 0] * e[None, :, 1] - d[:, None, 1] * e[None, :, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (w[..., 0] * e[None, :, 1] - w[..., 1] * e[None, :, 0]) / den
        u = (w[..., 0] * d[:, None, 1] - w[..., 1] * d[:, None, 0]) / den
    hit = (np.abs(den) > 1e-12) & (t > 0) & (u >= 0) & (u <= 1)
    r = np.where(hit, t, np.inf).min(axis=1)
    r = r + np.random.default_rng(seed).normal(0.0, sigma, r.size)
    keep = np.isfinite(r)
    b = URG04LX.angles_rad()[keep]
    return np.stack([r[keep] * np.cos(b), r[keep] * np.sin(b)], axis=1)


def pose_error(a: Pose2D, b: Pose2D) -> tuple[float, float]:
    """Translation (m) and absolute rotation (deg) between two poses."""
    d = a.between(b)
    return math.hypot(d.x_m, d.y_m), abs(math.degrees(d.theta_rad))


REF = scan_points(SENSOR)


def test_registered() -> None:
    assert REGISTRY.get("scan-matching", "icp") is Icp
    assert isinstance(REGISTRY.create("scan-matching", "icp", {"max_iterations": 5}), Icp)


@pytest.mark.parametrize(
    "bad", [{"max_iterations": 0}, {"max_correspondence_m": 0.0}, {"max_points": 2}, {"tolerance_m": -1.0}]
)
def test_invalid_parameters_are_refused(bad: dict[str, float]) -> None:
    with pytest.raises(KernelParameterError):
        Icp(bad)


def test_recovers_a_known_transform_of_the_same_scan() -> None:
    truth = Pose2D(0.08, -0.06, math.radians(5.0))  # 10 cm, 5 deg
    current = truth.inverse().transform_points(REF)  # reference = truth(current)
    match = Icp().apply(REF, current)
    dist, ang = pose_error(match.pose, truth)
    assert match.converged
    assert dist < 0.01
    assert ang < 0.2
    assert match.rmse_m < 0.005
    assert match.inlier_ratio > 0.95


def test_recovers_motion_between_two_simulated_scans() -> None:
    # two different noisy scans from poses 10 cm / 5 deg apart: different samples of the same walls
    motion = Pose2D(0.09, 0.04, math.radians(5.0))
    ref = scan_points(SENSOR, sigma=0.01, seed=1)
    cur = scan_points(SENSOR @ motion, sigma=0.01, seed=2)
    match = Icp().apply(ref, cur, Pose2D())
    dist, ang = pose_error(match.pose, motion)
    assert dist < 0.01
    assert ang < 0.2
    assert match.converged


def test_ten_percent_outliers() -> None:
    rng = np.random.default_rng(7)
    truth = Pose2D(-0.07, 0.05, math.radians(-4.0))
    cur = truth.inverse().transform_points(scan_points(SENSOR, sigma=0.01, seed=3))
    ref = scan_points(SENSOR, sigma=0.01, seed=4)
    for pts in (cur, ref):
        bad = rng.random(len(pts)) < 0.10
        pts[bad] *= rng.uniform(0.1, 1.0, (int(bad.sum()), 1))  # short spurious returns
    match = Icp().apply(ref, cur, Pose2D())
    dist, ang = pose_error(match.pose, truth)
    assert dist < 0.01
    assert ang < 0.2
    assert 0.7 < match.inlier_ratio < 1.0


@pytest.mark.parametrize(
    ("ref", "cur"),
    [
        (np.zeros((0, 2)), REF),
        (REF, np.zeros((0, 2))),
        (REF[:1], REF),
        (REF, REF[:1]),
        (REF[:2], REF[:2]),
        (np.full((5, 2), np.nan), REF),
        ([], []),
    ],
)
def test_too_few_points_returns_initial(ref: F, cur: F) -> None:
    initial = Pose2D(0.1, 0.2, 0.3)
    match = Icp().apply(ref, cur, initial)
    assert match.pose == initial
    assert not match.converged
    assert match.rmse_m == math.inf
    assert match.inlier_ratio == 0.0
    assert match.n_iter == 0


def test_no_pairs_within_reach_returns_initial() -> None:
    initial = Pose2D(0.0, 0.0, 0.0)
    match = Icp().apply(REF, REF + 50.0, initial)
    assert match.pose == initial
    assert not match.converged
    assert match.rmse_m == math.inf
    assert match.inlier_ratio == 0.0
    assert match.n_iter == 1


def test_default_initial_is_identity() -> None:
    match = Icp().apply(REF, REF)
    dist, ang = pose_error(match.pose, Pose2D())
    assert dist < 1e-9
    assert ang < 1e-9
    assert match.rmse_m < 1e-9
    assert match.inlier_ratio == 1.0


def test_non_finite_rows_are_ignored_and_inputs_untouched() -> None:
    truth = Pose2D(0.03, 0.02, math.radians(2.0))
    cur = truth.inverse().transform_points(REF)
    clean = Icp().apply(REF, cur, Pose2D())
    ref_bad = np.vstack([REF[:100], [[np.nan, 1.0]], REF[100:], [[np.inf, -np.inf]]])
    cur_bad = np.vstack([[[np.nan, np.nan]], cur, [[1.0, np.inf]]])
    ref_bad.setflags(write=False)
    cur_bad.setflags(write=False)
    before = (ref_bad.copy(), cur_bad.copy())
    dirty = Icp().apply(ref_bad, cur_bad, Pose2D())
    assert dirty == clean
    assert np.array_equal(ref_bad, before[0], equal_nan=True)
    assert np.array_equal(cur_bad, before[1], equal_nan=True)


def test_wrong_shape_is_refused() -> None:
    with pytest.raises(InvalidInputError):
        Icp().apply(np.zeros((5, 3)), REF)


def test_max_points_and_max_iterations() -> None:
    truth = Pose2D(0.05, -0.03, math.radians(3.0))
    cur = truth.inverse().transform_points(REF)
    one = Icp(max_iterations=1).apply(REF, cur, Pose2D())
    assert one.n_iter == 1
    assert not one.converged
    assert pose_error(one.pose, truth)[0] < pose_error(Pose2D(), truth)[0]
    few = Icp(max_points=50).apply(REF, cur, Pose2D())
    dist, ang = pose_error(few.pose, truth)
    assert dist < 0.01
    assert ang < 0.2


def test_single_line_and_duplicates_do_not_crash() -> None:
    line = np.stack([np.linspace(0.0, 3.0, 1000), np.full(1000, 1.0)], axis=1)
    match = Icp().apply(line, line + np.array([0.05, 0.02]), Pose2D())
    assert abs(match.pose.y_m + 0.02) < 1e-3  # the offset across the line is observable
    assert abs(match.pose.theta_rad) < 1e-3
    dup = np.tile([[1.0, 2.0]], (20, 1))
    match = Icp().apply(dup, dup, Pose2D())
    assert match.pose == Pose2D()
    assert match.rmse_m == 0.0


def test_symmetry_b_to_a_is_roughly_the_inverse() -> None:
    motion = Pose2D(0.06, -0.03, math.radians(2.5))
    a = scan_points(SENSOR, sigma=0.01, seed=5)
    b = scan_points(SENSOR @ motion, sigma=0.01, seed=6)
    ab = Icp().apply(a, b, Pose2D()).pose
    ba = Icp().apply(b, a, Pose2D()).pose
    dist, ang = pose_error(ab, ba.inverse())
    assert dist < 0.01
    assert ang < 0.2


def test_deterministic() -> None:
    cur = scan_points(SENSOR @ Pose2D(0.02, 0.01, 0.02), sigma=0.01, seed=9)
    assert Icp().apply(REF, cur) == Icp().apply(REF, cur)


@settings(max_examples=40, deadline=None)
@given(
    dx=st.floats(-0.05, 0.05),
    dy=st.floats(-0.05, 0.05),
    dth=st.floats(-3.0, 3.0),
    ex=st.floats(-0.02, 0.02),
    ey=st.floats(-0.02, 0.02),
    eth=st.floats(-1.0, 1.0),
)
def test_random_small_transforms(dx: float, dy: float, dth: float, ex: float, ey: float, eth: float) -> None:
    truth = Pose2D(dx, dy, math.radians(dth))
    cur = truth.inverse().transform_points(REF)
    initial = truth @ Pose2D(ex, ey, math.radians(eth))  # an odometry guess a little off
    match = Icp().apply(REF, cur, initial)
    dist, ang = pose_error(match.pose, truth)
    assert dist < 0.005
    assert ang < 0.1
    assert 0.0 <= match.inlier_ratio <= 1.0
    assert 1 <= match.n_iter <= Icp().params.max_iterations
