"""Regrouping an offline batch: the segments of successive scans that lie on one wall become one group.

Segmentation (paper §3.1) runs per scan, so a batch of N_smax scans holds each wall N_smax times, once per
scan. Lines and clusters must not straddle walls but should use every scan's points on a wall, so before
the batch is clustered, groups whose total-least-squares lines are collinear (angle within
``angle_tol_deg``, each group's end points within ``offset_tol_m`` of the other's line) and overlap or
nearly touch (gap <= ``gap_tol_m``) are united (union-find). Complexity O(N + G^2) for N points in G groups.
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
    around a corner the per-scan split missed, which would otherwise draw a line across the room)."""
    valid = groups >= 0
    out = np.full(len(groups), -1, dtype=np.intp)
    if not valid.any():
        return out
    uniq, inv = np.unique(groups[valid], return_inverse=True)
    g = len(uniq)
    pts = points[valid]
    n = np.bincount(inv, minlength=g).astype(np.float64)
    mx = np.bincount(inv, pts[:, 0], g) / n
    my = np.bincount(inv, pts[:, 1], g) / n
    dx, dy = pts[:, 0] - mx[inv], pts[:, 1] - my[inv]
    sxx = np.bincount(inv, dx * dx, g) / n
    sxy = np.bincount(inv, dx * dy, g) / n
    syy = np.bincount(inv, dy * dy, g) / n
    phi = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)
    ux, uy = np.cos(phi), np.sin(phi)
    t = dx * ux[inv] + dy * uy[inv]
    lo = np.full(g, np.inf)
    hi = np.full(g, -np.inf)
    np.minimum.at(lo, inv, t)
    np.maximum.at(hi, inv, t)
    half_trace = 0.5 * (sxx + syy)
    minor = half_trace - np.sqrt((0.5 * (sxx - syy)) ** 2 + sxy * sxy)  # smaller eigenvalue: residual var
    straight = np.sqrt(np.maximum(minor, 0.0)) <= max_rms_m
    ok = (n >= min_points) & straight
    roots = _unite(mx, my, ux, uy, lo, hi, ok, math.cos(math.radians(angle_tol_deg)), offset_tol_m, gap_tol_m)
    roots = np.where(straight, roots, -1)
    kept = roots >= 0
    compact = np.full(g, -1, dtype=np.intp)
    if kept.any():
        _, compact_kept = np.unique(roots[kept], return_inverse=True)
        compact[kept] = compact_kept
    out[valid] = compact[inv]
    return out


@njit
def _find(parent: IntArray, i: int) -> int:
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


@njit
def _unite(
    mx: FloatArray,
    my: FloatArray,
    ux: FloatArray,
    uy: FloatArray,
    lo: FloatArray,
    hi: FloatArray,
    ok: np.ndarray,
    cos_tol: float,
    offset_tol: float,
    gap_tol: float,
) -> IntArray:
    """Union-find over group pairs that are one wall; returns each group's root."""
    g = mx.shape[0]
    parent = np.arange(g)
    for i0 in range(g):
        if not ok[i0]:
            continue
        for j0 in range(i0 + 1, g):
            if not ok[j0]:
                continue
            # the longer group is the reference line; the shorter one's ends must lie on it
            i, j = (i0, j0) if hi[i0] - lo[i0] <= hi[j0] - lo[j0] else (j0, i0)
            if abs(ux[i] * ux[j] + uy[i] * uy[j]) < cos_tol:
                continue
            ax, ay = mx[i] + ux[i] * lo[i], my[i] + uy[i] * lo[i]
            bx, by = mx[i] + ux[i] * hi[i], my[i] + uy[i] * hi[i]
            nx, ny = -uy[j], ux[j]
            rax, ray, rbx, rby = ax - mx[j], ay - my[j], bx - mx[j], by - my[j]
            if abs(rax * nx + ray * ny) > offset_tol or abs(rbx * nx + rby * ny) > offset_tol:
                continue
            ta, tb = rax * ux[j] + ray * uy[j], rbx * ux[j] + rby * uy[j]
            if max(min(ta, tb) - hi[j], lo[j] - max(ta, tb)) > gap_tol:
                continue
            ri, rj = _find(parent, i0), _find(parent, j0)
            if ri != rj:
                parent[max(ri, rj)] = min(ri, rj)
    for i in range(g):
        parent[i] = _find(parent, i)
    return parent
