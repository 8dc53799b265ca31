"""The correlative score surface of a loop-closure search (Olson 2009) and what is read off it: which cell
to take, whether the window holds a second peak, and how far round a pose the scan fits about as well.

:class:`ScoreSurface` holds the look-up table of a submap (:func:`shared.kernels.matching._search._table`)
and the current returns (at most 150); :meth:`ScoreSurface.scores` gives, per translation cell of a window,
the best score over a fan of rotations (:func:`_score_grid`). :func:`peak` takes the cell nearest the guess
on the ridge of near-best cells, :func:`ambiguous` finds a second peak (a corridor whose doors repeat),
:func:`spread` and :func:`spread_of` read a match's covariance off the surface. Used by
:func:`shared.slam.closure.verify`.

Units: m, rad; scores are the mean look-up value of the returns (dimensionless, 0..1). Cost: O(R T N) for
R rotations, T translation cells and N <= 150 returns per score grid at worst, in practice the share of
the table that is not zero (about 5 %) of it; O(S^2) to read an S x S grid.
"""

from __future__ import annotations

import math

import numpy as np

from shared.kernels._jit import njit
from shared.kernels.matching._search import _table
from shared.types import BoolArray, FloatArray, IntArray, Pose2D

__all__ = [
    "AMBIGUITY_M",
    "AMBIGUITY_RATIO",
    "COARSE_CELL_M",
    "COARSE_RADIUS_M",
    "PROMINENCE",
    "SPREAD_M",
    "SPREAD_RATIO",
    "ScoreSurface",
    "ambiguous",
    "peak",
    "spread",
    "spread_of",
]


#: ambiguity (:func:`ambiguous`): another peak of the window farther than AMBIGUITY_M from the best,
#: rising to AMBIGUITY_RATIO of the best's height above the valley between them (itself at least
#: PROMINENCE of the best score deep), makes the match ambiguous (a corridor's doors repeating, two rooms
#: alike); it is then no closure
AMBIGUITY_RATIO = 0.75
AMBIGUITY_M = 0.35
PROMINENCE = 0.02
#: the spread of a match (:func:`spread`): translations within SPREAD_M scoring SPREAD_RATIO of the best
SPREAD_M = 0.5
SPREAD_RATIO = 0.95
#: the coarse search's cells and look-up table radius (m)
COARSE_CELL_M = 0.1
COARSE_RADIUS_M = 0.25


@njit
def _fill_row(table: FloatArray, u: int, first: IntArray, after: IntArray) -> None:
    """Where row ``u`` of ``table`` ``(nx, ny)`` is non-zero: ``first[u, v]``, the first column >= v with a
    non-zero value (``ny`` if none), and ``after[u, v]``, one past the last column < v with a non-zero value
    (0 if none), for v in 0..ny. A look-up table is zero beyond its radius of the submap's points (about
    95 % of its cells), and adding those zeros changes no sum. O(ny)."""
    ny = table.shape[1]
    first[u, ny] = ny
    for v in range(ny - 1, -1, -1):
        first[u, v] = v if table[u, v] != 0.0 else first[u, v + 1]
    after[u, 0] = 0
    for v in range(ny):
        after[u, v + 1] = v + 1 if table[u, v] != 0.0 else after[u, v]


@njit
def _extents(table: FloatArray) -> tuple[IntArray, IntArray]:
    """:func:`_fill_row` for every row: ``(first, after)``, both ``(nx, ny + 1)``. O(nx ny)."""
    nx, ny = table.shape
    first = np.empty((nx, ny + 1), dtype=np.int64)
    after = np.empty((nx, ny + 1), dtype=np.int64)
    for u in range(nx):
        _fill_row(table, u, first, after)
    return first, after


