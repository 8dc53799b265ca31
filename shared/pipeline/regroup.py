"""Regrouping an offline batch: the segments of successive scans that lie on one wall become one group.

Segmentation (paper §3.1) runs per scan, so a batch of N_smax scans holds each wall N_smax times, once per
scan. Lines and clusters must not straddle walls but should use every scan's points on a wall, so before
the batch is clustered, the per-scan groups are gathered into walls.

Gathering is done against each wall's *own* total-least-squares line, never pair by pair: uniting pairs
of groups that look collinear is transitive, and a chain of short groups, each within the angle tolerance
of the next (the few-point pieces a scan leaves around a corner), joins perpendicular walls into one group
whose line then runs across the room. Instead the groups are taken by decreasing point count; a group joins
the first wall (in order of creation) whose line all its points lie within ``offset_tol_m`` of and whose
span it overlaps or nearly touches (gap <= ``gap_tol_m``); otherwise it starts a new wall. A wall's line is
refitted from the moments of all its points as groups join. Finally walls are merged with each other when
their lines are parallel (``angle_tol_deg``), each one's end points lie within ``offset_tol_m`` of the
other's line and they overlap or nearly touch (two pieces of one wall that no single group bridged).
Complexity O(N W + W^3) for N points in G groups forming W walls (W << G).
"""

from __future__ import annotations

import math

import numpy as np

from shared.kernels._jit import njit
from shared.types import FloatArray, IntArray

__all__ = ["regroup"]


def regroup(
    points: FloatArray,
    groups: IntArray,
    *,
    angle_tol_deg: float = 5.0,
    offset_tol_m: float = 0.08,
    gap_tol_m: float = 0.3,
    min_points: int = 3,
    max_rms_m: float = 0.03,
) -> IntArray:
    """New group ids uniting the groups that lie on one wall. Ids are ``0..G'-1``; ``-1`` for points in no
    group or in a group that is not straight (RMS distance to its own line above ``max_rms_m``: a piece
    around a corner the per-scan split missed, which would otherwise draw a line across the room). Groups
    with fewer than ``min_points`` points keep a group of their own."""
    valid = groups >= 0
    out = np.full(len(groups), -1, dtype=np.intp)
    if not valid.any():
        return out
    uniq, inv = np.unique(groups[valid], return_inverse=True)
    g = len(uniq)
    order = np.argsort(inv, kind="stable")
    pts = np.ascontiguousarray(points[valid][order], dtype=np.float64)
    n_int = np.bincount(inv, minlength=g)
    starts = np.concatenate([[0], np.cumsum(n_int)]).astype(np.intp)
    n = n_int.astype(np.float64)
    sorted_inv = inv[order]
    mx = np.bincount(sorted_inv, pts[:, 0], g) / n
    my = np.bincount(sorted_inv, pts[:, 1], g) / n
    dx, dy = pts[:, 0] - mx[sorted_inv], pts[:, 1] - my[sorted_inv]
    sxx = np.bincount(sorted_inv, dx * dx, g) / n
    sxy = np.bincount(sorted_inv, dx * dy, g) / n
    syy = np.bincount(sorted_inv, dy * dy, g) / n
    half_trace = 0.5 * (sxx + syy)
    minor = half_trace - np.sqrt((0.5 * (sxx - syy)) ** 2 + sxy * sxy)  # smaller eigenvalue: residual var
    straight = np.sqrt(np.maximum(minor, 0.0)) <= max_rms_m
    ok = (n_int >= min_points) & straight
    by_size = np.lexsort((np.arange(g), -n_int)).astype(np.intp)
    wall = _gather(pts, starts, by_size, ok, offset_tol_m, gap_tol_m, math.cos(math.radians(angle_tol_deg)))
    wall = np.where(straight, wall, -1)
    kept = wall >= 0
    compact = np.full(g, -1, dtype=np.intp)
    if kept.any():
        _, compact_kept = np.unique(wall[kept], return_inverse=True)
        compact[kept] = compact_kept
    out[valid] = compact[inv]
    return out


@njit
def _line(m: FloatArray) -> tuple[float, float, float, float]:
    """Mean ``(mx, my)`` and direction ``(ux, uy)`` of the TLS line of the moments
    ``(n, sx, sy, sxx, sxy, syy)``."""
    cx = m[1] / m[0]
    cy = m[2] / m[0]
    vxx = m[3] / m[0] - cx * cx
    vxy = m[4] / m[0] - cx * cy
    vyy = m[5] / m[0] - cy * cy
    phi = 0.5 * math.atan2(2.0 * vxy, vxx - vyy)
    return cx, cy, math.cos(phi), math.sin(phi)


