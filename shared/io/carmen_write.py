"""Write scans as a CARMEN text log that :class:`shared.io.carmen.CarmenReader` (and CARMEN tools) read back.

Layout: a header comment block, ``PARAM robot_front_laser_max`` (the first scan's ``range_max_m``, the
FLASER no-return cut-off) and ``PARAM robot_frontlaser_offset``, then per scan one ``ODOM`` line (optional)
and one laser line:

- ``FLASER`` when the old-style record describes the scan exactly: beam 0 at -90 deg, CARMEN's spacing for
  its beam count (1 deg for 180/181 beams, 0.5 deg for 360/361, see :mod:`shared.io.carmen_format`), the
  file's ``robot_front_laser_max`` as maximum range, and no intensities;
- ``ROBOTLASER1`` otherwise (e.g. the URG-04LX's 682 beams over 240 deg): it carries start angle, fov,
  resolution and maximum range (written at full precision, so the geometry round-trips exactly) and the
  intensities as remissions.

Ranges are written in metres with 3 decimals (1 mm, the URG's resolution). A beam that is not valid
(:meth:`Scan.valid_mask`: NaN, inf, outside ``[range_min_m, range_max_m]``) is written as the maximum range,
CARMEN's "no return"; a valid reading that would print as ``>= range_max_m`` is written 1 mm below it so it
stays valid. Poses (m, rad) and stamps (s) get 6 decimals. The laser pose written is
``odometry @ laser_offset``. The reader gives ``range_min_m = 0`` back (CARMEN has no minimum range).
"""

from __future__ import annotations

import gzip
import logging
import math
import os
from collections.abc import Iterable, Iterator
from itertools import chain
from pathlib import Path
from typing import TextIO

import numpy as np

from shared.errors import InvalidInputError
from shared.io.carmen_format import FLASER_START_RAD, SICK_ERROR_MIN_M, flaser_increment_rad
from shared.io.errors import LogError
from shared.types import Pose2D, Scan

__all__ = ["write_carmen"]

logger = logging.getLogger(__name__)

_IDENTITY = Pose2D()
_HOST = "linemap"
_HEADER = (
    "# CARMEN Logfile\n"
    "# written by linemap (shared.io.carmen.write_carmen); units m, rad, s\n"
    "# file format is one message per line\n"
    "# message_name [message contents] ipc_timestamp ipc_hostname logger_timestamp\n"
    "# message formats defined: PARAM ODOM FLASER ROBOTLASER1\n"
    "# PARAM param_name param_value\n"
    "# ODOM x y theta tv rv accel\n"
    "# FLASER num_readings [range_readings] x y theta odom_x odom_y odom_theta\n"
    "# ROBOTLASER1 laser_type start_angle field_of_view angular_resolution maximum_range accuracy "
    "remission_mode num_readings [range_readings] num_remissions [remission_values] laser_pose_x "
    "laser_pose_y laser_pose_theta robot_pose_x robot_pose_y robot_pose_theta laser_tv laser_rv "
    "forward_safety_dist side_safty_dist turn_axis\n"
)
#: CARMEN's laser_type code for "unknown proximity sensor" (we do not claim a SICK or a URG).
_UNKNOWN_LASER_TYPE = 99


def _is_flaser(scan: Scan, file_max_m: float) -> bool:
    """Whether an old-style FLASER record describes ``scan`` exactly. O(1)."""
    n = scan.beam_count
    return (
        scan.intensities is None
        and scan.range_max_m == file_max_m
        and file_max_m <= SICK_ERROR_MIN_M
        and abs(scan.angle_min_rad - FLASER_START_RAD) <= 1e-12
        and abs(scan.angle_increment_rad - flaser_increment_rad(n)) <= 1e-15
    )


