"""Space seen free before: points that appear where earlier beams passed through are of things that moved in.

The per-wall evidence of :mod:`shared.pipeline.freespace` removes a wall that later beams see through;
it cannot act on a place the scanner never looks at again (a person crossing right beside or behind the
robot). This is the other half of "consistent over time": a log-odds occupancy grid of ``cell_m`` cells
over everything the scanner has seen. Per scan each cell a beam crossed clearly in front of its return
gains ``miss_logodds`` and the cell of each return ``hit_logodds``, once per scan each, clamped to
``+-clamp``. A new point in a cell at or below ``moved_logodds`` (seen through in several more scans than
it returned a beam) is of something that moved in: a person, a door leaf swinging, a chair pushed in;
:meth:`SeenFree.moved` flags it and the pipeline keeps it out of the shown map. A thing that stays
returns beams, its cells climb above ``moved_logodds`` within ``(clamp + moved_logodds) / hit_logodds``
scans and it is mapped from then on: a door that closed, a box put down.

"Clearly in front" keeps the grid from eating the walls it was built from: a beam counts as crossing only
the part of its path at least ``margin_m`` (across the surface it hit, so farther along a grazing beam:
``margin_m / sin(incidence)``, the incidence from the neighbouring returns) plus ``n_sigma`` range
standard deviations before its return, and farther than ``margin_m`` from the neighbouring beams'
returns (the edge of a box it passes beside). Beams without a return (glass, black, beyond range) are no
evidence. The grid grows with the area seen (about 4 bytes per 10 cm cell: 8 MB for 100 m x 100 m).
Update O(beams x range / cell_m); test O(points).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from shared.kernels._jit import njit
from shared.pipeline.rangenoise import URG_RANGE_SIGMA_NEAR_M, URG_RANGE_SIGMA_RATIO
from shared.types import BoolArray, FloatArray, Pose2D, Scan

__all__ = ["SeenFree", "SeenFreeModel"]


@dataclass(frozen=True, slots=True)
class SeenFreeModel:
    """The inverse sensor model of the seen-free grid (metres, log-odds)."""

    cell_m: float = 0.10
    miss_logodds: float = -0.4
    hit_logodds: float = 0.85
    clamp: float = 2.5
    #: a point in a cell at or below this has moved in (seen through in more scans than it returned a beam,
    #: a return counting about twice a pass as in the per-wall model): a cell seen free for long (at the
    #: clamp) is mapped from its second scan of returns on
    moved_logodds: float = -1.0
    #: clearance across the hit surface before which a beam's path counts as crossed (pose error, the
    #: scanner's beam width): 15 cm
    margin_m: float = 0.15
    #: the range noise, one sigma, as :class:`shared.pipeline.freespace.FreeSpaceModel` reads the URG-04LX
    range_sigma_near_m: float = URG_RANGE_SIGMA_NEAR_M
    range_sigma_ratio: float = URG_RANGE_SIGMA_RATIO
    n_sigma: float = 3.0
    #: incidences below this count as this (a grazing beam's free part ends 1.7 m before its return)
    min_incidence_deg: float = 5.0
    #: neighbouring returns farther apart than this are not one surface (no incidence from them)
    same_surface_m: float = 0.15
    max_range_m: float = 8.0


class SeenFree:
    """The grid of one pipeline (world frame). Not thread-safe."""

    def __init__(self, model: SeenFreeModel | None = None) -> None:
        self.model = model or SeenFreeModel()
        self._logodds = np.zeros((0, 0), dtype=np.float32)
        self._seen = np.zeros((0, 0), dtype=np.int32)  # scan number of the last miss / hit per cell
        self._hit = np.zeros((0, 0), dtype=np.int32)
        self._origin = (0.0, 0.0)  # world position of cell (0, 0)'s corner
        self._scans = 0

    @property
    def shape(self) -> tuple[int, int]:
        """Cells along x and y."""
        return self._logodds.shape[0], self._logodds.shape[1]

    def moved(self, points: FloatArray, spread_cells: int = 0) -> BoolArray:
        """Which of ``points`` ``(N, 2)`` (world frame, m) lie in cells seen free so far; with
        ``spread_cells`` > 0, only those whose every cell within that many cells is free (for points placed
        by a pose known to about ``spread_cells x cell_m``). O(N (2 spread + 1)^2)."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        out = np.zeros(len(pts), dtype=bool)
        if len(pts) == 0 or self._logodds.size == 0:
            return out
        c = self.model.cell_m
        i = np.floor((pts[:, 0] - self._origin[0]) / c).astype(np.intp)
        j = np.floor((pts[:, 1] - self._origin[1]) / c).astype(np.intp)
        k = int(spread_cells)
        nx, ny = self.shape
        inside = (i >= k) & (j >= k) & (i < nx - k) & (j < ny - k)
        ii, jj = i[inside], j[inside]
        free = np.ones(len(ii), dtype=bool)
        for di in range(-k, k + 1):
            for dj in range(-k, k + 1):
                free &= self._logodds[ii + di, jj + dj] <= self.model.moved_logodds
        out[inside] = free
        return out

    def free_share(self, segments: FloatArray, step_m: float = 0.05) -> FloatArray:
        """Per segment ``[x0, y0, x1, y1]`` (``(W, 4)``, world frame, m), the share of points sampled every
        ``step_m`` along it (ends included) that lie in cells seen free (:meth:`moved`): near 1 for the
        track a person left in a map built from every scan, near 0 for a wall. O(total length / step_m)."""
        segs = np.ascontiguousarray(np.asarray(segments, dtype=np.float64).reshape(-1, 4))
        if len(segs) == 0:
            return np.zeros(0)
        if self._logodds.size == 0:
            return np.zeros(len(segs))
        # the grid holds float32: compare as numpy compares it with a Python float (NEP 50)
        threshold = float(np.float32(self.model.moved_logodds))
        share: FloatArray = _free_share(
            segs, float(step_m), self._logodds, self._origin[0], self._origin[1], self.model.cell_m, threshold
        )
        return share

    def observe(self, laser: Pose2D, scan: Scan) -> None:
        """Add one scan taken from the scanner pose ``laser`` (world frame)."""
        md = self.model
        valid = scan.valid_mask()
        if not valid.any():
            return
        reach = min(float(scan.ranges_m[valid].max()), md.max_range_m)
        self._cover(laser.x_m - reach, laser.y_m - reach, laser.x_m + reach, laser.y_m + reach)
        self._scans += 1
        ranges = np.where(valid, scan.ranges_m, np.nan).astype(np.float64)
        _trace(
            self._logodds,
            self._seen,
            self._hit,
            self._scans,
            self._origin[0],
            self._origin[1],
            laser.x_m,
            laser.y_m,
            scan.angle_min_rad + laser.theta_rad,
            scan.angle_increment_rad,
            ranges,
            np.array(
                [
                    md.cell_m,
                    md.miss_logodds,
                    md.hit_logodds,
                    md.clamp,
                    md.margin_m,
                    md.range_sigma_near_m,
                    md.range_sigma_ratio,
                    md.n_sigma,
                    math.sin(math.radians(md.min_incidence_deg)),
                    md.same_surface_m,
                    md.max_range_m,
                ]
            ),
        )

    def _cover(self, x0: float, y0: float, x1: float, y1: float) -> None:
        """Grow the grid (doubling, with a margin) until it holds the box ``[x0, x1] x [y0, y1]``."""
        c = self.model.cell_m
        nx, ny = self.shape
        ox, oy = self._origin
        if nx and x0 >= ox and y0 >= oy and x1 < ox + nx * c and y1 < oy + ny * c:
            return
        if nx == 0:
            lo_x, lo_y, hi_x, hi_y = x0, y0, x1, y1
        else:
            lo_x, lo_y = min(ox, x0), min(oy, y0)
            hi_x, hi_y = max(ox + nx * c, x1), max(oy + ny * c, y1)
        pad_x, pad_y = 0.5 * (hi_x - lo_x), 0.5 * (hi_y - lo_y)
        new_ox = ox - c * math.ceil((ox - (lo_x - pad_x)) / c) if nx else lo_x - pad_x
        new_oy = oy - c * math.ceil((oy - (lo_y - pad_y)) / c) if nx else lo_y - pad_y
        new_nx = math.ceil((hi_x + pad_x - new_ox) / c) + 1
        new_ny = math.ceil((hi_y + pad_y - new_oy) / c) + 1
        di, dj = round((ox - new_ox) / c), round((oy - new_oy) / c)
        for name, dtype in (("_logodds", np.float32), ("_seen", np.int32), ("_hit", np.int32)):
            old = getattr(self, name)
            new = np.zeros((new_nx, new_ny), dtype=dtype)
            if nx:
                new[di : di + nx, dj : dj + ny] = old
            setattr(self, name, new)
        self._origin = (new_ox, new_oy)


