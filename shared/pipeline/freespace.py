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
``min_incidence_deg``). The compiled geometry is :mod:`shared.pipeline.freespace_kernels`; see
docs/freespace.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from shared.pipeline.freespace_kernels import (
    HIT,
    HIT_DRIFT,
    PASS,
    _extents,
    _near,
    _update_cells,
    beam_wall_events,
)
from shared.pipeline.rangenoise import URG_RANGE_SIGMA_NEAR_M, URG_RANGE_SIGMA_RATIO
from shared.pipeline.wallmap import WallMap
from shared.types import FloatArray, IntArray, Pose2D, Scan

__all__ = ["HIT", "HIT_DRIFT", "PASS", "FreeSpace", "FreeSpaceModel", "beam_wall_events", "supported_runs"]


@dataclass(frozen=True, slots=True)
class FreeSpaceModel:
    """The inverse sensor model of free-space evidence (metres, radians, log-odds)."""

    cell_m: float = 0.10
    #: range noise, one sigma: the URG-04LX's +-25 mm below 1 m and +-2.5 % beyond, read as two sigma
    range_sigma_near_m: float = URG_RANGE_SIGMA_NEAR_M
    range_sigma_ratio: float = URG_RANGE_SIGMA_RATIO
    range_near_limit_m: float = 1.0
    #: the wall's line relative to the scanner, one sigma (the map's merge band is +-8 cm)
    line_sigma_m: float = 0.04
    #: heading uncertainty of the scanner relative to the map, one sigma
    heading_sigma_rad: float = 0.01
    n_sigma: float = 3.0
    min_incidence_deg: float = 15.0
    #: crossings closer than this to the scanner are not evidence (the scanner's own body, range_min), nor
    #: those farther than ``max_range_m`` (weak there: heading uncertainty; and it bounds the cost)
    min_range_m: float = 0.1
    max_range_m: float = 8.0
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


#: index 7 is the sine of ``min_incidence_deg``
_SIGMAS = ("range_sigma_near_m", "range_sigma_ratio", "range_near_limit_m", "line_sigma_m")
_PACKED: tuple[str, ...] = (*_SIGMAS, "heading_sigma_rad", "n_sigma", "max_range_m", "sin_min", "min_range_m")
_PACKED += ("cell_m", "hit_logodds", "miss_logodds", "clamp", "free_logodds")


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
        self._keys, self._vals, self._stale = np.zeros(0, np.int64), np.zeros(0, np.intp), False
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
        all_ids, all_segs = walls.all_walls()
        valid = scan.valid_mask()
        if len(all_ids) == 0 or not valid.any():
            return []
        self._forget(all_ids)
        ranges = np.where(valid, scan.ranges_m, np.nan)
        reach = min(float(scan.ranges_m[valid].max()), self.model.max_range_m)
        near = _near(all_segs, laser.x_m, laser.y_m, reach)
        if len(near) == 0:
            return []
        ids, segs = all_ids[near], np.ascontiguousarray(all_segs[near])
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
            events,
            off,
            length,
            first,
            last,
            self._base[slots],
            self._i0[slots],
            self._pool,
            self._p,
            self._scratch,
        )
        self._since[slots[(flags & 2) > 0]] = self._travel
        hit = [int(w) for w in np.flatnonzero(flags & 1)]
        return [int(ids[w]) for w in hit if self._cut(walls, w, ids, slots, off, length, first, last)]

    # ------------------------------------------------------------------ cells
    def _slots_for(self, ids: IntArray, segs: FloatArray) -> IntArray:
        """The slot of every wall id (new ids get one, anchored at their first end point). O(walls)."""
        if self._stale:  # slots were freed: rebuild the sorted id -> slot arrays
            keys = np.fromiter(self._slot.keys(), np.int64, len(self._slot))
            vals = np.fromiter(self._slot.values(), np.intp, len(self._slot))
            order = np.argsort(keys)
            self._keys, self._vals, self._stale = keys[order], vals[order], False
        pos = np.minimum(np.searchsorted(self._keys, ids), max(len(self._keys) - 1, 0))
        slots = (
            np.where(self._keys[pos] == ids, self._vals[pos], -1) if len(self._keys) else -np.ones_like(ids)
        )
        new = np.flatnonzero(slots < 0)
        for w in new:  # new walls, or pieces of a cut wall (given a slot by the cut)
            wid = int(ids[w])
            slots[w] = self._slot[wid] if wid in self._slot else self._new_slot(wid, segs[w, :2])
        if len(new):
            keys, vals = np.concatenate([self._keys, ids[new]]), np.concatenate([self._vals, slots[new]])
            order = np.argsort(keys, kind="stable")
            self._keys, self._vals = keys[order], vals[order]
        return np.asarray(slots, dtype=np.intp)

    def _forget(self, ids: IntArray) -> None:
        """Free the slots of walls no longer in the map (fused into others), now and then. O(walls)."""
        if len(self._slot) > len(ids) + 32:
            live = set(ids.tolist())
            for wid in [k for k in self._slot if k not in live]:
                self._release(wid)

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
            self._n[s], self._stale = 0, True
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
        keep = [(t0, t1) for t0, t1 in keep if t1 - t0 >= md.min_piece_m]
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
