"""Immutable value types shared by the robot agent, the server and the kernels (SI units)."""

from shared.types.geometry import (
    BoolArray,
    FloatArray,
    IntArray,
    LineSegment,
    as_points,
    canonical_hesse,
    hesse_from_endpoints,
    point_line_distance,
    segments_from_hesse,
)
from shared.types.pose import Pose2D, wrap_angle
from shared.types.scan import URG04LX, BeamGeometry, Scan

__all__ = [
    "URG04LX",
    "BeamGeometry",
    "BoolArray",
    "FloatArray",
    "IntArray",
    "LineSegment",
    "Pose2D",
    "Scan",
    "as_points",
    "canonical_hesse",
    "hesse_from_endpoints",
    "point_line_distance",
    "segments_from_hesse",
    "wrap_angle",
]