@njit
def _gather(
    pts: FloatArray,
    starts: IntArray,
    by_size: IntArray,
    ok: np.ndarray,
    offset_tol: float,
    gap_tol: float,
    cos_tol: float,
) -> IntArray:
    """Wall index of every group (groups not ``ok`` get a wall of their own), see the module docstring."""
    g = starts.shape[0] - 1
    wall = np.full(g, -1, dtype=np.intp)
    mom = np.zeros((g, 6))  # per wall: n, sx, sy, sxx, sxy, syy (absolute; walls span metres, not km)
    ends = np.zeros((g, 4))  # per wall: two extreme points along its line
    n_walls = 0
    for q in range(g):
        i = by_size[q]
        s, e = starts[i], starts[i + 1]
        target = -1
        if ok[i]:
            for w in range(n_walls):
                cx, cy, ux, uy = _line(mom[w])
                nx, ny = -uy, ux
                lo, hi = math.inf, -math.inf
                fits = True
                for p in range(s, e):
                    rx, ry = pts[p, 0] - cx, pts[p, 1] - cy
                    if abs(rx * nx + ry * ny) > offset_tol:
                        fits = False
                        break
                    t = rx * ux + ry * uy
                    lo, hi = min(lo, t), max(hi, t)
                if not fits:
                    continue
                ta = (ends[w, 0] - cx) * ux + (ends[w, 1] - cy) * uy
                tb = (ends[w, 2] - cx) * ux + (ends[w, 3] - cy) * uy
                if max(lo - max(ta, tb), min(ta, tb) - hi) <= gap_tol:
                    target = w
                    break
        if target < 0:
            target = n_walls
            n_walls += 1
        _add(pts, s, e, mom[target], ends[target], mom[target, 0] == 0.0)
        wall[i] = target
    # merge walls that are pieces of one wall
    alive = np.ones(n_walls, dtype=np.bool_)
    changed = True
    while changed:
        changed = False
        for a in range(n_walls):
            if not alive[a]:
                continue
            for b in range(a + 1, n_walls):
                if not alive[b]:
                    continue
                if not _same_wall(mom[a], ends[a], mom[b], ends[b], offset_tol, gap_tol, cos_tol):
                    continue
                for k in range(6):
                    mom[a, k] += mom[b, k]
                _merge_ends(mom[a], ends[a], ends[b])
                alive[b] = False
                for i in range(g):
                    if wall[i] == b:
                        wall[i] = a
                changed = True
    return wall


@njit
def _add(pts: FloatArray, s: int, e: int, m: FloatArray, end: FloatArray, fresh: bool) -> None:
    """Add points ``pts[s:e]`` to a wall's moments ``m`` and extreme points ``end``."""
    for p in range(s, e):
        x, y = pts[p, 0], pts[p, 1]
        m[0] += 1.0
        m[1] += x
        m[2] += y
        m[3] += x * x
        m[4] += x * y
        m[5] += y * y
    cx, cy, ux, uy = _line(m)
    if fresh:
        end[0], end[1], end[2], end[3] = pts[s, 0], pts[s, 1], pts[s, 0], pts[s, 1]
    ta = (end[0] - cx) * ux + (end[1] - cy) * uy
    tb = (end[2] - cx) * ux + (end[3] - cy) * uy
    if ta > tb:
        end[0], end[1], end[2], end[3] = end[2], end[3], end[0], end[1]
        ta, tb = tb, ta
    for p in range(s, e):
        t = (pts[p, 0] - cx) * ux + (pts[p, 1] - cy) * uy
        if t < ta:
            ta = t
            end[0], end[1] = pts[p, 0], pts[p, 1]
        if t > tb:
            tb = t
            end[2], end[3] = pts[p, 0], pts[p, 1]


@njit
def _merge_ends(m: FloatArray, end: FloatArray, other: FloatArray) -> None:
    """The two outermost of the four extreme points ``end`` and ``other`` along the (merged) line ``m``."""
    cx, cy, ux, uy = _line(m)
    best_lo, best_hi = math.inf, -math.inf
    lo_x = lo_y = hi_x = hi_y = 0.0
    for k in range(4):
        src = end if k < 2 else other
        x, y = src[2 * (k % 2)], src[2 * (k % 2) + 1]
        t = (x - cx) * ux + (y - cy) * uy
        if t < best_lo:
            best_lo, lo_x, lo_y = t, x, y
        if t > best_hi:
            best_hi, hi_x, hi_y = t, x, y
    end[0], end[1], end[2], end[3] = lo_x, lo_y, hi_x, hi_y


@njit
def _same_wall(
    ma: FloatArray,
    ea: FloatArray,
    mb: FloatArray,
    eb: FloatArray,
    offset_tol: float,
    gap_tol: float,
    cos_tol: float,
) -> bool:
    """Whether two walls are parallel, each one's extreme points lie on the other's line, and they overlap
    or nearly touch."""
    ax, ay, aux, auy = _line(ma)
    bx, by, bux, buy = _line(mb)
    if abs(aux * bux + auy * buy) < cos_tol:
        return False
    for cx, cy, ux, uy, end in ((ax, ay, aux, auy, eb), (bx, by, bux, buy, ea)):
        for k in range(2):
            if abs((end[2 * k] - cx) * -uy + (end[2 * k + 1] - cy) * ux) > offset_tol:
                return False
    t0 = (ea[0] - ax) * aux + (ea[1] - ay) * auy
    t1 = (ea[2] - ax) * aux + (ea[3] - ay) * auy
    u0 = (eb[0] - ax) * aux + (eb[1] - ay) * auy
    u1 = (eb[2] - ax) * aux + (eb[3] - ay) * auy
    gap: float = max(min(u0, u1) - max(t0, t1), min(t0, t1) - max(u0, u1))
    return gap <= gap_tol
