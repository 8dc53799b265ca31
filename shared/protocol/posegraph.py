"""The pose graph's part of a map upload (issue 21 item 2): keyframe rows, loop-closure edges, the current
pose's covariance, and how a correction of keyframes moves a trajectory recorded before it.

Rows, as they go on the wire:

- a keyframe ``[keyframe_id, stamp_s, x_m, y_m, theta_rad]`` (world frame, corrected after each
  optimisation of the graph);
- a loop closure ``[keyframe_id_a, keyframe_id_b]`` (an accepted edge between two keyframes);
- the pose covariance, a 3x3 matrix over ``(x_m, y_m, theta_rad)`` in the world frame (m^2, m*rad,
  rad^2): symmetric and positive semi-definite within :data:`COV_TOLERANCE`.

:func:`correct_trajectory` is the rule a server and a viewer use to redraw a trajectory they hold when a
delta moves keyframes: a pose recorded after keyframe ``k`` (and before the next) moves with ``k``, i.e.
``p' = K'_k K_k^-1 p`` with ``K_k`` the keyframe's pose before and ``K'_k`` after. It is exact for the
robot's own rule (:mod:`shared.slam.mapper`: a step's pose is ``G(k) F(k)^-1 F(s)``). O(N log K).

:func:`keyframes_in_use` bounds what a store keeps of them (issue 21, a day with loop closure): a keyframe
serves only to move the poses it owns, so once a trajectory is thinned
(:func:`shared.protocol.thin_positions`) the keyframes owning none of the poses kept are dropped, with
the loop closures that reach them. Dropping them changes no kept pose's owner, and a row arriving later
for a dropped keyframe (older than the newest kept) moves nothing and is left out. Both sides apply it
to what they hold: the robot (its Robot DB's snapshot rows and what it records) and the server (its
stored map), so neither grows with the distance driven: at most one keyframe per kept pose.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
import numpy.typing as npt

from shared.types import FloatArray

__all__ = [
    "COV_TOLERANCE",
    "MAX_KEYFRAMES",
    "MAX_LOOP_CLOSURES",
    "check_covariance",
    "correct_trajectory",
    "keyframes_in_use",
    "sigmas",
]

#: keyframes in one upload (a keyframe each 0.5 m: 100 km of driving)
MAX_KEYFRAMES = 200_000
#: loop-closure edges in one upload
MAX_LOOP_CLOSURES = 200_000
#: relative tolerance of the covariance checks (asymmetry and negative eigenvalues, against its largest
#: entry): what float rounding of an optimiser's marginal leaves, not more
COV_TOLERANCE = 1e-6


def check_covariance(cov: Sequence[Sequence[float]]) -> None:
    """Raise ``ValueError`` naming the problem unless ``cov`` is a finite symmetric positive semi-definite
    3x3 matrix (within :data:`COV_TOLERANCE` of its largest entry). O(1)."""
    a = np.asarray(cov, dtype=np.float64)
    if a.shape != (3, 3):
        raise ValueError(f"pose_covariance must be 3x3 over (x_m, y_m, theta_rad), got shape {a.shape}")
    if not np.isfinite(a).all():
        raise ValueError("pose_covariance must hold finite numbers")
    scale = max(float(np.abs(a).max()), 1e-300)
    asym = float(np.abs(a - a.T).max())
    if asym > COV_TOLERANCE * scale:
        raise ValueError(
            f"pose_covariance must be symmetric (entries differ by {asym:.3g} across the diagonal)"
        )
    low = float(np.linalg.eigvalsh(0.5 * (a + a.T))[0])
    if low < -COV_TOLERANCE * scale:
        raise ValueError(
            f"pose_covariance must be positive semi-definite (smallest eigenvalue {low:.3g}); expected a "
            "covariance in m^2, m*rad, rad^2"
        )


def sigmas(cov: Sequence[Sequence[float]]) -> tuple[float, float, float]:
    """One standard deviation of x (m), y (m) and heading (rad) of a checked covariance. O(1)."""
    return tuple(math.sqrt(max(float(cov[i][i]), 0.0)) for i in range(3))  # type: ignore[return-value]


def _compose(a: FloatArray, b: FloatArray) -> FloatArray:
    """Rigid motions ``a @ b`` row by row (``(N, 3)`` x, y, theta)."""
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    out = np.empty_like(b)
    out[:, 0] = a[:, 0] + c * b[:, 0] - s * b[:, 1]
    out[:, 1] = a[:, 1] + s * b[:, 0] + c * b[:, 1]
    out[:, 2] = np.remainder(a[:, 2] + b[:, 2] + math.pi, 2.0 * math.pi) - math.pi
    return out


def _inverse(a: FloatArray) -> FloatArray:
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    out = np.empty_like(a)
    out[:, 0] = -(c * a[:, 0] + s * a[:, 1])
    out[:, 1] = s * a[:, 0] - c * a[:, 1]
    out[:, 2] = -a[:, 2]
    return out


def correct_trajectory(
    trajectory: FloatArray, before: Mapping[int, Sequence[float]], after: Mapping[int, Sequence[float]]
) -> FloatArray:
    """``trajectory`` ``(N, 4)`` rows ``[stamp_s, x_m, y_m, theta_rad]`` moved with its keyframes: each
    row after keyframe ``k`` (by stamp, ``before``'s keyframes, rows ``[stamp_s, x_m, y_m, theta_rad]`` by
    id) is moved by ``after[k] before[k]^-1`` when ``after`` has ``k``; rows before the first keyframe,
    or whose keyframe did not move, stay. Returns a new array. O(N log K)."""
    traj = np.array(trajectory, dtype=np.float64).reshape(-1, 4)
    moved = [k for k in after if k in before]
    if not len(traj) or not moved:
        return traj
    ids = sorted(before, key=lambda k: (float(before[k][0]), k))
    stamps = np.array([float(before[k][0]) for k in ids])
    owner = np.searchsorted(stamps, traj[:, 0], side="right") - 1  # the keyframe at or before each row
    old = np.array([before[k][1:4] for k in ids], dtype=np.float64).reshape(-1, 3)
    new = old.copy()
    for i, k in enumerate(ids):
        if k in after:
            new[i] = np.asarray(after[k][1:4], dtype=np.float64)
    delta = _compose(new, _inverse(old))  # per keyframe: the world-frame correction
    hit = owner >= 0
    traj[hit, 1:4] = _compose(delta[owner[hit]], traj[hit, 1:4])
    return traj


def keyframes_in_use(keyframes: Sequence[Sequence[float]], pose_stamps: npt.ArrayLike) -> set[int]:
    """The ids of ``keyframes`` (rows ``[keyframe_id, stamp_s, ...]``) that a store holding poses stamped
    ``pose_stamps`` (s) needs: each pose's owner (:func:`correct_trajectory`'s rule, the last keyframe at
    or before it by ``(stamp, id)``) and every keyframe stamped after the last pose (the owners of poses
    to come, the newest among them). Removing the others changes no pose's owner. O((N + K) log K)."""
    if not len(keyframes):
        return set()
    order = sorted(range(len(keyframes)), key=lambda i: (float(keyframes[i][1]), int(keyframes[i][0])))
    ids = np.array([int(keyframes[i][0]) for i in order], dtype=np.int64)
    stamps = np.array([float(keyframes[i][1]) for i in order])
    t = np.asarray(pose_stamps, dtype=np.float64).reshape(-1)
    if not len(t):
        return {int(k) for k in ids}
    owner = np.searchsorted(stamps, t, side="right") - 1
    used = np.zeros(len(ids), dtype=bool)
    used[owner[owner >= 0]] = True
    used |= stamps > float(t.max())
    return {int(k) for k in ids[used]}
