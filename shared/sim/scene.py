"""Scenes: a world that changes over time and surfaces that give no return, ray-cast like :mod:`.scans`.

A :class:`Scene` holds

- ``walls`` ``(W, 4)`` with a ``surface`` per wall: :data:`MATTE` (returns the beam), :data:`GLASS` (the
  beam passes through and may return from whatever is behind) or :data:`BLACK` (absorbs the beam: no
  return, and nothing behind is seen);
- ``wall_times`` ``(W, 2)``: wall ``i`` exists for ``t_on <= t < t_off`` (``-inf``/``inf`` for a static
  wall), which models a door that opens (the closed leaf ends, the open leaf starts) and furniture moved
  between passes;
- ``people``: :class:`Walker` s, each seen by the laser as two legs (circles) that swing as it walks.

:func:`scene_raycast` gives, per beam, the true range, the index of the wall hit (-1 for none or a leg)
and where along it; :func:`simulate_scene_scan` adds the URG-04LX noise of :class:`.RangeNoise` and mixed
pixels (a beam straddling a depth edge returns a range between the near and the far surface). Pure
functions of numpy arrays, deterministic for a given ``rng`` state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from shared.errors import InvalidInputError
from shared.sim.scans import RangeNoise, ray_wall_hits
from shared.sim.world import World
from shared.types import URG04LX, BeamGeometry, FloatArray, IntArray, Pose2D, Scan

__all__ = [
    "BLACK",
    "GLASS",
    "MATTE",
    "Hits",
    "Scene",
    "Walker",
    "scene_raycast",
    "simulate_scene_scan",
]

MATTE, GLASS, BLACK = 0, 1, 2

_LEG_RADIUS_M = 0.06
_HIP_HALF_WIDTH_M = 0.10
_STRIDE_M = 0.7  # one full gait cycle per 2 strides


@dataclass(frozen=True, slots=True)
class Walker:
    """A person walking a polyline ``waypoints`` ``(K, 2)`` (m) at ``speed_mps``, from ``start_s`` on.

    With ``bounce`` the person turns at the last waypoint and walks back, forever; without it, the person
    is gone (left the scene) once the last waypoint is reached. Before ``start_s`` the person is not there.
    """

    waypoints: FloatArray
    speed_mps: float
    start_s: float = 0.0
    bounce: bool = True

    def __post_init__(self) -> None:
        pts = np.array(self.waypoints, dtype=np.float64, copy=True)
        if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 2 or not np.all(np.isfinite(pts)):
            raise InvalidInputError(f"Walker.waypoints has shape {pts.shape}: expected finite (K, 2), K >= 2")
        if not (math.isfinite(self.speed_mps) and self.speed_mps > 0.0):
            raise InvalidInputError(f"Walker.speed_mps = {self.speed_mps!r}: expected a positive speed")
        pts.setflags(write=False)
        object.__setattr__(self, "waypoints", pts)

    def position(self, t_s: float) -> tuple[FloatArray, float] | None:
        """Where the person is at ``t_s`` and the heading of the walk (rad); ``None`` if not in the scene."""
        if t_s < self.start_s:
            return None
        legs = np.diff(self.waypoints, axis=0)
        lengths = np.hypot(legs[:, 0], legs[:, 1])
        total = float(lengths.sum())
        s = (t_s - self.start_s) * self.speed_mps
        pts, rev = self.waypoints, False
        if self.bounce:
            s = s % (2.0 * total)
            if s > total:
                s, rev = 2.0 * total - s, True
        elif s > total:
            return None
        cum = np.concatenate([[0.0], np.cumsum(lengths)])
        j = min(int(np.searchsorted(cum, s, side="right")) - 1, len(lengths) - 1)
        frac = (s - cum[j]) / lengths[j] if lengths[j] > 0 else 0.0
        xy = pts[j] + legs[j] * frac
        heading = math.atan2(legs[j, 1], legs[j, 0]) + (math.pi if rev else 0.0)
        return np.asarray(xy), heading

    def legs(self, t_s: float) -> FloatArray:
        """Centres ``(2, 2)`` of the two legs at ``t_s`` (empty ``(0, 2)`` if not in the scene)."""
        where = self.position(t_s)
        if where is None:
            return np.zeros((0, 2))
        xy, heading = where
        along = np.array([math.cos(heading), math.sin(heading)])
        side = np.array([-along[1], along[0]])
        swing = 0.15 * math.sin(2.0 * math.pi * (t_s - self.start_s) * self.speed_mps / (2.0 * _STRIDE_M))
        return np.vstack(
            [xy + side * _HIP_HALF_WIDTH_M + along * swing, xy - side * _HIP_HALF_WIDTH_M - along * swing]
        )


@dataclass(frozen=True, slots=True)
class Scene:
    """Walls with surfaces and lifetimes, walkers, the robot's path ``knots`` and mixed-pixel settings.

    ``mixed_pixel_rate`` is the chance that a beam straddling a depth edge of more than
    ``mixed_pixel_jump_m`` returns a range uniformly between the near and the far surface.
    """

    walls: FloatArray
    name: str
    knots: FloatArray
    surface: IntArray | None = None
    wall_times: FloatArray | None = None
    people: tuple[Walker, ...] = ()
    floor_area_m2: float = 1.0
    mixed_pixel_rate: float = 0.0
    mixed_pixel_jump_m: float = 0.05

    def __post_init__(self) -> None:
        walls = np.array(self.walls, dtype=np.float64, copy=True)
        if walls.ndim != 2 or walls.shape[1] != 4 or len(walls) == 0 or not np.all(np.isfinite(walls)):
            raise InvalidInputError(f"Scene.walls has shape {walls.shape}: expected finite (W, 4), W >= 1")
        n = len(walls)
        surface = np.zeros(n, np.int64) if self.surface is None else np.array(self.surface, np.int64)
        times = (
            np.tile([-np.inf, np.inf], (n, 1))
            if self.wall_times is None
            else np.array(self.wall_times, float)
        )
        if surface.shape != (n,) or not np.all(np.isin(surface, (MATTE, GLASS, BLACK))):
            raise InvalidInputError(f"Scene.surface: expected {n} values of MATTE, GLASS or BLACK")
        if times.shape != (n, 2) or np.any(np.isnan(times)) or np.any(times[:, 0] >= times[:, 1]):
            raise InvalidInputError(f"Scene.wall_times: expected ({n}, 2) rows t_on < t_off")
        knots = np.array(self.knots, dtype=np.float64, copy=True)
        if knots.ndim != 2 or knots.shape[1] != 2 or len(knots) < 2:
            raise InvalidInputError(f"Scene.knots has shape {knots.shape}: expected (K, 2), K >= 2")
        if not 0.0 <= self.mixed_pixel_rate <= 1.0:
            raise InvalidInputError(f"Scene.mixed_pixel_rate = {self.mixed_pixel_rate!r}: expected 0..1")
        for name, arr in (("walls", walls), ("surface", surface), ("wall_times", times), ("knots", knots)):
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "people", tuple(self.people))

    def present(self, t_s: float) -> FloatArray:
        """Boolean mask ``(W,)`` of the walls that exist at ``t_s``."""
        assert self.wall_times is not None
        return np.asarray((self.wall_times[:, 0] <= t_s) & (t_s < self.wall_times[:, 1]))

    def truth(self, t_end_s: float) -> tuple[World, IntArray]:
        """The ground truth at ``t_end_s`` (every wall that exists then, glass and black included) and the
        scene index of each of its walls."""
        idx = np.flatnonzero(self.present(t_end_s))
        return World(self.walls[idx], self.floor_area_m2, self.name, self.knots), idx


@dataclass(frozen=True, slots=True)
class Hits:
    """Noise-free answer of :func:`scene_raycast`: range (inf: nothing), wall index (-1: none or a
    person), position along the wall (0..1), and whether a person's leg is hit."""

    range_m: FloatArray
    wall: IntArray
    u: FloatArray
    person: FloatArray


