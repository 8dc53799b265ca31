"""The suite's static worlds: corridors, an L-shaped office, a hall, a lab, a loop, glass and mixed pixels.

Each builder draws its sizes and positions from ``rng`` and returns a :class:`shared.sim.scene.Scene` whose
``knots`` are the robot's path (a single pass; the suite turns it into out-and-back or laps).
"""

from __future__ import annotations

import numpy as np

from shared.sim.scene import BLACK, GLASS, MATTE, Scene
from shared.sim.world import polygon_walls
from shared.sim.worlds.geometry import box, path_segments, place_boxes, recessed_wall, spaced_positions
from shared.types import FloatArray

__all__ = [
    "corridor_doors",
    "corridor_long",
    "corridor_walls",
    "glass_black",
    "hall_pillars",
    "lab_clutter",
    "loop_block",
    "mixed_edges",
    "office_l",
]


def corridor_walls(
    rng: np.random.Generator, length_m: float, width_m: float, doors_per_side: int
) -> FloatArray:
    """A closed corridor along x, ``[0, length] x [0, width]``, with up to ``doors_per_side`` door recesses
    (0.8-1.0 m wide, 0.1-0.3 m deep) in each long wall."""
    walls = [np.array([[0.0, 0.0, 0.0, width_m], [length_m, 0.0, length_m, width_m]])]
    for y, outward in ((0.0, -1.0), (width_m, 1.0)):
        starts = spaced_positions(rng, 1.0, length_m - 1.0, doors_per_side, 1.0, 1.0)
        recesses = [(s, float(rng.uniform(0.8, 1.0)), float(rng.uniform(0.1, 0.3))) for s in starts]
        walls.append(recessed_wall(0.0, length_m, y, recesses, outward))
    return np.vstack(walls)


def corridor_long(rng: np.random.Generator) -> Scene:
    """A 14-22 m corridor, 1.5-2.2 m wide, no features: its ends are beyond the 5.6 m range for most of
    the drive along its middle."""
    length, width = float(rng.uniform(14.0, 22.0)), float(rng.uniform(1.5, 2.2))
    walls = corridor_walls(rng, length, width, 0)
    knots = np.array([[1.0, width / 2], [length - 1.0, width / 2]])
    return Scene(walls, "corridor-long", knots, floor_area_m2=length * width)


def corridor_doors(rng: np.random.Generator) -> Scene:
    """A 12-18 m corridor with 3-5 door recesses per side and 1-3 cabinets against its walls."""
    length, width = float(rng.uniform(12.0, 18.0)), float(rng.uniform(1.6, 2.2))
    walls = corridor_walls(rng, length, width, int(rng.integers(3, 6)))
    knots = np.array([[1.0, width / 2], [length - 1.0, width / 2]])
    cabinets = []
    for x in spaced_positions(rng, 1.0, length - 1.0, int(rng.integers(1, 4)), 0.6, 0.5):
        w, d = float(rng.uniform(0.4, 0.6)), float(rng.uniform(0.3, 0.4))
        cy = width - 0.02 - d / 2 if rng.random() < 0.5 else 0.02 + d / 2  # 2 cm off the wall
        cabinets.append(box(x + w / 2, cy, w, d))
    return Scene(np.vstack([walls, *cabinets]), "corridor-doors", knots, floor_area_m2=length * width)


