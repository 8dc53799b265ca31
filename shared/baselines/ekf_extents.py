"""Extents of the EKF baseline's line landmarks (:mod:`shared.baselines.ekf_lines`, "Extents"): the
observed end points of a landmark, kept as world pieces, projected on its current infinite line and joined
where they lie closer than a gap.

A line ``(rho, alpha)`` (m, rad, Hesse normal form) has the direction ``d = (-sin alpha, cos alpha)``; a
point's line coordinate is ``t = p . d`` (m). Pieces are kept as world points, not as ``t``: the foot of
the normal slides by ``rho * d_alpha`` as the estimate of ``alpha`` is corrected. O(K log K) for K pieces.
"""

from __future__ import annotations

import math

import numpy as np

from shared.types import FloatArray, segments_from_hesse

__all__ = ["extent_intervals", "join_extent"]


def extent_intervals(pieces: FloatArray, alpha: float) -> tuple[FloatArray, FloatArray]:
    """Line coordinates ``t`` (start, end; sorted by start) of world pieces ``(K, 4)`` on a line of normal
    angle ``alpha``: ``t = p . d``, ``d = (-sin alpha, cos alpha)``. O(K log K)."""
    d = np.array([-math.sin(alpha), math.cos(alpha)])
    t = pieces.reshape(-1, 2, 2) @ d
    lo, hi = t.min(axis=1), t.max(axis=1)
    order = np.argsort(lo, kind="stable")
    return lo[order], hi[order]


def join_extent(pieces: FloatArray, new: FloatArray, rho: float, alpha: float, gap: float) -> FloatArray:
    """Add the world piece ``new`` ``[x0, y0, x1, y1]`` to a landmark's ``pieces`` ``(K, 4)``, projected on
    the line ``(rho, alpha)``, joining intervals closer than ``gap``. Returns the pieces on that line.
    O(K log K).

    Pieces are kept as world points, not as line coordinates: ``t`` is measured from the foot of the normal,
    which slides by ``rho * d_alpha`` when the estimate of ``alpha`` moves (metres, for far lines).
    """
    lo, hi = extent_intervals(np.vstack([pieces, new[None, :]]), alpha)
    out_lo = [float(lo[0])]
    out_hi = [float(hi[0])]
    for a, b in zip(lo[1:].tolist(), hi[1:].tolist(), strict=True):
        if a > out_hi[-1] + gap:
            out_lo.append(a)
            out_hi.append(b)
        else:
            out_hi[-1] = max(out_hi[-1], b)
    return segments_from_hesse(np.full(len(out_lo), rho), np.full(len(out_lo), alpha), out_lo, out_hi)
