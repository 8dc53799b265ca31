"""Building blocks of the suite's worlds: walls with door recesses, boxes, and placing things clear of the
robot's path. Pure numpy; every random draw comes from the ``rng`` passed in."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from shared.metrics.distance import nearest_segment
from shared.sim.world import polygon_walls
from shared.types import FloatArray

__all__ = ["box", "path_segments", "place_boxes", "recessed_wall", "spaced_positions"]


def box(cx: float, cy: float, width_m: float, depth_m: float, angle_rad: float = 0.0) -> FloatArray:
    """The 4 walls ``(4, 4)`` of a ``width_m`` x ``depth_m`` box centred on ``(cx, cy)``, turned by
    ``angle_rad``."""
    hw, hd = width_m / 2.0, depth_m / 2.0
    corners = np.array([[-hw, -hd], [hw, -hd], [hw, hd], [-hw, hd]])
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    rotated = corners @ np.array([[c, s], [-s, c]]) + np.array([cx, cy])
    return polygon_walls(rotated)


def recessed_wall(
    x0_m: float, x1_m: float, y_m: float, recesses: Sequence[tuple[float, float, float]], outward: float
) -> FloatArray:
    """A wall along x from ``x0_m`` to ``x1_m`` at ``y_m`` with door recesses ``(x_start, width, depth)``
    set back by ``depth`` in direction ``outward`` (+1: +y, -1: -y). A depth of 0 leaves a gap (an open
    doorway). Recesses must be sorted and inside the span. Returns walls ``(W, 4)``."""
    walls: list[list[float]] = []
    x = x0_m
    for start, width, depth in recesses:
        if start > x:
            walls.append([x, y_m, start, y_m])
        if depth > 0.0:
            back = y_m + outward * depth
            walls += [[start, y_m, start, back], [start, back, start + width, back]]
            walls.append([start + width, back, start + width, y_m])
        x = start + width
    if x1_m > x:
        walls.append([x, y_m, x1_m, y_m])
    return np.array(walls, dtype=np.float64).reshape(-1, 4)


def spaced_positions(
    rng: np.random.Generator, low_m: float, high_m: float, count: int, width_m: float, gap_m: float
) -> list[float]:
    """Up to ``count`` sorted starts in ``[low_m, high_m - width_m]`` of intervals ``width_m`` long at
    least ``gap_m`` apart (rejection sampling, 200 tries)."""
    starts: list[float] = []
    for _ in range(200):
        if len(starts) == count or high_m - width_m <= low_m:
            break
        s = float(rng.uniform(low_m, high_m - width_m))
        if all(abs(s - o) >= width_m + gap_m for o in starts):
            starts.append(s)
    return sorted(starts)


def path_segments(knots: FloatArray) -> FloatArray:
    """The legs ``(K-1, 4)`` of a path through ``knots`` ``(K, 2)``."""
    k = np.asarray(knots, dtype=np.float64)
    return np.hstack([k[:-1], k[1:]])


def place_boxes(
    rng: np.random.Generator,
    count: int,
    inside: Callable[[float, float], bool],
    bounds: tuple[float, float, float, float],
    path: FloatArray,
    walls: FloatArray,
    *,
    size_m: tuple[float, float] = (0.2, 0.6),
    path_clear_m: float = 0.6,
    wall_clear_m: float = 0.3,
    rotate: bool = False,
) -> list[FloatArray]:
    """Up to ``count`` boxes (walls ``(4, 4)`` each) with centres in ``bounds`` ``(x0, y0, x1, y1)`` where
    ``inside`` holds, kept ``path_clear_m`` from the path, ``wall_clear_m`` from ``walls`` and from each
    other. Rejection sampling, 5,000 tries."""
    boxes: list[FloatArray] = []
    centres: list[tuple[float, float, float]] = []
    for _ in range(5_000):
        if len(boxes) == count:
            break
        w, d = rng.uniform(*size_m), rng.uniform(*size_m)
        cx, cy = rng.uniform(bounds[0], bounds[2]), rng.uniform(bounds[1], bounds[3])
        angle = float(rng.uniform(0.0, math.pi / 2)) if rotate else 0.0
        if not inside(cx, cy):
            continue
        reach = 0.5 * math.hypot(w, d)
        centre = np.array([[cx, cy]])
        if nearest_segment(centre, path)[0][0] < path_clear_m + reach:
            continue
        if nearest_segment(centre, walls)[0][0] < wall_clear_m + reach:
            continue
        if any(math.hypot(cx - ox, cy - oy) < r + reach + wall_clear_m for ox, oy, r in centres):
            continue
        boxes.append(box(cx, cy, w, d, angle))
        centres.append((cx, cy, reach))
    return boxes
