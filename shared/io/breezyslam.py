"""Streaming reader of the BreezySLAM / CoreSLAM URG-04LX logs (``exp1.dat``, ``exp2.dat``).

One scan per line, whitespace-separated integers (the data's SOURCE.md): field 0 the timestamp in
microseconds, fields 2 and 3 the cumulative left and right wheel encoder ticks (Q1, Q2), fields 4..23
undocumented telemetry (not checked), fields 24..705 the 682 URG-04LX ranges in millimetres, field 706 a
trailing value BreezySLAM drops (required here: a line of any other length is an error, so a lost range
can never shift the others). Ranges 0..19 mm are URG error codes, i.e. no return (NaN).

Odometry: the encoders are integrated with the robot model (default :data:`shared.odometry.MINES_ROVER`,
paper §2 eq. 9-11), starting at the origin on the first scan; each scan carries the robot pose.
Beam geometry: :data:`shared.types.URG04LX` (steps 44..725, counter-clockwise). O(beams) per line.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from shared.errors import InvalidInputError
from shared.io.errors import LogFormatError
from shared.io.reader import LogInfo, LogReader, parse_floats
from shared.odometry import MINES_ROVER, DiffDrive
from shared.types import URG04LX, BeamGeometry, Pose2D, Scan

__all__ = ["FIRST_RANGE_FIELD", "URG_ERROR_MAX_MM", "BreezySlamReader"]

#: Index of the first range field.
FIRST_RANGE_FIELD = 24
#: Readings up to this many millimetres are URG error codes (the URG-04LX measures from 20 mm).
URG_ERROR_MAX_MM = 19.0

_HEAD_NAMES = {0: "timestamp_us", 2: "left_ticks_Q1", 3: "right_ticks_Q2"}


class BreezySlamReader(LogReader):
    """Stream the scans of a BreezySLAM ``.dat`` log; ``robot`` integrates the encoders, ``geometry`` gives
    the beam layout (its beam count fixes the number of range fields)."""

    format_name = "breezyslam"

    def __init__(
        self, path: Path | str, *, robot: DiffDrive = MINES_ROVER, geometry: BeamGeometry = URG04LX
    ) -> None:
        self._robot = robot
        self._geometry = geometry
        super().__init__(path)
        self._info = LogInfo(
            self.format_name, self.path, geometry, robot.laser_offset, robot, self._compressed
        )

    def _read_scans(self) -> Iterator[Scan]:
        geometry, robot, path = self._geometry, self._robot, self.path
        n = geometry.beam_count
        stop = FIRST_RANGE_FIELD + n
        spans = ((0, 1), (2, 4), (FIRST_RANGE_FIELD, stop))

        def name_of(i: int) -> str:
            return _HEAD_NAMES.get(i, f"range_{i - FIRST_RANGE_FIELD + 1}_mm")

        pose: Pose2D | None = None
        q_left = q_right = 0.0
        for line_no, text in self._lines():
            fields = text.split()
            if not fields:
                continue
            if len(fields) != stop + 1:
                raise LogFormatError(
                    path,
                    line_no,
                    f"BreezySLAM scan has {len(fields)} fields: expected {stop + 1} (timestamp_us, counter, "
                    f"Q1, Q2, 20 telemetry fields, {n} ranges in mm, 1 trailing value)",
                )
            nums = parse_floats(path, line_no, fields, spans, name_of, "BreezySLAM")
            head = nums[:3]
            if not np.isfinite(head).all():
                i = (0, 2, 3)[int(np.flatnonzero(~np.isfinite(head))[0])]
                raise LogFormatError(
                    path,
                    line_no,
                    f"BreezySLAM field {i} ({name_of(i)}) = {fields[i]!r}: expected a finite number",
                )
            stamp_us, left, right = head.tolist()
            ranges_mm = nums[3:]
            with np.errstate(invalid="ignore"):
                no_return = ~(ranges_mm > URG_ERROR_MAX_MM)
            ranges_m = ranges_mm / 1000.0
            ranges_m[no_return] = np.nan
            try:
                pose = Pose2D() if pose is None else robot.step_ticks(pose, left - q_left, right - q_right)
            except (InvalidInputError, ValueError):  # tick steps near 1e308: no finite pose
                raise LogFormatError(
                    path,
                    line_no,
                    f"BreezySLAM encoder ticks Q1 = {fields[2]}, Q2 = {fields[3]} after {q_left:g}, "
                    f"{q_right:g}: the odometry step is not a finite number",
                ) from None
            q_left, q_right = left, right
            yield Scan(
                stamp_us / 1e6,
                geometry.angle_min_rad,
                geometry.angle_increment_rad,
                geometry.range_min_m,
                geometry.range_max_m,
                ranges_m,
                odometry=pose,
            )
