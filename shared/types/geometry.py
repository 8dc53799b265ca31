"""Point sets and straight line segments in SI units.

Points are plain ``(N, 2)`` float64 arrays (metres). A line is kept both as end points and in Hesse normal
form ``rho = x cos(theta) + y sin(theta)`` (paper eq. 34) with ``theta`` in ``[0, pi)`` and ``rho`` signed,
the convention of the Hough accumulator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from shared.errors import InvalidInputError

__all__ = [
    "BoolArray",
    "FloatArray",
    "IntArray",
    "LineSegment",
    "as_points",
    "canonical_hesse",
    "hesse_from_endpoints",
    "point_line_distance",
    "segments_from_hesse",
]

BoolArray = NDArray[np.bool_]
FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]


def as_points(points: ArrayLike, *, name: str = "points") -> FloatArray:
    """Validate and return ``points`` as a C-contiguous ``(N, 2)`` float64 array (a copy only if needed).

    Non-finite rows are allowed (kernels drop them); a wrong shape raises :class:`InvalidInputError`.
    """
    arr = np.asarray(points, dtype=np.float64)
    if arr.size == 0:
        return np.zeros((0, 2), dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise InvalidInputError(f"{name} has shape {arr.shape}: expected (N, 2) x/y coordinates in metres")
    return np.ascontiguousarray(arr)


def canonical_hesse(rho: ArrayLike, theta: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Map ``(rho, theta)`` to the equivalent line with ``theta`` in ``[0, pi)``.

    ``(rho, theta)`` and ``(-rho, theta + pi)`` are the same line (docs/design.md §4, the Hough seam). O(N).
    """
    r = np.asarray(rho, dtype=np.float64)
    t = np.asarray(theta, dtype=np.float64)
    turns = np.floor(t / np.pi)
    t2 = t - turns * np.pi
    flip = (turns.astype(np.int64) % 2) != 0
    r2 = np.where(flip, -r, r)
    # floating point can leave t2 == pi exactly, or a denormal just below 0 (t / pi underflows to -0.0)
    below = t2 < 0.0
    t2 = np.where(below, t2 + np.pi, t2)
    r2 = np.where(below, -r2, r2)
    at_pi = t2 >= np.pi
    t2 = np.where(at_pi, t2 - np.pi, t2)
    r2 = np.where(at_pi, -r2, r2)
    return np.asarray(r2, dtype=np.float64), np.asarray(t2, dtype=np.float64)


def hesse_from_endpoints(segments: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Hesse normal form ``(rho, theta)`` of the infinite lines through ``(L, 4)`` segments ``[x0,y0,x1,y1]``.

    Degenerate (zero-length) segments get ``theta`` from the direction of the point itself. O(L).
    """
    seg = np.asarray(segments, dtype=np.float64).reshape(-1, 4)
    dx = seg[:, 2] - seg[:, 0]
    dy = seg[:, 3] - seg[:, 1]
    theta = np.arctan2(dx, -dy)  # normal = direction rotated by -90 deg
    degenerate = (dx == 0.0) & (dy == 0.0)
    theta = np.where(degenerate, np.arctan2(seg[:, 1], seg[:, 0]), theta)
    rho = seg[:, 0] * np.cos(theta) + seg[:, 1] * np.sin(theta)
    return canonical_hesse(rho, theta)


def segments_from_hesse(rho: ArrayLike, theta: ArrayLike, t0: ArrayLike, t1: ArrayLike) -> FloatArray:
    """End points ``(L, 4)`` of lines ``(rho, theta)`` between line parameters ``t0`` and ``t1``.

    A point on the line is ``rho * n + t * d`` with normal ``n = (cos, sin)`` and direction
    ``d = (-sin, cos)``. O(L).
    """
    r = np.asarray(rho, dtype=np.float64)
    t = np.asarray(theta, dtype=np.float64)
    c, s = np.cos(t), np.sin(t)
    a = np.asarray(t0, dtype=np.float64)
    b = np.asarray(t1, dtype=np.float64)
    return np.stack([r * c - a * s, r * s + a * c, r * c - b * s, r * s + b * c], axis=-1).reshape(-1, 4)


def point_line_distance(points: FloatArray, rho: float, theta: float) -> FloatArray:
    """Signed orthogonal distance of ``(N, 2)`` points to the line ``(rho, theta)``. O(N)."""
    return np.asarray(points[:, 0] * math.cos(theta) + points[:, 1] * math.sin(theta) - rho)


@dataclass(frozen=True, slots=True)
class LineSegment:
    """A straight wall piece between two end points (metres)."""

    x0_m: float
    y0_m: float
    x1_m: float
    y1_m: float

    @property
    def length_m(self) -> float:
        """Euclidean length."""
        return math.hypot(self.x1_m - self.x0_m, self.y1_m - self.y0_m)

    @property
    def hesse(self) -> tuple[float, float]:
        """``(rho_m, theta_rad)`` of the infinite line, ``theta`` in ``[0, pi)``."""
        rho, theta = hesse_from_endpoints([self.as_array()])
        return float(rho[0]), float(theta[0])

    def as_array(self) -> FloatArray:
        """``[x0, y0, x1, y1]``."""
        return np.array([self.x0_m, self.y0_m, self.x1_m, self.y1_m])

    @classmethod
    def from_hesse(cls, rho_m: float, theta_rad: float, t0_m: float, t1_m: float) -> LineSegment:
        """The piece of line ``(rho, theta)`` between line parameters ``t0`` and ``t1``."""
        x0, y0, x1, y1 = segments_from_hesse(rho_m, theta_rad, t0_m, t1_m)[0]
        return cls(float(x0), float(y0), float(x1), float(y1))
