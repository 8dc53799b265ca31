"""A scan match fused with odometry under the ICP gate's noise figures (docs/worlds.md): the pipeline's
policies over the solver of :mod:`shared.pipeline.fusion_solve` (Gauss-Newton on the point-to-line residuals
plus odometry's information, its objective and units there).

- :func:`fuse_gated`: the match fused with odometry, odometry's term robust (Huber) and scaled by the
  learned noise factors (:mod:`shared.pipeline.odonoise`), refused when it leaves the match's heading basin;
- :func:`hold_unseen_directions`: a second-chance match whose translation along the directions the scan
  does not fix is put back to odometry's;
- :func:`wheel_prior`: odometry's translation prior for the wall refinement
  (:func:`shared.pipeline.localize.refine_to_walls`).

:class:`~shared.pipeline.fusion_solve.Reference` and :func:`~shared.pipeline.fusion_solve.prepare_reference`
are importable from here too (the pipeline builds its keyframe references through this module).

Complexity: O(M) for the reference lines and grid, O(iterations x N) for the N current points.
"""

from __future__ import annotations

import math

import numpy as np

from shared.pipeline.fusion_solve import (
    Fused,
    Reference,
    fuse_with_odometry,
    linear_fusion,
    mahalanobis2,
    odometry_information,
    prepare_reference,
)
from shared.pipeline.gate import IcpGate
from shared.pipeline.odonoise import OdometryNoise
from shared.pipeline.rangenoise import NO_RANGE_NOISE, RangeNoise
from shared.types import FloatArray, Pose2D

__all__ = ["fuse_gated", "hold_unseen_directions", "wheel_prior"]


def fuse_gated(
    gate: IcpGate,
    reference: FloatArray | Reference,
    current: FloatArray,
    matched: Pose2D,
    odometry: Pose2D,
    noise: OdometryNoise | None = None,
    range_noise: RangeNoise = NO_RANGE_NOISE,
) -> Pose2D:
    """``matched`` (scanner motion from the reference) fused with the ``odometry`` scanner motion under the
    gate's noise figures (``odom_sigma_*``, ``match_sigma_m``); ``matched`` itself when fusion is off or
    finds too few pairs.

    Gauss-Newton starts from odometry: the point-to-line objective with nearest-point association has a
    local minimum wherever it starts along a direction the scan does not constrain (each point keeps its
    neighbour), so that direction keeps odometry's value; from the match it would keep the matcher's slide.
    Odometry's term is robust (Huber): when the match lies farther than ``odom_huber`` standard deviations
    from it (Mahalanobis distance under the sum of odometry's and the scan's covariance, so only what the
    scan constrains counts: a wheel slipping in a turn, a stalled encoder stream), its information is
    scaled down by ``(odom_huber / distance)^2``. A fused pose whose heading is farther from the match's than
    the gate's ``max_correction_rad`` (Gauss-Newton converged elsewhere: a scan fixes the heading well
    everywhere, corridors included) is not taken.

    With a ``noise`` estimate (:class:`shared.pipeline.odonoise.OdometryNoise`, the pipeline's learned
    state) odometry's model is scaled by the factors learned so far, and this match's innovation is added
    to what it learns from."""
    if not gate.fuse_odometry:
        return matched
    model = _model_information(gate, odometry)
    info = _scaled(model, noise)
    at = _scan_at(gate, reference, current, matched, range_noise)
    if at is None:
        return matched
    reference, scan = at
    e = np.array(
        [
            matched.x_m - odometry.x_m,
            matched.y_m - odometry.y_m,
            math.remainder(matched.theta_rad - odometry.theta_rad, math.tau),
        ]
    )
    if noise is None:  # the whole innovation under both covariances
        both = np.linalg.inv(info) + np.linalg.inv(scan.information + np.eye(3) * 1e-6)
        m2, dof = float(e @ np.linalg.solve(both, e)), 1
    else:  # only the parts the scan fixes far better than odometry (shared.pipeline.odonoise)
        r_xy, r_th = noise.ratios(e, scan.information, model)
        m2, dof = noise.consistency(r_xy, r_th)
        noise.update(r_xy, r_th)
    limit = gate.odom_huber**2 * max(dof, 1)
    if m2 > limit:
        info = info * (limit / m2)
    fused = fuse_with_odometry(
        reference, current, odometry, odometry, info, sigma_m=gate.match_sigma_m, range_noise=range_noise
    )
    if fused is None:
        return matched
    if abs(math.remainder(fused.pose.theta_rad - matched.theta_rad, math.tau)) > gate.max_correction_rad:
        return matched  # Gauss-Newton fell into another basin: scans fix the heading, it must agree
    if gate.fusion_chi2 > 0.0 and range_noise.near_m > 0.0:
        linear, posterior = linear_fusion(odometry, matched, info, scan.information)
        if mahalanobis2(fused.pose, linear, posterior) > gate.fusion_chi2:
            return linear  # Gauss-Newton's associations pulled it beyond what the two estimates allow
    return fused.pose


