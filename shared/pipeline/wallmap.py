"""The line map: walls merged from the segments of successive steps (docs/design.md §4 "map assembly").

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
is not known better, and two short pieces do not vouch for each other's, unless the wall's direction is
known from the information of the many segments merged into it (``known_direction_sigmas``); both end points
within ``offset_tol_m`` of the wall's line) and overlaps it or leaves a gap of at most ``gap_tol_m``;
or when it is collinear in that sense, overlaps the wall along its length and both end points lie within
``merge_sigmas`` standard deviations (of the two's combined perpendicular scatter) of the wall's line. The
second test is what keeps a face seen from poses a few centimetres apart (pose error) or at 3 m (where
the URG-04LX scatters about 4 cm) one wall instead of parallel copies and short tilted hatches across it;
a precise wall is not widened by it, and pieces that only touch end to end still need ``offset_tol_m``.
A merged wall is then checked against the others again, so chains of pieces fuse into one wall. Walls keep
stable integer ids; when two walls fuse, the older id survives and the other is reported removed. A wall is
shown (``segments``/``ids``) once ``min_observations`` segments have merged into it: clutter seen once
stays out of the map, a wall seen from three steps is in. A segment may be given as one that starts no
wall (``may_create``): the pipeline does so for a noisy piece a mapped wall already explains within the
range noise (:meth:`WallMap.explained`), which would otherwise be a short wall crossing it.
Complexity: O(W) per inserted segment for W walls (the compiled loop in :mod:`shared.pipeline.wallmerge`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from shared.pipeline.crossings import crossing_walls
from shared.pipeline.wallmerge import explained_by, insert_all
from shared.types import BoolArray, FloatArray, IntArray

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
    #: a wall shorter than the angle test can bound still counts as having a known direction (short tilted
    #: pieces may join it within their end band) once its direction's standard deviation, from the
    #: information of the segments merged into it, is at most ``angle_tol_deg`` over this; 0 turns it off
    known_direction_sigmas: float = 3.0
    #: of two shown walls crossing through both interiors at more than twice ``angle_tol_deg`` (the
    #: longer reaching past the crossing by more than this, m, the shorter crossing near its middle),
    #: the shorter is not shown (:mod:`shared.pipeline.crossings`); 0 turns it off (the
    #: localisation maps: what they match against must not depend on it)
    cross_margin_m: float = 0.2


#: removed wall ids a map keeps at least (:attr:`WallMap.removed`)
REMOVED_KEPT = 1024

_STATE = ("_ids", "_obs", "_w", "_s1", "_s2", "_c", "_d", "_lo", "_hi", "_info")


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
        self._info = np.zeros(cap)  # direction information (rad^-2) of the merged segments
        self._next_id = 0
        #: ids of walls removed lately (fused into another, or cut away), oldest first: the newest
        #: :data:`REMOVED_KEPT` at most (a map kept for days fuses pieces at every step)
        self.removed: list[int] = []
        self._changes = 0  # counts the changes, for the shown walls' cache
        self._shown_cache: tuple[int, IntArray] | None = None

    def __len__(self) -> int:
        return self._n

    # ------------------------------------------------------------------ queries
    def _shown(self) -> IntArray:
        if self._shown_cache is not None and self._shown_cache[0] == self._changes:
            return self._shown_cache[1]
        k = np.flatnonzero(self._obs[: self._n] >= self.tol.min_observations)
        if self.tol.cross_margin_m > 0.0 and len(k) > 1:
            c, d = self._c[k], self._d[k]
            ends = np.hstack([c + d * self._lo[k, None], c + d * self._hi[k, None]])
            k = k[~crossing_walls(ends, self.tol.cross_margin_m, 2.0 * self.tol.angle_tol_deg)]
        self._shown_cache = (self._changes, k)
        return k

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

    def explained(
        self,
        segments: ArrayLike,
        direction_sds_rad: ArrayLike,
        band_m: ArrayLike,
        *,
        viewpoint: tuple[float, float] | None = None,
        k_sigma: float = 3.0,
    ) -> BoolArray:
        """Per segment ``[x0, y0, x1, y1]``: whether a wall of the map explains it within its noise: the
        segment overlaps the wall along it, both its ends lie within ``band_m`` (per segment, m) of the
        wall's line and its direction is within ``k_sigma`` of its ``direction_sds_rad`` of the wall's
        (seen from ``viewpoint``, of the wall's face towards it: the other face of a thin wall explains
        nothing). A noisy short piece of a known wall tilted past the merge's angle test is explained; a
        wall of its own there would cross the known one. O(segments x walls)."""
        segs = np.asarray(segments, dtype=np.float64).reshape(-1, 4)
        out = np.zeros(len(segs), dtype=np.bool_)
        n = self._n
        if n == 0 or len(segs) == 0:
            return out
        sd = np.asarray(direction_sds_rad, dtype=np.float64).reshape(-1)
        band = np.asarray(band_m, dtype=np.float64).reshape(-1)
        vx, vy = viewpoint if viewpoint is not None else (0.0, 0.0)
        return explained_by(
            np.ascontiguousarray(segs),
            np.ascontiguousarray(sd, dtype=np.float64),
            np.ascontiguousarray(np.broadcast_to(band, (len(segs),)), dtype=np.float64),
            self._c[:n],
            self._d[:n],
            self._lo[:n],
            self._hi[:n],
            float(vx),
            float(vy),
            viewpoint is not None,
            float(k_sigma),
        )

    # ------------------------------------------------------------------ updates
    def cut(self, wall_id: int, keep: list[tuple[float, float]]) -> list[int]:
        """Keep only the pieces ``keep`` of wall ``wall_id``, each ``(t0, t1)`` metres from its first end
        point along it (free space observed elsewhere, :mod:`shared.pipeline.freespace`). The first piece
        keeps the id, the others get new ids (returned) and the wall's observation count (counts saturate
        at :data:`~shared.pipeline.wallmerge.OBSERVATIONS_CAP`: pieces fused back would double it); no piece
        left removes the wall (its id is appended to ``removed``). Each piece's moments are those of a uniform
        segment with the wall's mass per metre and its scatter across (the merge's ``merge_sigmas`` test reads
        it), so later merges refit it consistently; its direction information is the wall's times the cube of
        its share of the length (that of evenly spread points). O(walls)."""
        self._changes += 1
        hit = np.flatnonzero(self._ids[: self._n] == wall_id)
        if len(hit) == 0:
            return []
        i = int(hit[0])
        pieces = [(t0, t1) for t0, t1 in keep if t1 > t0]
        if not pieces:
            for name in _STATE:
                arr = getattr(self, name)
                arr[i : self._n - 1] = arr[i + 1 : self._n]
            self._n -= 1
            self._note_removed([int(wall_id)])
            return []
        a = self._c[i] + self._d[i] * self._lo[i]
        d = self._d[i].copy()
        length = max(self._hi[i] - self._lo[i], 1e-12)
        per_m = self._w[i] / length
        info = self._info[i]
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
            self._info[j] = info * ((t1 - t0) / length) ** 3  # direction information grows as length^3
        return new_ids

    def add_segments(
        self,
        segments: ArrayLike,
        observations: int = 1,
        *,
        viewpoint: tuple[float, float] | None = None,
        sigmas_m: ArrayLike | None = None,
        direction_sds_rad: ArrayLike | None = None,
        may_create: ArrayLike | None = None,
    ) -> None:
        """Merge each segment ``[x0, y0, x1, y1]`` into the map (shorter than ``min_length_m`` ignored).

        ``observations`` is the evidence each segment carries: 1 for a segment from one step, the number
        of steps for a segment extracted from an offline batch. ``viewpoint`` (world frame, metres) is
        where the scanner saw the segments from: each is then stored facing it (the scanner on its left)
        and merges only with walls seen from the same side, so the two faces of a thin wall stay two. A
        map should be given a viewpoint always or never. ``sigmas_m`` ``(L,)`` is each segment's point
        scatter about its line and ``direction_sds_rad`` ``(L,)`` the standard deviation of its direction
        (see :func:`shared.pipeline.stages.line_uncertainty`; default 0, unknown). ``may_create`` ``(L,)``:
        False for a segment that may join a wall but not start one (default: all may).
        """
        segs = np.ascontiguousarray(np.asarray(segments, dtype=np.float64).reshape(-1, 4))
        if len(segs) == 0:
            return
        self._changes += 1
        sig = _per_segment(sigmas_m, "sigmas_m", len(segs))
        dir_sd = _per_segment(direction_sds_rad, "direction_sds_rad", len(segs))
        create = (
            np.ones(len(segs), dtype=np.bool_)
            if may_create is None
            else np.ascontiguousarray(np.asarray(may_create, dtype=np.bool_).reshape(-1))
        )
        if create.shape != (len(segs),):
            raise ValueError(f"may_create has {create.shape[0]} values for {len(segs)} segments")
        oriented = viewpoint is not None
        vx, vy = (float(viewpoint[0]), float(viewpoint[1])) if viewpoint is not None else (0.0, 0.0)
        while self._n + len(segs) > len(self._w):
            self._grow()
        removed = np.empty(len(segs) + self._n, dtype=np.intp)
        t = self.tol
        k_dir = float(t.known_direction_sigmas)
        min_info = (k_dir / math.radians(t.angle_tol_deg)) ** 2 if k_dir > 0.0 else math.inf
        self._n, self._next_id, n_removed = insert_all(
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
            dir_sd,
            self._info,
            min_info,
            create,
        )
        self._note_removed(removed[:n_removed].tolist())

    def _note_removed(self, ids: list[int]) -> None:
        self.removed.extend(ids)
        if len(self.removed) > 2 * REMOVED_KEPT:
            del self.removed[:-REMOVED_KEPT]

    def seed(self, ids: ArrayLike, segments: ArrayLike, observations: int | None = None) -> None:
        """Start an empty map from walls made elsewhere (a map continued from the server's copy): each
        segment ``[x0, y0, x1, y1]`` (its direction from the first end to the second, as :meth:`segments`
        gives a wall: facing the scanner that saw it) becomes one wall with the id given, none merged with
        another; later ids follow the largest given. ``observations`` (default ``min_observations``:
        shown) is the evidence each wall starts with; the points' scatter and the direction's information
        are not known (0), as for a segment given without them. Segments that are not finite or are
        shorter than ``min_length_m`` are left out, as :meth:`add_segments` leaves them. :class:`ValueError`
        for a map that is not empty or ids that repeat or are negative. O(walls)."""
        wid = np.asarray(ids, dtype=np.int64).reshape(-1)
        segs = np.asarray(segments, dtype=np.float64).reshape(-1, 4)
        if self._n:
            raise ValueError(f"a wall map can be seeded only while empty: it holds {self._n} walls")
        if len(wid) != len(segs):
            raise ValueError(f"{len(wid)} ids for {len(segs)} segments")
        if len(wid) == 0:
            return
        if (wid < 0).any() or len(np.unique(wid)) != len(wid):
            raise ValueError("wall ids must be distinct and not negative")
        next_id = int(wid.max()) + 1
        with np.errstate(invalid="ignore"):
            length = np.hypot(segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1])
            keep = np.isfinite(segs).all(axis=1) & (length >= self.tol.min_length_m)
        wid, segs, length = wid[keep], segs[keep], length[keep]
        a, b = segs[:, :2], segs[:, 2:]
        while len(wid) > len(self._w):
            self._grow()
        n = len(wid)
        mid, d = 0.5 * (a + b), (b - a) / length[:, None]
        var = length * length / 12.0  # a uniform mass along the wall; no scatter across it
        self._ids[:n] = wid
        self._obs[:n] = self.tol.min_observations if observations is None else max(int(observations), 1)
        self._w[:n] = length
        self._s1[:n] = length[:, None] * mid
        self._s2[:n, 0] = length * (var * d[:, 0] ** 2 + mid[:, 0] ** 2)
        self._s2[:n, 1] = length * (var * d[:, 0] * d[:, 1] + mid[:, 0] * mid[:, 1])
        self._s2[:n, 2] = length * (var * d[:, 1] ** 2 + mid[:, 1] ** 2)
        self._c[:n], self._d[:n] = mid, d
        self._lo[:n], self._hi[:n] = -0.5 * length, 0.5 * length
        self._info[:n] = 0.0
        self._n, self._next_id = n, next_id
        self._changes += 1

    def _grow(self) -> None:
        cap = 2 * len(self._w)
        for name in _STATE:
            old = getattr(self, name)
            new = np.zeros((cap, *old.shape[1:]), dtype=old.dtype)
            new[: len(old)] = old
            setattr(self, name, new)


def _per_segment(values: ArrayLike | None, name: str, count: int) -> FloatArray:
    """``values`` as a contiguous ``(count,)`` float array (zeros when not given)."""
    if values is None:
        return np.zeros(count)
    out = np.ascontiguousarray(np.asarray(values, dtype=np.float64).reshape(-1))
    if out.shape != (count,):
        raise ValueError(f"{name} has {out.shape[0]} values for {count} segments")
    return out
