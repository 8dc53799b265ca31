"""The suite's dynamic worlds: people walking along and across, doors that open, furniture moved.

Ground truth is the world at the end of the run (:meth:`shared.sim.scene.Scene.truth`): an opened door
is mapped open, a moved box at its new place; people are never walls.
"""

from __future__ import annotations

import numpy as np

from shared.sim.path import plan_path
from shared.sim.scene import Scene, Walker
from shared.sim.world import polygon_walls
from shared.sim.worlds.geometry import path_segments, place_boxes, spaced_positions
from shared.sim.worlds.static import corridor_walls
from shared.types import FloatArray

__all__ = ["door_opens", "furniture_moved", "people_across", "people_along"]

_ALWAYS = (-np.inf, np.inf)


def _pass_s(knots: FloatArray) -> float:
    """Seconds the robot takes for one pass through ``knots`` (10 Hz, as the suite drives)."""
    return len(plan_path(knots)) / 10.0


def people_along(rng: np.random.Generator) -> Scene:
    """A 12-18 m corridor, 2.4-3 m wide, two door recesses a side, and three people walking up and down
    it at 0.5-1.5 m/s, 0.5 m or more to the side of the robot's line."""
    length, width = float(rng.uniform(12.0, 18.0)), float(rng.uniform(2.4, 3.0))
    walls = corridor_walls(rng, length, width, 2)
    people = []
    for _ in range(3):
        side = 1.0 if rng.random() < 0.5 else -1.0
        y = width / 2 + side * float(rng.uniform(0.5, width / 2 - 0.3))
        ends = [[0.5, y], [length - 0.5, y]]
        if rng.random() < 0.5:
            ends.reverse()
        people.append(Walker(np.array(ends), float(rng.uniform(0.5, 1.5)), float(rng.uniform(0.0, 5.0))))
    knots = np.array([[1.0, width / 2], [length - 1.0, width / 2]])
    return Scene(walls, "people-along", knots, people=tuple(people), floor_area_m2=length * width)


def people_across(rng: np.random.Generator) -> Scene:
    """A 10-14 m x 6-8 m hall that four people cross back and forth at 0.5-1.5 m/s while the robot drives
    along its middle."""
    hx, hy = float(rng.uniform(10.0, 14.0)), float(rng.uniform(6.0, 8.0))
    walls = polygon_walls([(0.0, 0.0), (hx, 0.0), (hx, hy), (0.0, hy)])
    people = []
    for x in spaced_positions(rng, 1.5, hx - 1.5, 4, 0.5, 1.5):
        ends = [[x, 0.5], [x + float(rng.uniform(-1.0, 1.0)), hy - 0.5]]
        if rng.random() < 0.5:
            ends.reverse()
        people.append(Walker(np.array(ends), float(rng.uniform(0.5, 1.5)), float(rng.uniform(0.0, 4.0))))
    knots = np.array([[1.0, hy / 2], [hx - 1.0, hy / 2]])
    return Scene(walls, "people-across", knots, people=tuple(people), floor_area_m2=hx * hy)


def door_opens(rng: np.random.Generator) -> Scene:
    """A 10-14 m corridor with two 3 m x 3 m rooms off it behind closed doors (0.9 m leaves) that swing
    open into the rooms during the first pass; driven out and back, the way back sees them open."""
    length, width = float(rng.uniform(10.0, 14.0)), float(rng.uniform(1.8, 2.2))
    rooms = spaced_positions(rng, 1.0, length - 1.0, 2, 3.0, 0.5)
    doorways, room_walls = [], []
    for rx in rooms:
        dx = rx + float(rng.uniform(0.2, 3.0 - 1.1))
        doorways.append(dx)
        room_walls.append([[rx, width, rx, width + 3.0], [rx, width + 3.0, rx + 3.0, width + 3.0]])
        room_walls[-1].append([rx + 3.0, width + 3.0, rx + 3.0, width])
    knots = np.array([[1.0, width / 2], [length - 1.0, width / 2]])
    t_pass = _pass_s(knots)
    top: list[list[float]] = []
    x = 0.0
    for dx in doorways:
        top.append([x, width, dx, width])
        x = dx + 0.9
    top.append([x, width, length, width])
    base = np.vstack(
        [
            np.array([[0.0, 0.0, 0.0, width], [length, 0.0, length, width], [0.0, 0.0, length, 0.0]]),
            np.array(top),
            np.array(room_walls).reshape(-1, 4),
        ]
    )
    leaves, times = [], []
    for dx in doorways:
        t_open = float(rng.uniform(0.3, 0.9)) * t_pass
        leaves += [[dx, width, dx + 0.9, width], [dx, width, dx, width + 0.9]]
        times += [(-np.inf, t_open), (t_open, np.inf)]
    walls = np.vstack([base, np.array(leaves)])
    wall_times = np.array([_ALWAYS] * len(base) + times)
    area = length * width + 9.0 * len(rooms)
    return Scene(walls, "door-opens", knots, wall_times=wall_times, floor_area_m2=area)


def furniture_moved(rng: np.random.Generator) -> Scene:
    """A 8-11 m x 6-8 m room with 4-6 pieces of furniture (0.4-1 m); when the robot turns back at the end
    of its first pass, two or three of them have been moved elsewhere."""
    rx, ry = float(rng.uniform(8.0, 11.0)), float(rng.uniform(6.0, 8.0))
    walls = polygon_walls([(0.0, 0.0), (rx, 0.0), (rx, ry), (0.0, ry)])
    knots = np.array([[1.0, ry / 2], [rx - 1.0, ry / 2]])
    path = path_segments(knots)

    def inside(x: float, y: float) -> bool:
        return 0.0 < x < rx and 0.0 < y < ry

    bounds = (0.5, 0.5, rx - 0.5, ry - 0.5)
    old = place_boxes(
        rng, int(rng.integers(4, 7)), inside, bounds, path, walls, size_m=(0.4, 1.0), path_clear_m=0.8
    )
    n_move = min(len(old), int(rng.integers(2, 4)))
    taken = np.vstack([walls, *old])
    new = place_boxes(rng, n_move, inside, bounds, path, taken, size_m=(0.4, 1.0), path_clear_m=0.8)
    t_move = _pass_s(knots)
    parts, times = [walls], [np.tile(_ALWAYS, (len(walls), 1))]
    for i, b in enumerate(old):
        moved = i < len(new)
        parts.append(b)
        times.append(np.tile((-np.inf, t_move) if moved else _ALWAYS, (4, 1)))
        if moved:
            parts.append(new[i])
            times.append(np.tile((t_move, np.inf), (4, 1)))
    return Scene(
        np.vstack(parts), "furniture-moved", knots, wall_times=np.vstack(times), floor_area_m2=rx * ry
    )