@njit
def _trace(
    logodds: np.ndarray,
    seen: np.ndarray,
    hit: np.ndarray,
    scan_no: int,
    ox: float,
    oy: float,
    lx: float,
    ly: float,
    a_first: float,
    a_step: float,
    ranges: FloatArray,
    p: FloatArray,
) -> None:
    """Apply one scan's misses then hits to the grid (see the module docstring for the model)."""
    cell, miss, hit_lo, clamp, margin = p[0], p[1], p[2], p[3], p[4]
    sig_near, sig_ratio, n_sigma, sin_min, same, max_range = p[5], p[6], p[7], p[8], p[9], p[10]
    nx, ny = logodds.shape[0], logodds.shape[1]
    n = ranges.shape[0]
    ex = np.empty(n)
    ey = np.empty(n)
    block = np.empty((4, 2))
    for b in range(n):
        r = ranges[b]
        a = a_first + b * a_step
        ex[b] = lx + r * np.cos(a)
        ey[b] = ly + r * np.sin(a)
    for b in range(n):
        r = ranges[b]
        if not np.isfinite(r) or r > max_range:
            continue
        a = a_first + b * a_step
        dx, dy = np.cos(a), np.sin(a)
        # the hit surface's direction from the neighbouring returns on it, for the incidence
        sin_inc = sin_min
        lo, hi = b, b
        if b > 0 and np.isfinite(ranges[b - 1]) and abs(ranges[b - 1] - r) <= same:
            lo = b - 1
        if b + 1 < n and np.isfinite(ranges[b + 1]) and abs(ranges[b + 1] - r) <= same:
            hi = b + 1
        if hi > lo:
            tx, ty = ex[hi] - ex[lo], ey[hi] - ey[lo]
            tn = np.hypot(tx, ty)
            if tn > 0.0:
                sin_inc = max(abs(dx * ty - dy * tx) / tn, sin_min)
        sigma = max(sig_near, sig_ratio * r)
        free = r - n_sigma * sigma - margin / sin_inc
        # nor does it clear the cells of a surface it passes within the margin of (the neighbouring beams'
        # returns: the edge of a box or a door jamb it passes beside): the stretches of the ray within
        # ``margin`` of each, [t - h, t + h] with t the return's distance along the ray
        m = 0
        for q in range(max(b - 2, 0), min(b + 3, n)):
            rq = ranges[q]
            if q == b or not np.isfinite(rq):
                continue
            off = rq * abs(np.sin((q - b) * a_step))
            if off < margin:
                half = np.sqrt(margin * margin - off * off)
                t = rq * np.cos((q - b) * a_step)
                block[m, 0], block[m, 1] = t - half, t + half
                m += 1
        s = 0.5 * cell
        while s < free:
            beside = False
            for k in range(m):
                if block[k, 0] <= s <= block[k, 1]:
                    beside = True
            if not beside:
                i = int(np.floor((lx + s * dx - ox) / cell))
                j = int(np.floor((ly + s * dy - oy) / cell))
                if 0 <= i < nx and 0 <= j < ny and seen[i, j] != scan_no:
                    seen[i, j] = scan_no
                    logodds[i, j] = max(logodds[i, j] + miss, -clamp)
            s += 0.5 * cell
    for b in range(n):
        r = ranges[b]
        if not np.isfinite(r) or r > max_range:
            continue
        i = int(np.floor((ex[b] - ox) / cell))
        j = int(np.floor((ey[b] - oy) / cell))
        if 0 <= i < nx and 0 <= j < ny and hit[i, j] != scan_no:
            hit[i, j] = scan_no
            logodds[i, j] = min(logodds[i, j] + hit_lo, clamp)


@njit
def _free_share(
    segs: FloatArray,
    step_m: float,
    logodds: np.ndarray,
    ox: float,
    oy: float,
    cell: float,
    threshold: float,
) -> FloatArray:
    """:meth:`SeenFree.free_share`'s loop: per segment the share of its samples (``ceil(length / step_m)
    + 1``, evenly spaced, ends included) in cells at or below ``threshold``. O(total length / step_m)."""
    nx, ny = logodds.shape[0], logodds.shape[1]
    out = np.zeros(segs.shape[0])
    for w in range(segs.shape[0]):
        x0, y0, x1, y1 = segs[w, 0], segs[w, 1], segs[w, 2], segs[w, 3]
        count = max(math.ceil(math.hypot(x1 - x0, y1 - y0) / step_m), 1) + 1
        free = 0.0
        for q in range(count):
            t = q / (count - 1)
            i = math.floor((x0 + t * (x1 - x0) - ox) / cell)
            j = math.floor((y0 + t * (y1 - y0) - oy) / cell)
            if 0 <= i < nx and 0 <= j < ny and logodds[i, j] <= threshold:
                free += 1.0
        out[w] = free / count
    return out
