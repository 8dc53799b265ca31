"""The line map: walls merged from the segments of successive steps (SPEC §4 "map assembly").

Each wall keeps the length-weighted second moments of every segment merged into it, so merging is O(1)
and order-independent: a segment from ``a`` to ``b`` of length ``L`` counts as a uniform distribution of
mass ``L`` along it (mean ``(a + b) / 2``, covariance ``L^2 / 12 d d^T``). A wall's line is the total
least squares fit of its moments (the principal axis, as SVD in paper eq. 27-32) and its extent is the
union of the merged segments' projections on that line.

A new segment merges into a wall when it is collinear (angle within ``angle_tol_deg``, both end points
within ``offset_tol_m`` of the wall's line) and overlaps it or leaves a gap of at most ``gap_tol_m``.
A merged wall is then checked against the others again, so chains of pieces fuse into one wall. Walls keep
stable integer ids; when two walls fuse, the older id survives and the other is reported removed. A wall is
shown (``segments``/``ids``) once ``min_observations`` segments have merged into it: clutter seen once
stays out of the map, a wall seen from three steps is in.
Complexity: O(W) per inserted segment for W walls (vectorised).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from shared.types import FloatArray, IntArray

__all__ = ["MergeTolerances", "WallMap"]


@dataclass(frozen=True, slots=True)
class MergeTolerances:
    """When two collinear pieces are the same wall."""

    angle_tol_deg: float = 5.0
    offset_tol_m: float = 0.08
    gap_tol_m: float = 0.30
    min_length_m: float = 0.05
    min_observations: int = 3


class WallMap:
    """A growing set of walls with stable ids. Not thread-safe; one per pipeline."""

    def __init__(self, tolerances: MergeTolerances | None = None) -> None:
        self.tol = tolerances or MergeTolerances()
        self._cos_tol = math.cos(math.radians(self.tol.angle_tol_deg))
        self._n = 0
        cap = 64
        self._ids = np.zeros(cap, dtype=np.intp)
        self._obs = np.zeros(cap, dtype=np.intp)  # segments merged into the wall
        self._w = np.zeros(cap)  # total length
        self._s1 = np.zeros((cap, 2))  # sum of w * mean
        self._s2 = np.zeros((cap, 3))  # sum of w * E[x x^T] as (xx, xy, yy)
        self._c = np.zeros((cap, 2))  # fitted centroid
        self._d = np.zeros((cap, 2))  # fitted unit direction
        self._lo = np.zeros(cap)  # extent along d, relative to c
        self._hi = np.zeros(cap)
        self._next_id = 0
        self.removed: list[int] = []

    def __len__(self) -> int:
        return self._n

    # ------------------------------------------------------------------ queries
    def _shown(self) -> IntArray:
        return np.flatnonzero(self._obs[: self._n] >= self.tol.min_observations)

    @property
    def ids(self) -> IntArray:
        """Stable ids of the confirmed walls (seen ``min_observations`` times), in storage order."""
        return self._ids[self._shown()]

    def segments(self) -> FloatArray:
        """``(W, 4)`` end points ``[x0, y0, x1, y1]`` of the confirmed walls, in storage order."""
        k = self._shown()
        c, d = self._c[k], self._d[k]
        a = c + d * self._lo[k, None]
        b = c + d * self._hi[k, None]
        return np.hstack([a, b])

    # ------------------------------------------------------------------ updates
    def add_segments(self, segments: FloatArray) -> None:
        """Merge each segment ``[x0, y0, x1, y1]`` into the map (shorter than ``min_length_m`` ignored)."""
        for seg in np.asarray(segments, dtype=np.float64).reshape(-1, 4):
            if not np.all(np.isfinite(seg)):
                continue
            a, b = seg[:2], seg[2:]
            length = float(np.hypot(*(b - a)))
            if length < self.tol.min_length_m:
                continue
            idx = self._append(a, b, length)
            self._settle(idx)

    def _append(self, a: FloatArray, b: FloatArray, length: float) -> int:
        if self._n == len(self._w):
            self._grow()
        i = self._n
        mean = 0.5 * (a + b)
        d = (b - a) / length
        cov = (length * length / 12.0) * np.outer(d, d)
        second = cov + np.outer(mean, mean)
        self._ids[i] = self._next_id
        self._obs[i] = 1
        self._next_id += 1
        self._w[i] = length
        self._s1[i] = length * mean
        self._s2[i] = length * np.array([second[0, 0], second[0, 1], second[1, 1]])
        self._c[i] = mean
        self._d[i] = d
        self._lo[i], self._hi[i] = -0.5 * length, 0.5 * length
        self._n += 1
        return i

    def _grow(self) -> None:
        cap = 2 * len(self._w)
        for name in ("_ids", "_obs", "_w", "_s1", "_s2", "_c", "_d", "_lo", "_hi"):
            old = getattr(self, name)
            new = np.zeros((cap, *old.shape[1:]), dtype=old.dtype)
            new[: len(old)] = old
            setattr(self, name, new)

    def _candidates(self, i: int) -> IntArray:
        """Walls that wall ``i`` should merge with."""
        n = self._n
        c, d = self._c[:n], self._d[:n]
        ci, di = self._c[i], self._d[i]
        ends_i = np.array([ci + di * self._lo[i], ci + di * self._hi[i]])
        parallel = np.abs(d @ di) >= self._cos_tol
        normal = np.column_stack([-d[:, 1], d[:, 0]])
        # both ends of i close to each wall's line
        rel = ends_i[:, None, :] - c[None, :, :]  # (2 ends, W walls, xy)
        off = np.abs(np.einsum("kwj,wj->kw", rel, normal))
        close = np.all(off <= self.tol.offset_tol_m, axis=0)
        # overlap or small gap along each wall's direction
        t = np.einsum("kwj,wj->kw", rel, d)
        lo_i, hi_i = t.min(axis=0), t.max(axis=0)
        gap = np.maximum(lo_i - self._hi[:n], self._lo[:n] - hi_i)
        near = gap <= self.tol.gap_tol_m
        ok = parallel & close & near
        ok[i] = False
        return np.flatnonzero(ok)

    def _settle(self, i: int) -> None:
        """Merge wall ``i`` with every wall it matches, repeatedly, until nothing matches."""
        while True:
            cand = self._candidates(i)
            if cand.size == 0:
                return
            j = int(cand[0])
            keep, drop = (i, j) if self._ids[i] < self._ids[j] else (j, i)
            self._fuse(keep, drop)
            i = keep - 1 if drop < keep else keep  # removing row `drop` shifts later rows down

    def _fuse(self, keep: int, drop: int) -> None:
        ends = []
        for k in (keep, drop):
            ends.append(self._c[k] + self._d[k] * self._lo[k])
            ends.append(self._c[k] + self._d[k] * self._hi[k])
        self._w[keep] += self._w[drop]
        self._obs[keep] += self._obs[drop]
        self._s1[keep] += self._s1[drop]
        self._s2[keep] += self._s2[drop]
        w = self._w[keep]
        c = self._s1[keep] / w
        sxx, sxy, syy = self._s2[keep] / w
        cov = np.array([[sxx - c[0] * c[0], sxy - c[0] * c[1]], [sxy - c[0] * c[1], syy - c[1] * c[1]]])
        _, vecs = np.linalg.eigh(cov)
        d = vecs[:, 1]
        if d @ self._d[keep] < 0:
            d = -d
        proj = (np.asarray(ends) - c) @ d
        self._c[keep], self._d[keep] = c, d
        self._lo[keep], self._hi[keep] = float(proj.min()), float(proj.max())
        self.removed.append(int(self._ids[drop]))
        self._remove(drop)

    def _remove(self, k: int) -> None:
        n = self._n
        for name in ("_ids", "_obs", "_w", "_s1", "_s2", "_c", "_d", "_lo", "_hi"):
            arr = getattr(self, name)
            arr[k : n - 1] = arr[k + 1 : n]
        self._n -= 1
