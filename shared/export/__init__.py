"""Map export: GeoJSON (segments, centroids, trajectory, pose), trajectory CSV, MCAP (Foxglove) and SVG/PNG
drawings.

Also DXF drawings (units metres) and ROS map_server occupancy maps (PGM + YAML), each with a reader.
All coordinates are metres in the log's world frame, angles radians, stamps seconds (docs/design.md §3).
"""

from shared.export.dxf import DXFMap, encode_dxf, read_dxf, write_dxf
from shared.export.errors import (
    DXFFormatError,
    EmptyMapError,
    ExportError,
    ExportIOError,
    GeoJSONFormatError,
    McapMapError,
    OccupancyFormatError,
    SVGFormatError,
    TrajectoryCSVError,
    UnsupportedFormatError,
)
from shared.export.geojson import read_geojson_segments, write_geojson
from shared.export.mcap import MCAP_TOPICS, McapMap, read_map_mcap, write_map_mcap
from shared.export.occupancy import (
    OccupancyGrid,
    occupancy_files,
    occupancy_paths,
    rasterise_segments,
    read_occupancy,
    write_occupancy,
)
from shared.export.render import render_map, scale_bar_length_m
from shared.export.svg_meta import SVGMap, read_svg_segments
from shared.export.trajectory import TRAJECTORY_HEADER, read_trajectory_csv, write_trajectory_csv

__all__ = [
    "MCAP_TOPICS",
    "TRAJECTORY_HEADER",
    "DXFFormatError",
    "DXFMap",
    "EmptyMapError",
    "ExportError",
    "ExportIOError",
    "GeoJSONFormatError",
    "McapMap",
    "McapMapError",
    "OccupancyFormatError",
    "OccupancyGrid",
    "SVGFormatError",
    "SVGMap",
    "TrajectoryCSVError",
    "UnsupportedFormatError",
    "encode_dxf",
    "occupancy_files",
    "occupancy_paths",
    "rasterise_segments",
    "read_dxf",
    "read_geojson_segments",
    "read_map_mcap",
    "read_occupancy",
    "read_svg_segments",
    "read_trajectory_csv",
    "render_map",
    "scale_bar_length_m",
    "write_dxf",
    "write_geojson",
    "write_map_mcap",
    "write_occupancy",
    "write_trajectory_csv",
]
