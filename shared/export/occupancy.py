"""The line map as a ROS ``map_server`` occupancy map: a PGM image plus its YAML, at a chosen resolution.

Pixel values follow ``map_saver``'s trinary convention: 0 (black) = occupied, 254 = free, 205 = unknown;
the YAML says ``negate: 0``, ``occupied_thresh: 0.65``, ``free_thresh: 0.196``, ``mode: trinary``.

Frames (REP 103 / map_server): image row 0 is the TOP of the picture; ``origin`` ``[x, y, yaw]`` is the
pose of the image's LOWER-LEFT corner in the world frame. Pixel ``(row, col)`` of an ``H``-row image covers
``x in origin_x + [col, col + 1) * res`` and ``y in origin_y + [H - 1 - row, H - row) * res`` (yaw 0).

Walls: every segment is sampled every ``resolution / 2`` (consecutive samples then lie in the same or in
8-neighbouring cells), and where two consecutive samples sit in diagonal cells the cell the segment
actually passes through between them is added. Walls are therefore 4-connected (no diagonal gap a planner
could slip through) and every cell marked touches the segment. Free space: the region the map encloses
around the trajectory (:func:`shared.metrics.area.enclosed_area`, on the same grid, gaps up to
``close_gaps_m`` bridged); everything else is unknown. A map that does not enclose its trajectory (or has
no trajectory) gets walls and unknown only. O(cells + wall length / resolution). docs/design.md §1 (exporting
the finished map), §3 (metres, REP 103 frames), §5 (the enclosed-area fill).
"""

from __future__ import annotations

import logging
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import numpy as np
from numpy.typing import ArrayLike, NDArray

from shared.errors import InvalidInputError
from shared.export.atomic import atomic_write_bytes, atomic_write_text, read_text
from shared.export.errors import EmptyMapError, ExportIOError, OccupancyFormatError
from shared.export.mapserver import MapYaml, decode_map_yaml, decode_pgm, encode_map_yaml, encode_pgm
from shared.export.validate import check_rows, check_snapshot
from shared.pipeline.snapshot import MapSnapshot
from shared.types import BoolArray, FloatArray, IntArray

__all__ = [
    "DEFAULT_MAX_CELLS",
    "DEFAULT_RESOLUTION_M",
    "FREE",
    "OCCUPIED",
    "UNKNOWN",
    "OccupancyGrid",
    "occupancy_files",
    "occupancy_paths",
    "rasterise_segments",
    "read_occupancy",
    "write_occupancy",
]

_log = logging.getLogger(__name__)

OCCUPIED: Final = 0
FREE: Final = 254
UNKNOWN: Final = 205
DEFAULT_RESOLUTION_M: Final = 0.05
DEFAULT_MAX_CELLS: Final = 16_000_000
_MARGIN_CELLS = 3
_ORIGIN_DECIMALS = 9  # the origin is a whole number of cells, rounded to 1e-9 m so the YAML reads cleanly


