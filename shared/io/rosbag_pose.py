"""Pose helpers of the ROS bag reader: quaternion <-> yaw, 3D transforms, odometry interpolation.

ROS carries orientations as unit quaternions ``(x, y, z, w)`` (REP 103) and times as integer nanoseconds;
the map is 2D, so a 3D transform is reduced to ``(x, y, yaw)`` after composing in 3D. Pure functions and
a small sorted buffer (:class:`OdometryTrack`); every operation is O(1) or O(log n) in the buffer size.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Mapping
from dataclasses import dataclass

from shared.errors import InvalidInputError
from shared.types import Pose2D, wrap_angle

__all__ = [
    "OdometryTrack",
    "Transform3D",
    "chain_transform",
    "interpolate_pose",
    "quaternion_from_yaw",
    "yaw_from_quaternion",
]

Quaternion = tuple[float, float, float, float]


def yaw_from_quaternion(x: float, y: float, z: float, w: float) -> float:
    """The heading (rad, wrapped to (-pi, pi]) of the rotation ``(x, y, z, w)``: the ZYX Euler yaw.

    ``atan2(2 (w z + x y), w^2 + x^2 - y^2 - z^2)``: scale-invariant, so the quaternion need not be of unit
    length. Raises :class:`InvalidInputError` for a non-finite or zero quaternion. O(1).
    """
    if not all(math.isfinite(v) for v in (x, y, z, w)) or x * x + y * y + z * z + w * w == 0.0:
        raise InvalidInputError(f"quaternion ({x}, {y}, {z}, {w}): expected finite values, not all zero")
    return wrap_angle(math.atan2(2.0 * (w * z + x * y), w * w + x * x - y * y - z * z))


def quaternion_from_yaw(yaw_rad: float) -> Quaternion:
    """The unit quaternion ``(x, y, z, w)`` of a rotation by ``yaw_rad`` about z (w >= 0). O(1)."""
    half = 0.5 * wrap_angle(yaw_rad)
    return (0.0, 0.0, math.sin(half), math.cos(half))


def interpolate_pose(t0_ns: int, p0: Pose2D, t1_ns: int, p1: Pose2D, t_ns: int) -> Pose2D:
    """The pose at ``t_ns`` between ``p0`` (at ``t0_ns``) and ``p1`` (at ``t1_ns``).

    Position linear in time; heading along the shorter arc of the circle (``p0.theta + f * wrap(p1.theta -
    p0.theta)``), so a turn across +-pi does not sweep the long way round. ``f`` is clamped to [0, 1]; equal
    times give ``p1``. O(1).
    """
    if t1_ns == t0_ns:
        return p1
    f = min(1.0, max(0.0, (t_ns - t0_ns) / (t1_ns - t0_ns)))
    if f == 0.0:
        return p0
    if f == 1.0:
        return p1
    d_theta = wrap_angle(p1.theta_rad - p0.theta_rad)
    return Pose2D(
        p0.x_m + f * (p1.x_m - p0.x_m),
        p0.y_m + f * (p1.y_m - p0.y_m),
        p0.theta_rad + f * d_theta,
    )


def _qmul(a: Quaternion, b: Quaternion) -> Quaternion:
    """Hamilton product ``a b`` of ``(x, y, z, w)`` quaternions."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    )


