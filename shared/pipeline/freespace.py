"""Free-space evidence: a wall that later beams pass through loses its support and leaves the map.

A person crossing, a door leaf before it opened or a chair before it was moved leave walls in the map as
real walls do; what tells them apart is consistency over time and viewpoints. Each wall keeps log-odds of
"occupied" in cells of ``cell_m`` along it (an inverse sensor model as in occupancy grids). Per scan, a
cell crossed by beams returning *at* the wall gains ``hit_logodds``, one crossed by beams returning
clearly *beyond* it ``miss_logodds``, once per scan each, clamped to ``+-clamp``; cells at or below
``free_logodds`` are free and cut out of the wall (:meth:`WallMap.cut`, ``removed`` reports walls that
went). "At" and "beyond" compare the return with the crossing range ``s`` against ``n_sigma`` times
``sigma_along^2 = sigma_range(s)^2 + sigma_perp^2 / sin^2(incidence)``, with the wall's perpendicular
uncertainty ``sigma_perp^2 = line_sigma_m^2 + (s heading_sigma_rad)^2``. No evidence: beams without a
return (glass, black, max range), returns before the wall (occlusion), grazing beams (incidence below
``min_incidence_deg``). See docs/freespace.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from shared.kernels._jit import njit
from shared.pipeline.wallmap import WallMap
from shared.types import FloatArray, IntArray, Pose2D, Scan

__all__ = ["FreeSpace", "FreeSpaceModel", "beam_wall_events", "supported_runs"]

HIT = 1  # a return at the wall within the tolerance without drift: support, and the wall's clock reset
HIT_DRIFT = 2  # at the wall only within the tolerance widened by the drift since its last support
PASS = -1


@dataclass(frozen=True, slots=True)
class FreeSpaceModel:
    """The inverse sensor model of free-space evidence (metres, radians, log-odds)."""

    cell_m: float = 0.10
    #: range noise, one sigma: the URG-04LX's +-25 mm below 1 m and +-2.5 % beyond, read as two sigma
    range_sigma_near_m: float = 0.0125
    range_sigma_ratio: float = 0.0125
    range_near_limit_m: float = 1.0
    #: the wall's line relative to the scanner, one sigma (the map's merge band is +-8 cm)
    line_sigma_m: float = 0.04
    #: heading uncertainty of the scanner relative to the map, one sigma
    heading_sigma_rad: float = 0.01
    n_sigma: float = 3.0
    min_incidence_deg: float = 15.0
    #: crossings closer than this to the scanner are not evidence (the scanner's own body, range_min)
    min_range_m: float = 0.1
    hit_logodds: float = 0.85
    miss_logodds: float = -0.4
    clamp: float = 2.5
    free_logodds: float = -1.0
    #: supported runs shorter than this are dropped with the free cells around them
    min_piece_m: float = 0.1
    #: drift of the pose relative to a wall since the wall last returned a beam, one sigma: position per
    #: metre travelled, heading per metre travelled and per radian turned (wheel odometry's order)
    drift_m_per_m: float = 0.02
    drift_rad_per_m: float = 0.01
    drift_rad_per_rad: float = 0.02

    def packed(self) -> FloatArray:
        """The numbers the compiled loops read, in the order of :data:`_PACKED`. O(1)."""
        sin_min = math.sin(math.radians(self.min_incidence_deg))
        return np.array([sin_min if f == "sin_min" else getattr(self, f, 0.0) for f in _PACKED])


#: index 6 is unused ("-": 0), 7 is the sine of ``min_incidence_deg``
_SIGMAS = ("range_sigma_near_m", "range_sigma_ratio", "range_near_limit_m", "line_sigma_m")
_PACKED: tuple[str, ...] = (*_SIGMAS, "heading_sigma_rad", "n_sigma", "-", "sin_min", "min_range_m")
_PACKED += ("cell_m", "hit_logodds", "miss_logodds", "clamp", "free_logodds")


@njit
def _crossing(
    ox: float,
    oy: float,
    ux: float,
    uy: float,
    r: float,
    wall: tuple[float, ...],
    p: FloatArray,
) -> tuple[int, float]:
    """Whether the beam from ``(ox, oy)`` along unit ``(ux, uy)`` with return ``r`` hits (:data:`HIT`,
    :data:`HIT_DRIFT`) or passes through (:data:`PASS`) the wall ``(x0, y0, dx, dy, length, drift_xy2,
    drift_th2)`` (first end point, unit direction, metres; variances of its drift in position, m^2, and
    heading, rad^2), and where (metres from that end point); 0 when it is no evidence (no crossing,
    grazing, too near, occluded, no return). ``p``: :meth:`FreeSpaceModel.packed`. O(1)."""
    x0, y0, dx, dy, length, drift_xy2, drift_th2 = wall
    if not r > 0.0:  # NaN: no return
        return 0, 0.0
    den = ux * dy - uy * dx  # cross(u, d): sine of the incidence, signed
    if abs(den) < p[7]:
        return 0, 0.0
    # o + s u = p0 + t d  ->  s = cross(p0 - o, d) / cross(u, d), t = cross(p0 - o, u) / cross(u, d)
    qx, qy = x0 - ox, y0 - oy
    s = (qx * dy - qy * dx) / den
    t = (qx * uy - qy * ux) / den
    if s < p[8] or t < 0.0 or t > length:
        return 0, 0.0
    sig_r = p[0] if s < p[2] else p[1] * s
    sig_perp2 = p[3] * p[3] + (s * p[4]) ** 2
    tol0 = p[5] * math.sqrt(sig_r * sig_r + sig_perp2 / (den * den))
    tol = p[5] * math.sqrt(sig_r * sig_r + (sig_perp2 + drift_xy2 + s * s * drift_th2) / (den * den))
    if r < s - tol:
        return 0, 0.0  # occluded: the beam stopped before the wall
    if abs(r - s) <= tol0:
        return HIT, t
    return (HIT_DRIFT if r <= s + tol else PASS), t


@njit
def _windows(
    ox: float, oy: float, x0: float, y0: float, x1: float, y1: float, a_first: float, inc: float, nb: int
) -> tuple[int, int, int, int]:
    """The beam index windows ``[k0, k1)`` and ``[k2, k3)`` that can cross the segment (its angular span from
    the origin, one beam of margin each side); every beam when the span is unknown. O(1)."""
    if inc <= 0.0:
        return 0, nb, 0, 0
    f0 = math.atan2(y0 - oy, x0 - ox)
    f1 = math.atan2(y1 - oy, x1 - ox)
    span = (f1 - f0 + math.pi) % (2.0 * math.pi) - math.pi
    hw = 0.5 * abs(span)
    if hw > 0.5 * math.pi - 1e-6:
        return 0, nb, 0, 0
    rel = (f0 + 0.5 * span - a_first) % (2.0 * math.pi)
    k0 = max(math.floor((rel - hw) / inc) - 1, 0)
    k1 = min(math.ceil((rel + hw) / inc) + 2, nb)
    rel2 = rel - 2.0 * math.pi
    k2 = max(math.floor((rel2 - hw) / inc) - 1, 0)
    k3 = min(math.ceil((rel2 + hw) / inc) + 2, nb)
    return k0, max(k1, k0), k2, max(k3, k2)


@njit
def beam_wall_events(
    ox: float,
    oy: float,
    a_first: float,
    inc: float,
    ranges_m: FloatArray,
    segs: FloatArray,
    drift: FloatArray,
    p: FloatArray,
) -> FloatArray:
    """Every piece of evidence one scan gives about walls ``segs`` ``(W, 4)``: beam ``k`` leaves the scanner
    at ``(ox, oy)`` at world angle ``a_first + k inc`` with return ``ranges_m[k]`` (NaN: none). Returns
    ``(E, 3)`` rows ``[wall, t_m, kind]``: wall index, distance of the crossing from the wall's first end
    point (metres), :data:`HIT` / :data:`HIT_DRIFT` / :data:`PASS`, wall by wall. ``drift``: ``(W, 2)``
    drift variances per wall (see :func:`_crossing`); ``p``: :meth:`FreeSpaceModel.packed`.
    O(beams x walls), beams restricted to each wall's angular span."""
    nb, nw = ranges_m.shape[0], segs.shape[0]
    ev, m = np.empty((64, 3)), 0
    for w in range(nw):
        x0, y0, x1, y1 = segs[w, 0], segs[w, 1], segs[w, 2], segs[w, 3]
        length = math.hypot(x1 - x0, y1 - y0)
        if length <= 0.0:
            continue
        dx, dy = (x1 - x0) / length, (y1 - y0) / length
        k0, k1, k2, k3 = _windows(ox, oy, x0, y0, x1, y1, a_first, inc, nb)
        for win in range(2):
            for k in range(k0, k1) if win == 0 else range(k2, k3):
                a = a_first + k * inc
                wl = (x0, y0, dx, dy, length, drift[w, 0], drift[w, 1])
                c, t = _crossing(ox, oy, math.cos(a), math.sin(a), ranges_m[k], wl, p)
                if c == 0:
                    continue
                if m == ev.shape[0]:
                    grown = np.empty((2 * m, 3))
                    grown[:m] = ev
                    ev = grown
                ev[m, 0], ev[m, 1], ev[m, 2] = w, t, c
                m += 1
    return ev[:m]


