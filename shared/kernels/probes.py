"""Probe inputs: the point sets and scans the conformance battery and the dry run feed to kernels.

Everything here is deterministic (seeded) and pure; the arrays returned are fresh unless said otherwise.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from shared.types import URG04LX, FloatArray, Pose2D, Scan

__all__ = ["MOTION", "moved_copy", "points_to_scan", "readonly", "room_scan", "wall_points"]

#: Motion between the reference and the current scan fed to scan matchers.
MOTION = Pose2D(0.05, -0.03, 0.02)


def points_to_scan(points: FloatArray) -> Scan:
    """A URG-04LX scan whose returns are ``points`` (snapped to the nearest beam; non-finite rows -> inf).

    O(N + beams).
    """
    ranges = np.full(URG04LX.beam_count, np.nan)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    finite = np.all(np.isfinite(pts), axis=1)
    r = np.hypot(pts[finite, 0], pts[finite, 1])
    beam = np.rint(
        (np.arctan2(pts[finite, 1], pts[finite, 0]) - URG04LX.angle_min_rad) / URG04LX.angle_increment_rad
    ).astype(int)
    ok = (beam >= 0) & (beam < URG04LX.beam_count)
    ranges[beam[ok]] = r[ok]
    if (~finite).any():
        ranges[: int((~finite).sum())] = np.inf
    return Scan.from_geometry(URG04LX, ranges)


def moved_copy(points: FloatArray) -> FloatArray:
    """The "current scan" for scan matchers: ``points`` seen after the robot moved by ``MOTION^-1``. O(N)."""
    with np.errstate(invalid="ignore"):
        return MOTION.transform_points(np.asarray(points, dtype=np.float64))


def wall_points(n: int = 1000, seed: int = 0) -> FloatArray:
    """``n`` points along a wall 2 m in front of the scanner, y from -1.5 to 1.5 m, 2 mm noise (seeded)."""
    rng = np.random.default_rng(seed)
    y = np.linspace(-1.5, 1.5, n)
    return np.column_stack([2.0 + rng.normal(0, 0.002, n), y])


def readonly(arr: FloatArray) -> FloatArray:
    """A read-only float64 copy of ``arr`` (kernels must accept read-only input)."""
    out = np.array(arr, dtype=np.float64, copy=True)
    out.setflags(write=False)
    return out


@lru_cache(maxsize=1)
def room_scan() -> Scan:
    """A URG-04LX scan in the default world with 5 % clutter returns (seeded, cached; scans are immutable)."""
    from shared.sim import RangeNoise, default_world, simulate_scan

    rng = np.random.default_rng(1)
    return simulate_scan(default_world(), Pose2D(4.5, 2.0, np.pi), rng, RangeNoise(outlier_rate=0.05))
