"""The robot's trajectory as CSV: header ``stamp,x,y,theta``, one row per scan, seconds, metres, radians.

Stamps are written with ``%.6f`` (microseconds): the benchmark logs print ``ipc_timestamp`` with 6 decimals
and their ``.relations`` files with 6 (ACES, FR079) or 5 (MIT CSAIL), so a stamp read from a log is written
back as the identical string and can be matched to a relations file string-for-string (ACES, FR079) or by
nearest value (MIT CSAIL). Stamps finer than 1 us are rounded. Poses use ``%.9f`` (nm, nrad).
"""

from __future__ import annotations

import logging
import math
import os

import numpy as np
from numpy.typing import ArrayLike

from shared.export.atomic import atomic_write_text, read_text
from shared.export.errors import TrajectoryCSVError
from shared.export.validate import check_rows
from shared.types import FloatArray

__all__ = ["TRAJECTORY_HEADER", "read_trajectory_csv", "write_trajectory_csv"]

_log = logging.getLogger(__name__)

TRAJECTORY_HEADER = "stamp,x,y,theta"
"""The exact first line of a trajectory CSV file."""

_FIELDS = TRAJECTORY_HEADER.split(",")


def _fmt(value: float, decimals: int) -> str:
    text = f"{value:.{decimals}f}"
    return text[1:] if text.startswith("-") and float(text) == 0.0 else text  # no "-0.000"


def write_trajectory_csv(path: str | os.PathLike[str], trajectory: ArrayLike) -> None:
    """Write ``trajectory`` ``(T, 4)`` rows ``[stamp_s, x_m, y_m, theta_rad]`` to ``path`` as CSV.

    Header exactly ``stamp,x,y,theta``; one row per input row in input order; ``\\n`` line ends; written
    atomically (temp file + rename). Raises :class:`shared.errors.InvalidInputError` for a wrong shape or
    non-finite values, :class:`~shared.export.errors.ExportIOError` when the file cannot be written. O(T).
    """
    rows = check_rows(trajectory, 4, "trajectory", "[stamp_s, x_m, y_m, theta_rad] rows")
    lines = [TRAJECTORY_HEADER]
    lines.extend(f"{_fmt(s, 6)},{_fmt(x, 9)},{_fmt(y, 9)},{_fmt(t, 9)}" for s, x, y, t in rows.tolist())
    atomic_write_text(path, "\n".join(lines) + "\n")
    _log.debug("wrote trajectory %s: %d poses", path, rows.shape[0])


def read_trajectory_csv(path: str | os.PathLike[str]) -> tuple[FloatArray, FloatArray]:
    """Read a trajectory CSV written by :func:`write_trajectory_csv`: ``(stamps_s (T,), poses (T, 3))``.

    ``poses`` rows are ``[x_m, y_m, theta_rad]``. The first line must be exactly ``stamp,x,y,theta``
    (surrounding spaces, a UTF-8 BOM and ``\\r\\n`` line ends are tolerated); blank lines are skipped; every
    other line must hold four finite numbers. Raises :class:`TrajectoryCSVError` naming the file, the line
    number (1-based) and what was expected; :class:`~shared.export.errors.ExportIOError` if unreadable. O(T).
    """
    lines = read_text(path, TrajectoryCSVError).splitlines()
    if not lines:
        raise TrajectoryCSVError(f"{path}: file is empty: expected the header line '{TRAJECTORY_HEADER}'")
    header = [f.strip() for f in lines[0].split(",")]
    if header != _FIELDS:
        raise TrajectoryCSVError(f"{path}: line 1 is {lines[0]!r}: expected the header '{TRAJECTORY_HEADER}'")
    values: list[list[float]] = []
    for lineno, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        fields = line.split(",")
        if len(fields) != 4:
            raise TrajectoryCSVError(
                f"{path}: line {lineno} has {len(fields)} fields: expected 4 ({TRAJECTORY_HEADER})"
            )
        row: list[float] = []
        for name, field in zip(_FIELDS, fields, strict=True):
            try:
                value = float(field)
            except ValueError:
                value = math.nan
            if not math.isfinite(value):
                raise TrajectoryCSVError(
                    f"{path}: line {lineno}: {name} = {field.strip()!r}: expected a finite number"
                ) from None
            row.append(value)
        values.append(row)
    arr = np.array(values, dtype=np.float64).reshape(-1, 4)
    _log.debug("read trajectory %s: %d poses", path, arr.shape[0])
    return np.ascontiguousarray(arr[:, 0]), np.ascontiguousarray(arr[:, 1:])
