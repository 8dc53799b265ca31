"""Measuring a map (docs/design.md §5): area error, line accuracy against true walls, and relation error.

Pure functions on arrays; the only file I/O is :func:`read_relations` (module ``relations_io``).
"""

from shared.metrics.area import EnclosedArea, area_error_pct, enclosed_area, map_area_m2
from shared.metrics.errors import MapLeakError, MetricError, MetricInputError, RelationsFormatError
from shared.metrics.lines import LineAccuracy, line_accuracy
from shared.metrics.relations import RelationError, relation_error
from shared.metrics.relations_io import Relations, parse_relations, read_relations
from shared.metrics.trajectory import TrajectoryError, absolute_trajectory_error

__all__ = [
    "EnclosedArea",
    "LineAccuracy",
    "MapLeakError",
    "MetricError",
    "MetricInputError",
    "RelationError",
    "Relations",
    "RelationsFormatError",
    "TrajectoryError",
    "absolute_trajectory_error",
    "area_error_pct",
    "enclosed_area",
    "line_accuracy",
    "map_area_m2",
    "parse_relations",
    "read_relations",
    "relation_error",
]
