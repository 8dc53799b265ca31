"""The temporary map a pipeline exposes after each step (docs/design.md §9's "temporary map", in SI units)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from shared.types import FloatArray, IntArray, Pose2D

__all__ = ["MapSnapshot"]


@dataclass(frozen=True, slots=True)
class MapSnapshot:
    """The map after step ``version`` (an increasing integer), all in the world frame.

    ``segments`` ``(L, 4)`` ``[x0, y0, x1, y1]`` metres with stable integer ``segment_ids``; ``centroids``
    ``(C, 2)``; ``pose`` the robot's current pose; ``trajectory`` ``(T, 4)`` rows ``[stamp_s, x_m, y_m,
    theta_rad]``, one per scan stepped so far, in input order. Arrays are read-only.
    """

    version: int
    stamp_s: float
    segments: FloatArray
    segment_ids: IntArray
    centroids: FloatArray
    pose: Pose2D
    trajectory: FloatArray

    @classmethod
    def empty(cls) -> MapSnapshot:
        """The map before the first step."""
        out = cls(
            0, 0.0, np.zeros((0, 4)), np.zeros(0, dtype=np.intp), np.zeros((0, 2)), Pose2D(), np.zeros((0, 4))
        )
        for arr in (out.segments, out.segment_ids, out.centroids, out.trajectory):
            arr.setflags(write=False)
        return out
