"""Differential-drive odometry (paper §2, eq. 1-11) from wheel displacements or encoder ticks.

With left/right wheel displacements ``dD_l``, ``dD_r`` over one step and tread ``w`` (docs/design.md §3):
``dtheta = (dD_r - dD_l) / w`` (eq. 9), forward ``ds = (dD_r + dD_l) / 2`` and
``dx = ds cos(theta0)``, ``dy = ds sin(theta0)`` (eq. 10-11) at the heading ``theta0`` of the step's start.
The paper assumes ``dtheta`` small; :func:`integrate` can also integrate at the mid-step heading
(``midpoint=True``, exact for constant curvature to second order), which is the default because it costs
nothing and is what a robot turning at 10 Hz needs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from shared.errors import InvalidInputError
from shared.types import Pose2D

__all__ = ["MINES_ROVER", "PLAT_F1", "DiffDrive", "integrate"]


@dataclass(frozen=True, slots=True)
class DiffDrive:
    """Geometry of a differential-drive robot and its encoders (SI units).

    ``ticks_per_turn`` counts encoder ticks per wheel revolution; ``laser_offset`` is the scanner's pose in
    the robot frame (x forward from the wheel axle's midpoint).
    """

    wheel_diameter_m: float
    tread_m: float
    ticks_per_turn: float
    laser_offset: Pose2D = field(default_factory=Pose2D)

    def __post_init__(self) -> None:
        for name in ("wheel_diameter_m", "tread_m", "ticks_per_turn"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise InvalidInputError(f"DiffDrive.{name} = {value!r}: expected a positive finite number")

    @property
    def metres_per_tick(self) -> float:
        """Wheel travel per encoder tick: ``pi d / ticks_per_turn``."""
        return math.pi * self.wheel_diameter_m / self.ticks_per_turn

    def wheel_displacements(self, d_ticks_left: float, d_ticks_right: float) -> tuple[float, float]:
        """Left and right wheel travel (m) for encoder tick increments (eq. 1 integrated over a step)."""
        k = self.metres_per_tick
        return d_ticks_left * k, d_ticks_right * k

    def step(self, pose: Pose2D, d_left_m: float, d_right_m: float, midpoint: bool = True) -> Pose2D:
        """The robot pose after the wheels travelled ``d_left_m``, ``d_right_m`` from ``pose``."""
        return integrate(pose, d_left_m, d_right_m, self.tread_m, midpoint)

    def step_ticks(
        self, pose: Pose2D, d_ticks_left: float, d_ticks_right: float, midpoint: bool = True
    ) -> Pose2D:
        """The robot pose after encoder tick increments ``d_ticks_left``, ``d_ticks_right``."""
        d_l, d_r = self.wheel_displacements(d_ticks_left, d_ticks_right)
        return integrate(pose, d_l, d_r, self.tread_m, midpoint)

    def laser_pose(self, robot_pose: Pose2D) -> Pose2D:
        """The scanner's pose in the world for a robot pose."""
        return robot_pose @ self.laser_offset


def integrate(
    pose: Pose2D, d_left_m: float, d_right_m: float, tread_m: float, midpoint: bool = True
) -> Pose2D:
    """One odometry step, paper eq. 9-11. O(1).

    ``midpoint=False`` is the paper's form (translation along the start heading); ``True`` translates along
    the mid-step heading ``theta0 + dtheta / 2``.
    """
    d_theta = (d_right_m - d_left_m) / tread_m  # eq. 9
    ds = 0.5 * (d_right_m + d_left_m)  # eq. 8 over one step
    heading = pose.theta_rad + (0.5 * d_theta if midpoint else 0.0)
    return Pose2D(
        pose.x_m + ds * math.cos(heading),  # eq. 10
        pose.y_m + ds * math.sin(heading),  # eq. 11
        pose.theta_rad + d_theta,
    )


#: The BreezySLAM "MinesRover" (the URG-04LX logs' SOURCE.md): wheel radius r = 77 mm, half axle R = 165 mm,
#: laser 145 mm ahead of the axle. Its model ``d = r (pi / 2000) (dQ1 + dQ2)``,
#: ``dtheta = (r / R) (pi / 2000) (dQ2 - dQ1)`` is eq. 9-11 with a 154 mm wheel, 2000 ticks per turn and
#: a 330 mm tread (the path lengths it gives, ~46 m and ~44.5 m, match the logs' maps).
MINES_ROVER = DiffDrive(
    wheel_diameter_m=0.154, tread_m=0.330, ticks_per_turn=2000.0, laser_offset=Pose2D(0.145, 0.0, 0.0)
)

#: The paper's Plat-F1 (Japan Systems Design): its dimensions are not published; these are placeholders of
#: a typical small platform, to be replaced by the robot's configuration.
PLAT_F1 = DiffDrive(
    wheel_diameter_m=0.15, tread_m=0.40, ticks_per_turn=4096.0, laser_offset=Pose2D(0.1, 0.0, 0.0)
)
