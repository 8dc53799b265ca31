"""Polygonal worlds of straight walls, like the paper's artificial environment (§6.1, Fig. 8)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from shared.errors import InvalidInputError
from shared.types import FloatArray, Pose2D

__all__ = ["World", "default_path", "default_world"]


@dataclass(frozen=True, slots=True)
class World:
    """Straight walls ``(W, 4)`` as ``[x0, y0, x1, y1]`` in metres, and the true floor area in m^2."""

    walls: FloatArray
    floor_area_m2: float
    name: str = "world"

    def __post_init__(self) -> None:
        walls = np.array(self.walls, dtype=np.float64, copy=True)
        if walls.ndim != 2 or walls.shape[1] != 4 or walls.shape[0] == 0:
            raise InvalidInputError(f"World.walls has shape {walls.shape}: expected (W, 4) with W >= 1")
        if not np.all(np.isfinite(walls)):
            raise InvalidInputError("World.walls contains non-finite coordinates: expected finite metres")
        walls.setflags(write=False)
        object.__setattr__(self, "walls", walls)


def _polygon(vertices: list[tuple[float, float]]) -> FloatArray:
    v = np.asarray(vertices, dtype=np.float64)
    return np.hstack([v, np.roll(v, -1, axis=0)])


def _shoelace(vertices: list[tuple[float, float]]) -> float:
    v = np.asarray(vertices, dtype=np.float64)
    return float(0.5 * abs(np.dot(v[:, 0], np.roll(v[:, 1], -1)) - np.dot(v[:, 1], np.roll(v[:, 0], -1))))


def default_world() -> World:
    """An L-shaped room with a 1.6 m corridor and two box obstacles, about 10 m x 8 m (after Fig. 8).

    The floor area excludes the obstacles' footprints.
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
    walls = np.vstack([_polygon(outline), _polygon(box_a), _polygon(box_b)])
    area = _shoelace(outline) - _shoelace(box_a) - _shoelace(box_b)
    return World(walls, area, "default")


def default_path(n_steps: int = 120) -> list[Pose2D]:
    """A predefined path through :func:`default_world`: along the room, then up the corridor.

    Poses are evenly spaced along the polyline, heading along the direction of travel.
    """
    if n_steps < 2:
        raise InvalidInputError(f"n_steps = {n_steps}: expected at least 2 poses")
    knots = np.array([[1.0, 3.0], [6.0, 3.0], [9.0, 1.0], [4.2, 3.0], [4.2, 7.0]])
    seg = np.diff(knots, axis=0)
    seg_len = np.hypot(seg[:, 0], seg[:, 1])
    cum = np.concatenate([[0.0], np.cumsum(seg_len)])
    s = np.linspace(0.0, cum[-1], n_steps)
    idx = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg) - 1)
    frac = (s - cum[idx]) / seg_len[idx]
    xy = knots[idx] + seg[idx] * frac[:, None]
    heading = np.arctan2(seg[idx, 1], seg[idx, 0])
    return [Pose2D(float(x), float(y), float(h)) for (x, y), h in zip(xy, heading, strict=True)]