def _ray_circles(centres: FloatArray, radius: float, ox: float, oy: float, angles: FloatArray) -> FloatArray:
    """Distance ``(B,)`` along each ray to the nearest circle (inf where missed; circles round the origin
    are ignored)."""
    if len(centres) == 0:
        return np.full(angles.shape, np.inf)
    dx, dy = np.cos(angles)[:, None], np.sin(angles)[:, None]
    cx, cy = centres[:, 0] - ox, centres[:, 1] - oy
    b = dx * cx + dy * cy
    c = cx * cx + cy * cy - radius * radius
    disc = b * b - c
    with np.errstate(invalid="ignore"):
        t = b - np.sqrt(disc)
    ok = (disc >= 0.0) & (c > 0.0) & (t > 0.0)
    return np.asarray(np.where(ok, t, np.inf).min(axis=1))


def scene_raycast(scene: Scene, origin_xy: tuple[float, float], angles_rad: ArrayLike, t_s: float) -> Hits:
    """True ranges at time ``t_s`` from ``origin_xy`` along world-frame ``angles_rad``. O(beams x walls).

    Glass walls are passed through; a black wall stops the beam with no return (range inf, its index in
    ``wall`` so a caller can tell). Legs of walkers are circles of 6 cm radius.
    """
    assert scene.surface is not None
    angles = np.asarray(angles_rad, dtype=np.float64)
    ox, oy = origin_xy
    live = scene.present(t_s) & (scene.surface != GLASS)
    idx = np.flatnonzero(live)
    dist, u = ray_wall_hits(scene.walls[idx], (ox, oy), angles)
    if len(idx):
        k = dist.argmin(axis=1)
        rows = np.arange(len(angles))
        rng = dist[rows, k]
        wall = np.where(np.isfinite(rng), idx[k], -1)
        along = np.where(np.isfinite(rng), u[rows, k], np.nan)
    else:
        rng, wall, along = (
            np.full(angles.shape, np.inf),
            np.full(angles.shape, -1),
            np.full(angles.shape, np.nan),
        )
    legs = [w.legs(t_s) for w in scene.people]
    centres = np.vstack(legs) if legs else np.zeros((0, 2))
    leg = _ray_circles(centres, _LEG_RADIUS_M, ox, oy, angles)
    person = leg < rng
    rng = np.where(person, leg, rng)
    wall = np.where(person, -1, wall)
    along = np.where(person, np.nan, along)
    black = (wall >= 0) & (scene.surface[np.maximum(wall, 0)] == BLACK)
    rng = np.where(black, np.inf, rng)
    return Hits(np.asarray(rng), np.asarray(wall, dtype=np.int64), np.asarray(along), np.asarray(person))