@dataclass(frozen=True, slots=True)
class Transform3D:
    """A rigid 3D transform (a ROS ``geometry_msgs/Transform``): translation (m) and rotation ``(x, y, z,
    w)``, normalised on construction. ``a @ b`` applies ``b`` in ``a``'s frame."""

    translation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rotation: Quaternion = (0.0, 0.0, 0.0, 1.0)

    def __post_init__(self) -> None:
        values = (*self.translation, *self.rotation)
        norm = math.sqrt(sum(v * v for v in self.rotation))
        if not all(math.isfinite(v) for v in values) or norm == 0.0:
            raise InvalidInputError(
                f"transform {self.translation} {self.rotation}: expected finite numbers and a non-zero "
                "quaternion"
            )
        x, y, z, w = (v / norm for v in self.rotation)
        object.__setattr__(self, "translation", tuple(float(v) for v in self.translation))
        object.__setattr__(self, "rotation", (x, y, z, w))

    def rotate(self, v: tuple[float, float, float]) -> tuple[float, float, float]:
        """The vector ``v`` rotated by this transform's rotation. O(1)."""
        q = self.rotation
        conj = (-q[0], -q[1], -q[2], q[3])
        x, y, z, _ = _qmul(_qmul(q, (v[0], v[1], v[2], 0.0)), conj)
        return (x, y, z)

    def __matmul__(self, other: Transform3D) -> Transform3D:
        rx, ry, rz = self.rotate(other.translation)
        tx, ty, tz = self.translation
        return Transform3D((tx + rx, ty + ry, tz + rz), _qmul(self.rotation, other.rotation))

    def tilt_rad(self) -> float:
        """Angle between this frame's z axis and the parent's (0 for a level mount, pi upside down)."""
        x, y, _, _ = self.rotation
        return math.acos(max(-1.0, min(1.0, 1.0 - 2.0 * (x * x + y * y))))

    def to_pose2d(self) -> Pose2D:
        """The 2D part: ``(x, y, yaw)``, dropping z, roll and pitch."""
        return Pose2D(self.translation[0], self.translation[1], yaw_from_quaternion(*self.rotation))


def chain_transform(
    parents: Mapping[str, tuple[str, Transform3D]], base: str, leaf: str
) -> Transform3D | None:
    """The pose of frame ``leaf`` in frame ``base`` through a tf tree, or ``None`` if ``base`` is not an
    ancestor of ``leaf``.

    ``parents[child] = (parent, transform of child in parent)``. Walks up from ``leaf``; a cycle ends the
    walk. O(depth).
    """
    result = Transform3D()
    node = leaf
    seen = {node}
    while node != base:
        step = parents.get(node)
        if step is None:
            return None
        parent, transform = step
        result = transform @ result
        if parent in seen:
            return None
        seen.add(parent)
        node = parent
    return result


class OdometryTrack:
    """A time-sorted buffer of odometry poses (stamps in integer ns) with interpolation between them.

    :meth:`pose_at` brackets a stamp by binary search and interpolates (:func:`interpolate_pose`); a stamp
    outside the buffer's span gets the nearest end pose. :meth:`prune` drops poses no longer needed, so the
    buffer stays small while a bag streams. O(log n) lookups, O(n) insertion out of order (rare).
    """

    def __init__(self) -> None:
        self._stamps: list[int] = []
        self._poses: list[Pose2D] = []
        self.latest_ns: int | None = None

    def __len__(self) -> int:
        return len(self._stamps)

    def add(self, stamp_ns: int, pose: Pose2D) -> None:
        """Insert a pose at its stamp (a pose with an existing stamp replaces it)."""
        stamps = self._stamps
        if not stamps or stamp_ns > stamps[-1]:
            stamps.append(stamp_ns)
            self._poses.append(pose)
        else:
            i = bisect.bisect_left(stamps, stamp_ns)
            if i < len(stamps) and stamps[i] == stamp_ns:
                self._poses[i] = pose
            else:
                stamps.insert(i, stamp_ns)
                self._poses.insert(i, pose)
        if self.latest_ns is None or stamp_ns > self.latest_ns:
            self.latest_ns = stamp_ns

    def pose_at(self, stamp_ns: int) -> tuple[Pose2D, bool] | None:
        """``(pose, inside)`` at ``stamp_ns``; ``inside`` is False when the stamp lies outside the buffer's
        span and the nearest end pose was used. ``None`` if the buffer is empty."""
        stamps = self._stamps
        if not stamps:
            return None
        i = bisect.bisect_left(stamps, stamp_ns)
        if i < len(stamps) and stamps[i] == stamp_ns:
            return self._poses[i], True
        if i == 0:
            return self._poses[0], False
        if i == len(stamps):
            return self._poses[-1], False
        return interpolate_pose(stamps[i - 1], self._poses[i - 1], stamps[i], self._poses[i], stamp_ns), True

    def prune(self, before_ns: int, keep_max: int) -> None:
        """Drop every pose older than the last one at or before ``before_ns``, then the oldest beyond
        ``keep_max`` poses."""
        stamps = self._stamps
        cut = bisect.bisect_right(stamps, before_ns) - 1
        cut = max(cut, len(stamps) - keep_max)
        if cut > 0:
            del stamps[:cut]
            del self._poses[:cut]
