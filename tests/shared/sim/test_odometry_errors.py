"""Odometry error models: perfect encoders, worn wheels with a known bias, slip bursts on the spot."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from shared.errors import InvalidInputError
from shared.odometry import MINES_ROVER
from shared.sim.odometry_errors import ODOMETRY_MODELS, PERFECT, OdometryErrors, odometry_from_truth
from shared.sim.path import plan_path
from shared.types import Pose2D

STRAIGHT = plan_path(np.array([[0.0, 0.0], [10.0, 0.0]]))


def test_perfect_encoders_follow_the_truth_up_to_tick_quantisation() -> None:
    path = plan_path(np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 3.0]]))
    ticks, odo = odometry_from_truth(path, MINES_ROVER, PERFECT, np.random.default_rng(0))
    assert ticks.shape == (len(path), 2) and ticks[0].tolist() == [0, 0]
    err = max(math.hypot(a.x_m - b.x_m, a.y_m - b.y_m) for a, b in zip(path, odo, strict=True))
    assert err < 2e-3


def test_worn_wheels_bend_a_straight_leg_by_the_predicted_heading_and_stretch_it() -> None:
    worn = OdometryErrors("w", slip_sigma_ratio=0.0, scale_left=1.01, scale_right=1.0)
    _, odo = odometry_from_truth(STRAIGHT, MINES_ROVER, worn, np.random.default_rng(0))
    # d_theta = (d_right - d_left) / tread = -0.01 x 10 m / 0.33 m
    assert odo[-1].theta_rad == pytest.approx(-0.01 * 10.0 / MINES_ROVER.tread_m, rel=0.02)
    travelled = sum(math.hypot(b.x_m - a.x_m, b.y_m - a.y_m) for a, b in itertools.pairwise(odo))
    assert travelled == pytest.approx(10.0 * 1.005, rel=1e-3)


def test_a_slip_burst_counts_travel_while_the_robot_stands_still() -> None:
    still = [Pose2D(1.0, 2.0, 0.5)] * 200
    calm, _ = odometry_from_truth(still, MINES_ROVER, PERFECT, np.random.default_rng(0))
    assert np.all(calm == 0)
    bursts = OdometryErrors("b", slip_sigma_ratio=0.0, burst_rate_hz=1.0, burst_extra_m=(0.02, 0.02))
    ticks, odo = odometry_from_truth(still, MINES_ROVER, bursts, np.random.default_rng(0))
    d = np.diff(ticks, axis=0)
    assert np.count_nonzero(np.abs(d).sum(axis=1)) >= 10  # ~20 bursts of 4 steps in 20 s
    # one wheel at a time: every step that counts travel counts it on one wheel only
    moving = np.abs(d).sum(axis=1) > 0
    assert np.all((d[moving] == 0).any(axis=1))
    # the odometry turns on the spot although the robot stands still (0.06 rad per burst)
    assert max(abs(o.theta_rad - 0.5) for o in odo) > 0.05


def test_models_by_name_and_their_seeds() -> None:
    assert set(ODOMETRY_MODELS) == {"perfect", "slip", "worn", "bursts"}
    a = odometry_from_truth(STRAIGHT, MINES_ROVER, ODOMETRY_MODELS["bursts"], np.random.default_rng(5))
    b = odometry_from_truth(STRAIGHT, MINES_ROVER, ODOMETRY_MODELS["bursts"], np.random.default_rng(5))
    assert np.array_equal(a[0], b[0]) and a[1] == b[1]


@pytest.mark.parametrize(
    "kwargs",
    [{"slip_sigma_ratio": -0.1}, {"scale_left": 0.0}, {"burst_rate_hz": math.nan}, {"burst_steps": 0}],
)
def test_bad_models_are_refused(kwargs: dict[str, float]) -> None:
    with pytest.raises(InvalidInputError, match="OdometryErrors"):
        OdometryErrors("bad", **kwargs)  # type: ignore[arg-type]