@njit
def _update_cells(
    ev: FloatArray,
    off: FloatArray,
    first: IntArray,
    last: IntArray,
    base: IntArray,
    i0: IntArray,
    pool: FloatArray,
    p: FloatArray,
    scratch: IntArray,
) -> IntArray:
    """One scan's events (:func:`beam_wall_events`, wall by wall) added to the walls' cells in ``pool``: wall
    ``w``'s cell ``i`` (covering ``[i cell, (i + 1) cell)`` from the wall's anchor, its first end point at
    ``off[w]`` from it, cells ``first[w]..last[w]`` on it) is ``pool[base[w] + i - i0[w]]``. Each cell
    counts once per scan: a hit if its beams returned at the wall at least as often as beyond it, else a
    pass-through. Returns per wall bit 1 if one of its cells is now free, bit 2 if a beam returned at it
    within the tolerance without drift (:data:`HIT`). O(events + cells of walls seen)."""
    cell, hit_l, miss_l, clamp, free_l = p[9], p[10], p[11], p[12], p[13]
    flags = np.zeros(off.shape[0], dtype=np.intp)
    m, e = ev.shape[0], 0
    while e < m:
        w = int(ev[e, 0])
        n = last[w] - first[w] + 1
        scratch[: 2 * n] = 0
        while e < m and ev[e, 0] == w:
            i = min(max(math.floor((off[w] + ev[e, 1]) / cell) - first[w], 0), n - 1)
            scratch[2 * i + (0 if ev[e, 2] > 0 else 1)] += 1
            if ev[e, 2] == HIT:
                flags[w] |= 2
            e += 1
        shift = base[w] + first[w] - i0[w]
        for i in range(n):
            h, q = scratch[2 * i], scratch[2 * i + 1]
            if h + q > 0:
                v = pool[shift + i] + (hit_l if h >= q else miss_l)
                pool[shift + i] = min(max(v, -clamp), clamp)
            if pool[shift + i] <= free_l:
                flags[w] |= 1
    return flags


