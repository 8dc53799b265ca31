"""Where the agent's scans come from: ``sim``, ``sim:WORLD_FILE``, a log file, or ``urg:DEVICE``.

Sources are plain iterators of :class:`shared.types.Scan` (with odometry); pacing is the agent's job. A
source that cannot be opened raises :class:`SourceError` naming the spec and what was expected.

A simulated robot drives its world's path once, or patrols it ``laps`` times (0: until stopped): out along
the path, back along it, and round again, each lap simulated when it starts (O(lap) memory). The odometry
runs on across laps (each lap's encoder readings are chained to where the last lap's ended), as a robot's
wheel odometry would, drift included.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from robot_agent.errors import SourceError
from shared.errors import LinemapError
from shared.types import Pose2D, Scan

if TYPE_CHECKING:
    from shared.sim import World

__all__ = ["default_rate_hz", "open_scans"]

_TURN_RATE_RADPS = 0.8  # as shared.sim.plan_path turns in place
_RATE_HZ = 10.0


def default_rate_hz(spec: str) -> float:
    """The pace a source runs at unless told otherwise: the URG-04LX's 10 Hz."""
    return 10.0


def open_scans(spec: str, *, seed: int = 0, laps: int = 1) -> Iterator[Scan]:
    """Scans from ``spec`` (see the module docstring)."""
    if spec.startswith("urg:"):
        raise SourceError(
            f"source {spec!r}: the URG-04LX serial driver is not part of this version yet; use 'sim', "
            "'sim:WORLD_FILE' or a log file"
        )
    if laps != 1 and not (spec == "sim" or spec.startswith("sim:")):
        raise SourceError(
            f"source {spec!r}: laps = {laps} applies to simulated sources ('sim', 'sim:WORLD') only"
        )
    if spec == "sim" or spec.startswith("sim:"):
        from shared.sim import default_world, load_world, simulate_run

        try:
            world = default_world() if spec == "sim" else load_world(Path(spec[4:]))
        except LinemapError as exc:
            raise SourceError(f"source {spec!r}: {exc}") from None
        if laps == 1:
            yield from simulate_run(world, seed=seed).scans
        else:
            yield from _patrol(world, seed, laps)
        return
    from shared.io import open_log

    path = Path(spec)
    if not path.is_file():
        raise SourceError(
            f"source {spec!r}: no such file (expected 'sim', 'sim:WORLD_FILE', a log or 'urg:DEVICE')"
        )
    try:
        with open_log(path, None) as reader:
            yield from reader
    except LinemapError as exc:
        raise SourceError(f"source {spec!r}: {exc}") from None


def _patrol(world: World, seed: int, laps: int) -> Iterator[Scan]:
    """Out and back along ``world.knots``, ``laps`` times (0: forever), one continuous drive."""
    from shared.sim import plan_path, simulate_run

    if world.knots is None:
        raise SourceError(f"world '{world.name}' has no path to patrol")
    knots = np.asarray(world.knots, dtype=np.float64)
    tour = plan_path(np.vstack([knots, knots[-2::-1]]), rate_hz=_RATE_HZ)
    # Back at the start facing the way it came: turn in place to face the first leg again.
    turn = _turn_in_place(tour[-1], tour[0].theta_rad)
    lap = [*turn, *tour[1:]]
    odo_end: Pose2D | None = None
    stamp0 = 0.0
    n = 0
    while laps == 0 or n < laps:
        run = simulate_run(world, tour if n == 0 else lap, seed=seed + n)
        first = run.scans[0]
        for scan in run.scans:
            odo = scan.odometry
            if odo_end is not None and odo is not None and first.odometry is not None:
                odo = odo_end @ first.odometry.between(odo)
            yield replace(scan, stamp_s=stamp0 + scan.stamp_s, odometry=odo)
        last = run.scans[-1]
        odo_end = (
            last.odometry
            if odo_end is None or first.odometry is None or last.odometry is None
            else odo_end @ first.odometry.between(last.odometry)
        )
        stamp0 += last.stamp_s + 1.0 / _RATE_HZ
        n += 1


def _turn_in_place(at: Pose2D, to_theta_rad: float) -> list[Pose2D]:
    """Poses turning in place from ``at`` to heading ``to_theta_rad`` (first is ``at``)."""
    delta = math.remainder(to_theta_rad - at.theta_rad, math.tau)
    steps = max(1, math.ceil(abs(delta) / (_TURN_RATE_RADPS / _RATE_HZ)))
    return [Pose2D(at.x_m, at.y_m, at.theta_rad + delta * k / steps) for k in range(steps + 1)]
