"""How much the pose graph's edges are believed: covariance floors, closures held where they are blind, and
the gates a loop closure must pass (:mod:`shared.slam.mapper` builds the edges; these are its rules).

- :func:`with_floor`: an edge's information with a floor on its covariance for what a match misses
  (``SEQ_FLOOR_*``: 2 mm + 0.5 % of the travel, 0.02 degrees + 0.03 degrees per metre + 0.5 % of the turn);
- :func:`hold_unseen`: a closure's translation along the directions its covariance leaves wider than
  :data:`HOLD_SIGMA_M` becomes the graph's own estimate, with (next to) no information there;
- :func:`consistent`: a closure must agree with the graph within chi-square's 99.9 % point for 3 degrees of
  freedom (:data:`INNOVATION_CHI2`) under its covariance plus the chain's inflated by
  :data:`CHAIN_INFLATION`; :data:`AGREEMENT_CHI2` bounds how far its two estimates may differ.

Units: m, rad; information in m^-2 and rad^-2. Every function is O(1) (3x3 matrices).
"""

from __future__ import annotations

import math

import numpy as np

from shared.types import FloatArray, Pose2D

__all__ = [
    "AGREEMENT_CHI2",
    "CHAIN_INFLATION",
    "HOLD_SIGMA_M",
    "INNOVATION_CHI2",
    "SEQ_FLOOR_M",
    "SEQ_FLOOR_PER_M",
    "SEQ_FLOOR_RAD",
    "SEQ_FLOOR_RAD_PER_M",
    "SEQ_FLOOR_RAD_PER_RAD",
    "consistent",
    "hold_unseen",
    "with_floor",
]

#: what a scan-to-scan edge misses beyond its point-to-line information (one sigma): m, per m of the
#: edge's translation; rad, rad per m, rad per rad of its turn
SEQ_FLOOR_M = 0.002
SEQ_FLOOR_PER_M = 0.005
SEQ_FLOOR_RAD = 0.0003
SEQ_FLOOR_RAD_PER_M = 0.0005
SEQ_FLOOR_RAD_PER_RAD = 0.005
#: a loop closure's two estimates (ICP against the submap, point-to-line against the candidate keyframe's
#: scan) must agree within chi-square's 99 % point for 3 degrees of freedom under the second's
#: information: where they do not, one of them paired returns wrongly (clutter seen from another side)
AGREEMENT_CHI2 = 11.34
#: a loop closure must agree with the graph within chi-square's 99.9 % point for 3 degrees of freedom
#: under its own covariance plus the chain's (:func:`consistent`), the chain's variance taken
#: CHAIN_INFLATION times larger: the sequential edges' information is what the simulator's front end
#: errs by (normalised errors 0.2-1.2), a real scanner's front end errs by more than its model says
#: (timing, calibration, mixed pixels), and the gate is against gross errors only (a place that looks
#: alike 1-2 m along a corridor), not against drift
INNOVATION_CHI2 = 16.27
CHAIN_INFLATION = 10.0
#: a loop closure's translation directions with a standard deviation above this hold the graph's estimate
HOLD_SIGMA_M = 0.15


def with_floor(information: FloatArray, motion: Pose2D) -> FloatArray:
    """``(information^-1 + floor)^-1`` for an edge over ``motion``, the floor ``SEQ_FLOOR_*`` (computed
    without inverting a singular ``information``: Woodbury). O(1)."""
    dist = math.hypot(motion.x_m, motion.y_m)
    s_xy = SEQ_FLOOR_M + SEQ_FLOOR_PER_M * dist
    s_th = SEQ_FLOOR_RAD + SEQ_FLOOR_RAD_PER_M * dist + SEQ_FLOOR_RAD_PER_RAD * abs(motion.theta_rad)
    f_inv = np.diag([1.0 / s_xy**2, 1.0 / s_xy**2, 1.0 / s_th**2])
    out: FloatArray = f_inv - f_inv @ np.linalg.solve(np.asarray(information) + f_inv, f_inv)
    return 0.5 * (out + out.T) + np.eye(3) * 1e-6


def hold_unseen(predicted: Pose2D, pose: Pose2D, cov: FloatArray) -> tuple[Pose2D, FloatArray]:
    """A closure ``pose`` with covariance ``cov`` ``(3, 3)``, its translation along the directions ``cov``
    leaves wider than ``HOLD_SIGMA_M`` (along a corridor: the score surface is flat there) replaced by the
    graph's own estimate ``predicted``, with (next to) no information there; returns the pose and its
    information. A closure fixes what its scan sees and holds the rest, as the front end's second-chance
    matches do: many closures along one corridor would otherwise add up their arbitrary along-track places
    into a pull. O(1)."""
    out: FloatArray = np.asarray(np.linalg.inv(cov), dtype=np.float64)
    eig, vec = np.linalg.eigh(cov[:2, :2])
    blind = vec[:, eig > HOLD_SIGMA_M**2]
    if blind.shape[1] == 0:
        return pose, 0.5 * (out + out.T)
    d = np.array([predicted.x_m - pose.x_m, predicted.y_m - pose.y_m])
    pose_xy = np.array([pose.x_m, pose.y_m]) + blind @ (blind.T @ d)
    # the information: none along the blind directions (projected out of the translation block)
    keep = np.eye(3)
    keep[:2, :2] -= blind @ blind.T
    held = keep.T @ out @ keep + np.eye(3) * 1e-6
    return Pose2D(float(pose_xy[0]), float(pose_xy[1]), pose.theta_rad), 0.5 * (held + held.T)


def consistent(predicted: Pose2D, pose: Pose2D, info: FloatArray, chain: FloatArray) -> bool:
    """Whether a loop closure ``pose`` with information ``info`` agrees with the graph's estimate
    ``predicted`` of the same relative pose within ``INNOVATION_CHI2`` under the closure's covariance plus
    ``CHAIN_INFLATION`` times ``chain``, the covariance of the chain of sequential edges between the two
    keyframes: a closure the front end's own uncertainty cannot explain is a place that only looks alike.
    O(1)."""
    e = np.array(
        [
            pose.x_m - predicted.x_m,
            pose.y_m - predicted.y_m,
            math.remainder(pose.theta_rad - predicted.theta_rad, math.tau),
        ]
    )
    total = np.linalg.inv(info) + CHAIN_INFLATION * chain
    return float(e @ np.linalg.solve(total, e)) <= INNOVATION_CHI2