def _scan_at(
    gate: IcpGate,
    reference: FloatArray | Reference,
    current: FloatArray,
    pose: Pose2D,
    range_noise: RangeNoise,
) -> tuple[Reference, Fused] | None:
    """The prepared reference and the scan's own information at ``pose`` (one scan-only Gauss-Newton
    step); ``None`` when the reference or the pairs are too few."""
    if not isinstance(reference, Reference):
        prepared = prepare_reference(reference, range_noise=range_noise)
        if prepared is None:
            return None
        reference = prepared
    scan = fuse_with_odometry(
        reference,
        current,
        pose,
        pose,
        np.eye(3),
        iterations=1,
        scan_only=True,
        sigma_m=gate.match_sigma_m,
        range_noise=range_noise,
    )
    return None if scan is None else (reference, scan)


def _model_information(gate: IcpGate, motion: Pose2D) -> FloatArray:
    """Odometry's information over ``motion`` under the gate's noise figures (the model, unscaled)."""
    return odometry_information(
        motion,
        sigma_m=gate.odom_sigma_m,
        sigma_ratio=gate.odom_sigma_ratio,
        sigma_rad=gate.odom_sigma_rad,
        sigma_rad_per_rad=gate.odom_sigma_rad_per_rad,
    )


def _scaled(model: FloatArray, noise: OdometryNoise | None) -> FloatArray:
    """``model`` information divided by the learned variance factors (a copy; ``model`` when none)."""
    if noise is None:
        return model
    k = noise.scale
    d = 1.0 / np.sqrt([k.translation, k.translation, k.heading])
    return model * np.outer(d, d)


def wheel_prior(
    gate: IcpGate, scanner: Pose2D, motion: Pose2D, noise: OdometryNoise | None = None
) -> tuple[Pose2D | None, FloatArray | None]:
    """The odometry-predicted ``scanner`` pose and its information for the wall refinement
    (:func:`shared.pipeline.localize.refine_to_walls`), scaled to its residuals' variance
    (``match_sigma_m``): odometry's noise over one step's ``motion``, for the translation only (with a
    heading prior Freiburg 079's relation error was 0.075 m, without 0.054 m).
    ``(None, None)`` unless ``refine_with_odometry``; scaled by the learned ``noise`` factors if given."""
    if not gate.refine_with_odometry:
        return None, None
    info = _scaled(_model_information(gate, motion), noise).copy()
    info[2, 2] = 0.0  # translation only: the walls fix the heading wherever they fix anything
    return scanner, info * gate.match_sigma_m**2


def hold_unseen_directions(
    gate: IcpGate,
    reference: FloatArray | Reference,
    current: FloatArray,
    matched: Pose2D,
    odometry: Pose2D,
    noise: OdometryNoise | None = None,
    range_noise: RangeNoise = NO_RANGE_NOISE,
) -> Pose2D:
    """A second-chance match (odometry found wrong) with its translation along the directions the scan
    does not fix put back to odometry's: the search behind it picks one of many equally good poses along a
    corridor's axis, and there odometry still knows better.

    The scan's information at ``matched`` (Gauss-Newton's normal matrix, the heading marginalised out of
    the translation by its Schur complement) is compared, per eigen-direction ``v`` of the translation,
    with odometry's (the gate's model over ``odometry``, scaled by the learned ``noise``): where the scan's
    is the smaller, the match's translation along ``v`` becomes odometry's, and the heading moves by its
    conditional shift ``-H_tt^-1 H_t,xy dxy``. Everything the scan fixes stays the match's, so a wheel that
    slipped in a turn or a stalled encoder stream is still corrected; no Gauss-Newton from the (wrong)
    odometry, so no other basin. ``matched`` itself when fusion is off or the scan has too few pairs.
    O(N) for N points."""
    if not gate.fuse_odometry:
        return matched
    at = _scan_at(gate, reference, current, matched, range_noise)
    if at is None:
        return matched
    _, scan = at
    h = scan.information
    h_tt = max(float(h[2, 2]), 1e-12)
    marginal = h[:2, :2] - np.outer(h[:2, 2], h[2, :2]) / h_tt
    odo_xy = float(_scaled(_model_information(gate, odometry), noise)[0, 0])
    values, vectors = np.linalg.eigh(marginal)
    d = np.array([odometry.x_m - matched.x_m, odometry.y_m - matched.y_m])
    shift = np.zeros(2)
    for k in range(2):
        if values[k] < odo_xy:
            v = vectors[:, k]
            shift += v * float(v @ d)
    if not shift.any():
        return matched
    dth = -float(h[2, :2] @ shift) / h_tt
    return Pose2D(matched.x_m + shift[0], matched.y_m + shift[1], matched.theta_rad + dth)
