"""Area enclosed by a line map, and the area error against the true floor area (paper Table 3, Fig. 19).

Method (docs/design.md §5, "Area error"):

1. **Close gaps** up to ``close_gaps_m`` with straight bridges (:func:`shared.metrics.gaps.gap_bridges`):
   the same gaps a dilation by ``close_gaps_m / 2`` closes, but with no dilation to undo (dilating the
   walls and dilating the fill back loses ``(1 - pi/4) r^2`` at every convex corner and quantises walls to
   cells). As with a dilation, pockets narrower than ``close_gaps_m`` between clutter and a wall are cut off.
2. **Flood fill on a grid of cell centres** (``cell_m``, bounding box of the segments plus a margin): two
   4-neighbour centres are connected unless a segment or bridge crosses the straight edge between them
   (every crossing is computed exactly, :mod:`shared.metrics.fill`), so the fill cannot leak through a
   closed polygon however thin its walls, and walls have no raster thickness. The region is the union of
   the components holding the ``inside_points`` (the trajectory); obstacle interiors are not reachable and
   so are excluded, as in :attr:`shared.sim.World.floor_area_m2`.
3. **Measure without raster bias**: marching squares on the centres with the boundary placed at the exact
   wall crossings (exact for a wall straight across a square; only squares holding a corner or a segment
   end carry an O(cell^2) error). A map that does not enclose the trajectory raises
   :class:`MapLeakError` instead of returning a meaningless number.

Measured bias (2 cm cells; tests/shared/metrics/test_metrics_area.py): straight walls are exact wherever
they lie on the grid; only a wall corner inside a square of four centres is cut, by at most c^2/8 for a
right angle (5e-5 m^2), c^2/2 for one on a centre, up to about c^2 for a sharp corner. Perfect
10 m x 4 m rectangle: -2.0e-4 m^2 (-5e-4 %); default L-shaped world with two boxes: +2.0e-4 m^2
(+4.4e-4 %); the rectangle rotated by any angle: within 3.3e-4 m^2 (8e-4 %); a 20 cm gap in a wall is
rebuilt exactly by its bridge. Peak memory about 21 bytes per cell (a 60 m x 60 m map at 2 cm: 9 M cells,
190 MB, 0.5 s). Bridges grow with map density: 500 noisy segments on 42 m of wall give 21 k bridges
(0.06 s), 2,000 give 340 k (1.1 s).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from shared.metrics.distance import as_segments
from shared.metrics.errors import MapLeakError, MetricError, MetricInputError
from shared.metrics.fill import crossing_lattice, marching_area
from shared.metrics.gaps import gap_bridges
from shared.types import BoolArray, FloatArray

__all__ = ["EnclosedArea", "area_error_pct", "enclosed_area", "map_area_m2"]

log = logging.getLogger(__name__)

_MARGIN_CELLS = 3
DEFAULT_MAX_CELLS = 16_000_000


@dataclass(frozen=True, slots=True, eq=False)
class EnclosedArea:
    """The region a map encloses around the trajectory.

    ``region[i, j]`` is true for the cell centred at ``origin_xy + ((j + 0.5) cell_m, (i + 0.5) cell_m)``;
    ``area_m2`` is the sub-cell measurement (not ``region.sum() * cell_m**2``); ``bridges`` ``(B, 4)`` are
    the gap-closing segments that were added.
    """

    area_m2: float
    cell_m: float
    origin_xy: tuple[float, float]
    region: BoolArray
    bridges: FloatArray


def _as_inside(points: ArrayLike) -> FloatArray:
    arr = np.asarray(points, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 2 or arr.shape[0] == 0:
        raise MetricInputError(
            f"inside_points has shape {arr.shape}: expected (P, 2) x/y in metres with P >= 1 "
            "(e.g. the trajectory's x and y columns)"
        )
    if not np.all(np.isfinite(arr)):
        bad = int(np.flatnonzero(~np.all(np.isfinite(arr), axis=1))[0])
        raise MetricInputError(f"inside_points[{bad}] = {arr[bad].tolist()} is not finite")
    return arr


def enclosed_area(
    segments: ArrayLike,
    inside_points: ArrayLike,
    *,
    cell_m: float = 0.02,
    close_gaps_m: float = 0.3,
    max_cells: int = DEFAULT_MAX_CELLS,
) -> EnclosedArea:
    """The region the map ``segments`` ``(L, 4)`` (m) encloses around ``inside_points`` ``(P, 2)`` (m).

    See the module docstring for the method. Raises :class:`MapLeakError` when the region of any inside
    point reaches open space (a wall missing or a gap wider than ``close_gaps_m``) or an inside point lies
    outside the map's bounding box, and :class:`MetricError` for an empty map or a grid larger than
    ``max_cells`` (choose a larger ``cell_m``). O(cells + segments + crossings).
    """
    segs = as_segments(segments)
    inside = _as_inside(inside_points)
    if not (math.isfinite(cell_m) and cell_m > 0.0):
        raise MetricInputError(f"cell_m = {cell_m!r}: expected a positive cell size in metres")
    if not (math.isfinite(close_gaps_m) and close_gaps_m >= 0.0):
        raise MetricInputError(f"close_gaps_m = {close_gaps_m!r}: expected a gap width >= 0 in metres")
    if len(segs) == 0:
        raise MetricError("the map has no segments: it encloses no area")
    bridges = gap_bridges(segs, close_gaps_m)
    walls = np.vstack([segs, bridges])
    xmin, xmax = float(walls[:, [0, 2]].min()), float(walls[:, [0, 2]].max())
    ymin, ymax = float(walls[:, [1, 3]].min()), float(walls[:, [1, 3]].max())
    gx0 = (math.floor(xmin / cell_m) - _MARGIN_CELLS) * cell_m
    gy0 = (math.floor(ymin / cell_m) - _MARGIN_CELLS) * cell_m
    nx = math.ceil((xmax - gx0) / cell_m) + _MARGIN_CELLS
    ny = math.ceil((ymax - gy0) / cell_m) + _MARGIN_CELLS
    if nx * ny > max_cells:
        raise MetricError(
            f"the map spans {xmax - xmin:.1f} m x {ymax - ymin:.1f} m = {nx} x {ny} cells of {cell_m} m, "
            f"more than max_cells = {max_cells}: use a larger cell_m"
        )
    lattice = crossing_lattice(walls, gx0, gy0, cell_m, nx, ny)
    labels = lattice.labels
    col = np.floor((inside[:, 0] - gx0) / cell_m).astype(np.intp)
    row = np.floor((inside[:, 1] - gy0) / cell_m).astype(np.intp)
    outside = np.flatnonzero((col < 0) | (col >= nx) | (row < 0) | (row >= ny))
    if len(outside):
        k = int(outside[0])
        raise MapLeakError(
            f"inside point {k} ({inside[k, 0]:.3f}, {inside[k, 1]:.3f}) m lies outside the map's "
            f"bounding box x [{xmin:.3f}, {xmax:.3f}], y [{ymin:.3f}, {ymax:.3f}] m: "
            "the map cannot enclose it",
            seed_xy=(float(inside[k, 0]), float(inside[k, 1])),
            close_gaps_m=close_gaps_m,
        )
    seed_labels = labels[row, col]
    border = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
    border = border[border > 0]
    leaking = np.flatnonzero(np.isin(seed_labels, border))
    if len(leaking):
        k = int(leaking[0])
        raise MapLeakError(
            f"the map does not enclose the trajectory: the region around inside point {k} "
            f"({inside[k, 0]:.3f}, {inside[k, 1]:.3f}) m reaches open space even after closing gaps up to "
            f"{close_gaps_m} m ({len(leaking)} of {len(inside)} inside points leak); a wall is missing or a "
            "gap is wider than close_gaps_m",
            seed_xy=(float(inside[k, 0]), float(inside[k, 1])),
            close_gaps_m=close_gaps_m,
        )
    wanted = np.unique(seed_labels[seed_labels > 0])
    if len(wanted) == 0:
        raise MetricError("every inside point lies exactly on a wall: no region to fill")
    on_wall = int(np.count_nonzero(seed_labels == 0))
    if on_wall:
        log.debug("%d inside points lie exactly on a wall and seed nothing", on_wall)
    region = np.isin(labels, wanted)
    area = marching_area(region, lattice)
    region.setflags(write=False)
    bridges.setflags(write=False)
    return EnclosedArea(area, cell_m, (gx0, gy0), region, bridges)


def map_area_m2(
    segments: ArrayLike,
    inside_points: ArrayLike,
    *,
    cell_m: float = 0.02,
    close_gaps_m: float = 0.3,
) -> float:
    """Floor area (m^2) the map encloses around the trajectory; see :func:`enclosed_area`."""
    return enclosed_area(segments, inside_points, cell_m=cell_m, close_gaps_m=close_gaps_m).area_m2


def area_error_pct(
    segments: ArrayLike,
    floor_area_m2: float,
    inside_points: ArrayLike,
    *,
    cell_m: float = 0.02,
    close_gaps_m: float = 0.3,
) -> float:
    """``100 |A_map - A_true| / A_true`` (paper Table 3), A_map from :func:`map_area_m2`.

    Raises :class:`MapLeakError` when the map is not closed (the paper's metric needs a closed map).
    """
    if not (math.isfinite(floor_area_m2) and floor_area_m2 > 0.0):
        raise MetricInputError(f"floor_area_m2 = {floor_area_m2!r}: expected a positive area in m^2")
    area = map_area_m2(segments, inside_points, cell_m=cell_m, close_gaps_m=close_gaps_m)
    return 100.0 * abs(area - floor_area_m2) / floor_area_m2