def office_l(rng: np.random.Generator) -> Scene:
    """An L-shaped office: a 10-14 m corridor turning into a 6-10 m one, with 2-3 rooms (3-4 m wide,
    2.5-3.5 m deep) off the first leg through 1 m doorways; the path visits one room."""
    lx, ly, w = float(rng.uniform(10.0, 14.0)), float(rng.uniform(6.0, 10.0)), float(rng.uniform(1.6, 2.0))
    depth = float(rng.uniform(2.5, 3.5))
    rooms = spaced_positions(rng, 0.3, lx - w - 0.3, int(rng.integers(2, 4)), 3.5, 0.3)
    doors = []
    walls: list[FloatArray] = []
    for rx in rooms:
        dx = rx + float(rng.uniform(0.3, 3.5 - 1.3))
        doors.append((dx, 1.0, 0.0))
        walls.append(
            np.array(
                [[rx, 0.0, rx, -depth], [rx, -depth, rx + 3.5, -depth], [rx + 3.5, -depth, rx + 3.5, 0.0]]
            )
        )
    walls.append(recessed_wall(0.0, lx, 0.0, doors, -1.0))
    walls.append(
        np.array(
            [
                [lx, 0.0, lx, w + ly],
                [lx, w + ly, lx - w, w + ly],
                [lx - w, w + ly, lx - w, w],
                [lx - w, w, 0.0, w],
                [0.0, w, 0.0, 0.0],
            ]
        )
    )
    visit = doors[int(rng.integers(0, len(doors)))][0] + 0.5
    knots = np.array(
        [
            [0.8, w / 2],
            [visit, w / 2],
            [visit, -depth / 2],
            [visit, w / 2],
            [lx - w / 2, w / 2],
            [lx - w / 2, w + ly - 0.8],
        ]
    )
    area = lx * w + w * ly + len(rooms) * 3.5 * depth
    return Scene(np.vstack(walls), "office-l", knots, floor_area_m2=area)


def hall_pillars(rng: np.random.Generator) -> Scene:
    """An open hall of 10-16 m x 8-12 m with a grid of 0.3-0.5 m pillars about 3 m apart; the path runs
    round the inside, 1.2 m from the walls."""
    hx, hy = float(rng.uniform(10.0, 16.0)), float(rng.uniform(8.0, 12.0))
    outline = polygon_walls([(0.0, 0.0), (hx, 0.0), (hx, hy), (0.0, hy)])
    knots = np.array([[1.2, 1.2], [hx - 1.2, 1.2], [hx - 1.2, hy - 1.2], [1.2, hy - 1.2], [1.2, 3.0]])
    pillars = []
    for gx in np.arange(3.0, hx - 2.5, float(rng.uniform(2.8, 3.6))):
        for gy in np.arange(3.0, hy - 2.5, float(rng.uniform(2.8, 3.6))):
            size = float(rng.uniform(0.3, 0.5))
            pillars.append(box(gx + rng.uniform(-0.3, 0.3), gy + rng.uniform(-0.3, 0.3), size, size))
    return Scene(np.vstack([outline, *pillars]), "hall-pillars", knots, floor_area_m2=hx * hy)


def lab_clutter(rng: np.random.Generator) -> Scene:
    """A lab of 8-12 m x 6-9 m with a corner cut off by an angled wall and 10-18 boxes, some turned."""
    rx, ry = float(rng.uniform(8.0, 12.0)), float(rng.uniform(6.0, 9.0))
    a, b = float(rng.uniform(1.5, 2.5)), float(rng.uniform(1.0, ry / 2 - 1.0))
    outline = [(0.0, 0.0), (rx, 0.0), (rx, ry - b), (rx - a, ry), (0.0, ry)]
    walls = polygon_walls(outline)
    knots = np.array([[1.0, 1.0], [rx - 1.5, 1.0], [rx - 1.5, ry / 2], [1.5, ry / 2], [1.5, ry - 1.0]])

    def inside(x: float, y: float) -> bool:
        return 0.0 < x < rx and 0.0 < y < ry and (x - (rx - a)) * b + (y - ry) * a < 0.0

    boxes = place_boxes(
        rng,
        int(rng.integers(10, 19)),
        inside,
        (0.3, 0.3, rx - 0.3, ry - 0.3),
        path_segments(knots),
        walls,
        size_m=(0.2, 0.8),
        rotate=True,
    )
    return Scene(np.vstack([walls, *boxes]), "lab-clutter", knots, floor_area_m2=rx * ry - a * b / 2)


