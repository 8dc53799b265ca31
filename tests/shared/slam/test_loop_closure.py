"""Loop-closure candidates and verification on simulated scans: an earlier place is found again from a
guess far off; a place never seen, or one that repeats (pillars every 2 m), is no closure; along a
featureless corridor a closure fixes the pose across it only."""

from __future__ import annotations

import math

import numpy as np
import pytest

from shared.kernels import REGISTRY, Stage
from shared.pipeline.rangenoise import URG04LX_RANGE_NOISE
from shared.sim import RangeNoise, World, simulate_scan
from shared.sim.world import polygon_walls
from shared.slam import LoopClosureSettings, candidates, verify
from shared.slam.closure import chain_covariance
from shared.slam.edges import HOLD_SIGMA_M
from shared.slam.information import scan_edge
from shared.types import Pose2D

SETTINGS = LoopClosureSettings()
MATCHER = REGISTRY.create(Stage.SCAN_MATCHING, "icp", {"max_correspondence_m": 0.3})


def box(x: float, y: float, w: float, h: float) -> list[tuple[float, float, float, float]]:
    return [(x, y, x + w, y), (x + w, y, x + w, y + h), (x + w, y + h, x, y + h), (x, y + h, x, y)]


def world(walls: list[tuple[float, float, float, float]], name: str) -> World:
    arr = np.array(walls, dtype=np.float64)
    return World(arr, 1.0, name, np.array([[0.0, 0.0], [1.0, 0.0]]))


ROOM = world(
    [tuple(w) for w in polygon_walls([(-4.0, -3.0), (4.0, -3.0), (4.0, 3.0), (-4.0, 3.0)])]
    + box(1.0, 1.0, 0.6, 0.4)
    + box(-2.5, -2.0, 0.5, 0.9),
    "room",
)


def points(w: World, pose: Pose2D, seed: int) -> np.ndarray:
    """A URG-04LX scan at ``pose`` as returns in the robot frame (scanner at the robot's centre), in beam
    order."""
    scan = simulate_scan(w, pose, np.random.default_rng(seed), RangeNoise())
    pts, _ = scan.to_points()
    return pts


scan_points = points


def test_an_earlier_place_is_found_from_a_guess_far_off() -> None:
    a, b = Pose2D(-1.0, 0.0, 0.2), Pose2D(0.2, 0.6, -0.3)
    truth = a.between(b)
    guess = truth @ Pose2D(0.9, -0.7, 0.25)
    match = verify(points(ROOM, a, 1), points(ROOM, b, 2), guess, 7, SETTINGS, MATCHER)
    assert match is not None
    assert match.candidate == 7
    assert math.hypot(match.pose.x_m - truth.x_m, match.pose.y_m - truth.y_m) < 0.03
    assert abs(math.remainder(match.pose.theta_rad - truth.theta_rad, math.tau)) < math.radians(0.5)
    assert match.inlier_share >= SETTINGS.min_inlier_share


def test_a_place_never_seen_is_no_closure() -> None:
    other = world(
        [tuple(w) for w in polygon_walls([(0.0, 0.0), (2.5, 0.0), (2.5, 9.0), (0.0, 9.0)])]
        + box(1.0, 4.0, 0.3, 0.3),
        "narrow",
    )
    at = Pose2D(1.2, 2.0, 1.2)
    assert (
        verify(points(ROOM, Pose2D(), 1), points(other, at, 2), Pose2D(0.3, 0.2, 0.1), 0, SETTINGS, MATCHER)
        is None
    )


def pillared_corridor() -> World:
    """A 40 m corridor, 3 m wide, with a 0.3 m pillar every 2 m on both sides."""
    walls = [(-20.0, -1.5, 20.0, -1.5), (-20.0, 1.5, 20.0, 1.5)]
    for x in np.arange(-19.0, 20.0, 2.0):
        walls += box(float(x), -1.5, 0.3, 0.3) + box(float(x), 1.2, 0.3, 0.3)
    return world(walls, "pillars")


def submap(w: World, origin: Pose2D, xs: np.ndarray) -> np.ndarray:
    """Scans taken every so often along x (as a candidate's submap holds its neighbours' returns), in the
    robot frame of ``origin``."""
    parts = []
    for k, x in enumerate(xs):
        at = Pose2D(float(x), origin.y_m, origin.theta_rad)
        parts.append(origin.between(at).transform_points(points(w, at, 10 + k)))
    return np.vstack(parts)


