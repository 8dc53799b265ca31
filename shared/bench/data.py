"""Benchmark data: a simulated URG-04LX scan (online step) and a 9-scan offline batch (paper §3 modes)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from shared.sim import RangeNoise, World, default_world, simulate_scan
from shared.types import FloatArray, IntArray, Pose2D, Scan

__all__ = ["BenchData", "make_bench_data"]


@dataclass(frozen=True, slots=True)
class BenchData:
    """Inputs of the kernel benchmark.

    ``scan``/``previous_scan`` are consecutive scans; ``true_motion`` maps the current scanner frame into the
    previous one and ``odometry_motion`` is that motion with odometry error (ICP's starting guess).
    ``batch_points`` are 9 consecutive scans' returns in the world frame (offline mode, N_smax = 9).
    """

    world: World
    scan: Scan
    previous_scan: Scan
    true_motion: Pose2D
    odometry_motion: Pose2D
    batch_points: FloatArray
    batch_scans: tuple[Scan, ...]
    batch_poses: tuple[Pose2D, ...]


def make_bench_data(seed: int = 0, outlier_rate: float = 0.05) -> BenchData:
    """Simulate the benchmark data in :func:`shared.sim.default_world`; deterministic for ``seed``."""
    rng = np.random.default_rng(seed)
    world = default_world()
    noise = RangeNoise(outlier_rate=outlier_rate)
    # Stand in the big room looking east at the far wall and the box: all 682 beams return.
    poses = tuple(Pose2D(6.0 + 0.08 * i, 2.0 + 0.01 * i, 0.02 * i) for i in range(10))
    scans = tuple(simulate_scan(world, p, rng, noise, stamp_s=0.1 * i) for i, p in enumerate(poses))
    previous, current = scans[0], scans[1]
    true_motion = poses[0].between(poses[1])
    odometry_motion = true_motion @ Pose2D(0.03, -0.02, np.deg2rad(2.0))
    batch: list[FloatArray] = []
    for pose, scan in zip(poses[1:], scans[1:], strict=True):
        pts, _ = scan.to_points()
        batch.append(pose.transform_points(pts))
    return BenchData(
        world, current, previous, true_motion, odometry_motion, np.vstack(batch), scans[1:], poses[1:]
    )


def batch_groups(data: BenchData, labels_per_scan: list[IntArray]) -> IntArray:
    """Concatenate per-scan segment labels into batch-wide group ids (each scan's labels offset)."""
    out: list[IntArray] = []
    offset = 0
    for labels in labels_per_scan:
        shifted = np.where(labels >= 0, labels + offset, -1)
        out.append(shifted)
        offset += int(labels.max()) + 1 if labels.size and labels.max() >= 0 else 0
    return np.concatenate(out) if out else np.zeros(0, dtype=np.intp)
