"""Map export: GeoJSON (segments, centroids, trajectory, pose), trajectory CSV and SVG/PNG drawings.

All coordinates are metres in the log's world frame, angles radians, stamps seconds (SPEC §3).
"""

from shared.export.errors import (
    ExportError,
    ExportIOError,
    GeoJSONFormatError,
    TrajectoryCSVError,
    UnsupportedFormatError,
)
from shared.export.geojson import read_geojson_segments, write_geojson
from shared.export.render import render_map, scale_bar_length_m
from shared.export.trajectory import TRAJECTORY_HEADER, read_trajectory_csv, write_trajectory_csv

__all__ = [
    "TRAJECTORY_HEADER",
    "ExportError",
    "ExportIOError",
    "GeoJSONFormatError",
    "TrajectoryCSVError",
    "UnsupportedFormatError",
    "read_geojson_segments",
    "read_trajectory_csv",
    "render_map",
    "scale_bar_length_m",
    "write_geojson",
    "write_trajectory_csv",
]