def test_a_repeating_place_is_ambiguous_and_no_closure() -> None:
    w = pillared_corridor()
    a, b = Pose2D(0.0, 0.0, 0.0), Pose2D(0.3, 0.1, 0.05)
    guess = a.between(b) @ Pose2D(0.4, 0.0, 0.0)
    reference = submap(w, a, np.arange(-1.5, 1.6, 0.5))
    assert verify(reference, points(w, b, 2), guess, 0, SETTINGS, MATCHER) is None
    # the same corridor with two pillars only, not repeating: no rival, a closure across the corridor;
    # two small pillars move the score surface by less than its ridge's width, so along the axis the
    # closure claims nothing (its spread is wider than the mapper holds the graph's estimate for)
    walls = [
        (-20.0, -1.5, 20.0, -1.5),
        (-20.0, 1.5, 20.0, 1.5),
        *box(-0.6, -1.5, 0.3, 0.3),
        *box(1.7, 1.2, 0.5, 0.3),
    ]
    single = world(walls, "two pillars")
    found = verify(
        submap(single, a, np.arange(-1.5, 1.6, 0.5)), points(single, b, 2), guess, 0, SETTINGS, MATCHER
    )
    assert found is not None
    assert abs(found.pose.y_m - 0.1) < 0.03
    assert abs(found.pose.theta_rad - 0.05) < math.radians(0.5)
    assert math.sqrt(found.spread[0, 0]) > HOLD_SIGMA_M > 5 * math.sqrt(found.spread[1, 1])


def test_along_a_featureless_corridor_a_closure_fixes_only_what_it_sees() -> None:
    w = world([(-30.0, -1.0, 30.0, -1.0), (-30.0, 1.0, 30.0, 1.0)], "corridor")
    a, b = Pose2D(0.0, 0.0, 0.0), Pose2D(0.5, 0.3, 0.1)
    truth = a.between(b)
    guess = truth @ Pose2D(0.0, -0.25, -0.1)
    match = verify(points(w, a, 1), points(w, b, 2), guess, 0, SETTINGS, MATCHER)
    assert match is not None
    assert abs(match.pose.y_m - truth.y_m) < 0.02  # across: fixed
    assert abs(math.remainder(match.pose.theta_rad - truth.theta_rad, math.tau)) < math.radians(0.5)
    # the edge the mapper makes of it: point-to-line against the candidate's scan, blind along the axis
    edge = scan_edge(
        scan_points(w, a, 1),
        scan_points(w, b, 2),
        match.pose,
        Pose2D(),
        sigma_m=0.02,
        range_noise=URG04LX_RANGE_NOISE,
        refine=True,
    )
    assert edge is not None
    pose, info = edge
    assert abs(pose.y_m - truth.y_m) < 0.01
    cov = np.linalg.inv(info)
    # along: an order of magnitude less known (what is left comes from lines fitted to noisy returns)
    assert math.sqrt(cov[0, 0]) > 10 * math.sqrt(cov[1, 1])


@pytest.mark.parametrize("max_candidates", [1, 2, 3])
def test_candidates_are_old_near_and_from_different_submaps(max_candidates: int) -> None:
    # a path out along x and back: keyframe k at x = k (out) or 40 - k (back), every metre
    xs = np.array([k if k <= 20 else 40 - k for k in range(41)], dtype=np.float64)
    positions = np.column_stack([xs, np.zeros_like(xs)])
    travelled = np.arange(41, dtype=np.float64)
    settings = LoopClosureSettings(
        search_radius_m=2.5, recent_m=10.0, submap_keyframes=1, max_candidates=max_candidates
    )
    found = candidates(positions, travelled, 35, settings)  # at x = 5, 35 m travelled
    assert found[0] == 5  # the nearest earlier keyframe first
    assert all(travelled[c] <= 25.0 for c in found)  # nothing of the last 10 m
    assert all(abs(positions[c, 0] - 5.0) <= 2.5 for c in found)
    assert len(found) == max_candidates
    assert all(abs(a - b) > 1 for i, a in enumerate(found) for b in found[:i])
    assert candidates(positions, travelled, 12, settings) == []  # nothing old enough nearby


def test_the_chain_covariance_is_what_composing_noisy_motions_gives() -> None:
    """chain_covariance's first-order formula against a Monte Carlo of the same chain: 30 noisy motions
    of a curving path composed 4,000 times; the two agree within 10 % along every principal direction."""
    rng = np.random.default_rng(5)
    motions = [Pose2D(0.5, 0.02 * (k % 3), 0.08 if k % 3 else -0.05) for k in range(30)]
    covs = [np.diag([0.01**2, 0.004**2, 0.003**2]) for _ in motions]
    poses = [Pose2D()]
    for m in motions:
        poses.append(poses[-1] @ m)
    formula = chain_covariance(poses, covs)
    samples = []
    for _ in range(4000):
        pose = Pose2D()
        for m, c in zip(motions, covs, strict=True):
            e = rng.multivariate_normal(np.zeros(3), c)
            pose = pose @ Pose2D(m.x_m + e[0], m.y_m + e[1], m.theta_rad + e[2])
        samples.append(pose.as_tuple())
    empirical = np.cov(np.asarray(samples).T)
    _, directions = np.linalg.eigh(empirical)
    for d in directions.T:
        assert 0.9 < (d @ formula @ d) / (d @ empirical @ d) < 1.1
