"""2D rigid poses (SE(2)) in SI units, REP 103 conventions (x forward, y left, angles counter-clockwise)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["Pose2D", "wrap_angle"]


def wrap_angle(angle_rad: float) -> float:
    """Wrap an angle to (-pi, pi]. O(1)."""
    wrapped = math.remainder(angle_rad, 2.0 * math.pi)
    return math.pi if wrapped == -math.pi else wrapped


@dataclass(frozen=True, slots=True)
class Pose2D:
    """A 2D pose or rigid transform: translation (m) and heading (rad, wrapped to (-pi, pi]).

    ``a @ b`` composes: the pose ``b`` expressed in frame ``a`` gives ``a @ b`` in the parent frame
    (paper §2, eq. 9-11 integrate displacements the same way).
    """

    x_m: float = 0.0
    y_m: float = 0.0
    theta_rad: float = 0.0

    def __post_init__(self) -> None:
        x, y, theta = float(self.x_m), float(self.y_m), float(self.theta_rad)
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(theta)):
            from shared.errors import InvalidInputError

            for name, value in (("x_m", x), ("y_m", y), ("theta_rad", theta)):
                if not math.isfinite(value):
                    raise InvalidInputError(f"Pose2D.{name} = {value!r}: expected a finite number")
        object.__setattr__(self, "x_m", x)
        object.__setattr__(self, "y_m", y)
        object.__setattr__(self, "theta_rad", wrap_angle(theta))

    def __matmul__(self, other: Pose2D) -> Pose2D:
        c, s = math.cos(self.theta_rad), math.sin(self.theta_rad)
        return _composed(
            self.x_m + c * other.x_m - s * other.y_m,
            self.y_m + s * other.x_m + c * other.y_m,
            self.theta_rad + other.theta_rad,
        )

    def compose(self, other: Pose2D) -> Pose2D:
        """``self @ other``: apply ``other`` in this pose's frame."""
        return self @ other

    def inverse(self) -> Pose2D:
        """The transform that undoes this one: ``p @ p.inverse()`` is the identity."""
        c, s = math.cos(self.theta_rad), math.sin(self.theta_rad)
        return _composed(-c * self.x_m - s * self.y_m, s * self.x_m - c * self.y_m, -self.theta_rad)

    def between(self, other: Pose2D) -> Pose2D:
        """The relative pose ``self^-1 @ other`` (other expressed in this frame)."""
        return self.inverse() @ other

    def as_matrix(self) -> NDArray[np.float64]:
        """The 3x3 homogeneous matrix of this transform."""
        c, s = math.cos(self.theta_rad), math.sin(self.theta_rad)
        return np.array([[c, -s, self.x_m], [s, c, self.y_m], [0.0, 0.0, 1.0]])

    @classmethod
    def from_matrix(cls, matrix: NDArray[np.float64]) -> Pose2D:
        """Build a pose from a 3x3 homogeneous (or 2x3) rigid transform matrix."""
        return cls(float(matrix[0, 2]), float(matrix[1, 2]), math.atan2(matrix[1, 0], matrix[0, 0]))

    def transform_points(self, points: NDArray[np.float64]) -> NDArray[np.float64]:
        """Map an (N, 2) array of points from this pose's frame to the parent frame. O(N)."""
        c, s = math.cos(self.theta_rad), math.sin(self.theta_rad)
        rot = np.array([[c, s], [-s, c]])
        out: NDArray[np.float64] = points @ rot + np.array([self.x_m, self.y_m])
        return out

    def as_tuple(self) -> tuple[float, float, float]:
        """``(x_m, y_m, theta_rad)``."""
        return (self.x_m, self.y_m, self.theta_rad)


def _composed(x: float, y: float, theta: float) -> Pose2D:
    """The pose ``(x, y, theta)`` computed from valid poses (floats already): what the constructor would
    build, without its conversions and checks (a pipeline step composes about forty poses; a composition
    took about 2 us with them, 0.75 us without). Non-finite results (an overflow) still go through the
    constructor's error."""
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(theta)):
        return Pose2D(x, y, theta)
    pose = object.__new__(Pose2D)
    object.__setattr__(pose, "x_m", x)
    object.__setattr__(pose, "y_m", y)
    object.__setattr__(pose, "theta_rad", wrap_angle(theta))
    return pose
