"""The scanner's range noise in the scan matches: far returns count for what they are worth, the sensor is
read from the scan's range window, and a far noisy wall no longer drags a match along."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.errors import InvalidInputError
from shared.pipeline.fusion_solve import fuse_with_odometry
from shared.pipeline.localize import refine_to_walls
from shared.pipeline.rangenoise import (
    NO_RANGE_NOISE,
    URG04LX_RANGE_NOISE,
    RangeNoise,
    range_noise_for,
)
from shared.types import URG04LX, BeamGeometry, Pose2D, Scan

SIGMA_M = 0.02


def test_the_urg_noise_grows_with_range_beyond_a_metre() -> None:
    assert URG04LX_RANGE_NOISE.sigma_m(0.5) == pytest.approx(0.0125)
    assert URG04LX_RANGE_NOISE.sigma_m(4.0) == pytest.approx(0.05)
    assert NO_RANGE_NOISE.sigma_m(40.0) == 0.0


@pytest.mark.parametrize("bad", [-0.01, math.nan, math.inf])
def test_a_negative_or_non_finite_figure_is_refused_by_name(bad: float) -> None:
    with pytest.raises(InvalidInputError, match=r"RangeNoise\.ratio"):
        RangeNoise(0.01, bad)


def test_the_sensor_is_read_from_the_range_window() -> None:
    urg = Scan.from_geometry(URG04LX, np.full(URG04LX.beam_count, 2.0))
    assert range_noise_for(urg) == URG04LX_RANGE_NOISE
    sick = BeamGeometry.from_steps(0, 180, 90, 360, range_min_m=0.0, range_max_m=81.9, rate_hz=5.0)
    assert range_noise_for(Scan.from_geometry(sick, np.full(sick.beam_count, 2.0))) == NO_RANGE_NOISE


def _wall(x_m: float, y0: float, y1: float, n: int) -> np.ndarray:
    y = np.linspace(y0, y1, n)
    return np.column_stack([np.full(n, x_m), y])


def _two_walls(far_shift_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Reference and current scans (the same scanner pose) of a wall 1 m ahead and one 5 m behind; the far
    wall's current returns ``far_shift_m`` nearer (as a noisy far return may be)."""
    near, far = _wall(1.0, -0.5, 0.5, 80), _wall(-5.0, -2.0, 2.0, 80)
    ref = np.vstack([near, far])
    cur = np.vstack([near, far + np.array([far_shift_m, 0.0])])
    return ref, cur


def _expected_shift(far_shift_m: float, noise: RangeNoise) -> float:
    """The weighted least-squares x of the two walls' returns: each wall's offset by its returns' weight."""
    _, cur = _two_walls(far_shift_m)
    r = np.hypot(cur[:, 0], cur[:, 1])
    w = 1.0 / (SIGMA_M**2 + np.maximum(noise.near_m, noise.ratio * r) ** 2)
    offset = np.where(cur[:, 0] < 0.0, far_shift_m, 0.0)  # the far wall says "moved by -shift"
    return float(-(w * offset).sum() / w.sum())


@settings(max_examples=10, deadline=None)
@given(st.floats(0.01, 0.05))
def test_a_far_wall_counts_by_its_range_noise_in_the_fused_match(shift: float) -> None:
    ref, cur = _two_walls(shift)
    plain = fuse_with_odometry(ref, cur, Pose2D(), Pose2D(), np.eye(3), scan_only=True, max_points=1000)
    urg = fuse_with_odometry(
        ref,
        cur,
        Pose2D(),
        Pose2D(),
        np.eye(3),
        scan_only=True,
        max_points=1000,
        range_noise=URG04LX_RANGE_NOISE,
    )
    assert plain is not None and urg is not None
    assert plain.pose.x_m == pytest.approx(_expected_shift(shift, NO_RANGE_NOISE), abs=1e-3)
    assert urg.pose.x_m == pytest.approx(_expected_shift(shift, URG04LX_RANGE_NOISE), abs=1e-3)
    assert abs(urg.pose.x_m) < 0.35 * abs(plain.pose.x_m)  # the near wall decides
    # and the information says so: the far wall's returns carry less of it
    assert urg.information[0, 0] < 0.5 * plain.information[0, 0]


def test_a_far_wall_counts_by_its_range_noise_in_the_wall_refinement() -> None:
    walls = np.array([[1.0, -0.5, 1.0, 0.5], [-5.0, -2.0, -5.0, 2.0], [-5.0, -2.0, 1.0, -2.0]])
    base = np.vstack([_wall(1.0, -0.5, 0.5, 80), _wall(-5.0, -1.9, 1.9, 80)])
    side = np.column_stack([np.linspace(-4.5, 0.5, 80), np.full(80, -2.0)])  # fixes y
    shift = 0.04
    pts = np.vstack([base + np.where(base[:, :1] < 0.0, [shift, 0.0], [0.0, 0.0]), side])
    kwargs = {"iterations": 20, "damping": 1e-9}
    plain = refine_to_walls(pts, Pose2D(), walls, **kwargs)  # type: ignore[arg-type]
    urg = refine_to_walls(pts, Pose2D(), walls, range_noise=URG04LX_RANGE_NOISE, **kwargs)  # type: ignore[arg-type]
    assert plain is not None and urg is not None
    assert plain.pose.x_m == pytest.approx(-shift / 2, abs=2e-3)  # the two walls alike
    assert abs(urg.pose.x_m) < 0.35 * abs(plain.pose.x_m)
    same = refine_to_walls(pts, Pose2D(), walls, range_noise=NO_RANGE_NOISE, **kwargs)  # type: ignore[arg-type]
    assert same is not None and same.pose == plain.pose  # no model: every point alike, as before
