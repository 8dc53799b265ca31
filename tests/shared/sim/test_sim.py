"""The simulator of the paper's artificial environment (enough for the kernel benchmark)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from shared.errors import InvalidInputError
from shared.sim import RangeNoise, World, default_path, default_world, simulate_scan
from shared.sim.scans import raycast
from shared.types import Pose2D


def test_raycast_hits_known_walls() -> None:
    walls = np.array([[2.0, -5.0, 2.0, 5.0], [-5.0, 3.0, 5.0, 3.0]])
    d = raycast(walls, (0.0, 0.0), np.array([0.0, math.pi / 2, math.pi, math.atan2(3.0, 2.0)]))
    np.testing.assert_allclose(d[:2], [2.0, 3.0])
    assert math.isinf(d[2])
    np.testing.assert_allclose(d[3], math.hypot(2.0, 3.0))


def test_noise_free_scan_lies_on_walls() -> None:
    world = default_world()
    pose = Pose2D(4.5, 2.0, math.pi)
    scan = simulate_scan(
        world,
        pose,
        np.random.default_rng(0),
        RangeNoise(near_accuracy_m=0.0, far_accuracy_ratio=0.0, outlier_rate=0.0),
    )
    pts, _ = scan.to_points()
    world_pts = pose.transform_points(pts)
    w = world.walls
    # distance of each point to the nearest wall segment
    a, b = w[:, :2], w[:, 2:]
    ab = b - a
    t = np.clip(((world_pts[:, None, :] - a) * ab).sum(-1) / (ab * ab).sum(-1), 0.0, 1.0)
    nearest = a + t[..., None] * ab
    dist = np.linalg.norm(world_pts[:, None, :] - nearest, axis=-1).min(axis=1)
    assert len(pts) > 600 and dist.max() < 1e-9


def test_seeded_and_outliers_in_front_of_walls() -> None:
    world, pose = default_world(), Pose2D(4.5, 2.0, math.pi)
    clean = simulate_scan(world, pose, np.random.default_rng(5), RangeNoise(0.0, 0.0, outlier_rate=0.0))
    noisy = simulate_scan(world, pose, np.random.default_rng(5), RangeNoise(0.0, 0.0, outlier_rate=0.3))
    again = simulate_scan(world, pose, np.random.default_rng(5), RangeNoise(0.0, 0.0, outlier_rate=0.3))
    assert np.array_equal(noisy.ranges_m, again.ranges_m, equal_nan=True)
    both = np.isfinite(clean.ranges_m) & np.isfinite(noisy.ranges_m)
    changed = both & (noisy.ranges_m != clean.ranges_m)
    assert 0.2 < changed.sum() / both.sum() < 0.4
    assert np.all(noisy.ranges_m[changed] < clean.ranges_m[changed])


def test_default_world_and_path() -> None:
    world = default_world()
    assert math.isclose(world.floor_area_m2, 40.0 + 6.4 - 0.64 - 0.36)
    path = default_path(50)
    assert len(path) == 50
    steps = [math.hypot(b.x_m - a.x_m, b.y_m - a.y_m) for a, b in itertools.pairwise(path)]
    assert max(steps) < 0.5


def test_world_validates_area_and_knots() -> None:
    walls = np.array([[0.0, 0.0, 1.0, 0.0]])
    with pytest.raises(InvalidInputError, match="floor_area_m2"):
        World(walls, 0.0)
    with pytest.raises(InvalidInputError, match=r"knots has shape \(1, 2\)"):
        World(walls, 1.0, knots=np.zeros((1, 2)))
    world = World(walls, 1.0, knots=[[0.0, 0.5], [0.5, 0.5]])  # type: ignore[arg-type]
    assert world.knots is not None and not world.knots.flags.writeable
