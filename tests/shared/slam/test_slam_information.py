"""A match's information per direction: blind along a featureless corridor, full in a room; symmetric and
positive semi-definite for any scan and pose."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.pipeline.rangenoise import URG04LX_RANGE_NOISE
from shared.slam import match_information
from shared.types import Pose2D


def sampled(walls: list[tuple[float, float, float, float]], step_m: float = 0.02) -> np.ndarray:
    """Points every ``step_m`` along each wall ``(x0, y0, x1, y1)``."""
    parts = []
    for x0, y0, x1, y1 in walls:
        n = max(int(math.hypot(x1 - x0, y1 - y0) / step_m), 2)
        t = np.linspace(0.0, 1.0, n)
        parts.append(np.column_stack([x0 + t * (x1 - x0), y0 + t * (y1 - y0)]))
    return np.vstack(parts)


CORRIDOR = sampled([(-5.0, -1.0, 5.0, -1.0), (-5.0, 1.0, 5.0, 1.0)])
ROOM = sampled(
    [(-3.0, -2.0, 3.0, -2.0), (3.0, -2.0, 3.0, 2.0), (3.0, 2.0, -3.0, 2.0), (-3.0, 2.0, -3.0, -2.0)]
)


def test_a_corridor_fixes_the_pose_across_it_and_not_along_it() -> None:
    info = match_information(CORRIDOR, CORRIDOR, Pose2D(), range_noise=URG04LX_RANGE_NOISE).information
    assert info[1, 1] > 1e4  # across: thousands per m^2
    assert info[0, 0] < 1e-6 * info[1, 1]  # along: nothing
    assert info[2, 2] > 1e3  # the heading: the walls' direction


def test_a_room_fixes_every_direction() -> None:
    result = match_information(ROOM, ROOM, Pose2D())
    eig = np.linalg.eigvalsh(result.information)
    assert eig[0] > 1e3
    assert result.inlier_share == 1.0
    assert result.pairs > 50


def test_the_inlier_share_falls_when_the_scan_is_misplaced() -> None:
    assert match_information(ROOM, ROOM, Pose2D(0.0, 0.0, 0.0)).inlier_share == 1.0
    shifted = match_information(ROOM, ROOM, Pose2D(0.4, 0.3, 0.2)).inlier_share
    assert shifted < 0.3


def test_too_few_reference_points_give_no_information() -> None:
    result = match_information(ROOM[:3], ROOM, Pose2D())
    assert result.pairs == 0
    assert not result.information.any()


@settings(max_examples=40, deadline=None)
@given(
    x=st.floats(-0.5, 0.5),
    y=st.floats(-0.5, 0.5),
    theta=st.floats(-0.5, 0.5),
    seed=st.integers(0, 2**16),
)
def test_information_is_symmetric_and_positive_semidefinite(
    x: float, y: float, theta: float, seed: int
) -> None:
    rng = np.random.default_rng(seed)
    current = ROOM + rng.normal(0.0, 0.01, ROOM.shape)
    info = match_information(ROOM, current, Pose2D(x, y, theta), range_noise=URG04LX_RANGE_NOISE).information
    assert np.allclose(info, info.T)
    assert np.linalg.eigvalsh(info)[0] >= -1e-6 * max(1.0, float(np.abs(info).max()))


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.lists(st.integers(0, 29), min_size=1, max_size=12), min_size=1, max_size=20),
    st.integers(0, 2**31 - 1),
)
def test_the_grouped_moments_are_each_groups_own(groups: list[list[int]], seed: int) -> None:
    """_group_moments (all neighbourhoods at once) against each neighbourhood's moments taken alone: the
    sums of the products of the deviations from its own mean."""
    from shared.slam.information import _group_moments

    points = np.random.default_rng(seed).normal(0.0, 3.0, (30, 2)) + 100.0
    sizes = np.array([len(g) for g in groups])
    sxx, syy, sxy = _group_moments(points, groups, sizes)
    for i, g in enumerate(groups):
        d = points[g] - points[g].mean(axis=0)
        assert np.allclose(
            [sxx[i], syy[i], sxy[i]], [d[:, 0] @ d[:, 0], d[:, 1] @ d[:, 1], d[:, 0] @ d[:, 1]]
        )
