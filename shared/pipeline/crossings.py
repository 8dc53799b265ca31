"""Walls do not pass through walls: of two shown walls that cross each other through both interiors, the
shorter one is not shown.

A laser cannot see both halves of a wall that runs through another opaque wall: the half behind it is
hidden from every pose the first half is seen from. Such a crossing is the mark of a noisy piece that
accumulated enough observations to be confirmed (a wall seen grazing from far, piece after piece, lap
after lap: the "hatching" across long walls in a map left running), not of the building. Corners and
T-junctions are not crossings: the longer wall must reach past the crossing point by more than
``margin_m`` on both sides (ends overshoot each other by a few centimetres), and walls within
``min_angle_deg`` of
each other are the merge's business (parallel copies), not this. The shorter wall carries less evidence
and is the one hidden, when it crosses near its middle (each side holds at least a quarter of it: a
wall with less beyond the other's line is an end overshooting a corner, as where an angled wall meets a
straight one); it stays in the map, so it returns should the other go (a door that opened).
O(W^2) for W walls, compiled, with a bounding-box test first (0.1 ms for 300 walls).
"""

from __future__ import annotations

import math

import numpy as np

from shared.kernels._jit import njit
from shared.types import BoolArray, FloatArray

__all__ = ["crossing_walls"]

#: a wall whose smaller side of the crossing holds less than this share of its length overshoots a corner
_SIDE_SHARE = 0.25


@njit
def _crossed(segs: FloatArray, margin_m: float, sin_min: float) -> BoolArray:
    n = segs.shape[0]
    hide = np.zeros(n, dtype=np.bool_)
    length = np.empty(n)
    for i in range(n):
        length[i] = math.hypot(segs[i, 2] - segs[i, 0], segs[i, 3] - segs[i, 1])
    for i in range(n):
        ax0, ay0, ax1, ay1 = segs[i, 0], segs[i, 1], segs[i, 2], segs[i, 3]
        la = length[i]
        if la <= 2.0 * margin_m:
            continue
        for j in range(i + 1, n):
            bx0, by0, bx1, by1 = segs[j, 0], segs[j, 1], segs[j, 2], segs[j, 3]
            lb = length[j]
            if lb <= 2.0 * margin_m:
                continue
            if max(ax0, ax1) < min(bx0, bx1) or max(bx0, bx1) < min(ax0, ax1):
                continue
            if max(ay0, ay1) < min(by0, by1) or max(by0, by1) < min(ay0, ay1):
                continue
            dax, day, dbx, dby = ax1 - ax0, ay1 - ay0, bx1 - bx0, by1 - by0
            den = dax * dby - day * dbx
            if abs(den) <= sin_min * la * lb:
                continue
            wx, wy = bx0 - ax0, by0 - ay0
            ta = (wx * dby - wy * dbx) / den
            tb = (wx * day - wy * dax) / den
            if not (0.0 < ta < 1.0 and 0.0 < tb < 1.0):
                continue
            # the shorter one is hidden if it crosses near its middle and the longer one goes on past the
            # crossing on both sides; otherwise it is an end overshooting a corner or a junction
            if la < lb:
                short_t, long_t, long_l, k = ta, tb, lb, i
            else:
                short_t, long_t, long_l, k = tb, ta, la, j
            if (
                _SIDE_SHARE <= short_t <= 1.0 - _SIDE_SHARE
                and long_t * long_l > margin_m
                and (1.0 - long_t) * long_l > margin_m
            ):
                hide[k] = True
    return hide


def crossing_walls(segments: FloatArray, margin_m: float, min_angle_deg: float) -> BoolArray:
    """Which of ``segments`` ``(W, 4)`` (metres) cross a longer one through both interiors (module
    docstring): ``(W,)`` booleans."""
    segs = np.ascontiguousarray(np.asarray(segments, dtype=np.float64).reshape(-1, 4))
    if len(segs) < 2:
        return np.zeros(len(segs), dtype=np.bool_)
    return np.asarray(_crossed(segs, float(margin_m), math.sin(math.radians(min_angle_deg))))
