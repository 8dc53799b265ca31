"""A second chance for a scan match the gate refused: more starts, then the best good match.

ICP converges to the local minimum nearest its start. When the start (the odometry prediction) is several
degrees off, as in fast turns with slipping wheels or when the odometry stream stalls and then jumps, the
match from it is wrong or unconverged and the gate (:class:`shared.pipeline.gate.IcpGate`) refuses it.
:func:`rematch` then runs the matcher again from

1. the best pose of a correlative search around the prediction
   (:func:`shared.kernels.matching._search.correlative_search`; ``search_rad`` = 0 turns it off), which
   finds the right basin within +-``search_rad`` and +-``search_m`` whatever the local minima, and
2. any further starts the caller gives (the pipeline adds a constant-velocity prediction),

and returns the best of all the matches (the refused one included) that converged, have an inlier share
of at least ``rematch_min_inlier_ratio`` and a motion within ``rematch_max_m`` / ``rematch_max_rad`` of
the reference; the match from the prediction wins ties within ``rematch_margin``. ``None`` when none
qualifies: then odometry stands.

Pure: arrays and poses in, a :class:`~shared.kernels.results.Match` out. Cost: one search
(O(R T N), see its module) and ``1 + len(starts)`` matcher runs, on refused steps only (1-10 % of a log).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from shared.kernels.base import ScanMatchingKernel
from shared.kernels.matching._search import correlative_search
from shared.kernels.results import Match
from shared.pipeline.gate import IcpGate
from shared.types import FloatArray, Pose2D

__all__ = ["acceptable", "rematch"]


def acceptable(match: Match, gate: IcpGate) -> bool:
    """Whether a match may replace odometry on its own merits: converged, enough inliers, a possible motion
    (``pose`` is the motion from the reference scan's frame, m and rad)."""
    return (
        match.converged
        and match.inlier_ratio >= gate.rematch_min_inlier_ratio
        and math.hypot(match.pose.x_m, match.pose.y_m) <= gate.rematch_max_m
        and abs(match.pose.theta_rad) <= gate.rematch_max_rad
    )


def rematch(
    matcher: ScanMatchingKernel[Any],
    reference: FloatArray,
    current: FloatArray,
    guess: Pose2D,
    refused: Match,
    gate: IcpGate,
    starts: Sequence[Pose2D] = (),
) -> Match | None:
    """The best acceptable match of ``current`` onto ``reference`` (scanner frames, m) among ``refused``
    (the match from ``guess``) and the matcher run from a searched start and from ``starts``."""
    seeds = list(starts)
    if gate.search_rad > 0.0:
        coarse = correlative_search(
            reference, current, guess, rot_half_rad=gate.search_rad, xy_half_m=gate.search_m
        )
        seeds.insert(0, coarse.pose)
    tried = (refused, *(matcher.apply(reference, current, s) for s in seeds))
    candidates = [m for m in tried if acceptable(m, gate)]
    if not candidates:
        return None
    best = max(candidates, key=lambda m: m.inlier_ratio)
    if candidates[0] is refused and refused.inlier_ratio >= best.inlier_ratio - gate.rematch_margin:
        return refused
    return best
