"""Ray-cast laser scans of a :class:`World` with URG-04LX range noise and clutter returns."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from shared.sim.world import World
from shared.types import URG04LX, BeamGeometry, FloatArray, Pose2D, Scan

__all__ = ["RangeNoise", "ray_wall_hits", "raycast", "simulate_scan"]


@dataclass(frozen=True, slots=True)
class RangeNoise:
    """Range noise after the paper's Table 1: +-25 mm below 1 m, +-2.5 % of the range beyond.

    The quoted accuracy is read as two standard deviations. ``outlier_rate`` is the share of beams that
    return from clutter somewhere between the scanner and the wall (uniform in range).
    """

    near_accuracy_m: float = 0.025
    far_accuracy_ratio: float = 0.025
    near_limit_m: float = 1.0
    outlier_rate: float = 0.05

    def sigma_m(self, range_m: FloatArray) -> FloatArray:
        """Standard deviation of a range reading at ``range_m``."""
        acc = np.where(range_m < self.near_limit_m, self.near_accuracy_m, self.far_accuracy_ratio * range_m)
        return np.asarray(acc / 2.0)


def raycast(walls: FloatArray, origin_xy: tuple[float, float], angles_rad: FloatArray) -> FloatArray:
    """Distance from ``origin_xy`` along each world-frame angle to the nearest wall (inf if none).

    Vectorised segment-ray intersection, O(beams x walls).
    """
    dist, _u = ray_wall_hits(walls, origin_xy, angles_rad)
    return np.asarray(dist.min(axis=1))


def ray_wall_hits(
    walls: FloatArray, origin_xy: tuple[float, float], angles_rad: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Distance ``(B, W)`` from ``origin_xy`` along each world-frame angle to each wall (inf where the ray
    misses it) and where along the wall it hits (``u`` in 0..1 from its first end point). O(beams x walls).
    """
    ox, oy = origin_xy
    dx, dy = np.cos(angles_rad)[:, None], np.sin(angles_rad)[:, None]
    ax, ay = walls[:, 0] - ox, walls[:, 1] - oy
    ex, ey = walls[:, 2] - walls[:, 0], walls[:, 3] - walls[:, 1]
    denom = dx * ey - dy * ex
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (ax * ey - ay * ex) / denom
        u = (ax * dy - ay * dx) / denom
    hit = (np.abs(denom) > 1e-12) & (t > 0.0) & (u >= 0.0) & (u <= 1.0)
    return np.where(hit, t, np.inf), u


def simulate_scan(
    world: World,
    pose: Pose2D,
    rng: np.random.Generator,
    noise: RangeNoise | None = None,
    geometry: BeamGeometry = URG04LX,
    stamp_s: float = 0.0,
    laser_offset: Pose2D | None = None,
    odometry: Pose2D | None = None,
) -> Scan:
    """One scan from a scanner at ``pose`` (robot pose composed with ``laser_offset``) in ``world``.

    Walls beyond the range window give no return (NaN). The scan's ``odometry`` is ``odometry`` if given
    (what the robot believes, e.g. integrated encoder ticks), else the true ``pose``. Deterministic for a
    given ``rng`` state; O(beams x walls).
    """
    noise = noise or RangeNoise()
    sensor = pose @ laser_offset if laser_offset is not None else pose
    angles = geometry.angles_rad()
    true = raycast(world.walls, (sensor.x_m, sensor.y_m), angles + sensor.theta_rad)
    finite = np.isfinite(true)
    ranges = np.where(finite, true, np.nan)
    sigma = noise.sigma_m(np.where(finite, true, 0.0))
    ranges = ranges + rng.normal(0.0, 1.0, ranges.shape) * sigma
    clutter = finite & (rng.random(ranges.shape) < noise.outlier_rate)
    clutter_high = np.maximum(np.where(finite, true, 1.0), geometry.range_min_m)
    ranges = np.where(clutter, rng.uniform(geometry.range_min_m, clutter_high), ranges)
    ranges = np.where((ranges >= geometry.range_min_m) & (ranges <= geometry.range_max_m), ranges, np.nan)
    return Scan.from_geometry(
        geometry, ranges, stamp_s=stamp_s, odometry=pose if odometry is None else odometry
    )
