"""Errors raised by :mod:`shared.export` (map files: GeoJSON, trajectory CSV, rendered images).

Bad *arrays* handed to a writer raise :class:`shared.errors.InvalidInputError`; bad *files* and failed I/O
raise the classes below, whose messages name the file, the line or feature, and what was expected.
"""

from __future__ import annotations

from shared.errors import LinemapError

__all__ = [
    "ExportError",
    "ExportIOError",
    "GeoJSONFormatError",
    "TrajectoryCSVError",
    "UnsupportedFormatError",
]


class ExportError(LinemapError):
    """Root of the errors of :mod:`shared.export`."""


class ExportIOError(ExportError, OSError):
    """A map file could not be read or written (missing file, missing folder, no permission, disk full)."""


class GeoJSONFormatError(ExportError, ValueError):
    """A GeoJSON map file is not valid JSON or a segment feature breaks the output contract."""


class TrajectoryCSVError(ExportError, ValueError):
    """A trajectory CSV file has a bad header or a bad row."""


class UnsupportedFormatError(ExportError, ValueError):
    """The output file's suffix names a format the renderer cannot write."""
