"""Run one mapper over a stream of scans and keep what the report measures: walls, trajectory, step times.

Both mappers see exactly the same scans. linemap's pipeline is told the laser's offset on the robot; the
EKF baseline estimates the laser's pose, so its odometry is moved to the laser first and its poses moved
back to the robot afterwards (``robot = laser @ offset^-1``), which makes the two trajectories comparable.
"""

from __future__ import annotations

import time
from collections.abc import Iterable
from dataclasses import dataclass, replace

import numpy as np

from shared.pipeline import IcpGate, Pipeline, PipelineConfig
from shared.slam import GraphMapper, LoopClosureSettings
from shared.types import FloatArray, Pose2D, Scan

__all__ = ["MapRun", "run_ekf", "run_linemap", "run_linemap_loop"]


@dataclass(frozen=True)
class MapRun:
    """One mapper's run: ``segments`` ``(L, 4)`` m (world frame), ``stamps_s`` ``(N,)``, robot ``poses``
    ``(N, 3)`` ``[x_m, y_m, theta_rad]``, ``step_ms`` ``(N,)`` (wall-clock time of each step), and for the
    EKF the number of landmarks after each step and ``filter_ms``, the part of each step spent in the
    filter (prediction, association, update, augmentation), i.e. without line extraction."""

    method: str
    segments: FloatArray
    stamps_s: FloatArray
    poses: FloatArray
    step_ms: FloatArray
    landmarks: FloatArray | None = None
    filter_ms: FloatArray | None = None

    @property
    def trajectory(self) -> FloatArray:
        """``(N, 4)`` ``[stamp_s, x_m, y_m, theta_rad]``."""
        return np.column_stack([self.stamps_s, self.poses]) if len(self.stamps_s) else np.zeros((0, 4))


def run_linemap(
    scans: Iterable[Scan],
    laser_offset: Pose2D | None = None,
    config: PipelineConfig | None = None,
    gate: IcpGate | None = None,
) -> MapRun:
    """linemap's pipeline, one ``step`` per scan (then ``flush``). O(scans x step)."""
    pipe = Pipeline(config or PipelineConfig(), laser_offset=laser_offset, icp_gate=gate or IcpGate())
    stamps: list[float] = []
    poses: list[tuple[float, float, float]] = []
    times: list[float] = []
    for scan in scans:
        t0 = time.perf_counter()
        result = pipe.step(scan)
        times.append((time.perf_counter() - t0) * 1e3)
        stamps.append(scan.stamp_s)
        poses.append(result.pose.as_tuple())
    pipe.flush()
    _ids, segments = pipe.walls()
    return MapRun(
        "linemap", np.asarray(segments, dtype=np.float64).reshape(-1, 4), *_arrays(stamps, poses, times)
    )


def run_linemap_loop(
    scans: Iterable[Scan],
    laser_offset: Pose2D | None = None,
    config: PipelineConfig | None = None,
    settings: LoopClosureSettings | None = None,
) -> MapRun:
    """linemap's pipeline under the keyframe pose graph with loop closure (:class:`shared.slam.GraphMapper`,
    as ``linemap map`` runs it): the trajectory is the graph's after its final batch optimisation, the
    walls those drawn again from it. ``step_ms`` is each online step's time (front end, keyframes, loop
    search and the incremental update). O(scans x step), twice (the map is drawn again)."""
    mapper = GraphMapper(
        lambda: Pipeline(config or PipelineConfig(), laser_offset=laser_offset, icp_gate=IcpGate()), settings
    )
    stamps: list[float] = []
    times: list[float] = []
    for scan in scans:
        t0 = time.perf_counter()
        mapper.step(scan)
        times.append((time.perf_counter() - t0) * 1e3)
        stamps.append(scan.stamp_s)
    snapshot = mapper.finish()
    poses = [tuple(row[1:]) for row in snapshot.trajectory]
    return MapRun(
        "linemap + loop closure",
        np.asarray(snapshot.segments, dtype=np.float64).reshape(-1, 4),
        *_arrays(stamps, poses, times),
    )


def run_ekf(
    scans: Iterable[Scan], laser_offset: Pose2D | None = None, params: object | None = None
) -> MapRun:
    """The line-segment EKF-SLAM baseline (:mod:`shared.baselines.ekf_lines`), one ``step`` per scan."""
    from shared.baselines.ekf_lines import EkfLineSlam
    from shared.baselines.ekf_params import EkfLineSlamParams

    offset = laser_offset or Pose2D()
    back = offset.inverse()
    slam = EkfLineSlam(params if isinstance(params, EkfLineSlamParams) else None)
    stamps: list[float] = []
    poses: list[tuple[float, float, float]] = []
    times: list[float] = []
    landmarks: list[float] = []
    for scan in scans:
        moved = scan if scan.odometry is None else replace(scan, odometry=scan.odometry @ offset)
        t0 = time.perf_counter()
        laser_pose = slam.step(moved)
        times.append((time.perf_counter() - t0) * 1e3)
        stamps.append(scan.stamp_s)
        poses.append((laser_pose @ back).as_tuple())
        landmarks.append(float(slam.n_landmarks))
    segments = np.asarray(slam.walls(), dtype=np.float64).reshape(-1, 4)
    filter_ms = np.asarray(slam.step_ms, dtype=np.float64) - np.asarray(slam.extract_ms, dtype=np.float64)
    return MapRun(
        "ekf-slam", segments, *_arrays(stamps, poses, times), np.asarray(landmarks), filter_ms.clip(min=0.0)
    )


def _arrays(
    stamps: list[float], poses: list[tuple[float, float, float]], times: list[float]
) -> tuple[FloatArray, FloatArray, FloatArray]:
    return (
        np.asarray(stamps, dtype=np.float64),
        np.asarray(poses, dtype=np.float64).reshape(-1, 3),
        np.asarray(times, dtype=np.float64),
    )
