"""Streaming reader of CARMEN text logs (``.clf``/``.log``): ACES, Freiburg 079, MIT CSAIL, Freiburg clinic.

One message per line, whitespace separated, ``#`` comments (layouts in :mod:`shared.io.carmen_format`):

- ``FLASER``/``RLASER`` (old style): ``n`` ranges, laser pose, robot odometry pose, timestamps. Beam 0 at
  -90 deg, spacing after CARMEN's rule (1 deg for 180/181 beams, 0.5 deg for 360/361) unless the PARAM
  ``laser_front_laser_resolution`` (deg) says otherwise.
- ``ROBOTLASER1``/``ROBOTLASER2`` (new style): start angle, angular resolution, maximum range and an
  optional remission per beam travel in the record (``start + i * res``, the fov field is not needed).
- ``ODOM`` is checked (field count, numbers) and counted, ``PARAM`` kept (:attr:`CarmenReader.params`);
  comments and unknown message types are skipped and counted.

Each laser record becomes a :class:`Scan`: ``stamp_s`` = ``ipc_timestamp``, ``odometry`` = the *robot* pose
of the record (what the Kümmerle et al. benchmark evaluates), ranges in metres with "no return" as NaN:
readings ``>= max_range`` (ROBOTLASER: its ``max_range`` field; FLASER: PARAM ``robot_front_laser_max``, else
:data:`DEFAULT_FLASER_MAX_RANGE_M`), readings ``<= 0`` and, for SICK scanners (FLASER/RLASER, and
ROBOTLASER with laser_type 0), the SICK error codes from :data:`SICK_ERROR_MIN_M` (81.83 m) up. The
laser mounting offset (laser pose in the robot frame) comes from the first laser record, else from PARAM
``robot_frontlaser_offset``. Cost O(beams) per line; memory O(beams).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Iterator
from pathlib import Path
from types import MappingProxyType

import numpy as np

from shared.errors import InvalidInputError
from shared.io.carmen_format import (
    DEFAULT_FLASER_MAX_RANGE_M,
    FLASER_LAYOUT,
    FLASER_START_RAD,
    FRONT_LASER_RECORDS,
    ODOM_LAYOUT,
    REAR_LASER_RECORDS,
    ROBOTLASER_LAYOUT,
    SICK_ERROR_MIN_M,
    flaser_increment_rad,
)
from shared.io.carmen_write import write_carmen
from shared.io.errors import LogFormatError
from shared.io.reader import LogInfo, LogReader, parse_count, parse_floats
from shared.types import BeamGeometry, FloatArray, Pose2D, Scan

__all__ = ["CarmenReader", "write_carmen"]

logger = logging.getLogger(__name__)

_FLASER_TAIL = ("x", "y", "theta", "odom_x", "odom_y", "odom_theta", "ipc_timestamp", "ipc_hostname")
_ROBOTLASER_HEAD = ("laser_type", "start_angle", "fov", "angular_res", "max_range", "accuracy")
_ROBOTLASER_TAIL = (
    *("laser_x", "laser_y", "laser_theta", "robot_x", "robot_y", "robot_theta"),
    *("tv", "rv", "forward_safety_dist", "side_safety_dist", "turn_axis", "ipc_timestamp"),
)
_FLASER_TAIL_ALL = (*_FLASER_TAIL, "logger_timestamp")
_ROBOTLASER_TAIL_ALL = (*_ROBOTLASER_TAIL, "ipc_hostname", "logger_timestamp")
_ODOM_NAMES = ("ODOM", "x", "y", "theta", "tv", "rv", "accel", "ipc_timestamp", "ipc_hostname")
#: PARAMs the reader uses (per laser side): (max range m, resolution deg, mounting offset m).
_SIDE_PARAMS = {
    "front": ("robot_front_laser_max", "laser_front_laser_resolution", "robot_frontlaser_offset"),
    "rear": ("robot_rear_laser_max", "laser_rear_laser_resolution", "robot_rearlaser_offset"),
}
#: Offsets derived from two 6-decimal poses are rounded to this many decimals (10 um, 10 urad).
_OFFSET_DECIMALS = 5


#: CARMEN's laser_type code of a SICK LMS.
_SICK_LMS = 0


def _no_return_to_nan(ranges: FloatArray, cutoff_m: float) -> FloatArray:
    """Ranges with readings ``>= cutoff_m``, ``<= 0`` or non-finite replaced by NaN (in place). O(n)."""
    with np.errstate(invalid="ignore"):
        bad = ~((ranges > 0.0) & (ranges < cutoff_m))
    ranges[bad] = np.nan
    return ranges


class CarmenReader(LogReader):
    """Stream the scans of one laser (``laser="front"``: FLASER + ROBOTLASER1; ``"rear"``: RLASER +
    ROBOTLASER2) of a CARMEN log; ``max_range_m`` overrides the FLASER no-return cut-off.

    Reads ahead to the first laser record when opened, so :attr:`info` is complete at once.
    """

    format_name = "carmen"

    def __init__(self, path: Path | str, *, laser: str = "front", max_range_m: float | None = None) -> None:
        if laser not in _SIDE_PARAMS:
            raise InvalidInputError(f"CARMEN laser {laser!r}: expected 'front' or 'rear'")
        if max_range_m is not None and not (math.isfinite(max_range_m) and max_range_m > 0.0):
            raise InvalidInputError(f"max_range_m = {max_range_m!r}: expected a positive number of metres")
        names = FRONT_LASER_RECORDS if laser == "front" else REAR_LASER_RECORDS
        self._parsers: dict[str, Callable[[list[str], int], Scan]] = {
            names[0]: self._parse_flaser,
            names[1]: self._parse_robotlaser,
        }
        self._max_param, self._res_param, self._offset_param = _SIDE_PARAMS[laser]
        self._max_override = max_range_m
        self.params: dict[str, str] = {}
        self.record_counts: dict[str, int] = {}
        self._numeric_params: dict[str, float] = {}
        self._flaser_geometry: dict[int, tuple[float, float, float]] = {}
        self._laser_offset: Pose2D | None = None
        self._first_geometry: BeamGeometry | None = None
        self._warned_remissions = False
        super().__init__(path)
        self._prime()
        offset = self._laser_offset
        if offset is None:
            offset = Pose2D(self._numeric_params.get(self._offset_param, 0.0), 0.0, 0.0)
        self._info = LogInfo(
            self.format_name,
            self.path,
            self._first_geometry,
            offset,
            None,
            self._compressed,
            MappingProxyType(dict(self.params)),
        )

    def _read_scans(self) -> Iterator[Scan]:
        counts = self.record_counts
        parsers = self._parsers
        for line_no, text in self._lines():
            fields = text.split()
            if not fields or fields[0][0] == "#":
                continue
            name = fields[0]
            counts[name] = counts.get(name, 0) + 1
            parser = parsers.get(name)
            if parser is not None:
                scan = parser(fields, line_no)
                if self._first_geometry is None:
                    self._first_geometry = BeamGeometry(
                        scan.angle_min_rad,
                        scan.angle_increment_rad,
                        scan.beam_count,
                        scan.range_min_m,
                        scan.range_max_m,
                    )
                yield scan
            elif name == "ODOM":
                self._check_odom(fields, line_no)
            elif name == "PARAM":
                self._take_param(fields, line_no)
            elif not name[0].isalpha():
                raise LogFormatError(
                    self.path,
                    line_no,
                    f"line starts with {name[:20]!r}: expected a CARMEN message name "
                    "(FLASER, ODOM, PARAM, ...) or a # comment",
                )
            elif counts[name] == 1:
                logger.debug("%s line %d: skipping %s records", self.path.name, line_no, name)

    # -- records ---------------------------------------------------------------------------------------

    def _take_param(self, fields: list[str], line_no: int) -> None:
        """Keep ``PARAM name value ...``; the ones the reader uses must be numbers."""
        if len(fields) < 3:
            raise LogFormatError(
                self.path, line_no, f"PARAM has {len(fields) - 1} fields: expected a name and a value"
            )
        key, value = fields[1], fields[2]
        self.params[key] = value
        if key in (self._max_param, self._res_param, self._offset_param):
            try:
                number = float(value)
            except ValueError:
                number = math.nan
            positive = key != self._offset_param
            if not math.isfinite(number) or (positive and number <= 0.0):
                what = "a positive number" if positive else "a number"
                raise LogFormatError(self.path, line_no, f"PARAM {key} = {value!r}: expected {what}")
            self._numeric_params[key] = number
            self._flaser_geometry.clear()

    def _check_odom(self, fields: list[str], line_no: int) -> None:
        """Validate an ``ODOM`` record (10 fields, numbers where numbers belong)."""
        if len(fields) != len(_ODOM_NAMES) + 1:
            raise LogFormatError(
                self.path,
                line_no,
                f"ODOM has {len(fields)} fields: expected {len(_ODOM_NAMES) + 1} ({ODOM_LAYOUT})",
            )
        parse_floats(self.path, line_no, fields, ((1, 8), (9, 10)), self._odom_name)

    @staticmethod
    def _odom_name(i: int) -> str:
        return _ODOM_NAMES[i] if i < len(_ODOM_NAMES) else "logger_timestamp"

    def _flaser_layout(self, beam_count: int) -> tuple[float, float, float]:
        """``(angle_min, increment, max_range)`` of an old-style record of ``beam_count`` beams."""
        layout = self._flaser_geometry.get(beam_count)
        if layout is None:
            inc = flaser_increment_rad(beam_count)
            res_deg = self._numeric_params.get(self._res_param)
            if res_deg is not None:
                from_param = math.radians(res_deg)
                if (beam_count - 1) * from_param <= math.pi + 1e-9:
                    inc = from_param
                else:
                    logger.warning(
                        "%s: %d beams at %s = %s deg exceed 180 deg; using %.4f deg",
                        self.path.name, beam_count, self._res_param, res_deg, math.degrees(inc),
                    )  # fmt: skip
            max_range = self._max_override or self._numeric_params.get(
                self._max_param, DEFAULT_FLASER_MAX_RANGE_M
            )
            layout = (FLASER_START_RAD, inc, max_range)
            self._flaser_geometry[beam_count] = layout
        return layout

    def _remember_offset(
        self, line_no: int, name: str, laser: tuple[float, float, float], robot: Pose2D
    ) -> None:
        try:
            rel = robot.between(Pose2D(*laser))
        except InvalidInputError:  # finite poses whose difference overflows (|x| near 1e308)
            raise LogFormatError(
                self.path,
                line_no,
                f"{name} laser pose {laser} is too far from robot pose {robot.as_tuple()}: their offset is "
                "not a finite number",
            ) from None
        self._laser_offset = Pose2D(
            round(rel.x_m, _OFFSET_DECIMALS) + 0.0,
            round(rel.y_m, _OFFSET_DECIMALS) + 0.0,
            round(rel.theta_rad, _OFFSET_DECIMALS) + 0.0,
        )

    def _finite_or_raise(
        self, line_no: int, fields: list[str], values: FloatArray, first_field: int, names: tuple[str, ...]
    ) -> None:
        """Raise if a value of consecutive fields from ``first_field`` (poses, stamps) is not finite."""
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            i = int(bad[0])
            raise LogFormatError(
                self.path,
                line_no,
                f"{fields[0]} field {first_field + i} ({names[i]}) = {fields[first_field + i]!r}: "
                "expected a finite number",
            )

    def _parse_flaser(self, fields: list[str], line_no: int) -> Scan:
        """``FLASER n r_1..r_n x y theta odom_x odom_y odom_theta ipc_timestamp host logger_timestamp``."""
        name = fields[0]
        n = parse_count(self.path, line_no, fields, 1, "num_readings")
        expected = n + 11
        if len(fields) != expected:
            if len(fields) < 11:
                reason = f"{name} record is truncated: {len(fields)} fields, expected {expected}"
            else:
                reason = f"{name} declares {n} ranges but has {len(fields) - 11} values"
            raise LogFormatError(self.path, line_no, f"{reason} ({FLASER_LAYOUT})")

        def name_of(i: int) -> str:
            return f"r_{i - 1}" if i < n + 2 else _FLASER_TAIL_ALL[i - n - 2]

        nums = parse_floats(self.path, line_no, fields, ((2, n + 9), (n + 10, n + 11)), name_of)
        tail = nums[n:]
        self._finite_or_raise(line_no, fields, tail[:7], n + 2, _FLASER_TAIL)
        x, y, th, ox, oy, oth, stamp = tail[:7].tolist()
        robot = Pose2D(ox, oy, oth)
        if self._laser_offset is None:
            self._remember_offset(line_no, name, (x, y, th), robot)
        start, inc, max_range = self._flaser_layout(n)
        ranges = _no_return_to_nan(nums[:n], min(max_range, SICK_ERROR_MIN_M))
        return Scan(stamp, start, inc, 0.0, max_range, ranges, odometry=robot)

    def _parse_robotlaser(self, fields: list[str], line_no: int) -> Scan:
        """A ``ROBOTLASER1`` record (layout in :data:`ROBOTLASER_LAYOUT`)."""
        name = fields[0]
        path = self.path
        laser_type = parse_count(path, line_no, fields, 1, "laser_type")
        parse_count(path, line_no, fields, 7, "remission_mode")
        n = parse_count(path, line_no, fields, 8, "num_readings")
        if len(fields) <= 9 + n:
            raise LogFormatError(
                path,
                line_no,
                f"{name} declares {n} ranges but has {max(len(fields) - 9, 0)} values and no remission count "
                f"(expected at least {n + 24} fields: {ROBOTLASER_LAYOUT})",
            )
        token = fields[9 + n]
        n_rem = int(token) if token.isascii() and token.isdigit() else -1  # not '²': isdigit, no int
        if n_rem < 0:
            raise LogFormatError(
                path,
                line_no,
                f"{name} declares {n} ranges but field {9 + n}, the remission count after them, is "
                f"{token!r}: expected a non-negative integer (are there more or fewer ranges than declared?)",
            )
        expected = n + n_rem + 24
        if len(fields) != expected:
            raise LogFormatError(
                path,
                line_no,
                f"{name} declares {n} ranges and {n_rem} remissions but has {len(fields) - 24} values "
                f"(expected {expected} fields: {ROBOTLASER_LAYOUT})",
            )
        rem0 = 10 + n
        tail0 = rem0 + n_rem

        def name_of(i: int) -> str:
            if i < 7:
                return _ROBOTLASER_HEAD[i - 1]
            if i < 9 + n:
                return f"r_{i - 8}"
            if i < tail0:
                return f"rem_{i - rem0 + 1}"
            return _ROBOTLASER_TAIL_ALL[i - tail0]

        spans = ((2, 7), (9, 9 + n), (rem0, tail0 + 12), (expected - 1, expected))
        nums = parse_floats(path, line_no, fields, spans, name_of)
        self._finite_or_raise(line_no, fields, nums[:5], 2, _ROBOTLASER_HEAD[1:])
        start, _fov, res, max_range, _accuracy = nums[:5].tolist()
        if not math.isfinite(start + res * max(n - 1, 0)):
            raise LogFormatError(
                path,
                line_no,
                f"{name} start_angle {fields[2]!r} + {n - 1} x angular_res {fields[4]!r}: expected beam "
                "angles that are finite numbers",
            )
        if res == 0.0 or max_range <= 0.0:
            i, what = (4, "a non-zero angle") if res == 0.0 else (5, "a positive range (m)")
            raise LogFormatError(
                path, line_no, f"{name} field {i} ({name_of(i)}) = {fields[i]!r}: expected {what}"
            )
        tail = nums[5 + n + n_rem :]
        self._finite_or_raise(line_no, fields, tail[:12], tail0, _ROBOTLASER_TAIL)
        lx, ly, lth, rx, ry, rth = tail[:6].tolist()
        robot = Pose2D(rx, ry, rth)
        if self._laser_offset is None:
            self._remember_offset(line_no, name, (lx, ly, lth), robot)
        intensities = None
        if n_rem:
            if n_rem == n:
                intensities = nums[5 + n : 5 + n + n_rem]
            elif not self._warned_remissions:
                self._warned_remissions = True
                logger.warning(
                    "%s line %d: %d remissions for %d ranges: remissions dropped",
                    path.name,
                    line_no,
                    n_rem,
                    n,
                )
        cutoff = min(max_range, SICK_ERROR_MIN_M) if laser_type == _SICK_LMS else max_range
        ranges = _no_return_to_nan(nums[5 : 5 + n], cutoff)
        return Scan(float(tail[11]), start, res, 0.0, max_range, ranges, intensities, odometry=robot)
