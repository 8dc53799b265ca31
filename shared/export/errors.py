"""Errors raised by :mod:`shared.export` (map files: GeoJSON, trajectory CSV, MCAP, rendered images).

Bad *arrays* handed to a writer raise :class:`shared.errors.InvalidInputError`; bad *files* and failed I/O
raise the classes below, whose messages name the file, the line or feature, and what was expected.
"""

from __future__ import annotations

from shared.errors import LinemapError

__all__ = [
    "DXFFormatError",
    "EmptyMapError",
    "ExportError",
    "ExportIOError",
    "GeoJSONFormatError",
    "McapMapError",
    "OccupancyFormatError",
    "SVGFormatError",
    "TrajectoryCSVError",
    "UnsupportedFormatError",
]


class ExportError(LinemapError):
    """Root of the errors of :mod:`shared.export`."""


class ExportIOError(ExportError, OSError):
    """A map file could not be read or written (missing file, missing folder, no permission, disk full)."""


class GeoJSONFormatError(ExportError, ValueError):
    """A GeoJSON map file is not valid JSON or a segment feature breaks the output contract."""


class McapMapError(ExportError, ValueError):
    """An MCAP map file has the wrong name, cannot be decoded, or lacks the topics and markers linemap
    writes."""


class TrajectoryCSVError(ExportError, ValueError):
    """A trajectory CSV file has a bad header or a bad row."""


class UnsupportedFormatError(ExportError, ValueError):
    """The output file's suffix names a format the renderer cannot write."""


class DXFFormatError(ExportError, ValueError):
    """A DXF map file is not DXF, is damaged, or its units cannot be converted to metres."""


class OccupancyFormatError(ExportError, ValueError):
    """A ROS map_server map (PGM image or its YAML) is malformed or the two do not fit together."""


class SVGFormatError(ExportError, ValueError):
    """An SVG file is not XML or carries no linemap map metadata (it was not drawn by linemap)."""


class EmptyMapError(ExportError, ValueError):
    """The map has no walls, and the format needs some (an occupancy grid has no extent without them)."""
