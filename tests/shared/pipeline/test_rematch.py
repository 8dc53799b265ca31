"""The second chance for a refused scan match: searched and extra starts, then the best good match."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.kernels.matching import Icp
from shared.kernels.results import Match
from shared.pipeline.gate import IcpGate
from shared.pipeline.rematch import acceptable, rematch
from shared.types import Pose2D
from tests.shared.kernels.matching.test_icp import REF, SENSOR, scan_points

ICP = Icp()
TRUTH = Pose2D(0.05, -0.03, 0.1)  # scanner motion between the reference and the current scan
CURRENT = scan_points(SENSOR @ TRUTH, sigma=0.005, seed=1)


def close(pose: Pose2D, to: Pose2D = TRUTH) -> bool:
    err = to.between(pose)
    return math.hypot(err.x_m, err.y_m) < 0.01 and abs(err.theta_rad) < math.radians(0.3)


@settings(max_examples=15, deadline=None)
@given(st.sampled_from([-1.0, 1.0]), st.floats(0.45, 0.55))
def test_a_far_off_prediction_is_recovered_by_the_search(sign: float, off_rad: float) -> None:
    guess = Pose2D(TRUTH.x_m, TRUTH.y_m, TRUTH.theta_rad + sign * off_rad)
    refused = ICP.apply(REF, CURRENT, guess)
    assert not close(refused.pose), "plain ICP from this start lands in a wrong minimum"
    match = rematch(ICP, REF, CURRENT, guess, refused, IcpGate(search_rad=0.6))
    assert match is not None and close(match.pose)


def test_extra_starts_are_tried_and_nothing_good_gives_none() -> None:
    guess = Pose2D(TRUTH.x_m, TRUTH.y_m, TRUTH.theta_rad + 0.5)
    refused = ICP.apply(REF, CURRENT, guess)
    no_search = IcpGate(search_rad=0.0)
    assert rematch(ICP, REF, CURRENT, guess, refused, no_search) is None
    seeded = rematch(ICP, REF, CURRENT, guess, refused, no_search, [Pose2D(0.0, 0.0, 0.05)])
    assert seeded is not None and close(seeded.pose)


def test_the_refused_match_wins_ties() -> None:
    refused = ICP.apply(REF, CURRENT, TRUTH)
    assert acceptable(refused, IcpGate())
    assert rematch(ICP, REF, CURRENT, TRUTH, refused, IcpGate(), [TRUTH]) is refused


def test_unrelated_scans_give_none() -> None:
    far = np.random.default_rng(0).uniform(20.0, 30.0, size=(300, 2))
    refused = ICP.apply(REF, far, Pose2D())
    assert rematch(ICP, REF, far, Pose2D(), refused, IcpGate()) is None


@settings(max_examples=30, deadline=None)
@given(st.floats(0.0, 3.0), st.floats(-math.pi, math.pi), st.floats(0.0, 1.0), st.booleans())
def test_acceptable_needs_convergence_inliers_and_a_possible_motion(
    dist_m: float, theta: float, inliers: float, converged: bool
) -> None:
    gate = IcpGate()
    match = Match(Pose2D(dist_m, 0.0, theta), 0.01, inliers, 5, converged)
    expected = (
        converged
        and inliers >= gate.rematch_min_inlier_ratio
        and dist_m <= gate.rematch_max_m
        and abs(theta) <= gate.rematch_max_rad
    )
    assert acceptable(match, gate) == expected
