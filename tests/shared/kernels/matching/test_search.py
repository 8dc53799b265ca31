"""The correlative coarse pose search that seeds ICP when the prediction is far off."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.kernels.matching import Icp
from shared.kernels.matching._search import correlative_search
from shared.types import Pose2D
from tests.shared.kernels.matching.test_icp import REF, SENSOR, scan_points


@settings(max_examples=30, deadline=None)
@given(
    st.floats(-0.3, 0.3),
    st.floats(-0.15, 0.15),
    st.floats(-0.15, 0.15),
)
def test_finds_the_basin_of_a_far_off_prediction(dth: float, dx: float, dy: float) -> None:
    """Within the window, the searched pose is within a cell and an angular step of the truth, and ICP from
    it converges to the truth."""
    truth = Pose2D(0.05, -0.03, 0.1)  # motion of the scanner between the two scans
    current = scan_points(SENSOR @ truth, sigma=0.005, seed=1)
    guess = Pose2D(truth.x_m + dx, truth.y_m + dy, truth.theta_rad + dth)
    coarse = correlative_search(REF, current, guess, rot_half_rad=0.35, xy_half_m=0.2)
    err = truth.between(coarse.pose)
    assert abs(err.theta_rad) <= math.radians(2.0)
    assert math.hypot(err.x_m, err.y_m) <= 0.08
    assert 0.5 < coarse.score <= 1.0
    match = Icp().apply(REF, current, coarse.pose)
    fine = truth.between(match.pose)
    assert math.hypot(fine.x_m, fine.y_m) < 0.01 and abs(fine.theta_rad) < math.radians(0.3)


@settings(max_examples=20, deadline=None)
@given(st.floats(-math.pi, math.pi), st.floats(-2.0, 2.0), st.floats(-2.0, 2.0))
def test_score_is_a_share_and_the_identity_scores_highest_on_itself(th: float, x: float, y: float) -> None:
    """A scan matched against itself from its own pose scores ~1; any grid pose scores within [0, 1]."""
    start = Pose2D(x, y, th)
    coarse = correlative_search(REF, REF, start)
    assert 0.0 <= coarse.score <= 1.0
    own = correlative_search(REF, REF, Pose2D(), rot_half_rad=0.1)
    assert own.score > 0.95 and own.pose == Pose2D()


def test_no_points_returns_the_prediction() -> None:
    guess = Pose2D(0.1, 0.2, 0.3)
    empty = np.zeros((0, 2))
    assert correlative_search(REF, empty, guess).pose == guess
    assert correlative_search(empty, REF, guess).score == 0.0
    nan = np.full((5, 2), np.nan)
    assert correlative_search(nan, REF, guess).pose == guess
