"""Shape and finiteness checks on what the exporters are handed (a :class:`MapSnapshot`, wall arrays)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from shared.errors import InvalidInputError
from shared.pipeline.snapshot import MapSnapshot
from shared.types import FloatArray, IntArray

__all__ = ["CheckedSnapshot", "check_rows", "check_snapshot"]


def check_rows(values: ArrayLike, width: int, name: str, what: str) -> FloatArray:
    """Return ``values`` as a finite float64 ``(N, width)`` array; ``(0, width)`` when empty. O(N).

    Raises :class:`InvalidInputError` naming ``name`` and the expected layout ``what`` otherwise.
    """
    try:
        arr = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"{name} is not numeric: expected (N, {width}) {what}") from exc
    if arr.size == 0:
        return np.zeros((0, width), dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != width:
        raise InvalidInputError(f"{name} has shape {arr.shape}: expected (N, {width}) {what}")
    bad = ~np.isfinite(arr).all(axis=1)
    if bad.any():
        row = int(np.flatnonzero(bad)[0])
        raise InvalidInputError(f"{name} row {row} is {arr[row].tolist()}: expected finite {what}")
    return arr


@dataclass(frozen=True, slots=True)
class CheckedSnapshot:
    """The arrays of a :class:`MapSnapshot` after :func:`check_snapshot` (same meaning and units)."""

    segments: FloatArray
    segment_ids: IntArray
    centroids: FloatArray
    trajectory: FloatArray
    pose_xy_theta: tuple[float, float, float]


def check_snapshot(snapshot: MapSnapshot) -> CheckedSnapshot:
    """Validate the arrays of ``snapshot`` (shapes, finite values, one id per segment). O(L + C + T)."""
    segments = check_rows(snapshot.segments, 4, "snapshot.segments", "[x0, y0, x1, y1] metres")
    centroids = check_rows(snapshot.centroids, 2, "snapshot.centroids", "[x, y] metres")
    trajectory = check_rows(
        snapshot.trajectory, 4, "snapshot.trajectory", "[stamp_s, x_m, y_m, theta_rad] rows"
    )
    ids = np.asarray(snapshot.segment_ids)
    if ids.size == 0:
        ids = np.zeros(0, dtype=np.intp)
    if ids.ndim != 1 or ids.shape[0] != segments.shape[0]:
        raise InvalidInputError(
            f"snapshot.segment_ids has shape {ids.shape}: expected ({segments.shape[0]},), one id per segment"
        )
    if not np.issubdtype(ids.dtype, np.integer):
        raise InvalidInputError(f"snapshot.segment_ids has dtype {ids.dtype}: expected integers")
    pose = snapshot.pose
    return CheckedSnapshot(
        segments, ids.astype(np.intp, copy=False), centroids, trajectory, (pose.x_m, pose.y_m, pose.theta_rad)
    )
