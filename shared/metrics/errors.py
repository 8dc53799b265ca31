"""Errors raised by the map metrics (docs/design.md §5)."""

from __future__ import annotations

from pathlib import Path

from shared.errors import InvalidInputError, LinemapError

__all__ = ["MapLeakError", "MetricError", "MetricInputError", "RelationsFormatError"]


class MetricError(LinemapError):
    """A map or trajectory metric cannot be computed for the data given."""


class MetricInputError(MetricError, InvalidInputError):
    """An array handed to a metric has the wrong shape or non-finite values (the message names it)."""


class MapLeakError(MetricError):
    """The map does not enclose the trajectory: the flood fill from ``inside_points`` reached open space.

    ``seed_xy`` is the first inside point whose region leaks; ``close_gaps_m`` the gap closing that was tried.
    """

    def __init__(self, message: str, *, seed_xy: tuple[float, float], close_gaps_m: float) -> None:
        super().__init__(message)
        self.seed_xy = seed_xy
        self.close_gaps_m = close_gaps_m


class RelationsFormatError(MetricError, ValueError):
    """A line of a Kümmerle et al. ``.relations`` file is malformed (``source``, 1-based ``line_number``)."""

    def __init__(self, source: str | Path, line_number: int, reason: str) -> None:
        self.source = str(source)
        self.line_number = line_number
        self.reason = reason
        super().__init__(f"{source}:{line_number}: {reason}")
