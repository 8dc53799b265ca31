"""The loop search's window from the graph's knowledge of the relative pose (shared.slam.window): the
path covariance is what composing the noisy parts gives (a chain walked backwards included), a tie narrows
the window to a few standard deviations but never below the floor, a tie blind along a corridor or none at
all leaves the operator's window; and a narrow search in a room finds what the whole window finds, while
along a corridor it falls back to the whole window."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.slam import LoopClosureSettings, verify
from shared.slam.window import (
    MIN_WINDOW_M,
    MIN_WINDOW_RAD,
    TIE_KEYFRAMES,
    WINDOW_SIGMAS,
    inverse_covariance,
    path_covariance,
    search_window,
)
from shared.types import Pose2D
from tests.shared.slam.test_loop_closure import MATCHER, ROOM, points, world

SETTINGS = LoopClosureSettings()


def _noisy(motion: Pose2D, cov: np.ndarray, rng: np.random.Generator) -> Pose2D:
    e = rng.multivariate_normal(np.zeros(3), cov)
    return Pose2D(motion.x_m + e[0], motion.y_m + e[1], motion.theta_rad + e[2])


@settings(max_examples=25, deadline=None)
@given(
    st.floats(-3.0, 3.0),
    st.floats(-3.0, 3.0),
    st.floats(-3.0, 3.0),
    st.floats(0.001, 0.05),
    st.floats(0.001, 0.05),
)
def test_the_inverse_covariance_is_the_jacobian_of_the_inverse(
    x: float, y: float, theta: float, sxy: float, sth: float
) -> None:
    """inverse_covariance against the central-difference Jacobian of the inverse motion's parameters."""
    motion = Pose2D(x, y, theta)
    cov = np.diag([sxy**2, (0.5 * sxy) ** 2, sth**2])
    jac = np.zeros((3, 3))
    base = np.array(motion.as_tuple())
    for a in range(3):
        step = np.zeros(3)
        step[a] = 1e-6
        hi = np.array(Pose2D(*(base + step)).inverse().as_tuple())
        lo = np.array(Pose2D(*(base - step)).inverse().as_tuple())
        diff = hi - lo
        diff[2] = math.remainder(diff[2], math.tau)
        jac[:, a] = diff / 2e-6
    assert np.allclose(inverse_covariance(motion, cov), jac @ cov @ jac.T, rtol=1e-5, atol=1e-12)


def _path_case() -> tuple[np.ndarray, np.ndarray, list[Pose2D]]:
    """Keyframe poses along a curving path (0..20) and their sequential covariances."""
    motions = [Pose2D(0.5, 0.02 * (k % 3), 0.08 if k % 3 else -0.05) for k in range(20)]
    poses = [Pose2D()]
    for m in motions:
        poses.append(poses[-1] @ m)
    seq = np.array([np.diag([0.01**2, 0.004**2, 0.003**2]).ravel() for _ in motions])
    return np.array([p.as_tuple() for p in poses]), seq, motions


def test_the_path_covariance_is_what_composing_the_noisy_parts_gives() -> None:
    """c = 8, c' = 5 (the chain walked backwards), the closure j = 14 seen in 5's frame, then 14 -> 17:
    the first-order covariance against 4,000 samples of the three noisy parts composed, within 12 % along
    every principal direction."""
    rows, seq, motions = _path_case()
    poses = [Pose2D(*r) for r in rows.tolist()]
    c, cp, j, k = 8, 5, 14, 17
    tie_cov = np.diag([0.02**2, 0.01**2, 0.004**2])
    formula = path_covariance(rows, seq, c, k, (j, cp), tie_cov)
    rng = np.random.default_rng(3)
    covs = seq.reshape(-1, 3, 3)
    samples = []
    for _ in range(4000):
        back = Pose2D()
        for m in range(cp, c):  # cp -> c, then inverted: c' in c's frame
            back = back @ _noisy(motions[m], covs[m], rng)
        tie = _noisy(poses[cp].between(poses[j]), tie_cov, rng)
        ahead = Pose2D()
        for m in range(j, k):
            ahead = ahead @ _noisy(motions[m], covs[m], rng)
        samples.append((back.inverse() @ tie @ ahead).as_tuple())
    empirical = np.cov(np.asarray(samples).T)
    _, directions = np.linalg.eigh(empirical)
    for d in directions.T:
        assert 0.88 < (d @ formula @ d) / (d @ empirical @ d) < 1.12