@dataclass(frozen=True, slots=True, eq=False)
class OccupancyGrid:
    """An occupancy image and where it lies: ``pixels`` ``(H, W)`` uint8 (row 0 = top), ``resolution_m``
    metres per pixel, ``origin`` ``(x_m, y_m, yaw_rad)`` of the lower-left image corner, and how to read the
    grey values (``negate``, ``occupied_thresh``, ``free_thresh`` as in the map_server YAML)."""

    pixels: NDArray[np.uint8]
    resolution_m: float
    origin: tuple[float, float, float]
    negate: int = 0
    occupied_thresh: float = 0.65
    free_thresh: float = 0.196

    @property
    def height(self) -> int:
        return int(self.pixels.shape[0])

    @property
    def width(self) -> int:
        return int(self.pixels.shape[1])

    def world_to_pixel(self, xy: ArrayLike) -> tuple[IntArray, IntArray]:
        """``(row, col)`` of the pixels holding the world points ``xy`` ``(N, 2)`` m; may lie outside the
        image (check against :attr:`height` / :attr:`width`). O(N)."""
        pts = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        ox, oy, yaw = self.origin
        c, s = math.cos(yaw), math.sin(yaw)
        dx, dy = pts[:, 0] - ox, pts[:, 1] - oy
        u = (c * dx + s * dy) / self.resolution_m
        v = (-s * dx + c * dy) / self.resolution_m
        col = np.floor(u).astype(np.intp)
        row = self.height - 1 - np.floor(v).astype(np.intp)
        return row, col

    def pixel_to_world(self, row: ArrayLike, col: ArrayLike) -> FloatArray:
        """World ``(N, 2)`` m of the centres of pixels ``(row, col)``. O(N)."""
        r = np.asarray(row, dtype=np.float64).ravel()
        k = np.asarray(col, dtype=np.float64).ravel()
        ox, oy, yaw = self.origin
        u = (k + 0.5) * self.resolution_m
        v = (self.height - 1 - r + 0.5) * self.resolution_m
        c, s = math.cos(yaw), math.sin(yaw)
        return np.column_stack([ox + c * u - s * v, oy + s * u + c * v])

    def _occupancy(self) -> FloatArray:
        grey = self.pixels.astype(np.float64) / 255.0
        return grey if self.negate else 1.0 - grey

    def occupied(self) -> BoolArray:
        """Pixels map_server reads as occupied (probability above ``occupied_thresh``)."""
        return self._occupancy() > self.occupied_thresh

    def free(self) -> BoolArray:
        """Pixels map_server reads as free (probability below ``free_thresh``)."""
        return self._occupancy() < self.free_thresh


def _wall_cells(segments: FloatArray, ox: float, oy: float, res: float) -> tuple[IntArray, IntArray]:
    """``(ix, iy)`` (columns from the left, rows from the BOTTOM) of the cells the segments pass through."""
    x0, y0, x1, y1 = segments.T
    dx, dy = x1 - x0, y1 - y0
    n = np.ceil(np.hypot(dx, dy) / (0.5 * res)).astype(np.intp) + 1
    seg = np.repeat(np.arange(len(segments), dtype=np.intp), n)
    k = np.arange(int(n.sum()), dtype=np.intp) - np.repeat(np.cumsum(n) - n, n)
    t = k / np.maximum(n[seg] - 1, 1)
    x = x0[seg] + t * dx[seg]
    y = y0[seg] + t * dy[seg]
    ix = np.floor((x - ox) / res).astype(np.intp)
    iy = np.floor((y - oy) / res).astype(np.intp)
    a = np.flatnonzero((seg[1:] == seg[:-1]) & (ix[1:] != ix[:-1]) & (iy[1:] != iy[:-1]))
    b = a + 1
    # the grid lines crossed between the two samples, and the fraction of the step at which each is crossed
    t_v = (ox + np.maximum(ix[a], ix[b]) * res - x[a]) / (x[b] - x[a])
    t_h = (oy + np.maximum(iy[a], iy[b]) * res - y[a]) / (y[b] - y[a])
    first_x = t_v <= t_h  # column changes first: the cell between is (ix[b], iy[a]); a tie adds both
    first_y = t_h <= t_v
    ix_all = np.concatenate([ix, ix[b][first_x], ix[a][first_y]])
    iy_all = np.concatenate([iy, iy[a][first_x], iy[b][first_y]])
    return ix_all, iy_all


def _check_resolution(resolution_m: float) -> float:
    if isinstance(resolution_m, bool) or not isinstance(resolution_m, int | float | np.floating):
        raise InvalidInputError(f"resolution_m = {resolution_m!r}: expected a number of metres per pixel")
    res = float(resolution_m)
    if not (math.isfinite(res) and res > 0.0):
        raise InvalidInputError(
            f"resolution_m = {resolution_m!r}: expected a positive number of metres per pixel"
        )
    return res


def _too_many_cells(res: float, span: FloatArray, nx: str, ny: str, max_cells: int) -> InvalidInputError:
    return InvalidInputError(
        f"resolution_m = {res:g}: the map spans {span[0]:.1f} m x {span[1]:.1f} m = {nx} x {ny} cells, "
        f"more than max_cells = {max_cells}: use a larger resolution"
    )