def _format_ranges(scan: Scan) -> str:
    """The ranges as text: 3 decimals, invalid beams as the maximum range. O(beams)."""
    max_m = scan.range_max_m
    below_max = math.floor(max_m * 1000.0 - 1e-6) / 1000.0
    valid = scan.valid_mask()
    values = np.minimum(np.round(np.where(valid, scan.ranges_m, 0.0), 3), below_max).tolist()
    texts = [f"{v:.3f}" for v in values]
    no_return = repr(max_m)
    for i in np.flatnonzero(~valid).tolist():
        texts[i] = no_return
    return " ".join(texts)


def _pose_text(pose: Pose2D) -> str:
    return f"{pose.x_m:.6f} {pose.y_m:.6f} {pose.theta_rad:.6f}"


def _lines(scans: Iterator[Scan], first: Scan, laser_offset: Pose2D, odometry_records: bool) -> Iterator[str]:
    """The log's text, line by line (header included)."""
    file_max_m = first.range_max_m
    yield _HEADER
    yield f"PARAM robot_front_laser_max {file_max_m!r} 0.000000 {_HOST} 0.000000\n"
    yield f"PARAM robot_frontlaser_offset {laser_offset.x_m!r} 0.000000 {_HOST} 0.000000\n"
    t0 = first.stamp_s
    for index, scan in enumerate(chain((first,), scans)):
        if scan.odometry is None:
            raise InvalidInputError(
                f"scan {index} (stamp {scan.stamp_s} s) has no odometry pose: CARMEN laser records carry "
                "the robot's odometry; give every scan one"
            )
        robot = scan.odometry
        stamps = f"{scan.stamp_s:.6f} {_HOST} {scan.stamp_s - t0:.6f}"
        robot_text = _pose_text(robot)
        laser_text = _pose_text(robot @ laser_offset)
        if odometry_records:
            yield f"ODOM {robot_text} 0.000000 0.000000 0.000000 {stamps}\n"
        ranges = _format_ranges(scan)
        n = scan.beam_count
        if _is_flaser(scan, file_max_m):
            yield f"FLASER {n} {ranges} {laser_text} {robot_text} {stamps}\n"
            continue
        inc = scan.angle_increment_rad
        if scan.intensities is None:
            remissions = "0"
        else:
            remissions = " ".join([str(n), *(f"{v:.6g}" for v in scan.intensities.tolist())])
        yield (
            f"ROBOTLASER1 {_UNKNOWN_LASER_TYPE} {scan.angle_min_rad!r} {inc * max(n - 1, 0)!r} {inc!r} "
            f"{scan.range_max_m!r} 0.001 0 {n} {ranges} {remissions} {laser_text} {robot_text} "
            f"0.000000 0.000000 0.000000 0.000000 0.000000 {stamps}\n"
        )


def _open_for_writing(path: Path, compress: bool) -> TextIO:
    if compress:
        return gzip.open(path, "wt", encoding="ascii", compresslevel=6)
    return path.open("w", encoding="ascii", newline="\n")


def write_carmen(
    path: Path,
    scans: Iterable[Scan],
    *,
    laser_offset: Pose2D = _IDENTITY,
    odometry_records: bool = True,
) -> int:
    """Write ``scans`` (each with ``odometry`` set) to ``path`` as a CARMEN log; returns the scans written.

    ``laser_offset`` is the scanner's pose in the robot frame; ``odometry_records`` adds one ``ODOM`` line
    before each laser line. A ``.gz`` suffix writes gzip. The file appears whole or not at all (written to a
    temporary file beside it, then renamed). Streams: O(beams) memory, O(total beams) time.
    Raises :class:`InvalidInputError` for a scan without odometry, :class:`LogError` if it cannot write.
    """
    path = Path(path)
    iterator = iter(scans)
    first = next(iterator, None)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    count = 0
    try:
        with _open_for_writing(tmp, path.suffix == ".gz") as fh:
            if first is None:
                fh.write(_HEADER)
            else:
                for text in _lines(iterator, first, laser_offset, odometry_records):
                    fh.write(text)
                    count += text.startswith(("FLASER", "ROBOTLASER1"))
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise LogError(f"cannot write CARMEN log {path}: {exc}") from exc
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    logger.debug("wrote %d scans to %s", count, path)
    return count
