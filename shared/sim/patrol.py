"""A simulated robot that patrols its world's path: out along it, back, and round again.

:func:`patrol_scans` patrols a static :class:`World`; :func:`scene_patrol_scans` a world of the scenario
suite (:mod:`shared.sim.worlds`: glass, people walking, a door that opens ...), driven with that kind's
odometry error model while the scene's clock runs on. Each lap is simulated when it starts (O(lap)
memory, so "until stopped" is fine). Time stamps run on, and the odometry runs on across laps: each lap's
encoder-integrated poses are chained to where the previous lap's ended, as a robot's wheel odometry would
be, drift included. Between laps the robot turns in place to face its first leg again.
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Iterator
from dataclasses import replace

import numpy as np

from shared.errors import InvalidInputError
from shared.odometry import MINES_ROVER
from shared.sim.path import plan_path
from shared.sim.run import simulate_run
from shared.sim.scans import RangeNoise
from shared.sim.world import World
from shared.types import Pose2D, Scan

__all__ = ["patrol_lap_steps", "patrol_scans", "scene_patrol", "scene_patrol_scans"]

_TURN_RATE_RADPS = 0.8  # as plan_path turns in place
_RATE_HZ = 10.0


def patrol_scans(
    world: World, *, seed: int = 0, laps: int = 0, noise: RangeNoise | None = None
) -> Iterator[Scan]:
    """Scans of ``laps`` out-and-back patrols of ``world.knots`` (0: forever) at 10 Hz; lap ``n`` draws its
    noise from ``seed + n``. O(beams x walls) per scan."""
    if laps < 0:
        raise InvalidInputError(f"patrol laps = {laps}: expected 0 (forever) or a positive count")
    tour, lap = _tour_and_lap(world)
    odo_end: Pose2D | None = None
    stamp0 = 0.0
    n = 0
    while laps == 0 or n < laps:
        run = simulate_run(world, tour if n == 0 else lap, seed=seed + n, noise=noise or RangeNoise())
        first = run.scans[0].odometry
        for scan in run.scans:
            odo = _chain(odo_end, first, scan.odometry)
            yield replace(scan, stamp_s=stamp0 + scan.stamp_s, odometry=odo)
        odo_end = _chain(odo_end, first, run.scans[-1].odometry)
        stamp0 += run.scans[-1].stamp_s + 1.0 / _RATE_HZ
        n += 1


def scene_patrol_scans(
    kind: str,
    *,
    seed: int = 0,
    laps: int = 0,
    odometry: str | None = None,
    noise: RangeNoise | None = None,
) -> Iterator[Scan]:
    """:func:`scene_patrol`'s scans alone."""
    for scan, _truth in scene_patrol(kind, seed=seed, laps=laps, odometry=odometry, noise=noise):
        yield scan


def scene_patrol(
    kind: str,
    *,
    seed: int = 0,
    laps: int = 0,
    odometry: str | None = None,
    noise: RangeNoise | None = None,
) -> Iterator[tuple[Scan, Pose2D]]:
    """Scans, each with the robot's true pose then (world frame), of ``laps`` patrols (0: forever) of the
    suite world ``kind`` drawn with ``seed``, at 10 Hz.

    Each lap drives the world's path out and back (a closed path, e.g. ``loop-block``: once round), then
    turns in place to face the first leg again. Odometry follows the kind's error model (or ``odometry``,
    a name of :data:`shared.sim.ODOMETRY_MODELS`), chained across laps like :func:`patrol_scans`; the
    scene's clock runs on, so people keep walking, an opened door stays open and moved furniture stays
    moved. Deterministic for ``(kind, seed)``. O(beams x walls) per scan, O(lap) memory.

    Raises :class:`InvalidInputError` for an unknown kind or odometry model or a negative ``laps``.
    """
    from shared.sim.odometry_errors import ODOMETRY_MODELS, odometry_from_truth
    from shared.sim.scene import simulate_scene_scan
    from shared.sim.worlds import KINDS, build_scene

    if laps < 0:
        raise InvalidInputError(f"patrol laps = {laps}: expected 0 (forever) or a positive count")
    scene = build_scene(kind, seed)  # validates kind and seed
    model = odometry or KINDS[kind].odometry
    if model not in ODOMETRY_MODELS:
        raise InvalidInputError(
            f"unknown odometry model {model!r}: expected one of {', '.join(ODOMETRY_MODELS)}"
        )
    knots = np.asarray(scene.knots, dtype=np.float64)
    closed = bool(np.allclose(knots[0], knots[-1]))
    tour = plan_path(knots if closed else np.vstack([knots, knots[-2::-1]]), rate_hz=_RATE_HZ)
    later = [*_turn_in_place(tour[-1], tour[0].theta_rad), *tour[1:]]
    streams = np.random.SeedSequence([zlib.crc32(kind.encode()), seed, 19]).spawn(2)
    odo_rng, scan_rng = (np.random.default_rng(s) for s in streams)
    odo_end: Pose2D | None = None
    step = 0
    n = 0
    while laps == 0 or n < laps:
        poses = tour if n == 0 else later
        _ticks, odo = odometry_from_truth(poses, MINES_ROVER, ODOMETRY_MODELS[model], odo_rng, _RATE_HZ)
        first = odo[0]
        for pose, o in zip(poses, odo, strict=True):
            laser = MINES_ROVER.laser_pose(pose)
            odo_pose = _chain(odo_end, first, o)
            scan, _hits = simulate_scene_scan(
                scene, laser, step / _RATE_HZ, scan_rng, noise, odometry=odo_pose
            )
            yield scan, pose
            step += 1
        odo_end = _chain(odo_end, first, odo[-1])
        n += 1


def patrol_lap_steps(world: World) -> tuple[int, int]:
    """Scans in the first lap of :func:`patrol_scans` and in every later lap (which starts with the turn
    in place): step ``i >= first`` is at the same place of the patrol as step ``i - later``."""
    tour, lap = _tour_and_lap(world)
    return len(tour), len(lap)


def _tour_and_lap(world: World) -> tuple[list[Pose2D], list[Pose2D]]:
    """The first lap's poses (out and back) and a later lap's (turn in place, then out and back)."""
    if world.knots is None:
        raise InvalidInputError(f"world '{world.name}' has no path knots to patrol")
    knots = np.asarray(world.knots, dtype=np.float64)
    tour = plan_path(np.vstack([knots, knots[-2::-1]]), rate_hz=_RATE_HZ)
    turn = _turn_in_place(tour[-1], tour[0].theta_rad)
    return list(tour), [*turn, *tour[1:]]


def _chain(end: Pose2D | None, first: Pose2D | None, pose: Pose2D | None) -> Pose2D | None:
    """``pose`` of a lap that began at ``first``, continued from the previous lap's ``end``."""
    if end is None or first is None or pose is None:
        return pose
    return end @ first.between(pose)


def _turn_in_place(at: Pose2D, to_theta_rad: float) -> list[Pose2D]:
    """Poses turning in place from ``at`` to heading ``to_theta_rad`` (first is ``at``)."""
    delta = math.remainder(to_theta_rad - at.theta_rad, math.tau)
    steps = max(1, math.ceil(abs(delta) / (_TURN_RATE_RADPS / _RATE_HZ)))
    return [Pose2D(at.x_m, at.y_m, at.theta_rad + delta * k / steps) for k in range(steps + 1)]