def loop_block(rng: np.random.Generator) -> Scene:
    """A loop of corridors (1.6-2.2 m wide) round a block, outer 12-18 m x 9-13 m, a few door recesses on
    the outer walls; the path is the closed loop (the suite drives it in laps)."""
    x, y, w = float(rng.uniform(12.0, 18.0)), float(rng.uniform(9.0, 13.0)), float(rng.uniform(1.6, 2.2))
    inner = polygon_walls([(w, w), (x - w, w), (x - w, y - w), (w, y - w)])
    starts = spaced_positions(rng, 1.0, x - 1.0, int(rng.integers(2, 5)), 1.0, 1.0)
    bottom = recessed_wall(0.0, x, 0.0, [(s, 0.9, float(rng.uniform(0.1, 0.3))) for s in starts], -1.0)
    rest = np.array([[x, 0.0, x, y], [x, y, 0.0, y], [0.0, y, 0.0, 0.0]])
    h = w / 2
    knots = np.array([[h, h], [x - h, h], [x - h, y - h], [h, y - h], [h, h]])
    area = x * y - (x - 2 * w) * (y - 2 * w)
    return Scene(np.vstack([inner, bottom, rest]), "loop-block", knots, floor_area_m2=area)


def glass_black(rng: np.random.Generator) -> Scene:
    """A 10-14 m x 4-6 m room whose one long wall is partly glass windows (beams pass, nothing behind in
    range) and whose other has black panels and a black cabinet (beams absorbed): no return from them."""
    lx, ly = float(rng.uniform(10.0, 14.0)), float(rng.uniform(4.0, 6.0))
    segs: list[list[float]] = [[0.0, 0.0, 0.0, ly], [lx, 0.0, lx, ly]]
    surf: list[int] = [MATTE, MATTE]
    for y, kind in ((ly, GLASS), (0.0, BLACK)):
        x = 0.0
        for s in spaced_positions(rng, 0.5, lx - 0.5, int(rng.integers(2, 4)), 2.0, 0.8):
            width = float(rng.uniform(1.0, 2.0))
            segs += [[x, y, s, y], [s, y, s + width, y]]
            surf += [MATTE, kind]
            x = s + width
        segs.append([x, y, lx, y])
        surf.append(MATTE)
    cab = box(float(rng.uniform(2.0, lx - 2.0)), 0.35, 0.8, 0.6)
    walls = np.vstack([np.array(segs), cab])
    surface = np.array(surf + [BLACK] * 4)
    knots = np.array([[1.0, ly / 2], [lx - 1.0, ly / 2]])
    return Scene(walls, "glass-black", knots, surface=surface, floor_area_m2=lx * ly)


def mixed_edges(rng: np.random.Generator) -> Scene:
    """A 8-12 m x 6-8 m room with thin posts and free-standing partitions 0.3-1 m in front of its walls:
    many depth edges, where half the beams straddling one return a mixed pixel."""
    rx, ry = float(rng.uniform(8.0, 12.0)), float(rng.uniform(6.0, 8.0))
    walls = [polygon_walls([(0.0, 0.0), (rx, 0.0), (rx, ry), (0.0, ry)])]
    for y, sign in ((0.0, 1.0), (ry, -1.0)):
        for s in spaced_positions(rng, 0.5, rx - 0.5, int(rng.integers(3, 6)), 1.2, 0.4):
            off = float(rng.uniform(0.3, 1.0))
            if rng.random() < 0.5:
                walls.append(
                    np.array([[s, y + sign * off, s + float(rng.uniform(0.6, 1.2)), y + sign * off]])
                )
            else:
                post = float(rng.uniform(0.08, 0.2))
                walls.append(box(s + 0.3, y + sign * (off + post / 2), post, post))
    knots = np.array([[1.0, ry / 2], [rx - 1.0, ry / 2], [rx - 1.0, ry / 2 + 0.8], [1.0, ry / 2 + 0.8]])
    return Scene(np.vstack(walls), "mixed-edges", knots, floor_area_m2=rx * ry, mixed_pixel_rate=0.5)
