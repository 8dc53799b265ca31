"""Polygonal worlds of straight walls, like the paper's artificial environment (§6.1, Fig. 8)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from shared.errors import InvalidInputError
from shared.sim.path import plan_path
from shared.types import FloatArray, Pose2D

__all__ = ["DEFAULT_KNOTS", "World", "default_path", "default_world", "polygon_area", "polygon_walls"]

#: Knots (m) of the predefined path through :func:`default_world`: along the room, round the east box,
#: back west and up the corridor.
DEFAULT_KNOTS: tuple[tuple[float, float], ...] = ((1.0, 3.0), (6.0, 3.0), (9.0, 1.0), (4.2, 3.0), (4.2, 7.0))


@dataclass(frozen=True, slots=True)
class World:
    """Straight walls ``(W, 4)`` as ``[x0, y0, x1, y1]`` in metres, and the true floor area in m^2.

    ``knots`` optionally holds the world's predefined path ``(K, 2)`` in metres (K >= 2), which
    :func:`shared.sim.simulate_run` drives when no path is given. Arrays are copied and read-only.
    """

    walls: FloatArray
    floor_area_m2: float
    name: str = "world"
    knots: FloatArray | None = None

    def __post_init__(self) -> None:
        walls = np.array(self.walls, dtype=np.float64, copy=True)
        if walls.ndim != 2 or walls.shape[1] != 4 or walls.shape[0] == 0:
            raise InvalidInputError(f"World.walls has shape {walls.shape}: expected (W, 4) with W >= 1")
        if not np.all(np.isfinite(walls)):
            raise InvalidInputError("World.walls contains non-finite coordinates: expected finite metres")
        walls.setflags(write=False)
        object.__setattr__(self, "walls", walls)
        area = float(self.floor_area_m2)
        if not (math.isfinite(area) and area > 0.0):
            raise InvalidInputError(f"World.floor_area_m2 = {area!r}: expected a positive finite area in m^2")
        object.__setattr__(self, "floor_area_m2", area)
        if self.knots is not None:
            knots = np.array(self.knots, dtype=np.float64, copy=True)
            if knots.ndim != 2 or knots.shape[1] != 2 or knots.shape[0] < 2:
                raise InvalidInputError(f"World.knots has shape {knots.shape}: expected (K, 2) with K >= 2")
            if not np.all(np.isfinite(knots)):
                raise InvalidInputError("World.knots contains non-finite coordinates: expected finite metres")
            knots.setflags(write=False)
            object.__setattr__(self, "knots", knots)


def polygon_walls(vertices: ArrayLike) -> FloatArray:
    """The walls ``(V, 4)`` of the closed polygon with ``V`` vertices (the last joins the first). O(V)."""
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 2)
    return np.hstack([v, np.roll(v, -1, axis=0)])


def polygon_area(vertices: ArrayLike) -> float:
    """Area (m^2) enclosed by a simple polygon, by the shoelace formula. O(V)."""
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 2)
    return float(0.5 * abs(np.dot(v[:, 0], np.roll(v[:, 1], -1)) - np.dot(v[:, 1], np.roll(v[:, 0], -1))))


def default_world() -> World:
    """An L-shaped room with a 1.6 m corridor and two box obstacles, about 10 m x 8 m (after Fig. 8).

    The floor area excludes the obstacles' footprints; ``knots`` is :data:`DEFAULT_KNOTS`.
    """
    outline = [
        (0.0, 0.0),
        (10.0, 0.0),
        (10.0, 4.0),
        (5.0, 4.0),
        (5.0, 8.0),
        (3.4, 8.0),
        (3.4, 4.0),
        (0.0, 4.0),
    ]
    box_a = [(2.0, 1.2), (2.8, 1.2), (2.8, 2.0), (2.0, 2.0)]
    box_b = [(7.0, 2.4), (7.6, 2.4), (7.6, 3.0), (7.0, 3.0)]
    walls = np.vstack([polygon_walls(outline), polygon_walls(box_a), polygon_walls(box_b)])
    area = polygon_area(outline) - polygon_area(box_a) - polygon_area(box_b)
    return World(walls, area, "default", np.asarray(DEFAULT_KNOTS))


def default_path(
    n_steps: int | None = None,
    *,
    speed_mps: float = 0.4,
    turn_rate_radps: float = 0.8,
    rate_hz: float = 10.0,
) -> list[Pose2D]:
    """The predefined path through :func:`default_world` (:data:`DEFAULT_KNOTS`).

    Without ``n_steps``: what a robot driving it reports at ``rate_hz`` (:func:`shared.sim.plan_path`:
    straight legs at ``speed_mps``, turns in place at the knots), ~510 poses with the defaults.
    With ``n_steps`` (kept for the kernel tests): ``n_steps`` poses evenly spaced along the polyline, heading
    along the direction of travel, no turns in place.
    """
    knots = np.asarray(DEFAULT_KNOTS, dtype=np.float64)
    if n_steps is None:
        return plan_path(knots, speed_mps=speed_mps, turn_rate_radps=turn_rate_radps, rate_hz=rate_hz)
    if n_steps < 2:
        raise InvalidInputError(f"n_steps = {n_steps}: expected at least 2 poses")
    return _evenly_spaced(knots, n_steps)


def _evenly_spaced(knots: FloatArray, n_steps: int) -> list[Pose2D]:
    seg = np.diff(knots, axis=0)
    seg_len = np.hypot(seg[:, 0], seg[:, 1])
    cum = np.concatenate([[0.0], np.cumsum(seg_len)])
    s = np.linspace(0.0, cum[-1], n_steps)
    idx = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg) - 1)
    frac = (s - cum[idx]) / seg_len[idx]
    xy = knots[idx] + seg[idx] * frac[:, None]
    heading = np.arctan2(seg[idx, 1], seg[idx, 0])
    return [Pose2D(float(x), float(y), float(h)) for (x, y), h in zip(xy, heading, strict=True)]
