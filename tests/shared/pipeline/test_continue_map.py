"""A pipeline continues a map made elsewhere (``Pipeline.continue_map``: the server's copy, taken by a new
Robot DB). Seeded walls come back exactly with their ids and later walls get larger ones; on the simulated
world a pipeline that continues at scan N from the walls and pose of one stepped through the first N scans
follows the uninterrupted pipeline within a few centimetres and keeps its wall count (no wall drawn twice);
a robot up to 5 cm or a degree off the pose given is put back on the map by the first step; seeding is
refused once a pipeline has stepped."""

from __future__ import annotations

import itertools
import math
from functools import cache

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.errors import LinemapError
from shared.pipeline import Pipeline, PipelineConfig
from shared.pipeline.wallmap import WallMap
from shared.sim import default_world, simulate_run
from shared.types import Pose2D, Scan

OFFSET = Pose2D(0.1, 0.0, 0.0)

coords = st.floats(-50.0, 50.0, allow_nan=False)


@st.composite
def seeded_walls(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray]:
    n = draw(st.integers(1, 30))
    ids = draw(st.lists(st.integers(0, 10_000), min_size=n, max_size=n, unique=True))
    rows = []
    for _ in range(n):
        x, y = draw(coords), draw(coords)
        length, angle = draw(st.floats(0.1, 20.0)), draw(st.floats(-math.pi, math.pi))
        rows.append([x, y, x + length * math.cos(angle), y + length * math.sin(angle)])
    return np.array(ids, dtype=np.int64), np.array(rows)


@settings(max_examples=60, deadline=None)
@given(seeded_walls())
def test_seeded_walls_come_back_with_their_ids_and_new_ones_follow(
    walls: tuple[np.ndarray, np.ndarray],
) -> None:
    ids, segs = walls
    m = WallMap()
    m.seed(ids, segs)
    got_ids, got_segs = m.all_walls()  # (the shown ones leave out the shorter of two crossing walls)
    np.testing.assert_array_equal(got_ids, ids)
    np.testing.assert_allclose(got_segs, segs, atol=1e-9)
    m.add_segments([[500.0, 500.0, 503.0, 500.0]], observations=3)
    assert m.all_walls()[0][-1] == ids.max() + 1


def test_seeded_walls_are_not_merged_with_each_other() -> None:
    # two faces of one thin wall, and two collinear pieces with a gap: distinct walls on the server stay so
    segs = np.array([[0, 0, 4, 0], [4, 0.05, 0, 0.05], [4.1, 0, 6, 0]], dtype=float)
    m = WallMap()
    m.seed(np.array([3, 7, 9]), segs)
    assert m.ids.tolist() == [3, 7, 9]


def test_seed_refuses_a_map_in_use_and_ids_that_repeat_and_leaves_out_what_is_no_wall() -> None:
    m = WallMap()
    with pytest.raises(ValueError, match="distinct"):
        m.seed(np.array([1, 1]), np.array([[0, 0, 1, 0], [0, 1, 1, 1]], dtype=float))
    with pytest.raises(ValueError, match="negative"):
        m.seed(np.array([-1]), np.array([[0, 0, 1, 0]], dtype=float))
    m.seed(np.array([1, 2, 3]), np.array([[0, 0, 1, 0], [0, 1, 0.01, 1], [np.nan, 0, 1, 1]]))
    assert m.ids.tolist() == [1]  # too short and not finite: left out, as add_segments leaves them
    with pytest.raises(ValueError, match="empty"):
        m.seed(np.array([5]), np.array([[0, 0, 1, 0]], dtype=float))


@cache
def _run(seed: int) -> tuple[tuple[Scan, ...], tuple[Pose2D, ...]]:
    scans = tuple(itertools.islice(simulate_run(default_world(), seed=seed).scans, 400))
    pipe = Pipeline(PipelineConfig(), laser_offset=OFFSET)
    return scans, tuple(pipe.step(s).pose for s in scans)


def _stepped(scans: tuple[Scan, ...]) -> Pipeline:
    pipe = Pipeline(PipelineConfig(), laser_offset=OFFSET)
    for s in scans:
        pipe.step(s)
    return pipe


@pytest.mark.parametrize(("seed", "n"), [(3, 60), (3, 250), (5, 150)])
def test_a_continued_map_follows_the_uninterrupted_run(seed: int, n: int) -> None:
    scans, through = _run(seed)
    first = _stepped(scans[:n])
    ids, segs = first.walls()
    cont = Pipeline(PipelineConfig(), laser_offset=OFFSET)
    cont.continue_map(ids, segs, first.pose, scans[n - 1].odometry)
    poses = [cont.step(s).pose for s in scans[n:]]
    off_m = max(math.hypot(a.x_m - b.x_m, a.y_m - b.y_m) for a, b in zip(poses, through[n:], strict=True))
    off_rad = max(
        abs(math.remainder(a.theta_rad - b.theta_rad, math.tau))
        for a, b in zip(poses, through[n:], strict=True)
    )
    assert off_m < 0.05 and off_rad < math.radians(0.5), (off_m, math.degrees(off_rad))
    uninterrupted = _stepped(scans)
    assert abs(len(cont.walls()[0]) - len(uninterrupted.walls()[0])) <= 1, "a wall drawn twice"
    # the continued walls keep their ids; the map's own new ones follow the largest
    kept = set(ids.tolist()) & set(cont.walls()[0].tolist())
    assert len(kept) >= len(ids) - 1
    assert all(i > ids.max() for i in set(cont.walls()[0].tolist()) - set(ids.tolist()))


@pytest.mark.parametrize("off", [Pose2D(0.05, 0.025, 0.0), Pose2D(0.0, 0.0, math.radians(1.0))])
def test_a_robot_a_little_off_the_pose_given_is_put_back_on_the_map(off: Pose2D) -> None:
    scans, through = _run(3)
    n = 250
    first = _stepped(scans[:n])
    ids, segs = first.walls()
    cont = Pipeline(PipelineConfig(), laser_offset=OFFSET)
    cont.continue_map(ids, segs, first.pose @ off, scans[n - 1].odometry)
    pose = cont.step(scans[n]).pose
    assert math.hypot(pose.x_m - through[n].x_m, pose.y_m - through[n].y_m) < 0.01


def test_a_pipeline_that_stepped_cannot_continue_a_map() -> None:
    scans, _ = _run(3)
    pipe = _stepped(scans[:2])
    with pytest.raises(LinemapError, match="before its first step"):
        pipe.continue_map(np.array([0]), np.array([[0.0, 0.0, 1.0, 0.0]]), Pose2D())
    with pytest.raises(LinemapError, match="cannot be taken"):
        Pipeline().continue_map(np.array([0, 0]), np.zeros((2, 4)), Pose2D())