@njit
def _score_grid(
    table: FloatArray,
    first: IntArray,
    after: IntArray,
    filled: BoolArray,
    x0: float,
    y0: float,
    cell: float,
    cur: FloatArray,
    x: float,
    y: float,
    theta: float,
    n_rot: int,
    rot_step: float,
    n_xy: int,
) -> tuple[FloatArray, FloatArray]:
    """Per translation cell of the window the best score over the rotations and that rotation (rad):
    two ``(2 n_xy + 1, 2 n_xy + 1)`` arrays, index ``[a, b]`` for the shift ``((a - n_xy) cell,
    (b - n_xy) cell)`` from ``(x, y)``. Each return adds the table's window round its cell to the sums,
    row by row, only over the span of the row that is non-zero (``first``, ``after``: :func:`_fill_row`,
    filled for a row the first time one of these calls reads it, ``filled`` ``(nx,)`` saying which are);
    the sums, added in the returns' order, are those of the whole window bit for bit
    (tests/shared/slam/test_surface.py keeps the plain loop to compare)."""
    nx, ny = table.shape
    n = cur.shape[0]
    side = 2 * n_xy + 1
    best = np.full((side, side), -1.0)
    best_th = np.zeros((side, side))
    sums = np.empty((side, side))
    cx = np.empty(n, dtype=np.int64)
    cy = np.empty(n, dtype=np.int64)
    for k in range(-n_rot, n_rot + 1):
        th = theta + k * rot_step
        c = math.cos(th)
        s = math.sin(th)
        for i in range(n):
            cx[i] = math.floor((c * cur[i, 0] - s * cur[i, 1] + x - x0) / cell)
            cy[i] = math.floor((s * cur[i, 0] + c * cur[i, 1] + y - y0) / cell)
        sums[:, :] = 0.0
        for i in range(n):
            u0 = cx[i] - n_xy
            v0 = cy[i] - n_xy
            v_lo = max(v0, 0)
            v_hi = min(v0 + side, ny)
            if v_lo >= v_hi:
                continue
            for a in range(max(-u0, 0), min(side, nx - u0)):
                u = u0 + a
                if not filled[u]:
                    _fill_row(table, u, first, after)
                    filled[u] = True
                lo = first[u, v_lo]
                hi = after[u, v_hi]
                row = table[u]
                out = sums[a]
                for v in range(lo, hi):
                    out[v - v0] += row[v]
        for a in range(side):
            for b in range(side):
                score = sums[a, b] / n
                if score > best[a, b]:
                    best[a, b] = score
                    best_th[a, b] = th
    return best, best_th


