"""The report's simulated worlds: the paper's room (Fig. 8) and a cluttered variant of it (§6.3).

The cluttered world keeps the default room and path and adds many small box obstacles (chairs, bins,
table legs) placed deterministically away from the path and the walls; its runs use 10 % outlier beams.
"""

from __future__ import annotations

import numpy as np

from shared.metrics.distance import nearest_segment
from shared.sim import DEFAULT_KNOTS, RangeNoise, World, default_world, polygon_area, polygon_walls

__all__ = ["CLUTTER_NOISE", "cluttered_world"]

#: Range noise of the cluttered runs: the default model with 10 % outlier beams.
CLUTTER_NOISE = RangeNoise(outlier_rate=0.10)


def cluttered_world(n_obstacles: int = 24, seed: int = 7) -> World:
    """The default room with ``n_obstacles`` boxes of 0.15-0.4 m, each >= 0.6 m from the path and >= 0.3 m
    from the walls and the other boxes. Deterministic for ``seed``; O(candidates x walls)."""
    base = default_world()
    rng = np.random.default_rng(seed)
    knots = np.asarray(DEFAULT_KNOTS, dtype=np.float64)
    path = np.hstack([knots[:-1], knots[1:]])
    boxes: list[np.ndarray] = []
    walls = base.walls
    tries = 0
    while len(boxes) < n_obstacles and tries < 20_000:
        tries += 1
        size = rng.uniform(0.15, 0.4)
        cx, cy = rng.uniform(0.3, 9.7), rng.uniform(0.3, 7.7)
        if not _inside_room(cx, cy):
            continue
        centre = np.array([[cx, cy]])
        clear = size / 2 * np.sqrt(2)
        if nearest_segment(centre, path)[0][0] < 0.6 + clear:
            continue
        if nearest_segment(centre, walls)[0][0] < 0.3 + clear:
            continue
        if any(np.hypot(*(b.mean(axis=0) - centre[0])) < 0.3 + clear + 0.3 for b in boxes):
            continue
        h = size / 2
        boxes.append(np.array([[cx - h, cy - h], [cx + h, cy - h], [cx + h, cy + h], [cx - h, cy + h]]))
    all_walls = np.vstack([walls, *[polygon_walls(b) for b in boxes]])
    area = base.floor_area_m2 - sum(polygon_area(b) for b in boxes)
    return World(all_walls, area, "cluttered", knots)


def _inside_room(x: float, y: float) -> bool:
    """Inside the default L-shaped outline (0..10 x 0..4 plus the corridor 3.4..5 x 4..8)."""
    return (0.0 < x < 10.0 and 0.0 < y < 4.0) or (3.4 < x < 5.0 and 4.0 <= y < 8.0)
