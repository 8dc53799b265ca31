"""Odometry error models for the scenario suite: random slip, worn wheels (scale and heading bias) and
slip bursts (a wheel spinning on the spot for a moment).

:func:`odometry_from_truth` turns true poses into the cumulative encoder ticks a robot would count and the
odometry it would integrate from them (paper §2, eq. 9-11), as :func:`shared.sim.simulate_run` does, with
the error terms of an :class:`OdometryErrors`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from shared.errors import InvalidInputError
from shared.odometry import DiffDrive
from shared.sim.run import wheel_displacements_between
from shared.types import IntArray, Pose2D

__all__ = ["BURSTS", "ODOMETRY_MODELS", "PERFECT", "SLIP", "WORN", "OdometryErrors", "odometry_from_truth"]


@dataclass(frozen=True, slots=True)
class OdometryErrors:
    """Encoder errors per wheel and step: measured = true x ``scale`` x N(1, ``slip_sigma_ratio``), plus
    bursts.

    ``scale_left`` / ``scale_right`` != 1 are worn wheels: a common factor scales every distance, a
    difference between them bends every straight leg (a heading bias). Bursts start at
    ``burst_rate_hz`` (Poisson) and last ``burst_steps`` steps; in a burst one wheel, drawn at random,
    counts ``burst_extra_m`` (drawn uniformly in the range) more travel than it made, spread over the
    steps: a wheel spinning on the spot.
    """

    name: str
    slip_sigma_ratio: float = 0.02
    scale_left: float = 1.0
    scale_right: float = 1.0
    burst_rate_hz: float = 0.0
    burst_steps: int = 4
    burst_extra_m: tuple[float, float] = (0.01, 0.03)

    def __post_init__(self) -> None:
        checks = [
            ("slip_sigma_ratio", self.slip_sigma_ratio, self.slip_sigma_ratio >= 0.0),
            ("scale_left", self.scale_left, self.scale_left > 0.0),
            ("scale_right", self.scale_right, self.scale_right > 0.0),
            ("burst_rate_hz", self.burst_rate_hz, self.burst_rate_hz >= 0.0),
        ]
        for name, value, ok in checks:
            if not (math.isfinite(value) and ok):
                raise InvalidInputError(f"OdometryErrors.{name} = {value!r}: out of range")
        if self.burst_steps < 1 or not 0.0 <= self.burst_extra_m[0] <= self.burst_extra_m[1]:
            raise InvalidInputError("OdometryErrors burst: expected burst_steps >= 1 and 0 <= low <= high")


#: No error but tick quantisation.
PERFECT = OdometryErrors("perfect", slip_sigma_ratio=0.0)
#: Random slip, 2 % per wheel and step (the simulator's default).
SLIP = OdometryErrors("slip")
#: Worn wheels: 1 % random slip, the left wheel reads 0.5 % long, the right 0.1 % (distances 0.3 % long,
#: a heading bias of about 0.012 rad per metre driven).
WORN = OdometryErrors("worn", slip_sigma_ratio=0.01, scale_left=1.005, scale_right=1.001)
#: Slip bursts: 1 % random slip and a wheel spinning on the spot every ~8 s (1-3 cm of phantom travel,
#: 0.03-0.09 rad of heading each).
BURSTS = OdometryErrors("bursts", slip_sigma_ratio=0.01, burst_rate_hz=0.125)

#: The models by name.
ODOMETRY_MODELS: dict[str, OdometryErrors] = {m.name: m for m in (PERFECT, SLIP, WORN, BURSTS)}


def odometry_from_truth(
    true_poses: Sequence[Pose2D],
    drive: DiffDrive,
    errors: OdometryErrors,
    rng: np.random.Generator,
    rate_hz: float = 10.0,
) -> tuple[IntArray, list[Pose2D]]:
    """Cumulative ticks ``(N, 2)`` (0 at step 0) and the odometry poses integrated from them, starting at
    the true first pose. Deterministic for a given ``rng`` state; O(N)."""
    n = len(true_poses)
    if n == 0:
        raise InvalidInputError("odometry_from_truth: expected at least one pose")
    d = np.zeros((n, 2), dtype=np.float64)
    for i in range(1, n):
        d[i] = wheel_displacements_between(true_poses[i - 1], true_poses[i], drive.tread_m)
    factor = 1.0 + errors.slip_sigma_ratio * rng.standard_normal((n, 2))
    measured = d * factor * np.array([errors.scale_left, errors.scale_right])
    if errors.burst_rate_hz > 0.0:
        starts = np.flatnonzero(rng.random(n) < errors.burst_rate_hz / rate_hz)
        for start in starts.tolist():
            wheel = int(rng.integers(0, 2))
            extra = rng.uniform(*errors.burst_extra_m) * (1.0 if rng.random() < 0.5 else -1.0)
            stop = min(n, start + errors.burst_steps)
            measured[start:stop, wheel] += extra / errors.burst_steps
    measured[0] = 0.0
    ticks: IntArray = np.rint(np.cumsum(measured / drive.metres_per_tick, axis=0)).astype(np.int64)
    odometry = [true_poses[0]]
    for d_left, d_right in np.diff(ticks, axis=0).tolist():
        odometry.append(drive.step_ticks(odometry[-1], d_left, d_right))
    return ticks, odometry
