"""The fused pose must agree with the linear fusion of the match and odometry (shared.pipeline.fusion):
the linear fusion lies between its two inputs, and fuse_gated falls back to it when Gauss-Newton's
result lies farther off than ``fusion_chi2`` allows, only for scanners with a range-noise model."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.pipeline import IcpGate
from shared.pipeline.fusion import fuse_gated
from shared.pipeline.fusion_solve import linear_fusion, mahalanobis2
from shared.pipeline.rangenoise import NO_RANGE_NOISE, URG04LX_RANGE_NOISE
from shared.sim import RangeNoise, World, simulate_scan
from shared.sim.world import polygon_walls
from shared.types import Pose2D

_sd = st.floats(1e-3, 1.0)
_value = st.floats(-1.0, 1.0)


@settings(max_examples=200, deadline=None)
@given(
    st.tuples(_value, _value, _value),
    st.tuples(_value, _value, _value),
    st.tuples(_sd, _sd, _sd),
    st.tuples(_sd, _sd, _sd),
)
def test_the_linear_fusion_lies_between_its_inputs_by_their_weights(
    odo: tuple[float, float, float],
    match: tuple[float, float, float],
    sd_odo: tuple[float, float, float],
    sd_scan: tuple[float, float, float],
) -> None:
    a, b = Pose2D(*odo), Pose2D(*match)
    i_odo, i_scan = np.diag(1.0 / np.square(sd_odo)), np.diag(1.0 / np.square(sd_scan))
    fused, posterior = linear_fusion(a, b, i_odo, i_scan)
    np.testing.assert_allclose(posterior, i_odo + i_scan)
    for k, (u, v) in enumerate(zip(odo, match, strict=True)):
        w = i_scan[k, k] / (i_odo[k, k] + i_scan[k, k])
        expected = u + w * (v - u) if k < 2 else u + w * math.remainder(v - u, math.tau)
        got = (fused.x_m, fused.y_m, fused.theta_rad)[k]
        assert math.remainder(got - expected, math.tau) == pytest.approx(0.0, abs=1e-9)
    assert mahalanobis2(fused, fused, posterior) == 0.0


def test_a_scan_that_says_nothing_leaves_odometry_and_the_heading_wraps() -> None:
    odo, match = Pose2D(0.1, 0.2, math.pi - 0.01), Pose2D(0.5, -0.3, -math.pi + 0.01)
    fused, _ = linear_fusion(odo, match, np.eye(3), np.zeros((3, 3)))
    assert (fused.x_m, fused.y_m) == pytest.approx((0.1, 0.2))
    half, _ = linear_fusion(odo, match, np.eye(3), np.eye(3))
    assert abs(math.remainder(half.theta_rad - math.pi, math.tau)) < 1e-9  # halfway across +-pi, not 0
    assert mahalanobis2(odo, match, np.eye(3)) == pytest.approx(0.4**2 + 0.5**2 + 0.02**2)


def _corridor_case() -> tuple[np.ndarray, np.ndarray, Pose2D, Pose2D]:
    """A corridor whose ends are out of range, a matcher that slid back along it, odometry 3 cm long."""
    h = 0.8
    world = World(
        polygon_walls([(0.0, -h), (40.0, -h), (40.0, h), (0.0, h)]),
        64.0,
        "corridor",
        np.array([[0.5, 0.0], [39.5, 0.0]]),
    )
    ref = simulate_scan(world, Pose2D(20.0, 0.0, 0.0), np.random.default_rng(0), RangeNoise()).to_points()[0]
    cur = simulate_scan(world, Pose2D(20.3, 0.1, 0.02), np.random.default_rng(1), RangeNoise()).to_points()[0]
    return ref, cur, Pose2D(0.2, 0.1, 0.02), Pose2D(0.33, 0.1, 0.02)


def test_a_fused_pose_off_the_linear_fusion_is_replaced_by_it() -> None:
    ref, cur, matched, odo = _corridor_case()
    off = replace(IcpGate(), fusion_chi2=0.0)
    strict = replace(IcpGate(), fusion_chi2=1e-12)  # any difference at all counts as inconsistent
    gauss_newton = fuse_gated(off, ref, cur, matched, odo, range_noise=URG04LX_RANGE_NOISE)
    linear = fuse_gated(strict, ref, cur, matched, odo, range_noise=URG04LX_RANGE_NOISE)
    assert gauss_newton != linear
    # the linear fusion lies between the slid match and odometry along the corridor
    assert min(matched.x_m, odo.x_m) <= linear.x_m <= max(matched.x_m, odo.x_m)
    default = fuse_gated(IcpGate(), ref, cur, matched, odo, range_noise=URG04LX_RANGE_NOISE)
    assert default == gauss_newton  # a consistent Gauss-Newton result stands


def test_without_a_range_noise_model_the_test_is_not_made() -> None:
    ref, cur, matched, odo = _corridor_case()
    strict = replace(IcpGate(), fusion_chi2=1e-12)
    off = replace(IcpGate(), fusion_chi2=0.0)
    assert fuse_gated(strict, ref, cur, matched, odo, range_noise=NO_RANGE_NOISE) == fuse_gated(
        off, ref, cur, matched, odo, range_noise=NO_RANGE_NOISE
    )
