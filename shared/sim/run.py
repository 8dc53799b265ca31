"""Whole simulated runs: a robot drives a path through a :class:`World`, its encoders slip, its laser scans.

Each step yields the true pose, the encoder ticks (true wheel travel with slip noise, quantised), the
odometry pose integrated from those ticks (paper §2, eq. 9-11; what a real robot knows) and a scan taken at
the true laser pose but tagged with the odometry pose, as a real log would be.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from shared.errors import InvalidInputError
from shared.odometry import MINES_ROVER, DiffDrive
from shared.sim.path import plan_path
from shared.sim.scans import RangeNoise, simulate_scan
from shared.sim.world import World
from shared.types import URG04LX, BeamGeometry, FloatArray, IntArray, Pose2D, Scan, wrap_angle

__all__ = ["NO_SLIP", "SimRun", "SlipNoise", "simulate_run", "wheel_displacements_between"]


@dataclass(frozen=True, slots=True)
class SlipNoise:
    """Encoder error: measured tick increment = true increment x ``scale`` x N(1, ``sigma_ratio``).

    ``sigma_ratio`` is drawn independently per wheel per step (wheel slip, 2 % by default);
    ``scale_left``/``scale_right`` are systematic errors (e.g. a wrong wheel diameter), 1.0 for none.
    """

    sigma_ratio: float = 0.02
    scale_left: float = 1.0
    scale_right: float = 1.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.sigma_ratio) and self.sigma_ratio >= 0.0):
            raise InvalidInputError(
                f"SlipNoise.sigma_ratio = {self.sigma_ratio!r}: expected a finite ratio >= 0"
            )
        for name in ("scale_left", "scale_right"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise InvalidInputError(f"SlipNoise.{name} = {value!r}: expected a positive finite factor")


#: Ideal encoders: no slip, no systematic error (odometry = truth up to tick quantisation).
NO_SLIP = SlipNoise(0.0)
_DEFAULT_SLIP = SlipNoise()
_DEFAULT_NOISE = RangeNoise()


def wheel_displacements_between(start: Pose2D, end: Pose2D, tread_m: float) -> tuple[float, float]:
    """Left and right wheel travel (m) that takes a robot from ``start`` to ``end``: eq. 9-11 inverted. O(1).

    ``dD_r - dD_l = w dtheta`` and ``dD_r + dD_l = 2 ds``, with ``ds`` the displacement projected on the
    mid-step heading (exact for pure translations, pure rotations and constant-curvature arcs, the
    least-squares answer otherwise), so that :meth:`DiffDrive.step` with ``midpoint=True`` gives ``end``
    back.
    """
    d_theta = wrap_angle(end.theta_rad - start.theta_rad)
    mid = start.theta_rad + 0.5 * d_theta
    ds = (end.x_m - start.x_m) * math.cos(mid) + (end.y_m - start.y_m) * math.sin(mid)
    half = 0.5 * tread_m * d_theta
    return ds - half, ds + half


@dataclass(frozen=True, slots=True)
class SimRun:
    """One simulated run of N steps.

    ``scans[i]`` was taken at ``stamp_s = i / rate_hz`` from the true laser pose
    ``drive.laser_pose(true_poses[i])`` and carries ``odometry_poses[i]`` (robot frame, not laser) as its
    odometry. ``ticks`` ``(N, 2)`` int64 holds the cumulative encoder counts ``[left, right]``, 0 at step 0.
    """

    world: World
    drive: DiffDrive
    scans: tuple[Scan, ...]
    true_poses: tuple[Pose2D, ...]
    odometry_poses: tuple[Pose2D, ...]
    ticks: IntArray
    rate_hz: float = 10.0

    def __post_init__(self) -> None:
        for name in ("scans", "true_poses", "odometry_poses"):
            object.__setattr__(self, name, tuple(getattr(self, name)))
        n = len(self.scans)
        ticks = np.array(self.ticks, dtype=np.int64, copy=True)
        if len(self.true_poses) != n or len(self.odometry_poses) != n or ticks.shape != (n, 2):
            raise InvalidInputError(
                f"SimRun has {n} scans, {len(self.true_poses)} true poses, {len(self.odometry_poses)} "
                f"odometry poses and ticks of shape {ticks.shape}: expected N of each and ticks (N, 2)"
            )
        ticks.setflags(write=False)
        object.__setattr__(self, "ticks", ticks)

    def __len__(self) -> int:
        return len(self.scans)

    @property
    def stamps_s(self) -> FloatArray:
        """Scan time stamps (s), ``(N,)``."""
        return np.array([s.stamp_s for s in self.scans], dtype=np.float64)

    def trajectory(self, which: Literal["true", "odometry"] = "true") -> FloatArray:
        """Robot poses as ``(N, 4)`` rows ``[stamp_s, x_m, y_m, theta_rad]`` (the MapSnapshot layout)."""
        if which not in ("true", "odometry"):
            raise InvalidInputError(f"trajectory which = {which!r}: expected 'true' or 'odometry'")
        poses = self.true_poses if which == "true" else self.odometry_poses
        out = np.array([p.as_tuple() for p in poses], dtype=np.float64).reshape(-1, 3)
        return np.column_stack([self.stamps_s, out])


def _encoder_ticks(
    true_poses: Sequence[Pose2D], drive: DiffDrive, slip: SlipNoise, rng: np.random.Generator
) -> IntArray:
    """Cumulative integer ticks ``(N, 2)`` measured while driving ``true_poses``."""
    n = len(true_poses)
    d = np.zeros((n, 2), dtype=np.float64)
    for i in range(1, n):
        d[i] = wheel_displacements_between(true_poses[i - 1], true_poses[i], drive.tread_m)
    true_ticks = d / drive.metres_per_tick
    factor = 1.0 + slip.sigma_ratio * rng.standard_normal((n, 2))
    measured = true_ticks * factor * np.array([slip.scale_left, slip.scale_right])
    measured[0] = 0.0
    ticks: IntArray = np.rint(np.cumsum(measured, axis=0)).astype(np.int64)
    return ticks


def simulate_run(
    world: World,
    path: Sequence[Pose2D] | None = None,
    *,
    seed: int = 0,
    noise: RangeNoise = _DEFAULT_NOISE,
    drive: DiffDrive = MINES_ROVER,
    slip: SlipNoise = _DEFAULT_SLIP,
    geometry: BeamGeometry = URG04LX,
    rate_hz: float = 10.0,
) -> SimRun:
    """Drive ``path`` (default: :func:`plan_path` over ``world.knots`` at ``rate_hz``) through ``world``.

    Per step: true wheel travel from consecutive true poses (eq. 9-11 inverted), encoder ticks with
    multiplicative ``slip`` and integer quantisation of the cumulative count, the odometry pose integrated
    from the tick increments with ``drive`` (starting at the true first pose), and a scan with ``noise`` from
    the true laser pose. Slip and range noise draw from separate streams of ``seed``, so changing the slip
    leaves the scans' noise unchanged. Deterministic for a seed; O(N x beams x walls).
    """
    if not (math.isfinite(rate_hz) and rate_hz > 0.0):
        raise InvalidInputError(f"simulate_run rate_hz = {rate_hz!r}: expected a positive finite rate")
    if path is None:
        if world.knots is None:
            raise InvalidInputError(
                f"world '{world.name}' has no path knots: pass path= or give the world a 'path' entry"
            )
        path = plan_path(world.knots, rate_hz=rate_hz)
    true_poses = tuple(path)
    if not true_poses or not all(isinstance(p, Pose2D) for p in true_poses):
        raise InvalidInputError("simulate_run path: expected a non-empty sequence of Pose2D")
    slip_seq, scan_seq = np.random.SeedSequence(seed).spawn(2)
    ticks = _encoder_ticks(true_poses, drive, slip, np.random.default_rng(slip_seq))
    steps = np.diff(ticks, axis=0)
    odometry = [true_poses[0]]
    for d_left, d_right in steps.tolist():
        odometry.append(drive.step_ticks(odometry[-1], d_left, d_right))
    scan_rng = np.random.default_rng(scan_seq)
    scans = tuple(
        simulate_scan(
            world, drive.laser_pose(pose), scan_rng, noise, geometry, stamp_s=i / rate_hz, odometry=odo
        )
        for i, (pose, odo) in enumerate(zip(true_poses, odometry, strict=True))
    )
    return SimRun(world, drive, scans, true_poses, tuple(odometry), ticks, float(rate_hz))
