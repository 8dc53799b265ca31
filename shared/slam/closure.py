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

The score surface and what is read off it (the cell to take, a second peak, the spread) are
:mod:`shared.slam.surface`. It is no closure when the window holds a second peak
(:func:`~shared.slam.surface.ambiguous`: a corridor whose doors repeat), when the pose ended on the window's
border (the best place may lie beyond it), when fewer than ``min_inlier_share`` of the returns lie within
``inlier_m`` of the submap, or when fewer than :data:`MIN_PAIRS` returns have a straight neighbourhood there
(:mod:`shared.slam.information`). The edge's information is the mapper's business
(:mod:`shared.slam.mapper`: a point-to-line refinement against the candidate's own scan).

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

from shared.kernels.matching._search import correlative_search
from shared.pipeline.rangenoise import NO_RANGE_NOISE, RangeNoise
from shared.slam.information import match_information
from shared.slam.settings import LoopClosureSettings
from shared.slam.surface import (
    COARSE_CELL_M,
    COARSE_RADIUS_M,
    ScoreSurface,
    ambiguous,
    peak,
    spread,
    spread_of,
)
from shared.types import BoolArray, FloatArray, Pose2D

__all__ = [
    "LoopMatch",
    "candidates",
    "chain_covariance",
    "stacked",
    "verify",
]


#: a match needs this many straight-neighbourhood pairs to say anything
MIN_PAIRS = 20


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
    usable: BoolArray | None = None,
) -> list[int]:
    """Keyframes ``0..current-1`` that may close a loop with keyframe ``current`` (module docstring):
    ``positions`` ``(K, 2)`` are the estimated keyframe positions (m), ``travelled_m`` ``(K,)`` the
    distance travelled up to each, ``headings_rad`` ``(K,)`` their headings (then a keyframe whose heading
    differs by more than ``max_view_change_rad`` is none), ``usable`` ``(K,)`` which may be one at all (the
    held ones, :mod:`shared.slam.places`). O(K)."""
    if current <= 0:
        return []
    recent = travelled_m[:current] <= travelled_m[current] - settings.recent_m
    old = np.flatnonzero(recent if usable is None else recent & usable[:current])
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


def _coarse(
    sub: FloatArray, cur: FloatArray, guess: Pose2D, window: tuple[float, float], rot_step: float
) -> tuple[Pose2D, FloatArray, tuple[int, int], BoolArray]:
    """The best pose of the window (``(half-width m, half-width rad)``), per translation cell the best
    score over the rotations, the chosen cell and the cells that explain the scan about as well
    (:func:`peak`): ``(pose, scores (S, S), cell, plausible (S, S))``."""
    cell = COARSE_CELL_M
    surface = ScoreSurface(sub, cur, guess, cell, COARSE_RADIUS_M, window[0], clip_m=30.0)
    scores, thetas = surface.scores(guess, int(window[1] / rot_step), rot_step)
    ox, oy = surface.offsets()
    (a, b), plausible = peak(scores, np.hypot(ox, oy))
    pose = Pose2D(guess.x_m + ox[a, b], guess.y_m + oy[a, b], float(thetas[a, b]))
    return pose, scores, (a, b), plausible


def _reaches_border(
    plausible: BoolArray, pose: Pose2D, guess: Pose2D, window_rad: float, step: float
) -> bool:
    """Whether a coarse search's plausible cells reach its grid's border or its pose lies on the last
    rotation of its fan: the scan does not fix the place within the window."""
    edge = plausible[0, :].any() or plausible[-1, :].any() or plausible[:, 0].any() or plausible[:, -1].any()
    turn = abs(math.remainder(pose.theta_rad - guess.theta_rad, math.tau))
    return bool(edge) or turn >= window_rad - 1.5 * step


def verify(
    submap: FloatArray,
    current: FloatArray,
    guess: Pose2D,
    candidate: int,
    settings: LoopClosureSettings,
    matcher: Any,
    *,
    range_noise: RangeNoise = NO_RANGE_NOISE,
    window: tuple[float, float] | None = None,
) -> LoopMatch | None:
    """Match ``current`` (robot frame of the current keyframe, m) onto ``submap`` (robot frame of keyframe
    ``candidate``) from ``guess`` (the current keyframe in the candidate's frame, from the graph); a
    :class:`LoopMatch` when it passes (module docstring), else ``None``. ``matcher`` is a scan-matching
    kernel (``apply(reference, current, initial) -> Match``). ``window``: half-widths ``(m, rad)`` of a
    narrower search that the graph's knowledge of the relative pose allows
    (:func:`shared.slam.window.search_window`); where its plausible cells reach its border, the
    settings' whole window is searched instead, so a narrow search never cuts a spread short."""
    sub = submap[np.isfinite(submap).all(axis=1)]
    cur = current[np.isfinite(current).all(axis=1)]
    if len(sub) < MIN_PAIRS or len(cur) < MIN_PAIRS:
        return None
    reach = float(np.percentile(np.hypot(cur[:, 0], cur[:, 1]), 90))
    # a rotation step moving the far returns by about one cell
    coarse_step = min(max(0.1 / max(reach, 0.5), 0.004), 0.035)
    whole = (settings.window_m, settings.window_rad)
    used = whole if window is None else (min(window[0], whole[0]), min(window[1], whole[1]))
    coarse, scores, cell, plausible = _coarse(sub, cur, guess, used, coarse_step)
    if used != whole and _reaches_border(plausible, coarse, guess, used[1], coarse_step):
        used = whole
        coarse, scores, cell, plausible = _coarse(sub, cur, guess, used, coarse_step)
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
    edge = used[0] - 0.1
    if used[0] > 0.15 and (abs(shift.x_m) > edge or abs(shift.y_m) > edge):
        return None  # on the window's border: the best place may lie beyond it
    if abs(math.remainder(pose.theta_rad - guess.theta_rad, math.tau)) > used[1] + 0.02:
        return None
    info = match_information(
        sub, cur, pose, inlier_m=settings.inlier_m, range_noise=range_noise, tree=cKDTree(sub)
    )
    if info.inlier_share < settings.min_inlier_share or info.pairs < MIN_PAIRS:
        return None
    # the spread on the fine grid round the pose, or on the whole window where the surface is flat
    # beyond the fine one (a corridor: the places along it score alike for metres)
    wide = spread_of(plausible, COARSE_CELL_M, cell)
    fine_spread = spread(sub, cur, pose, coarse_step / 4.0)
    if wide is not None:
        fine_spread[:2, :2] += wide
    return LoopMatch(candidate, pose, info.inlier_share, fine_spread)


def chain_covariance(poses: Sequence[Pose2D], covariances: Sequence[FloatArray] | FloatArray) -> FloatArray:
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
