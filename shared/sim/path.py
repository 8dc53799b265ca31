"""A predefined path driven like a differential-drive robot: straight legs at constant speed, turns in place.

Offline mode (paper §3) flushes its batch when the heading changes; this path makes heading changes happen
only at the knots, as a robot following waypoints does.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from shared.errors import InvalidInputError
from shared.types import Pose2D, wrap_angle

__all__ = ["plan_path"]


def _positive(name: str, value: float) -> float:
    if isinstance(value, bool) or not (
        isinstance(value, (int, float)) and math.isfinite(value) and value > 0
    ):
        raise InvalidInputError(f"plan_path {name} = {value!r}: expected a positive finite number")
    return float(value)


def _fractions(total: float, step: float) -> list[float]:
    """``step, 2 step, ...`` below ``total``, then ``total`` itself (empty if ``total`` is ~0)."""
    if total <= 1e-12:
        return []
    n = math.ceil(total / step - 1e-9)
    return [step * i for i in range(1, n)] + [total]


def plan_path(
    knots: ArrayLike,
    speed_mps: float = 0.4,
    turn_rate_radps: float = 0.8,
    rate_hz: float = 10.0,
) -> list[Pose2D]:
    """Robot poses sampled at ``rate_hz`` while driving through ``knots`` ``(K, 2)`` (metres), K >= 2.

    The robot starts on the first knot facing the second. Each leg is driven straight in steps of exactly
    ``speed_mps / rate_hz`` metres (the last step of a leg is shorter, so every knot is hit exactly); at
    each inner knot the robot turns in place by the smaller angle towards the next leg, in steps of
    ``turn_rate_radps / rate_hz`` radians (the last one shorter). Every step is either a pure translation
    or a pure rotation, and the heading changes only on the knots. O(number of poses).
    """
    speed = _positive("speed_mps", speed_mps)
    turn_rate = _positive("turn_rate_radps", turn_rate_radps)
    rate = _positive("rate_hz", rate_hz)
    pts = np.asarray(knots, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2 or pts.shape[0] < 2:
        raise InvalidInputError(f"plan_path knots have shape {pts.shape}: expected (K, 2) with K >= 2")
    if not np.all(np.isfinite(pts)):
        raise InvalidInputError("plan_path knots contain non-finite coordinates: expected finite metres")
    legs = np.diff(pts, axis=0)
    lengths = np.hypot(legs[:, 0], legs[:, 1])
    for j, length in enumerate(lengths):
        if length <= 1e-9:
            raise InvalidInputError(
                f"plan_path knots[{j + 1}] = {pts[j + 1].tolist()} repeats knots[{j}]: expected distinct "
                "consecutive knots"
            )
    headings = np.arctan2(legs[:, 1], legs[:, 0])
    step_m, step_rad = speed / rate, turn_rate / rate
    poses = [Pose2D(float(pts[0, 0]), float(pts[0, 1]), float(headings[0]))]
    for j, (length, heading) in enumerate(zip(lengths, headings, strict=True)):
        x0, y0 = float(pts[j, 0]), float(pts[j, 1])
        if j > 0:
            turn = wrap_angle(float(heading - headings[j - 1]))
            start = float(headings[j - 1])
            for a in _fractions(abs(turn), step_rad):
                poses.append(Pose2D(x0, y0, start + math.copysign(a, turn)))
            poses[-1] = Pose2D(x0, y0, float(heading))
        ux, uy = math.cos(heading), math.sin(heading)
        steps = _fractions(float(length), step_m)
        for s in steps[:-1]:
            poses.append(Pose2D(x0 + s * ux, y0 + s * uy, float(heading)))
        poses.append(Pose2D(float(pts[j + 1, 0]), float(pts[j + 1, 1]), float(heading)))
    return poses
