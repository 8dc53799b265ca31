"""Loop-closure candidates and their verification: is the current scan a view of an earlier place?

**Candidates** (:func:`candidates`): earlier keyframes whose estimated position lies within
``search_radius_m`` of the current one and that are more than ``recent_m`` of travel back (nearer ones are
the chain the front end already matched), nearest first, at most ``max_candidates``, no two from the same
submap.

**Verification** (:func:`verify`): the current keyframe's returns are matched against the candidate's
submap (its own returns and those of ``submap_keyframes`` keyframes either side, placed by the graph's
estimate) in three steps, each finer than the last:

1. a correlative search over the whole window (+-``window_m``, +-``window_rad``, 10 cm cells) round the
   graph's guess (Olson 2009; the look-up table of
   :func:`shared.kernels.matching._search.correlative_search`), keeping the best score of every
   translation cell: it finds the basin whatever the drift within the window;
2. the same search 2.5 cm fine round the best cell;
3. the project's ICP kernel from there.

It is no closure when the window holds a second peak (:func:`ambiguous`: a corridor whose doors repeat),
when the pose ended on the window's border (the best place may lie beyond it), when fewer than
``min_inlier_share`` of the returns lie within ``inlier_m`` of the submap, or when fewer than
:data:`MIN_PAIRS` returns have a straight neighbourhood there (:mod:`shared.slam.information`). The edge's
information is the mapper's business (:mod:`shared.slam.mapper`: a point-to-line refinement against the
candidate's own scan).

Pure: arrays, poses and settings in, a :class:`LoopMatch` or ``None`` out.
Cost per candidate: O(R T N) for the coarse search (R rotations, T = (2 window / 10 cm)^2 shifts, N <= 150
returns), O(M log M) for the submap's tree.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from shared.kernels._jit import njit
from shared.kernels.matching._search import _table, correlative_search
from shared.pipeline.rangenoise import NO_RANGE_NOISE, RangeNoise
from shared.slam.information import match_information
from shared.slam.settings import LoopClosureSettings
from shared.types import BoolArray, FloatArray, Pose2D

__all__ = [
    "LoopMatch",
    "ambiguous",
    "candidates",
    "chain_covariance",
    "peak",
    "spread",
    "spread_of",
    "stacked",
    "verify",
]

#: a match needs this many straight-neighbourhood pairs to say anything
MIN_PAIRS = 20
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
_COARSE_CELL_M = 0.1
_COARSE_RADIUS_M = 0.25


@dataclass(frozen=True, slots=True)
class LoopMatch:
    """A verified loop closure: the current keyframe's pose in the candidate's frame and the share of its
    returns the submap explains, and how far round that pose the scan fits about as well."""

    candidate: int
    pose: Pose2D
    inlier_share: float
    #: ``(3, 3)`` m^2, rad^2: the spread of the poses that explain the scan about as well (:func:`spread`)
    spread: FloatArray


def candidates(
    positions: FloatArray,
    travelled_m: FloatArray,
    current: int,
    settings: LoopClosureSettings,
    headings_rad: FloatArray | None = None,
) -> list[int]:
    """Keyframes ``0..current-1`` that may close a loop with keyframe ``current`` (module docstring):
    ``positions`` ``(K, 2)`` are the estimated keyframe positions (m), ``travelled_m`` ``(K,)`` the
    distance travelled up to each, ``headings_rad`` ``(K,)`` their headings (then a keyframe whose heading
    differs by more than ``max_view_change_rad`` is none). O(K)."""
    if current <= 0:
        return []
    old = np.flatnonzero(travelled_m[:current] <= travelled_m[current] - settings.recent_m)
    if headings_rad is not None and len(old):
        turn = np.abs(np.remainder(headings_rad[old] - headings_rad[current] + np.pi, 2 * np.pi) - np.pi)
        old = old[turn <= settings.max_view_change_rad]
    if len(old) == 0:
        return []
    dist = np.hypot(*(positions[old] - positions[current]).T)
    near = old[dist <= settings.search_radius_m]
    order = near[np.argsort(dist[dist <= settings.search_radius_m], kind="stable")]
    chosen: list[int] = []
    for k in order:
        if all(abs(int(k) - c) > settings.submap_keyframes for c in chosen):
            chosen.append(int(k))
        if len(chosen) >= settings.max_candidates:
            break
    return chosen


@njit
def _score_grid(
    table: FloatArray,
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
    (b - n_xy) cell)`` from ``(x, y)``."""
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
            for a in range(side):
                u = cx[i] + a - n_xy
                if u < 0 or u >= nx:
                    continue
                for b in range(side):
                    v = cy[i] + b - n_xy
                    if 0 <= v < ny:
                        sums[a, b] += table[u, v]
        for a in range(side):
            for b in range(side):
                score = sums[a, b] / n
                if score > best[a, b]:
                    best[a, b] = score
                    best_th[a, b] = th
    return best, best_th