class ScoreSurface:
    """A correlative score surface (Olson 2009): the look-up table of ``sub`` (``cell`` m cells, table
    radius ``radius`` m) round ``centre`` (at most ``clip_m`` away, so the table stays bounded) and the
    current returns (at most 150, even stride), scored over translations within +-``half_m``."""

    def __init__(
        self,
        sub: FloatArray,
        cur: FloatArray,
        centre: Pose2D,
        cell: float,
        radius: float,
        half_m: float,
        *,
        clip_m: float,
    ) -> None:
        if len(cur) > 150:
            cur = cur[(np.arange(150) * len(cur)) // 150]
        self.cur = np.ascontiguousarray(cur)
        self.cell = cell
        self.n_xy = round(half_m / cell)
        margin = half_m + radius + cell
        c = np.array([centre.x_m, centre.y_m])
        self.lo = np.maximum(sub.min(axis=0) - margin, c - clip_m)
        hi = np.minimum(sub.max(axis=0) + margin, c + clip_m)
        nx, ny = (int(v) for v in np.maximum(np.ceil((hi - self.lo) / cell), 1))
        self.table = _table(
            np.ascontiguousarray(sub), float(self.lo[0]), float(self.lo[1]), cell, nx, ny, radius
        )
        # where each row is non-zero, filled as the searches first read a row (:func:`_fill_row`)
        self.first = np.empty((nx, ny + 1), dtype=np.int64)
        self.after = np.empty((nx, ny + 1), dtype=np.int64)
        self.filled = np.zeros(nx, dtype=np.bool_)

    def scores(
        self, pose: Pose2D, n_rot: int, rot_step: float, n_xy: int | None = None
    ) -> tuple[FloatArray, FloatArray]:
        """Per translation cell round ``pose`` the best score over ``2 n_rot + 1`` rotations and that
        rotation (rad): two ``(S, S)`` arrays (:func:`_score_grid`)."""
        return _score_grid(
            self.table,
            self.first,
            self.after,
            self.filled,
            float(self.lo[0]),
            float(self.lo[1]),
            self.cell,
            self.cur,
            pose.x_m,
            pose.y_m,
            pose.theta_rad,
            n_rot,
            rot_step,
            self.n_xy if n_xy is None else n_xy,
        )

    def at(self, pose: Pose2D) -> float:
        """The score of ``pose`` itself."""
        return float(self.scores(pose, 0, 0.0, 0)[0][0, 0])

    def offsets(self) -> tuple[FloatArray, FloatArray]:
        """The translation of each cell of :meth:`scores` (m): two ``(S, S)`` arrays, x and y."""
        shifts = (np.arange(2 * self.n_xy + 1) - self.n_xy) * self.cell
        ox, oy = np.meshgrid(shifts, shifts, indexing="ij")
        return ox, oy


def peak(scores: FloatArray, distance: FloatArray) -> tuple[tuple[int, int], BoolArray]:
    """The cell of a score grid ``(S, S)`` to take and the cells that explain the scan about as well.

    The plausible cells are those scoring at least :data:`SPREAD_RATIO` of the best (the ridge: along
    a featureless corridor, every place along it); the one nearest the guess (``distance`` ``(S, S)``, m)
    is taken: where the scan does not tell, the graph's estimate stands. O(S^2)."""
    ridge = scores >= SPREAD_RATIO * float(scores.max())
    a, b = np.unravel_index(int(np.argmax(np.where(ridge, -distance, -np.inf))), scores.shape)
    return (int(a), int(b)), ridge


def ambiguous(scores: FloatArray, best: tuple[int, int]) -> bool:
    """Whether the window's score grid ``scores`` ``(S, S)`` (per translation cell, the best over the
    rotations) has a second peak: a cell farther than :data:`AMBIGUITY_M` from the ``best`` cell whose
    score, above the lowest cell on the straight line between them (the valley), reaches
    :data:`AMBIGUITY_RATIO` of the best's height above that valley, where the valley lies at least
    :data:`PROMINENCE` of the best score below it. Along a featureless corridor the cells along its axis
    score alike all the way (one ridge, no valley: the match's information says it does not fix that
    direction); along a corridor whose doors or pillars repeat, the places between two repeats score
    less, and the match could be either (the walls score everywhere, so the valley is shallow: heights
    are measured from it). O(R S) for R candidate cells."""
    a0, b0 = best
    top = scores[a0, b0]
    ia, ib = np.nonzero(scores >= top * (1.0 - 2.0 * PROMINENCE))
    far = np.hypot(ia - a0, ib - b0) * COARSE_CELL_M > AMBIGUITY_M
    ia, ib = ia[far], ib[far]
    if len(ia) == 0:
        return False
    steps = int(np.ceil(np.hypot(ia - a0, ib - b0).max())) + 1
    t = np.linspace(0.0, 1.0, steps)[None, :]
    path_a = np.rint(a0 + t * (ia - a0)[:, None]).astype(np.intp)
    path_b = np.rint(b0 + t * (ib - b0)[:, None]).astype(np.intp)
    valley = scores[path_a, path_b].min(axis=1)
    depth = top - valley
    rise = scores[ia, ib] - valley
    return bool(((depth >= PROMINENCE * top) & (rise >= AMBIGUITY_RATIO * depth)).any())


def spread(sub: FloatArray, cur: FloatArray, pose: Pose2D, rot_step: float) -> FloatArray:
    """How well the scan's shape pins its place down, read off the correlative score surface as Olson
    (2009) reads a match's covariance: a diagonal-block ``(3, 3)`` second moment about ``pose`` (m^2,
    rad^2) of the translations within +-:data:`SPREAD_M` (2.5 cm cells, 10 cm table radius, best over
    rotations within four steps of ``rot_step``) and of the rotations within +-16 ``rot_step`` (at the
    pose's translation) that score at least :data:`SPREAD_RATIO` of the best. Along a corridor whose door
    recesses are all the scan has, the surface is nearly flat for tens of centimetres; in a hall whose
    pillars are all the scan has, for half a degree; a loop edge must not claim more. O(R T N) for
    R = 9 rotations, T = (2 SPREAD_M / 2.5 cm)^2 shifts and N <= 150 returns."""
    cell = 0.025
    surface = ScoreSurface(sub, cur, pose, cell, 0.1, SPREAD_M, clip_m=15.0)
    scores, _ = surface.scores(pose, 4, rot_step)
    ox, oy = surface.offsets()
    near = scores >= SPREAD_RATIO * scores.max()
    d = np.column_stack([ox[near], oy[near]])
    out: FloatArray = np.zeros((3, 3))
    out[:2, :2] = d.T @ d / len(d) + np.eye(2) * cell**2 / 12.0
    # the rotations: the score at the pose's translation, turned in steps of rot_step
    turns = np.arange(-16, 17) * rot_step
    at = np.array([surface.at(Pose2D(pose.x_m, pose.y_m, pose.theta_rad + t)) for t in turns])
    plausible = turns[at >= SPREAD_RATIO * at.max()]
    out[2, 2] = float(np.mean(plausible**2)) + rot_step**2 / 12.0
    return out


def spread_of(near: BoolArray, cell_m: float, best: tuple[int, int]) -> FloatArray | None:
    """The second moment ``(2, 2)`` (m^2) about the ``best`` cell of the ``near`` cells of a grid
    ``(S, S)`` of ``cell_m`` cells; ``None`` unless they reach the grid's border (the surface is flat
    beyond the fine grid, and its spread is read here). O(S^2)."""
    if not (near[0, :].any() or near[-1, :].any() or near[:, 0].any() or near[:, -1].any()):
        return None
    ia, ib = np.nonzero(near)
    d = np.column_stack([ia - best[0], ib - best[1]]) * cell_m
    out: FloatArray = d.T @ d / len(d)
    return out