def simulate_scene_scan(
    scene: Scene,
    pose: Pose2D,
    t_s: float,
    rng: np.random.Generator,
    noise: RangeNoise | None = None,
    geometry: BeamGeometry = URG04LX,
    odometry: Pose2D | None = None,
) -> tuple[Scan, Hits]:
    """One scan from a scanner at ``pose`` (the laser's pose) at time ``t_s``, and its noise-free hits.

    Noise as :func:`shared.sim.simulate_scan` (Gaussian range noise, clutter returns); then mixed pixels:
    with ``scene.mixed_pixel_rate`` > 0 each beam is also cast at its footprint's two edges (+-1/4 beam
    step) and, where they differ by more than ``scene.mixed_pixel_jump_m``, returns with that chance a
    range uniform between them. Beams outside the range window give NaN. O(beams x walls).
    """
    noise = noise or RangeNoise()
    angles = geometry.angles_rad() + pose.theta_rad
    origin = (pose.x_m, pose.y_m)
    hits = scene_raycast(scene, origin, angles, t_s)
    true = hits.range_m
    finite = np.isfinite(true)
    sigma = noise.sigma_m(np.where(finite, true, 0.0))
    ranges = np.where(finite, true, np.nan) + rng.normal(0.0, 1.0, true.shape) * sigma
    clutter = finite & (rng.random(true.shape) < noise.outlier_rate)
    high = np.maximum(np.where(finite, true, 1.0), geometry.range_min_m)
    ranges = np.where(clutter, rng.uniform(geometry.range_min_m, high), ranges)
    if scene.mixed_pixel_rate > 0.0:
        quarter = 0.25 * geometry.angle_increment_rad
        lo = scene_raycast(scene, origin, angles - quarter, t_s).range_m
        hi = scene_raycast(scene, origin, angles + quarter, t_s).range_m
        near, far = np.minimum(lo, hi), np.maximum(lo, hi)
        jump = np.where(np.isfinite(far), far - np.where(np.isfinite(near), near, far), 0.0)
        edge = jump > scene.mixed_pixel_jump_m
        mixed = edge & (rng.random(true.shape) < scene.mixed_pixel_rate)
        between = near + rng.random(true.shape) * np.where(edge, jump, 0.0)
        ranges = np.where(mixed, between, ranges)
    window = (ranges >= geometry.range_min_m) & (ranges <= geometry.range_max_m)
    ranges = np.where(window, ranges, np.nan)
    scan = Scan.from_geometry(geometry, ranges, stamp_s=t_s, odometry=pose if odometry is None else odometry)
    return scan, hits