class _Surface:
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

    def scores(
        self, pose: Pose2D, n_rot: int, rot_step: float, n_xy: int | None = None
    ) -> tuple[FloatArray, FloatArray]:
        """Per translation cell round ``pose`` the best score over ``2 n_rot + 1`` rotations and that
        rotation (rad): two ``(S, S)`` arrays (:func:`_score_grid`)."""
        return _score_grid(
            self.table,
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


def _coarse(
    sub: FloatArray, cur: FloatArray, guess: Pose2D, settings: LoopClosureSettings, rot_step: float
) -> tuple[Pose2D, FloatArray, tuple[int, int], BoolArray]:
    """The window's best pose, per translation cell the best score over the rotations, the chosen cell
    and the cells that explain the scan about as well (:func:`peak`): ``(pose, scores (S, S), cell,
    plausible (S, S))``."""
    cell = _COARSE_CELL_M
    surface = _Surface(sub, cur, guess, cell, _COARSE_RADIUS_M, settings.window_m, clip_m=30.0)
    scores, thetas = surface.scores(guess, int(settings.window_rad / rot_step), rot_step)
    ox, oy = surface.offsets()
    (a, b), plausible = peak(scores, np.hypot(ox, oy))
    pose = Pose2D(guess.x_m + ox[a, b], guess.y_m + oy[a, b], float(thetas[a, b]))
    return pose, scores, (a, b), plausible


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
    far = np.hypot(ia - a0, ib - b0) * _COARSE_CELL_M > AMBIGUITY_M
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


def verify(
    submap: FloatArray,
    current: FloatArray,
    guess: Pose2D,
    candidate: int,
    settings: LoopClosureSettings,
    matcher: Any,
    *,
    range_noise: RangeNoise = NO_RANGE_NOISE,
) -> LoopMatch | None:
    """Match ``current`` (robot frame of the current keyframe, m) onto ``submap`` (robot frame of keyframe
    ``candidate``) from ``guess`` (the current keyframe in the candidate's frame, from the graph); a
    :class:`LoopMatch` when it passes (module docstring), else ``None``. ``matcher`` is a scan-matching
    kernel (``apply(reference, current, initial) -> Match``)."""
    sub = submap[np.isfinite(submap).all(axis=1)]
    cur = current[np.isfinite(current).all(axis=1)]
    if len(sub) < MIN_PAIRS or len(cur) < MIN_PAIRS:
        return None
    reach = float(np.percentile(np.hypot(cur[:, 0], cur[:, 1]), 90))
    # a rotation step moving the far returns by about one cell
    coarse_step = min(max(0.1 / max(reach, 0.5), 0.004), 0.035)
    coarse, scores, cell, plausible = _coarse(sub, cur, guess, settings, coarse_step)
    if ambiguous(scores, cell):
        return None
    fine = correlative_search(
        sub,
        cur,
        coarse,
        rot_half_rad=coarse_step,
        rot_step_rad=coarse_step / 4.0,
        xy_half_m=0.1,
        cell_m=0.025,
        radius_m=0.1,
        max_points=150,
    )
    match = matcher.apply(sub, cur, fine.pose)
    pose = match.pose if match.converged else fine.pose
    shift = guess.between(pose)
    edge = settings.window_m - 0.1
    if settings.window_m > 0.15 and (abs(shift.x_m) > edge or abs(shift.y_m) > edge):
        return None  # on the window's border: the best place may lie beyond it
    if abs(math.remainder(pose.theta_rad - guess.theta_rad, math.tau)) > settings.window_rad + 0.02:
        return None
    info = match_information(
        sub, cur, pose, inlier_m=settings.inlier_m, range_noise=range_noise, tree=cKDTree(sub)
    )
    if info.inlier_share < settings.min_inlier_share or info.pairs < MIN_PAIRS:
        return None
    # the spread on the fine grid round the pose, or on the whole window where the surface is flat
    # beyond the fine one (a corridor: the places along it score alike for metres)
    wide = spread_of(plausible, _COARSE_CELL_M, cell)
    fine_spread = spread(sub, cur, pose, coarse_step / 4.0)
    if wide is not None:
        fine_spread[:2, :2] += wide
    return LoopMatch(candidate, pose, info.inlier_share, fine_spread)


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
    surface = _Surface(sub, cur, pose, cell, 0.1, SPREAD_M, clip_m=15.0)
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


def chain_covariance(poses: Sequence[Pose2D], covariances: Sequence[FloatArray]) -> FloatArray:
    """Covariance ``(3, 3)`` of the last of ``poses`` in the frame of the first, by dead reckoning along
    the chain: ``covariances[m]`` ``(3, 3)`` is that of the motion from ``poses[m]`` to ``poses[m + 1]``
    (in the frame of ``poses[m]``); first order, ``sum_m A_m S_m A_m^T`` with
    ``A_m = [[R_0m, J (p_last - p_m+1)], [0, 0, 1]]`` (an error of motion m moves everything after it, its
    heading error about ``p_m+1``). What the graph knows of that relative pose is at most this (loops in
    between only shrink it). O(len(poses)), vectorised."""
    if len(poses) < 2:
        return np.zeros((3, 3))
    base = poses[0]
    rel = np.array([base.between(p).as_tuple() for p in poses])
    theta = rel[:-1, 2]
    lever = rel[-1, :2] - rel[1:, :2]  # p_last - p_(m+1)
    a = np.zeros((len(poses) - 1, 3, 3))
    a[:, 0, 0], a[:, 0, 1] = np.cos(theta), -np.sin(theta)
    a[:, 1, 0], a[:, 1, 1] = np.sin(theta), np.cos(theta)
    a[:, 0, 2], a[:, 1, 2] = -lever[:, 1], lever[:, 0]
    a[:, 2, 2] = 1.0
    out: FloatArray = np.einsum("mij,mjk,mlk->il", a, np.asarray(covariances), a)
    return out


def stacked(parts: Sequence[FloatArray]) -> FloatArray:
    """Point sets ``(N_i, 2)`` stacked into one ``(sum N_i, 2)`` (an empty one when there are none)."""
    return np.vstack(parts) if parts else np.zeros((0, 2))
