"""The compiled geometry of free-space evidence (:mod:`shared.pipeline.freespace`): where each beam of a
scan crosses each wall, whether it returned at the wall or beyond it, and the per-cell log-odds update.
Pure functions on arrays; the model's numbers come packed by :meth:`FreeSpaceModel.packed`.
"""

from __future__ import annotations

import math

import numpy as np

from shared.kernels._jit import njit
from shared.types import FloatArray, IntArray

__all__ = ["HIT", "HIT_DRIFT", "PASS", "beam_wall_events"]

HIT = 1  # a return at the wall within the tolerance without drift: support, and the wall's clock reset
HIT_DRIFT = 2  # at the wall only within the tolerance widened by the drift since its last support
PASS = -1


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
    if s < p[8] or s > p[6] or t < 0.0 or t > length:
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
    length: FloatArray,
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
            # a free cell counts once the wall covers half of it (or of itself): not an end poking in
            lo_m, hi_m = (
                max((first[w] + i) * cell, off[w]),
                min((first[w] + i + 1) * cell, off[w] + length[w]),
            )
            if pool[shift + i] <= free_l and hi_m - lo_m >= 0.5 * min(cell, length[w]):
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


@njit
def _near(segs: FloatArray, ox: float, oy: float, reach: float) -> IntArray:
    """Indices of the segments whose bounding box comes within ``reach`` of ``(ox, oy)``. O(walls)."""
    out = np.empty(segs.shape[0], dtype=np.intp)
    m = 0
    for w in range(segs.shape[0]):
        x0, y0, x1, y1 = segs[w, 0], segs[w, 1], segs[w, 2], segs[w, 3]
        in_x = min(x0, x1) <= ox + reach and max(x0, x1) >= ox - reach
        if in_x and min(y0, y1) <= oy + reach and max(y0, y1) >= oy - reach:
            out[m] = w
            m += 1
    return out[:m]
