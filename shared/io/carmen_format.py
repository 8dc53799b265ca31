"""The CARMEN text log format: record layouts and the beam geometry an old-style ``FLASER`` implies.

Old CARMEN records (``FLASER``/``RLASER``) carry no angles: CARMEN's own reader
(``carmen_laser_guess_angle_increment`` in ``readlog.c``) puts beam 0 at -90 deg and spaces the beams
1 deg for 180/181 beams, 0.5 deg for 360/361, 0.25 deg for 400/401, else 180 deg / (n - 1); beams run
counter-clockwise (beam 0 on the right). New-style ``ROBOTLASER1`` records carry start angle, field of view,
angular resolution and maximum range themselves.
"""

from __future__ import annotations

import math

__all__ = [
    "DEFAULT_FLASER_MAX_RANGE_M",
    "FLASER_LAYOUT",
    "FLASER_START_RAD",
    "FRONT_LASER_RECORDS",
    "ODOM_LAYOUT",
    "REAR_LASER_RECORDS",
    "ROBOTLASER_LAYOUT",
    "SICK_ERROR_MIN_M",
    "flaser_increment_rad",
]

#: Beam 0 of an old-style FLASER/RLASER record, radians (CARMEN: -M_PI / 2).
FLASER_START_RAD = -math.pi / 2.0

#: No-return cut-off of FLASER ranges when the log has no ``robot_front_laser_max`` PARAM: ACES marks
#: "no return" with 50.00 m, the SICK logs of Freiburg and MIT with 81.91 m (both >= 50 m). Readings at
#: or beyond the cut-off become NaN.
DEFAULT_FLASER_MAX_RANGE_M = 50.0

#: SICK LMS scanners (CARMEN laser_type 0, and every old-style FLASER/RLASER) report in centimetre mode
#: 8191 cm for "no object" and 8183..8190 cm for errors such as dazzling: readings from 81.83 m up are
#: never distances (the Freiburg clinic log has 5,849 readings of 81.83 m besides 81.91 m).
SICK_ERROR_MIN_M = 81.83

#: Message types that make scans, per laser.
FRONT_LASER_RECORDS = ("FLASER", "ROBOTLASER1")
REAR_LASER_RECORDS = ("RLASER", "ROBOTLASER2")

FLASER_LAYOUT = (
    "FLASER n r_1..r_n x y theta odom_x odom_y odom_theta ipc_timestamp ipc_hostname logger_timestamp"
)
ROBOTLASER_LAYOUT = (
    "ROBOTLASER1 laser_type start_angle fov angular_res max_range accuracy remission_mode n r_1..r_n "
    "n_rem rem_1..rem_nrem laser_x laser_y laser_theta robot_x robot_y robot_theta tv rv "
    "forward_safety_dist side_safety_dist turn_axis ipc_timestamp ipc_hostname logger_timestamp"
)
ODOM_LAYOUT = "ODOM x y theta tv rv accel ipc_timestamp ipc_hostname logger_timestamp"


def flaser_increment_rad(beam_count: int) -> float:
    """Beam spacing CARMEN assumes for an old-style laser record of ``beam_count`` beams (rad). O(1)."""
    if beam_count in (180, 181):
        return math.pi / 180.0
    if beam_count in (360, 361):
        return math.pi / 360.0
    if beam_count in (400, 401):
        return math.pi / 720.0
    if beam_count <= 1:
        return math.pi
    return math.pi / (beam_count - 1)
