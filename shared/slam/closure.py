"""Loop-closure candidates and their verification: is the current scan a view of an earlier place?

**Candidates** (:func:`candidates`): earlier keyframes whose estimated position lies within
``search_radius_m`` of the current one and that are more than ``recent_m`` of travel back (nearer ones are
the chain the front end already matched), nearest first, at most ``max_candidates``, no two from the same
submap.

**Verification** (:func:`verify`): the current keyframe's returns are matched against the candidate's
submap (its own returns and those of ``submap_keyframes`` keyframes either side, placed by the graph's
estimate) in three steps, each finer than the last:

1. a correlative search over the whole window (+-``window_m``, +-``window_rad``, 10 cm cells) round the
   graph's guess (Olson 2009, :func:`shared.kernels.matching._search.correlative_search`): it finds the
   basin whatever the drift within the window;
2. the same search 2.5 cm fine round the best cell;
3. the project's ICP kernel from there.

The match is a loop closure when its inlier share (returns within ``inlier_m`` of the submap) reaches
``min_inlier_share``, its pose did not end on the window's border (the best place may lie beyond it) and
its information (:mod:`shared.slam.information`) fixes some direction at all. The edge's covariance is the
inverse of that information plus a floor (2 cm, 0.3 degrees: what the submap's own placement is worth);
along a featureless corridor it stays blind, so such a closure corrects across the corridor only.

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
from shared.types import FloatArray, Pose2D

__all__ = ["LoopMatch", "ambiguous", "candidates", "loop_information", "stacked", "verify"]

#: the covariance floor of a loop edge: the submap's own placement error (m, rad, one sigma)
FLOOR_SIGMA_M = 0.02
FLOOR_SIGMA_RAD = math.radians(0.3)
#: a match needs this many straight-neighbourhood pairs to say anything
MIN_PAIRS = 20
#: ambiguity: another place of the window scoring this share of the best, farther than AMBIGUITY_M from
#: it and more than AMBIGUITY_SIGMAS standard deviations away along what the match constrains, makes the
#: match ambiguous (a corridor's doors repeating, two rooms alike); it is then no loop closure
AMBIGUITY_RATIO = 0.9
AMBIGUITY_M = 0.35
AMBIGUITY_SIGMAS = 3.0
_COARSE_CELL_M = 0.1
_COARSE_RADIUS_M = 0.25


@dataclass(frozen=True, slots=True)
class LoopMatch:
    """A verified loop closure: the current keyframe's pose in the candidate's frame, the share of its
    returns the submap explains, and the edge's information ``(3, 3)``."""

    candidate: int
    pose: Pose2D
    inlier_share: float
    information: FloatArray


def candidates(
    positions: FloatArray,
    travelled_m: FloatArray,
    current: int,
    settings: LoopClosureSettings,
) -> list[int]:
    """Keyframes ``0..current-1`` that may close a loop with keyframe ``current`` (module docstring):
    ``positions`` ``(K, 2)`` are the estimated keyframe positions (m), ``travelled_m`` ``(K,)`` the
    distance travelled up to each. O(K)."""
    if current <= 0:
        return []
    old = np.flatnonzero(travelled_m[:current] <= travelled_m[current] - settings.recent_m)
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


def loop_information(information: FloatArray) -> FloatArray:
    """A loop edge's information: ``(information^-1 + floor)^-1`` with the module's covariance floor; a
    direction the match does not fix keeps (near) zero information. O(1)."""
    floor = np.diag([FLOOR_SIGMA_M**2, FLOOR_SIGMA_M**2, FLOOR_SIGMA_RAD**2])
    # Woodbury, without inverting a singular I: (I^-1 + F)^-1 = F^-1 - F^-1 (I + F^-1)^-1 F^-1
    f_inv = np.linalg.inv(floor)
    out = f_inv - f_inv @ np.linalg.solve(np.asarray(information) + f_inv, f_inv)
    out = 0.5 * (out + out.T)
    # a direction no pair constrains: a tiny information keeps the system positive definite
    return out + np.eye(3) * 1e-6


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


def _coarse(
    sub: FloatArray, cur: FloatArray, guess: Pose2D, settings: LoopClosureSettings, rot_step: float
) -> tuple[Pose2D, float, FloatArray, FloatArray]:
    """The window's best pose and score, and per translation cell the best score and its offset (m) from
    the guess: ``(pose, score, scores (C,), offsets (C, 2))``."""
    cell = _COARSE_CELL_M
    if len(cur) > 150:
        cur = cur[(np.arange(150) * len(cur)) // 150]
    margin = settings.window_m + _COARSE_RADIUS_M + cell
    lo = np.maximum(sub.min(axis=0) - margin, np.array([guess.x_m, guess.y_m]) - 30.0)
    hi = np.minimum(sub.max(axis=0) + margin, np.array([guess.x_m, guess.y_m]) + 30.0)
    nx, ny = (int(v) for v in np.maximum(np.ceil((hi - lo) / cell), 1))
    table = _table(np.ascontiguousarray(sub), float(lo[0]), float(lo[1]), cell, nx, ny, _COARSE_RADIUS_M)
    n_xy = round(settings.window_m / cell)
    scores, thetas = _score_grid(
        table,
        float(lo[0]),
        float(lo[1]),
        cell,
        np.ascontiguousarray(cur),
        guess.x_m,
        guess.y_m,
        guess.theta_rad,
        int(settings.window_rad / rot_step),
        rot_step,
        n_xy,
    )
    shifts = (np.arange(2 * n_xy + 1) - n_xy) * cell
    ox, oy = np.meshgrid(shifts, shifts, indexing="ij")
    a, b = np.unravel_index(int(np.argmax(scores)), scores.shape)
    pose = Pose2D(guess.x_m + ox[a, b], guess.y_m + oy[a, b], float(thetas[a, b]))
    offsets = np.column_stack([ox.ravel(), oy.ravel()])
    return pose, float(scores[a, b]), scores.ravel(), offsets


def ambiguous(
    best_offset: FloatArray,
    best_score: float,
    scores: FloatArray,
    offsets: FloatArray,
    information: FloatArray,
) -> bool:
    """Whether another place of the window (``offsets`` (C, 2) m from the guess, with ``scores``) scores
    at least :data:`AMBIGUITY_RATIO` of ``best_score``, lies more than :data:`AMBIGUITY_M` from the best
    and more than :data:`AMBIGUITY_SIGMAS` standard deviations from it under the translation block of
    the match's ``information``: along a featureless corridor every shift scores alike and none counts,
    across a repeating pattern one does. O(C)."""
    d = offsets - best_offset
    far = np.hypot(d[:, 0], d[:, 1]) > AMBIGUITY_M
    rival = far & (scores >= AMBIGUITY_RATIO * best_score)
    if not rival.any():
        return False
    block = np.asarray(information)[:2, :2]
    m2 = np.einsum("ij,jk,ik->i", d[rival], block, d[rival])
    return bool((m2 > AMBIGUITY_SIGMAS**2).any())


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
    coarse, score, scores, offsets = _coarse(sub, cur, guess, settings, coarse_step)
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
    best = np.array([coarse.x_m - guess.x_m, coarse.y_m - guess.y_m])
    if ambiguous(best, score, scores, offsets, loop_information(info.information)):
        return None
    return LoopMatch(candidate, pose, info.inlier_share, loop_information(info.information))


def stacked(parts: Sequence[FloatArray]) -> FloatArray:
    """Point sets ``(N_i, 2)`` stacked into one ``(sum N_i, 2)`` (an empty one when there are none)."""
    return np.vstack(parts) if parts else np.zeros((0, 2))
