"""Pose2D: composition, inverse and point transforms (hypothesis properties)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from shared.errors import InvalidInputError
from shared.types import Pose2D, wrap_angle

coord = st.floats(-100.0, 100.0, allow_nan=False)
angle = st.floats(-10.0, 10.0, allow_nan=False)
poses = st.builds(Pose2D, coord, coord, angle)


def close(a: Pose2D, b: Pose2D, tol: float = 1e-9) -> bool:
    return (
        abs(a.x_m - b.x_m) < tol
        and abs(a.y_m - b.y_m) < tol
        and abs(wrap_angle(a.theta_rad - b.theta_rad)) < tol
    )


@given(poses)
def test_inverse_composes_to_identity(p: Pose2D) -> None:
    assert close(p @ p.inverse(), Pose2D(), 1e-7)
    assert close(p.inverse() @ p, Pose2D(), 1e-7)


@given(poses, poses, poses)
def test_composition_is_associative(a: Pose2D, b: Pose2D, c: Pose2D) -> None:
    assert close((a @ b) @ c, a @ (b @ c), 1e-6)


@given(poses, poses)
def test_matches_homogeneous_matrices(a: Pose2D, b: Pose2D) -> None:
    m = a.as_matrix() @ b.as_matrix()
    assert close(Pose2D.from_matrix(m), a @ b, 1e-6)


@given(poses)
def test_transform_points_matches_matrix(p: Pose2D) -> None:
    pts = np.array([[1.0, 2.0], [-3.0, 0.5], [0.0, 0.0]])
    homo = np.column_stack([pts, np.ones(3)]) @ p.as_matrix().T
    np.testing.assert_allclose(p.transform_points(pts), homo[:, :2], atol=1e-9)


@given(angle)
def test_heading_is_wrapped(theta: float) -> None:
    t = Pose2D(0.0, 0.0, theta).theta_rad
    assert -math.pi < t <= math.pi
    assert math.isclose(math.cos(t), math.cos(theta), abs_tol=1e-9)


def test_between_is_relative_pose() -> None:
    a, b = Pose2D(1.0, 2.0, 0.5), Pose2D(3.0, -1.0, 2.0)
    assert close(a @ a.between(b), b)


@pytest.mark.parametrize("bad", [math.nan, math.inf])
def test_non_finite_rejected(bad: float) -> None:
    with pytest.raises(InvalidInputError, match="x_m"):
        Pose2D(bad, 0.0, 0.0)


@given(
    st.tuples(*[st.floats(-1e3, 1e3)] * 3),
    st.tuples(*[st.floats(-1e3, 1e3)] * 3),
)
def test_composition_builds_what_the_constructor_builds(
    a: tuple[float, float, float], b: tuple[float, float, float]
) -> None:
    """Composition and inverse skip the constructor's checks; their poses must equal constructed ones."""
    p, q = Pose2D(*a), Pose2D(*b)
    for pose in (p @ q, p.inverse(), p.between(q)):
        again = Pose2D(pose.x_m, pose.y_m, pose.theta_rad)
        assert pose == again and hash(pose) == hash(again)
        assert -math.pi < pose.theta_rad <= math.pi


def test_an_overflowing_composition_is_an_error() -> None:
    with pytest.raises(InvalidInputError, match="x_m"):
        Pose2D(1e308, 0.0, 0.0) @ Pose2D(1e308, 0.0, 0.0)