@njit
def _extents(
    segs: FloatArray, slots: IntArray, anchor: FloatArray, cell: float
) -> tuple[FloatArray, FloatArray, IntArray, IntArray]:
    """Per wall: its first end point's distance along it from its slot's anchor, its length, and its first
    and last cell index (metres, cells of ``cell``). O(walls)."""
    nw = segs.shape[0]
    off, length = np.empty(nw), np.empty(nw)
    first, last = np.empty(nw, dtype=np.intp), np.empty(nw, dtype=np.intp)
    for w in range(nw):
        ex, ey = segs[w, 2] - segs[w, 0], segs[w, 3] - segs[w, 1]
        length[w] = math.hypot(ex, ey)
        inv = 1.0 / max(length[w], 1e-12)
        s = slots[w]
        off[w] = ((segs[w, 0] - anchor[s, 0]) * ex + (segs[w, 1] - anchor[s, 1]) * ey) * inv
        first[w] = math.floor(off[w] / cell)
        last[w] = max(math.floor((off[w] + length[w]) / cell - 1e-9), first[w])
    return off, length, first, last


def supported_runs(free: np.ndarray, cell_m: float, min_piece_m: float) -> list[tuple[int, int]]:
    """Maximal runs ``[i0, i1)`` of cells not ``free`` (boolean), at least ``min_piece_m`` long. O(cells)."""
    keep = np.concatenate(([False], ~np.asarray(free, dtype=bool), [False]))
    edges = np.flatnonzero(np.diff(keep.astype(np.int8)))
    runs = [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]
    return [(a, b) for a, b in runs if (b - a) * cell_m >= min_piece_m - 1e-12]