def rasterise_segments(
    segments: ArrayLike,
    *,
    resolution_m: float = DEFAULT_RESOLUTION_M,
    inside_xy: ArrayLike | None = None,
    mark_free: bool = True,
    close_gaps_m: float = 0.3,
    max_cells: int = DEFAULT_MAX_CELLS,
) -> OccupancyGrid:
    """Rasterise wall ``segments`` ``(L, 4)`` m into an occupancy grid (method in the module docstring).

    The image covers the walls and the ``inside_xy`` ``(P, 2)`` points (the trajectory) plus a margin of
    three unknown cells; its origin is a whole number of cells from the world origin. With ``mark_free``
    the region the walls enclose around ``inside_xy`` is free. Raises :class:`EmptyMapError` without
    walls, :class:`InvalidInputError` for a bad resolution, bad arrays, or a grid of more than
    ``max_cells`` cells (use a larger resolution). O(W H + wall length / resolution).
    """
    res = _check_resolution(resolution_m)
    segs = check_rows(segments, 4, "segments", "[x0, y0, x1, y1] metres")
    inside = check_rows([] if inside_xy is None else inside_xy, 2, "inside_xy", "[x, y] metres")
    if len(segs) == 0:
        raise EmptyMapError("the map has no walls: an occupancy map needs at least one segment")
    pts = np.vstack([segs.reshape(-1, 2), inside])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    with np.errstate(over="ignore", invalid="ignore"):  # a float estimate first: no overflow below
        span_cells = (hi - lo) / res + 2 * _MARGIN_CELLS + 2
        scaled = np.concatenate([lo / res, span_cells])
        too_many = not np.isfinite(scaled).all() or float(np.prod(span_cells)) > max_cells
    if too_many:
        nx_est, ny_est = (f"{v:.3g}" for v in span_cells)
        raise _too_many_cells(res, hi - lo, nx_est, ny_est, max_cells)
    ox = round((math.floor(lo[0] / res) - _MARGIN_CELLS) * res, _ORIGIN_DECIMALS)
    oy = round((math.floor(lo[1] / res) - _MARGIN_CELLS) * res, _ORIGIN_DECIMALS)
    nx = math.floor((hi[0] - ox) / res) + 1 + _MARGIN_CELLS
    ny = math.floor((hi[1] - oy) / res) + 1 + _MARGIN_CELLS
    if nx * ny > max_cells:
        raise _too_many_cells(res, hi - lo, str(nx), str(ny), max_cells)
    bottom_up = np.full((ny, nx), UNKNOWN, dtype=np.uint8)  # row 0 = the lowest y; flipped at the end
    if mark_free and len(inside):
        _mark_free(bottom_up, segs, inside, ox, oy, res, close_gaps_m, max_cells)
    ix, iy = _wall_cells(segs, ox, oy, res)
    keep = (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
    bottom_up[iy[keep], ix[keep]] = OCCUPIED
    pixels = np.ascontiguousarray(bottom_up[::-1])
    _log.debug("rasterised %d segments into %d x %d cells of %g m", len(segs), nx, ny, res)
    return OccupancyGrid(pixels, res, (ox, oy, 0.0))


def _mark_free(
    bottom_up: NDArray[np.uint8],
    segs: FloatArray,
    inside: FloatArray,
    ox: float,
    oy: float,
    res: float,
    close_gaps_m: float,
    max_cells: int,
) -> None:
    from shared.metrics.area import enclosed_area
    from shared.metrics.errors import MetricError

    try:
        region = enclosed_area(segs, inside, cell_m=res, close_gaps_m=close_gaps_m, max_cells=max_cells)
    except MetricError as exc:
        _log.info("free space not marked (walls and unknown only): %s", exc)
        return
    gx0, gy0 = region.origin_xy
    di, dj = round((gy0 - oy) / res), round((gx0 - ox) / res)  # both grids are whole cells from 0
    i, j = np.nonzero(region.region)
    i, j = i + di, j + dj
    keep = (i >= 0) & (i < bottom_up.shape[0]) & (j >= 0) & (j < bottom_up.shape[1])
    bottom_up[i[keep], j[keep]] = FREE


def occupancy_paths(path: str | os.PathLike[str]) -> tuple[Path, Path]:
    """``(image, yaml)`` paths for ``path``, always in one folder: ``m.pgm``, ``m.yaml`` (or ``m.yml``)
    give their sibling with the other suffix; any other name gets both appended (``m`` -> ``m.pgm`` and
    ``m.yaml``, ``run.v2`` -> ``run.v2.pgm`` and ``run.v2.yaml``)."""
    target = Path(path)
    suffix = target.suffix.lower()
    if suffix == ".pgm":
        return target, target.with_suffix(".yaml")
    if suffix in (".yaml", ".yml"):
        return target.with_suffix(".pgm"), target
    return target.with_name(target.name + ".pgm"), target.with_name(target.name + ".yaml")


def occupancy_files(grid: OccupancyGrid, image_name: str) -> tuple[bytes, str]:
    """The PGM bytes and the YAML text (whose ``image`` is ``image_name``) of ``grid``. O(W H)."""
    comment = f"CREATOR: linemap {grid.resolution_m:.3f} m/pix"
    pgm = encode_pgm(grid.pixels, comment=comment)
    meta = MapYaml(
        image_name, grid.resolution_m, grid.origin, grid.negate, grid.occupied_thresh, grid.free_thresh
    )
    return pgm, encode_map_yaml(meta)


def write_occupancy(
    path: str | os.PathLike[str],
    snapshot: MapSnapshot,
    *,
    resolution_m: float = DEFAULT_RESOLUTION_M,
    mark_free: bool = True,
    max_cells: int = DEFAULT_MAX_CELLS,
) -> tuple[Path, Path]:
    """Rasterise ``snapshot`` (free space around its trajectory) and write the PGM and the YAML for
    ``path`` (see :func:`occupancy_paths`); returns ``(pgm, yaml)``. Each file is written atomically, the
    image first, so a reader of the YAML always finds a whole image. Errors as
    :func:`rasterise_segments`, and :class:`~shared.export.errors.ExportIOError` when writing fails."""
    checked = check_snapshot(snapshot)
    grid = rasterise_segments(
        checked.segments,
        resolution_m=resolution_m,
        inside_xy=checked.trajectory[:, 1:3],
        mark_free=mark_free,
        max_cells=max_cells,
    )
    pgm_path, yaml_path = occupancy_paths(path)
    pgm, text = occupancy_files(grid, pgm_path.name)  # the two are siblings: the YAML names the image alone
    atomic_write_bytes(pgm_path, pgm)
    atomic_write_text(yaml_path, text)
    _log.debug("wrote occupancy map %s + %s (%d x %d)", pgm_path, yaml_path, grid.width, grid.height)
    return pgm_path, yaml_path


def read_occupancy(path: str | os.PathLike[str]) -> OccupancyGrid:
    """Read a map_server map from its YAML (``m.yaml``; ``m`` or ``m.pgm`` name the YAML beside it) and
    the PGM image it names (relative to the YAML's folder). Raises
    :class:`~shared.export.errors.OccupancyFormatError` for a malformed YAML or image, and
    :class:`~shared.export.errors.ExportIOError` when a file cannot be read. O(file size)."""
    yaml_path = occupancy_paths(path)[1]
    meta = decode_map_yaml(read_text(yaml_path, OccupancyFormatError), str(yaml_path))
    image_path = yaml_path.parent / meta.image
    if image_path.suffix.lower() != ".pgm":
        raise OccupancyFormatError(f"{yaml_path}: image {meta.image!r}: expected a .pgm image")
    try:
        data = image_path.read_bytes()
    except OSError as exc:
        reason = exc.strerror or exc
        raise ExportIOError(f"cannot read {image_path} (named by {yaml_path}): {reason}") from exc
    pixels = decode_pgm(data, str(image_path))
    return OccupancyGrid(
        pixels, meta.resolution_m, meta.origin, meta.negate, meta.occupied_thresh, meta.free_thresh
    )