def test_a_tie_narrows_the_window_to_a_few_sigmas_above_the_floor() -> None:
    rows, seq, _ = _path_case()
    ties = np.array([[14.0, 5.0]])
    small = np.diag([0.02**2, 0.01**2, 0.004**2]).ravel()[None, :]
    assert search_window(rows, seq, 8, 17, ties, small, SETTINGS) == (MIN_WINDOW_M, MIN_WINDOW_RAD)
    # an uncertain tie: 4 sigma of the path, between the floor and the operator's window
    loose = np.diag([0.2**2, 0.1**2, 0.02**2]).ravel()[None, :]
    half_m, half_rad = search_window(rows, seq, 8, 17, ties, loose, SETTINGS)
    cov = path_covariance(rows, seq, 8, 17, (14, 5), loose.reshape(3, 3))
    assert math.isclose(half_m, WINDOW_SIGMAS * math.sqrt(np.linalg.eigvalsh(cov[:2, :2])[-1]))
    assert MIN_WINDOW_M < half_m < SETTINGS.window_m
    assert math.isclose(half_rad, max(WINDOW_SIGMAS * math.sqrt(cov[2, 2]), MIN_WINDOW_RAD))
    # the tightest of several ties
    both = np.vstack([loose, small])
    assert search_window(rows, seq, 8, 17, np.array([[14.0, 5.0], [15.0, 6.0]]), both, SETTINGS) == (
        MIN_WINDOW_M,
        MIN_WINDOW_RAD,
    )


def test_without_a_close_tie_the_window_is_the_operators() -> None:
    rows, seq, _ = _path_case()
    small = np.diag([0.02**2, 0.01**2, 0.004**2]).ravel()[None, :]
    whole = (SETTINGS.window_m, SETTINGS.window_rad)
    empty = np.zeros((0, 2))
    assert search_window(rows, seq, 8, 17, empty, np.zeros((0, 9)), SETTINGS) == whole
    far_back = np.array([[17.0 - TIE_KEYFRAMES - 1, 5.0]])  # too many keyframes before k
    assert search_window(rows, seq, 8, 17, far_back, small, SETTINGS) == whole
    elsewhere = np.array([[14.0, 8.0 + TIE_KEYFRAMES + 1]])  # another place than c's
    assert search_window(rows, seq, 8, 17, elsewhere, small, SETTINGS) == whole
    later = np.array([[17.0, 8.0]])  # k's own closure (not accepted before its search)
    assert search_window(rows, seq, 8, 17, later, small, SETTINGS) == whole
    # a corridor closure: held at the estimate along the axis, no information there
    blind = np.diag([1e6, 0.01**2, 0.004**2]).ravel()[None, :]
    assert search_window(rows, seq, 8, 17, np.array([[14.0, 5.0]]), blind, SETTINGS) == whole
    # never wider than the operator's window
    tight = LoopClosureSettings(window_m=0.3, window_rad=0.05)
    assert search_window(rows, seq, 8, 17, np.array([[14.0, 5.0]]), small, tight) == (0.3, 0.05)


def test_a_narrow_search_in_a_room_finds_what_the_whole_window_finds() -> None:
    a, b = Pose2D(-1.0, 0.0, 0.2), Pose2D(0.2, 0.6, -0.3)
    truth = a.between(b)
    guess = truth @ Pose2D(0.15, -0.1, 0.03)
    reference, current = points(ROOM, a, 1), points(ROOM, b, 2)
    whole = verify(reference, current, guess, 7, SETTINGS, MATCHER)
    narrow = verify(reference, current, guess, 7, SETTINGS, MATCHER, window=(MIN_WINDOW_M, MIN_WINDOW_RAD))
    assert whole is not None and narrow is not None
    assert math.hypot(narrow.pose.x_m - whole.pose.x_m, narrow.pose.y_m - whole.pose.y_m) < 0.01
    assert abs(math.remainder(narrow.pose.theta_rad - whole.pose.theta_rad, math.tau)) < math.radians(0.2)
    assert math.hypot(narrow.pose.x_m - truth.x_m, narrow.pose.y_m - truth.y_m) < 0.03


def test_along_a_corridor_a_narrow_search_falls_back_to_the_whole_window() -> None:
    """The ridge of a featureless corridor reaches the narrow window's border: the whole window is searched
    and the match (its spread along the axis included) is the whole window's."""
    w = world([(-30.0, -1.0, 30.0, -1.0), (-30.0, 1.0, 30.0, 1.0)], "corridor")
    a, b = Pose2D(0.0, 0.0, 0.0), Pose2D(0.5, 0.3, 0.1)
    guess = a.between(b) @ Pose2D(0.0, -0.1, -0.02)
    reference, current = points(w, a, 1), points(w, b, 2)
    whole = verify(reference, current, guess, 0, SETTINGS, MATCHER)
    narrow = verify(reference, current, guess, 0, SETTINGS, MATCHER, window=(MIN_WINDOW_M, MIN_WINDOW_RAD))
    assert whole is not None and narrow is not None
    assert narrow.pose == whole.pose
    assert np.array_equal(narrow.spread, whole.spread)
    # the premise: the narrow window's ridge reaches its border (the scan does not fix the place in it)
    from shared.slam.closure import _coarse, _reaches_border

    step = 0.0125
    pose, _, _, plausible = _coarse(reference, current, guess, (MIN_WINDOW_M, MIN_WINDOW_RAD), step)
    assert _reaches_border(plausible, pose, guess, MIN_WINDOW_RAD, step)