class FreeSpace:
    """Per-wall free-space evidence for one :class:`WallMap` (stateful; the geometry is pure).

    ``observe(walls, laser_pose, scan)`` updates the cells of every wall (shown or not yet) the scan's
    beams cross and cuts the free parts out of the map. Cells live in one pool, a block per wall id
    anchored at the wall's first end point when first seen (so they stay put as the wall grows).
    O(beams in each wall's angular span x walls) per scan.
    """

    _MARGIN = 8  # cells of headroom each side when a wall's block grows

    def __init__(self, model: FreeSpaceModel | None = None) -> None:
        self.model = model or FreeSpaceModel()
        self._p = self.model.packed()
        self._slot: dict[int, int] = {}
        self._free_slots: list[int] = []
        # per slot: cell anchor, travel (m, rad) when the wall last returned a beam (HIT), cell block
        self._anchor, self._since = np.zeros((64, 2)), np.zeros((64, 2))
        self._i0, self._n, self._base = (np.zeros(64, dtype=np.intp) for _ in range(3))
        self._travel = np.zeros(2)  # the scanner's path length (m) and turning (rad) so far
        self._last: Pose2D | None = None
        self._pool, self._used = np.zeros(4096), 0
        self._scratch = np.zeros(64, dtype=np.intp)
        self.cut_walls = 0

    def observe(self, walls: WallMap, laser: Pose2D, scan: Scan) -> list[int]:
        """Apply one scan taken from the scanner pose ``laser`` (world frame) to ``walls``; returns the ids of
        the walls it removed (also appended to ``walls.removed``)."""
        if self._last is not None:
            step = self._last.between(laser)
            self._travel += (math.hypot(step.x_m, step.y_m), abs(step.theta_rad))
        self._last = laser
        ids, segs = walls.all_walls()
        if len(ids) == 0:
            return []
        ranges = np.where(scan.valid_mask(), scan.ranges_m, np.nan)
        slots = self._slots_for(ids, segs)
        off, length, first, last = _extents(segs, slots, self._anchor, self.model.cell_m)
        for w in np.flatnonzero((first < self._i0[slots]) | (last >= self._i0[slots] + self._n[slots])):
            self._cover(int(slots[w]), int(first[w]), int(last[w]))
        need = 2 * int((last - first).max() + 1)
        if len(self._scratch) < need:
            self._scratch = np.zeros(2 * need, dtype=np.intp)
        a_first = scan.angle_min_rad + laser.theta_rad
        md = self.model
        dist, turn = (self._travel - self._since[slots]).T  # since each wall's last support
        xy2 = (md.drift_m_per_m * dist) ** 2
        th2 = (md.drift_rad_per_m * dist + md.drift_rad_per_rad * turn) ** 2
        drift = np.ascontiguousarray(np.column_stack([xy2, th2]))
        events = beam_wall_events(
            laser.x_m, laser.y_m, a_first, scan.angle_increment_rad, ranges, segs, drift, self._p
        )
        if len(events) == 0:
            return []
        flags = _update_cells(
            events, off, first, last, self._base[slots], self._i0[slots], self._pool, self._p, self._scratch
        )
        self._since[slots[(flags & 2) > 0]] = self._travel
        hit = [int(w) for w in np.flatnonzero(flags & 1)]
        return [int(ids[w]) for w in hit if self._cut(walls, w, ids, slots, off, length, first, last)]

    # ------------------------------------------------------------------ cells
    def _slots_for(self, ids: IntArray, segs: FloatArray) -> IntArray:
        """The slot of every wall id (new ids get one, anchored at their first end point); slots of ids no
        longer in the map are freed. O(walls)."""
        get = self._slot.get
        slots = np.fromiter((get(i, -1) for i in ids.tolist()), dtype=np.intp, count=len(ids))
        for w in np.flatnonzero(slots < 0):
            slots[w] = self._new_slot(int(ids[w]), segs[w, :2])
        if len(self._slot) > len(ids) + 32:
            live = set(ids.tolist())
            for wid in [k for k in self._slot if k not in live]:
                self._release(wid)
        return slots

    def _new_slot(self, wid: int, anchor: FloatArray) -> int:
        if self._free_slots:
            s = self._free_slots.pop()
        else:
            s = len(self._slot)
            if s == len(self._i0):
                for name in ("_anchor", "_i0", "_n", "_base", "_since"):
                    old = getattr(self, name)
                    new = np.zeros((2 * len(old), *old.shape[1:]), dtype=old.dtype)
                    new[: len(old)] = old
                    setattr(self, name, new)
        self._slot[wid] = s
        self._anchor[s], self._since[s] = anchor, self._travel
        self._i0[s], self._n[s], self._base[s] = 0, 0, 0
        return s

    def _release(self, wid: int) -> None:
        s = self._slot.pop(wid, None)
        if s is not None:
            self._n[s] = 0
            self._free_slots.append(s)

    def _cover(self, s: int, first: int, last: int) -> None:
        """Move slot ``s``'s block to the pool's end, grown (zero log-odds: no evidence) to hold cells
        ``first..last`` with some headroom. Amortised O(cells)."""
        n_old, i0_old = int(self._n[s]), int(self._i0[s])
        lo_i = first - self._MARGIN if n_old == 0 or first < i0_old else i0_old
        hi_i = last + self._MARGIN if n_old == 0 or last >= i0_old + n_old else i0_old + n_old - 1
        n_new = hi_i - lo_i + 1
        if self._used + n_new > len(self._pool):
            self._compact(n_new)
        b = self._used
        self._pool[b : b + n_new] = 0.0
        if n_old:
            src = int(self._base[s])
            self._pool[b + i0_old - lo_i : b + i0_old - lo_i + n_old] = self._pool[src : src + n_old]
        self._base[s], self._i0[s], self._n[s] = b, lo_i, n_new
        self._used += n_new

    def _compact(self, extra: int) -> None:
        """Copy the live blocks to a fresh pool with room for ``extra`` more cells. O(live cells)."""
        live = list(self._slot.values())
        total = int(self._n[live].sum()) if live else 0
        pool = np.zeros(max(2 * (total + extra), 4096))
        b = 0
        for s in live:
            n = int(self._n[s])
            pool[b : b + n] = self._pool[self._base[s] : self._base[s] + n]
            self._base[s] = b
            b += n
        self._pool, self._used = pool, b

    def _cut(self, walls: WallMap, w: int, *per_wall: np.ndarray) -> bool:
        """Cut wall ``w``'s free cells out of the map (:meth:`WallMap.cut`); True if none of it is left.
        ``per_wall``: the walls' ids, slots, offsets, lengths, first and last cells."""
        wid, s, first, last = (int(per_wall[k][w]) for k in (0, 1, 4, 5))
        off, length = float(per_wall[2][w]), float(per_wall[3][w])
        md = self.model
        b = int(self._base[s]) + first - int(self._i0[s])
        free = self._pool[b : b + last - first + 1] <= md.free_logodds
        runs = supported_runs(free, md.cell_m, md.min_piece_m)
        keep = [
            (max((first + r0) * md.cell_m - off, 0.0), min((first + r1) * md.cell_m - off, length))
            for r0, r1 in runs
        ]
        self.cut_walls += 1
        new_ids = walls.cut(wid, keep)
        for nid in new_ids:  # the other pieces share the cut wall's evidence
            t = self._new_slot(nid, self._anchor[s].copy())
            self._since[t] = self._since[s]
            self._cover(t, int(self._i0[s]), int(self._i0[s] + self._n[s] - 1))
            n, src = int(self._n[s]), int(self._base[s])
            self._pool[self._base[t] + self._i0[s] - self._i0[t] :][:n] = self._pool[src : src + n]
        if not keep:
            self._release(wid)
            return True
        return False
