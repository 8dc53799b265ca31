"""The line map: walls merged from the segments of successive steps (SPEC §4 "map assembly").

Each wall keeps the length-weighted second moments of every segment merged into it, so merging is O(1)
and order-independent: a segment from ``a`` to ``b`` of length ``L`` counts as a uniform distribution of
mass ``L`` along it (mean ``(a + b) / 2``, covariance ``L^2 / 12 d d^T + sigma^2 n n^T``, with ``sigma``
the scatter of the segment's points about its line, ``n`` its normal). A wall's line is the total
least squares fit of its moments (the principal axis, as SVD in paper eq. 27-32), its extent is the
union of the merged segments' projections on that line, and its perpendicular scatter (the moments'
minor eigenvalue) says how well the line is known: the points' noise plus the spread of the merged pieces.

Segments given with the scanner's viewpoint are stored facing it (the scanner on their left), and then
merge only with walls facing the same way: the two faces of a thin wall, seen from opposite sides, stay
two walls however close.

A new segment merges into a wall when it is collinear (angle within ``angle_tol_deg``, or for a piece
shorter than ``2 offset_tol_m / sin(angle_tol_deg)`` within the tilt its end band allows,
``asin(2 offset_tol_m / length)``, if the wall is not that short itself: a short noisy piece's direction
is not known better, and two short pieces do not vouch for each other's; both end points
within ``offset_tol_m`` of the wall's line) and overlaps it or leaves a gap of at most ``gap_tol_m``;
or when it is collinear in that sense, overlaps the wall along its length and both end points lie within
``merge_sigmas`` standard deviations (of the two's combined perpendicular scatter) of the wall's line. The
second test is what keeps a face seen from poses a few centimetres apart (pose error) or at 3 m (where
the URG-04LX scatters about 4 cm) one wall instead of parallel copies and short tilted hatches across it;
a precise wall is not widened by it, and pieces that only touch end to end still need ``offset_tol_m``.
A merged wall is then checked against the others again, so chains of pieces fuse into one wall. Walls keep
stable integer ids; when two walls fuse, the older id survives and the other is reported removed. A wall is
shown (``segments``/``ids``) once ``min_observations`` segments have merged into it: clutter seen once
stays out of the map, a wall seen from three steps is in.
Complexity: O(W) per inserted segment for W walls (compiled loop).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from shared.kernels._jit import njit
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
    #: short pieces may tilt as far as their end band allows (the shown map; the pipeline's localisation
    #: maps keep the plain angle test: merging tilted pieces there moved the benchmark logs' poses)
    short_by_band: bool = True
    #: overlapping pieces of one face whose lines are within this many standard deviations of their
    #: combined perpendicular scatter (from the moments) are one wall even beyond ``offset_tol_m``;
    #: 0 turns the test off (the localisation maps)
    merge_sigmas: float = 3.0


class WallMap:
    """A growing set of walls with stable ids. Not thread-safe; one per pipeline."""

    def __init__(self, tolerances: MergeTolerances | None = None) -> None:
        self.tol = tolerances or MergeTolerances()
        self._cos_tol = math.cos(math.radians(self.tol.angle_tol_deg))
        self._n = 0
        cap = 64
        self._ids = np.zeros(cap, dtype=np.int64)
        self._obs = np.zeros(cap, dtype=np.int64)  # segments merged into the wall
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

    def all_walls(self) -> tuple[IntArray, FloatArray]:
        """Ids and ``(W, 4)`` end points of every wall, shown or not yet confirmed, in storage order."""
        n = self._n
        c, d = self._c[:n], self._d[:n]
        return self._ids[:n].copy(), np.hstack([c + d * self._lo[:n, None], c + d * self._hi[:n, None]])

    # ------------------------------------------------------------------ updates
    def cut(self, wall_id: int, keep: list[tuple[float, float]]) -> list[int]:
        """Keep only the pieces ``keep`` of wall ``wall_id``, each ``(t0, t1)`` metres from its first end
        point along it (free space observed elsewhere, :mod:`shared.pipeline.freespace`). The first piece
        keeps the id, the others get new ids (returned) and the wall's observation count; no piece left
        removes the wall (its id is appended to ``removed``). Each piece's moments are those of a uniform
        segment with the wall's mass per metre and its scatter across (the merge's ``merge_sigmas`` test reads
        it), so later merges refit it consistently. O(walls)."""
        hit = np.flatnonzero(self._ids[: self._n] == wall_id)
        if len(hit) == 0:
            return []
        i = int(hit[0])
        pieces = [(t0, t1) for t0, t1 in keep if t1 > t0]
        if not pieces:
            for name in ("_ids", "_obs", "_w", "_s1", "_s2", "_c", "_d", "_lo", "_hi"):
                arr = getattr(self, name)
                arr[i : self._n - 1] = arr[i + 1 : self._n]
            self._n -= 1
            self.removed.append(int(wall_id))
            return []
        a = self._c[i] + self._d[i] * self._lo[i]
        d = self._d[i].copy()
        per_m = self._w[i] / max(self._hi[i] - self._lo[i], 1e-12)
        n = np.array([-d[1], d[0]])
        w_i = max(self._w[i], 1e-12)
        xx, xy, yy = self._s2[i] / w_i
        cx, cy = self._s1[i] / w_i
        cov = np.array([[xx - cx * cx, xy - cx * cy], [xy - cx * cy, yy - cy * cy]])
        across = max(float(n @ cov @ n), 0.0)  # the pieces' scatter about the line, m^2
        new_ids: list[int] = []
        for k, (t0, t1) in enumerate(pieces):
            j = i
            if k > 0:
                if self._n == len(self._w):
                    self._grow()
                j, self._n = self._n, self._n + 1
                self._ids[j], self._obs[j] = self._next_id, self._obs[i]
                new_ids.append(self._next_id)
                self._next_id += 1
            mid, half = a + d * (0.5 * (t0 + t1)), 0.5 * (t1 - t0)
            w = per_m * (t1 - t0)
            var = (t1 - t0) ** 2 / 12.0
            self._w[j], self._s1[j] = w, w * mid
            self._s2[j] = w * (
                var * np.array([d[0] * d[0], d[0] * d[1], d[1] * d[1]])
                + across * np.array([n[0] * n[0], n[0] * n[1], n[1] * n[1]])
                + np.array([mid[0] * mid[0], mid[0] * mid[1], mid[1] * mid[1]])
            )
            self._c[j], self._d[j], self._lo[j], self._hi[j] = mid, d, -half, half
        return new_ids

    def add_segments(
        self,
        segments: ArrayLike,
        observations: int = 1,
        *,
        viewpoint: tuple[float, float] | None = None,
        sigmas_m: ArrayLike | None = None,
    ) -> None:
        """Merge each segment ``[x0, y0, x1, y1]`` into the map (shorter than ``min_length_m`` ignored).

        ``observations`` is the evidence each segment carries: 1 for a segment from one step, the number
        of steps for a segment extracted from an offline batch. ``viewpoint`` (world frame, metres) is
        where the scanner saw the segments from: each is then stored facing it (the scanner on its left)
        and merges only with walls seen from the same side, so the two faces of a thin wall stay two. A
        map should be given a viewpoint always or never. ``sigmas_m`` ``(L,)`` is each segment's point
        scatter about its line (see :func:`shared.pipeline.stages.line_sigmas`; default 0).
        """
        segs = np.ascontiguousarray(np.asarray(segments, dtype=np.float64).reshape(-1, 4))
        if len(segs) == 0:
            return
        if sigmas_m is None:
            sig = np.zeros(len(segs))
        else:
            sig = np.ascontiguousarray(np.asarray(sigmas_m, dtype=np.float64).reshape(-1))
            if sig.shape != (len(segs),):
                raise ValueError(f"sigmas_m has {sig.shape[0]} values for {len(segs)} segments")
        oriented = viewpoint is not None
        vx, vy = (float(viewpoint[0]), float(viewpoint[1])) if viewpoint is not None else (0.0, 0.0)
        while self._n + len(segs) > len(self._w):
            self._grow()
        removed = np.empty(len(segs) + self._n, dtype=np.intp)
        t = self.tol
        self._n, self._next_id, n_removed = _insert_all(
            segs,
            self._ids,
            self._obs,
            self._w,
            self._s1,
            self._s2,
            self._c,
            self._d,
            self._lo,
            self._hi,
            self._n,
            self._next_id,
            self._cos_tol,
            t.offset_tol_m,
            t.gap_tol_m,
            t.min_length_m,
            max(int(observations), 1),
            removed,
            t.short_by_band,
            sig,
            oriented,
            vx,
            vy,
            float(t.merge_sigmas),
        )
        self.removed.extend(int(r) for r in removed[:n_removed])

    def _grow(self) -> None:
        cap = 2 * len(self._w)
        for name in ("_ids", "_obs", "_w", "_s1", "_s2", "_c", "_d", "_lo", "_hi"):
            old = getattr(self, name)
            new = np.zeros((cap, *old.shape[1:]), dtype=old.dtype)
            new[: len(old)] = old
            setattr(self, name, new)


@njit
def _insert_all(
    segs: FloatArray,
    ids: IntArray,
    obs: IntArray,
    w: FloatArray,
    s1: FloatArray,
    s2: FloatArray,
    c: FloatArray,
    d: FloatArray,
    lo: FloatArray,
    hi: FloatArray,
    n: int,
    next_id: int,
    cos_tol: float,
    offset_tol: float,
    gap_tol: float,
    min_length: float,
    observations: int,
    removed: IntArray,
    by_band: bool,
    sigmas: FloatArray,
    oriented: bool,
    vx: float,
    vy: float,
    k_sigma: float,
) -> tuple[int, int, int]:
    """Insert and settle every segment; returns the new wall count, next id and number of removed ids."""
    n_removed = 0
    for k in range(segs.shape[0]):
        x0, y0, x1, y1 = segs[k, 0], segs[k, 1], segs[k, 2], segs[k, 3]
        sig = sigmas[k]
        if not (np.isfinite(x0) and np.isfinite(y0) and np.isfinite(x1) and np.isfinite(y1)):
            continue
        if not np.isfinite(sig):
            sig = 0.0
        length = np.hypot(x1 - x0, y1 - y0)
        if length < min_length:
            continue
        i = n
        mx, my = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
        dx, dy = (x1 - x0) / length, (y1 - y0) / length
        if oriented and dx * (vy - my) - dy * (vx - mx) < 0.0:  # face the scanner: it is on the left
            dx, dy = -dx, -dy
        # a uniform mass along the segment plus its points' scatter across it (covariance
        # L^2 / 12 d d^T + sigma^2 n n^T, n the normal)
        var = length * length / 12.0
        var_n = sig * sig
        ids[i] = next_id
        obs[i] = observations
        next_id += 1
        w[i] = length
        s1[i, 0], s1[i, 1] = length * mx, length * my
        s2[i, 0] = length * (var * dx * dx + var_n * dy * dy + mx * mx)
        s2[i, 1] = length * ((var - var_n) * dx * dy + mx * my)
        s2[i, 2] = length * (var * dy * dy + var_n * dx * dx + my * my)
        c[i, 0], c[i, 1] = mx, my
        d[i, 0], d[i, 1] = dx, dy
        lo[i], hi[i] = -0.5 * length, 0.5 * length
        n += 1
        while True:
            j = _match(
                i, n, w, s1, s2, c, d, lo, hi, cos_tol, offset_tol, gap_tol, by_band, oriented, k_sigma
            )
            if j < 0:
                break
            keep, drop = (i, j) if ids[i] < ids[j] else (j, i)
            removed[n_removed] = ids[drop]
            n_removed += 1
            _fuse(keep, drop, obs, w, s1, s2, c, d, lo, hi)
            for arr1 in (ids, obs):
                arr1[drop : n - 1] = arr1[drop + 1 : n]
            for arr2 in (w, lo, hi):
                arr2[drop : n - 1] = arr2[drop + 1 : n]
            s1[drop : n - 1] = s1[drop + 1 : n]
            s2[drop : n - 1] = s2[drop + 1 : n]
            c[drop : n - 1] = c[drop + 1 : n]
            d[drop : n - 1] = d[drop + 1 : n]
            n -= 1
            i = keep - 1 if drop < keep else keep
    return n, next_id, n_removed


@njit
def _cross_var(k: int, w: FloatArray, s1: FloatArray, s2: FloatArray) -> float:
    """Wall ``k``'s perpendicular scatter (m^2): the minor eigenvalue of its moments' covariance."""
    cx, cy = s1[k, 0] / w[k], s1[k, 1] / w[k]
    sxx = s2[k, 0] / w[k] - cx * cx
    sxy = s2[k, 1] / w[k] - cx * cy
    syy = s2[k, 2] / w[k] - cy * cy
    half = 0.5 * (sxx + syy)
    minor: float = half - np.sqrt(0.25 * (sxx - syy) ** 2 + sxy * sxy)
    return max(minor, 0.0)


@njit
def _match(
    i: int,
    n: int,
    w: FloatArray,
    s1: FloatArray,
    s2: FloatArray,
    c: FloatArray,
    d: FloatArray,
    lo: FloatArray,
    hi: FloatArray,
    cos_tol: float,
    offset_tol: float,
    gap_tol: float,
    by_band: bool,
    oriented: bool,
    k_sigma: float,
) -> int:
    """The first wall wall ``i`` should merge with (collinear, close, overlapping or a small gap), or -1.

    Oriented walls (seen from a known side) merge only with walls facing the same way. With ``k_sigma >
    0`` a wall whose ends lie farther than ``offset_tol`` from the other's line still merges when they lie
    within ``k_sigma`` standard deviations of the two walls' combined perpendicular scatter and the two
    overlap along their length (the same surface drawn twice, e.g. from poses a few cm apart)."""
    ax, ay = c[i, 0] + d[i, 0] * lo[i], c[i, 1] + d[i, 1] * lo[i]
    bx, by = c[i, 0] + d[i, 0] * hi[i], c[i, 1] + d[i, 1] * hi[i]
    # a short piece's direction is only known to within its ends' band: both ends within offset_tol of a
    # line allow a tilt of up to asin(2 offset_tol / length), so that bounds the angle test from below. Only
    # against a wall whose own direction is known to within the angle test (not itself that short): two
    # short pieces (a person's legs in successive scans) do not vouch for each other's direction.
    length = hi[i] - lo[i]
    cos_i = cos_tol
    if by_band:
        sin_band = min(2.0 * offset_tol / max(length, 1e-12), 1.0)
        cos_i = min(cos_tol, np.sqrt(1.0 - sin_band * sin_band))
    determined_m = 2.0 * offset_tol / max(np.sqrt(max(1.0 - cos_tol * cos_tol, 0.0)), 1e-12)
    var_i = _cross_var(i, w, s1, s2) if k_sigma > 0.0 else 0.0
    for j in range(n):
        if j == i:
            continue
        cos_ij = d[j, 0] * d[i, 0] + d[j, 1] * d[i, 1]
        if not oriented:
            cos_ij = abs(cos_ij)
        if cos_ij < cos_i or (cos_ij < cos_tol and hi[j] - lo[j] < determined_m):
            continue
        nx, ny = -d[j, 1], d[j, 0]
        rax, ray, rbx, rby = ax - c[j, 0], ay - c[j, 1], bx - c[j, 0], by - c[j, 1]
        off = max(abs(rax * nx + ray * ny), abs(rbx * nx + rby * ny))
        ta, tb = rax * d[j, 0] + ray * d[j, 1], rbx * d[j, 0] + rby * d[j, 1]
        gap = max(min(ta, tb) - hi[j], lo[j] - max(ta, tb))
        if off <= offset_tol:
            if gap <= gap_tol:
                return j
            continue
        if (
            k_sigma > 0.0
            and gap < 0.0
            and off * off <= k_sigma * k_sigma * (var_i + _cross_var(j, w, s1, s2))
        ):
            return j
    return -1


@njit
def _fuse(
    keep: int,
    drop: int,
    obs: IntArray,
    w: FloatArray,
    s1: FloatArray,
    s2: FloatArray,
    c: FloatArray,
    d: FloatArray,
    lo: FloatArray,
    hi: FloatArray,
) -> None:
    """Add wall ``drop``'s moments to wall ``keep`` and refit its line and extent (closed-form 2x2 PCA)."""
    ends = np.empty((4, 2))
    for r, k in enumerate((keep, drop)):
        ends[2 * r, 0], ends[2 * r, 1] = c[k, 0] + d[k, 0] * lo[k], c[k, 1] + d[k, 1] * lo[k]
        ends[2 * r + 1, 0], ends[2 * r + 1, 1] = c[k, 0] + d[k, 0] * hi[k], c[k, 1] + d[k, 1] * hi[k]
    obs[keep] += obs[drop]
    w[keep] += w[drop]
    s1[keep, 0] += s1[drop, 0]
    s1[keep, 1] += s1[drop, 1]
    for q in range(3):
        s2[keep, q] += s2[drop, q]
    cx, cy = s1[keep, 0] / w[keep], s1[keep, 1] / w[keep]
    sxx = s2[keep, 0] / w[keep] - cx * cx
    sxy = s2[keep, 1] / w[keep] - cx * cy
    syy = s2[keep, 2] / w[keep] - cy * cy
    phi = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)  # major axis of the 2x2 covariance
    dx, dy = np.cos(phi), np.sin(phi)
    if dx * d[keep, 0] + dy * d[keep, 1] < 0.0:
        dx, dy = -dx, -dy
    t_lo, t_hi = np.inf, -np.inf
    for r in range(4):
        t = (ends[r, 0] - cx) * dx + (ends[r, 1] - cy) * dy
        t_lo, t_hi = min(t_lo, t), max(t_hi, t)
    c[keep, 0], c[keep, 1] = cx, cy
    d[keep, 0], d[keep, 1] = dx, dy
    lo[keep], hi[keep] = t_lo, t_hi
