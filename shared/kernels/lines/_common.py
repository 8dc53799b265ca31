"""Helpers shared by the straight-line kernels (paper §3.4, §4): grouping, Hough voting, spans, results.

Every straight-line kernel follows the same three steps:

1. :func:`group_points` drops non-finite rows (and absurd ones beyond :data:`MAX_COORDINATE_M`) and rows
   with a negative group label, and sorts the rest by group with a *stable* sort, so each group is one
   contiguous block still in scan order.
2. The kernel proposes infinite lines ``(rho, theta)`` (any ``theta``; they are made canonical later) and
   says which points support each line (an *incidence* list of ``(point, line)`` pairs).
3. :func:`build_lines` projects each line's supporting points on the line (direction ``(-sin, cos)``),
   takes the min/max as the segment, counts the support and drops lines shorter than
   :data:`MIN_LENGTH_M` (a line needs two distinct points), then freezes a :class:`Lines`.

The Hough kernels share one accumulator layout. Theta runs over ``[0, pi)`` in ``n_theta = round(180 /
theta_resolution_deg)`` cells ``theta_k = k pi / n_theta`` (so the grid closes exactly on the seam). Each
group votes in coordinates relative to its own centroid ``c``, so the rho range is per group:
``rho_rel`` in ``[-R, R]`` with ``R`` the group's largest distance from ``c``, in cells
``rho_rel_j = (j - half) * rho_resolution_m``. A cell ``(theta_k, rho_rel_j)`` is the absolute line
``rho = rho_rel_j + c . (cos theta_k, sin theta_k)``. This is an ordinary Hough transform (eq. 34) whose
rho grid is shifted per group; it keeps the accumulator small (a 3 m wall needs 180 x 153 cells). The
numba functions ``_accumulator_setup``, ``_vote``, ``_peak`` and ``_clear`` are the voting core of both
``hough`` and ``hough-cluster``; one accumulator is allocated per call and only touched cells are cleared.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from shared.errors import InvalidInputError
from shared.kernels._jit import njit
from shared.kernels.results import Lines, freeze
from shared.types import BoolArray, FloatArray, IntArray, as_points, canonical_hesse, segments_from_hesse

__all__ = [
    "MAX_ACCUMULATOR_CELLS",
    "MAX_COORDINATE_M",
    "MIN_LENGTH_M",
    "GroupedPoints",
    "VoteArray",
    "build_lines",
    "empty_lines",
    "group_points",
    "theta_grid",
]

#: Lines whose span is not longer than this are dropped (all supporting points coincide), metres.
MIN_LENGTH_M = 1e-9

#: Groups whose accumulator would need more cells than this (a group spanning kilometres) get no line.
MAX_ACCUMULATOR_CELLS = 1 << 24

#: Rows with a coordinate beyond this many metres are dropped like non-finite ones.
MAX_COORDINATE_M = 1.0e6

#: A Hough accumulator ``(n_theta, n_rho)`` of vote counts.
VoteArray = NDArray[np.int32]


@dataclass(frozen=True, slots=True)
class GroupedPoints:
    """Finite points with a non-negative group label, sorted by label (stable: scan order kept).

    ``points[starts[g]:starts[g + 1]]`` are the points of group ``labels[g]``; ``group_index[i]`` is the
    group (``0..G-1``) of sorted point ``i``.
    """

    points: FloatArray
    labels: IntArray
    starts: IntArray
    group_index: IntArray

    @property
    def n_groups(self) -> int:
        """Number of non-empty groups."""
        return int(self.labels.shape[0])

    @property
    def counts(self) -> IntArray:
        """Points per group."""
        return np.diff(self.starts)


def _as_labels(groups: ArrayLike, n: int) -> IntArray:
    """``groups`` as an ``(n,)`` intp array; float labels must be integral (non-finite ones become -1)."""
    arr = np.asarray(groups)
    if arr.shape != (n,):
        raise InvalidInputError(f"groups has shape {arr.shape}: expected ({n},), one group label per point")
    if arr.dtype.kind in "biu":
        return arr.astype(np.intp)
    if arr.dtype.kind == "f":
        finite = np.isfinite(arr)
        clean = np.where(finite, arr, -1.0)
        if not np.array_equal(clean, np.round(clean)):
            raise InvalidInputError("groups holds non-integer values: expected integer group labels")
        return clean.astype(np.intp)
    raise InvalidInputError(f"groups has dtype {arr.dtype}: expected integer group labels")


def group_points(points: ArrayLike, groups: ArrayLike | None) -> GroupedPoints:
    """Validate ``points`` ``(N, 2)`` and ``groups`` ``(N,)`` (``None``: all in group 0) and group them.

    Non-finite rows, rows beyond :data:`MAX_COORDINATE_M` and negative labels are dropped. The input is
    never modified. O(N log N).
    """
    pts = as_points(points)
    n = pts.shape[0]
    lab = np.zeros(n, dtype=np.intp) if groups is None else _as_labels(groups, n)
    return GroupedPoints(*_group(np.ascontiguousarray(pts, dtype=np.float64), lab, MAX_COORDINATE_M))


@njit
def _group(
    pts: FloatArray, lab: IntArray, max_coordinate_m: float
) -> tuple[FloatArray, IntArray, IntArray, IntArray]:
    """:func:`group_points`' sort in one compiled pass: the rows with both coordinates within
    ``max_coordinate_m`` (so finite) and a label >= 0, stably sorted by label. O(N log N)."""
    n = pts.shape[0]
    idx = np.empty(n, dtype=np.intp)
    m = 0
    for i in range(n):
        if lab[i] >= 0 and abs(pts[i, 0]) <= max_coordinate_m and abs(pts[i, 1]) <= max_coordinate_m:
            idx[m] = i
            m += 1
    idx = idx[:m]
    ascending = True
    for k in range(1, m):
        if lab[idx[k]] < lab[idx[k - 1]]:
            ascending = False
            break
    order = idx if ascending else idx[np.argsort(lab[idx], kind="mergesort")]  # stable: scan order kept
    sorted_pts = np.empty((m, 2), dtype=np.float64)
    group_index = np.empty(m, dtype=np.intp)
    n_groups = 0
    for k in range(m):
        i = order[k]
        sorted_pts[k, 0] = pts[i, 0]
        sorted_pts[k, 1] = pts[i, 1]
        if k == 0 or lab[i] != lab[order[k - 1]]:
            n_groups += 1
        group_index[k] = n_groups - 1
    starts = np.zeros(n_groups + 1, dtype=np.intp)
    labels = np.empty(n_groups, dtype=np.intp)
    for k in range(m):
        g = group_index[k]
        if k == 0 or g != group_index[k - 1]:
            starts[g] = k
            labels[g] = lab[order[k]]
    starts[n_groups] = m
    return sorted_pts, labels, starts, group_index


def empty_lines() -> Lines:
    """A frozen :class:`Lines` with no line."""
    return _make_lines(np.zeros((0, 4)), np.zeros(0), np.zeros(0), np.zeros(0, np.intp), np.zeros(0, np.intp))


def _make_lines(
    segments: FloatArray, rho: FloatArray, theta: FloatArray, group: IntArray, support: IntArray
) -> Lines:
    """A :class:`Lines` of contiguous, read-only copies of the arrays."""
    arrays = (
        np.ascontiguousarray(segments, dtype=np.float64).reshape(-1, 4),
        np.ascontiguousarray(rho, dtype=np.float64),
        np.ascontiguousarray(theta, dtype=np.float64),
        np.ascontiguousarray(group, dtype=np.intp),
        np.ascontiguousarray(support, dtype=np.intp),
    )
    freeze(*arrays)
    return Lines(*arrays)


def build_lines(
    grouped: GroupedPoints,
    point_idx: IntArray,
    line_idx: IntArray,
    rho: FloatArray,
    theta: FloatArray,
    line_group: IntArray,
    tolerance_m: float | None = None,
) -> Lines:
    """Turn proposed infinite lines into a frozen :class:`Lines` with their spans (docs/design.md §4).

    ``rho``/``theta`` ``(L,)`` are the lines (any theta; made canonical with :func:`canonical_hesse`),
    ``line_group`` ``(L,)`` their group index (``0..G-1``). Sorted point ``point_idx[m]`` supports line
    ``line_idx[m]``. With ``tolerance_m`` only supporting points within that orthogonal distance count.
    Each segment runs from the smallest to the largest projection along ``(-sin theta, cos theta)``;
    ``support`` counts the supporting points; lines with no support or a span <= :data:`MIN_LENGTH_M`
    are dropped. Line order is kept. O(L + M).
    """
    rho_c, theta_c = canonical_hesse(rho, theta)
    n_lines = rho_c.shape[0]
    if n_lines == 0:
        return empty_lines()
    t0, t1, support = _spans(
        grouped.points,
        np.ascontiguousarray(point_idx, dtype=np.intp),
        np.ascontiguousarray(line_idx, dtype=np.intp),
        np.cos(theta_c),
        np.sin(theta_c),
        rho_c,
        math.inf if tolerance_m is None else float(tolerance_m),
    )
    ok = (support > 0) & (t1 - t0 > MIN_LENGTH_M)
    segments = segments_from_hesse(rho_c[ok], theta_c[ok], t0[ok], t1[ok])
    return _make_lines(segments, rho_c[ok], theta_c[ok], grouped.labels[line_group[ok]], support[ok])


@njit
def _spans(
    points: FloatArray,
    point_idx: IntArray,
    line_idx: IntArray,
    cos_l: FloatArray,
    sin_l: FloatArray,
    rho: FloatArray,
    tolerance_m: float,
) -> tuple[FloatArray, FloatArray, IntArray]:
    """Per line the smallest and largest projection ``t`` (along ``(-sin, cos)``) of its supporting
    points ``points[point_idx[m]]`` of line ``line_idx[m]`` within ``tolerance_m`` of it, and their count.
    O(M)."""
    n_lines = rho.shape[0]
    t0 = np.full(n_lines, np.inf)
    t1 = np.full(n_lines, -np.inf)
    support = np.zeros(n_lines, dtype=np.intp)
    for m in range(line_idx.shape[0]):
        k = line_idx[m]
        px, py = points[point_idx[m], 0], points[point_idx[m], 1]
        c, s = cos_l[k], sin_l[k]
        if not abs(px * c + py * s - rho[k]) <= tolerance_m:
            continue
        t = py * c - px * s
        t0[k] = min(t0[k], t)
        t1[k] = max(t1[k], t)
        support[k] += 1
    return t0, t1, support


@functools.lru_cache(maxsize=16)
def theta_grid(theta_resolution_deg: float) -> tuple[FloatArray, FloatArray]:
    """``(cos, sin)`` of the accumulator's theta cells ``k pi / n_theta``, ``n_theta = round(180 / res)``.

    The effective step is ``180 / n_theta`` degrees (the requested one when it divides 180).
    """
    n_theta = max(1, round(180.0 / theta_resolution_deg))
    theta = np.arange(n_theta, dtype=np.float64) * (math.pi / n_theta)
    cos_t, sin_t = np.cos(theta), np.sin(theta)
    cos_t.flags.writeable = sin_t.flags.writeable = False  # cached: shared by every call
    return cos_t, sin_t


@njit
def _accumulator_setup(
    pts: FloatArray, starts: IntArray, n_theta: int, inv_res: float, min_points: int
) -> tuple[FloatArray, FloatArray, IntArray, BoolArray, VoteArray, IntArray]:
    """Voting frames of all groups and one zeroed accumulator wide enough for the widest. O(N).

    Returns per group the centroid ``(cx, cy)``, the rho half-width ``half`` (cells) and whether it votes
    (``>= min_points`` points and an accumulator within :data:`MAX_ACCUMULATOR_CELLS`), then the shared
    accumulator ``(n_theta, width)`` and the ``(n_theta, 3)`` row summary that :func:`_vote` fills.
    """
    n_groups = starts.shape[0] - 1
    max_half = (MAX_ACCUMULATOR_CELLS // n_theta - 1) // 2
    cx = np.zeros(n_groups)
    cy = np.zeros(n_groups)
    half = np.zeros(n_groups, dtype=np.intp)
    votes = np.zeros(n_groups, dtype=np.bool_)
    for g in range(n_groups):
        s = starts[g]
        e = starts[g + 1]
        for i in range(s, e):
            cx[g] += pts[i, 0]
            cy[g] += pts[i, 1]
        cx[g] /= e - s
        cy[g] /= e - s
        r2 = 0.0
        for i in range(s, e):
            dx = pts[i, 0] - cx[g]
            dy = pts[i, 1] - cy[g]
            r2 = max(r2, dx * dx + dy * dy)
        cells = math.sqrt(r2) * inv_res + 2.0
        if e - s >= min_points and cells <= max_half:
            half[g] = math.ceil(cells) - 1
            votes[g] = True
    width = 2 * np.max(half) + 1 if n_groups > 0 else 1
    acc = np.zeros((n_theta, width), dtype=np.int32)
    rows = np.zeros((n_theta, 3), dtype=np.intp)
    return cx, cy, half, votes, acc, rows


@njit
def _rho_cell(dx: float, dy: float, c_scaled: float, s_scaled: float, offset: float) -> int:
    """Accumulator rho index of point ``(dx, dy)`` (relative to the group centroid).

    ``c_scaled, s_scaled = cos(theta_k) / res, sin(theta_k) / res`` and ``offset = half + 0.5``; the sum
    is positive (``|rho_rel| < (half - 1) res``), so truncation is rounding to the nearest cell.
    """
    return int(dx * c_scaled + dy * s_scaled + offset)


@njit
def _vote(
    pts: FloatArray,
    members: IntArray,
    cx: float,
    cy: float,
    half: int,
    cos_t: FloatArray,
    sin_t: FloatArray,
    inv_res: float,
    acc: VoteArray,
    rows: IntArray,
) -> None:
    """Vote points ``pts[members]`` into the all-zero accumulator ``acc`` (eq. 34). O(len(members) n_theta).

    ``acc`` is ``(n_theta, >= 2 half + 1)``; ``rows`` ``(n_theta, 3)`` receives each theta row's highest
    vote and the first and last rho cell it touched, so that :func:`_peak` and :func:`_clear` (and any
    scan for cells above a threshold) only visit touched cells.
    """
    n = members.shape[0]
    dx = np.empty(n)
    dy = np.empty(n)
    cells = np.empty(n, dtype=np.intp)
    for q in range(n):
        dx[q] = pts[members[q], 0] - cx
        dy[q] = pts[members[q], 1] - cy
    offset = half + 0.5
    for k in range(cos_t.shape[0]):
        c = cos_t[k] * inv_res
        s = sin_t[k] * inv_res
        # three passes, so that the first two vectorise: the cells, their range, then the votes
        for q in range(n):
            cells[q] = _rho_cell(dx[q], dy[q], c, s, offset)
        lo = acc.shape[1]
        hi = -1
        for q in range(n):
            lo = min(lo, cells[q])
            hi = max(hi, cells[q])
        best = 0
        for q in range(n):
            j = cells[q]
            v = acc[k, j] + 1
            acc[k, j] = v
            best = max(best, v)
        rows[k, 0] = best
        rows[k, 1] = lo
        rows[k, 2] = hi


@njit
def _peak(acc: VoteArray, rows: IntArray) -> tuple[int, int, int]:
    """``(k, j, votes)`` of the highest cell; ties go to the first in row-major order (smallest theta,
    then smallest rho), as Algorithm 1's strict ``T < V`` scan does. ``votes`` is 0 for an empty vote.
    O(n_theta + n_rho)."""
    kb = 0
    for k in range(rows.shape[0]):
        if rows[k, 0] > rows[kb, 0]:
            kb = k
    top = rows[kb, 0]
    if top <= 0:
        return 0, 0, 0
    for j in range(rows[kb, 1], rows[kb, 2] + 1):
        if acc[kb, j] == top:
            return kb, j, int(top)
    return kb, rows[kb, 1], int(top)  # unreachable: the row's maximum is in its touched range


@njit
def _clear(acc: VoteArray, rows: IntArray) -> None:
    """Zero the cells :func:`_vote` touched, so ``acc`` can be reused. O(touched cells)."""
    for k in range(rows.shape[0]):
        for j in range(rows[k, 1], rows[k, 2] + 1):
            acc[k, j] = 0
