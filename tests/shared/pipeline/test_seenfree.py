"""Space seen free before: points where earlier beams passed through stay out of the map; walls the grid
was built from, grazing views and things that stay do not."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.pipeline import IcpGate, Pipeline, PipelineConfig
from shared.pipeline.seenfree import SeenFree, SeenFreeModel
from shared.sim.scene import Scene, Walker, simulate_scene_scan
from shared.types import URG04LX, Pose2D, Scan


def _box(x0: float, y0: float, x1: float, y1: float) -> list[list[float]]:
    return [[x0, y0, x1, y0], [x1, y0, x1, y1], [x1, y1, x0, y1], [x0, y1, x0, y0]]


def _scan_to_wall(distance_m: float, n: int = 181) -> Scan:
    """A scan from the origin facing +x of a wall across at x = ``distance_m`` (fan of +-45 degrees)."""
    angles = np.linspace(-math.pi / 4, math.pi / 4, n)
    return Scan(0.0, float(angles[0]), float(angles[1] - angles[0]), 0.02, 5.6, distance_m / np.cos(angles))


def test_a_point_where_beams_passed_is_flagged_and_the_wall_is_not() -> None:
    grid = SeenFree()
    for _ in range(6):
        grid.observe(Pose2D(), _scan_to_wall(3.0))
    pts = np.array([[1.5, 0.0], [2.5, 0.4], [3.0, 0.0], [3.0, 1.5], [2.9, 0.0], [3.5, 0.0], [-2.0, 0.0]])
    moved = grid.moved(pts)
    # passed through at 1.5 m and 2.5 m; the wall itself, 10 cm in front of it (inside the margin), behind
    # it and behind the scanner: not seen free
    assert moved.tolist() == [True, True, False, False, False, False, False]


def test_free_share_of_a_track_across_seen_space_and_of_the_wall() -> None:
    grid = SeenFree()
    for _ in range(6):
        grid.observe(Pose2D(), _scan_to_wall(3.0))
    segs = np.array(
        [
            [1.5, -0.8, 1.5, 0.8],  # a person's track across the fan: seen through
            [3.0, -1.0, 3.0, 1.0],  # the wall
            [1.5, 0.0, 4.5, 0.0],  # half in front of the wall, half behind it
        ]
    )
    share = grid.free_share(segs)
    assert share[0] == 1.0 and share[1] == 0.0
    assert 0.35 <= share[2] <= 0.5
    assert grid.free_share(np.zeros((0, 4))).shape == (0,)


def test_one_pass_is_not_enough_and_a_thing_that_stays_is_accepted() -> None:
    grid = SeenFree()
    grid.observe(Pose2D(), _scan_to_wall(3.0))
    box = np.array([[1.5, 0.0]])
    assert not grid.moved(box)[0]  # seen through once: no verdict yet
    for _ in range(5):
        grid.observe(Pose2D(), _scan_to_wall(3.0))
    assert grid.moved(box)[0]
    # a box put down at 1.5 m stays: it returns beams and is accepted within a few scans
    scans = 0
    while grid.moved(box)[0]:
        grid.observe(Pose2D(), _scan_to_wall(1.5))
        scans += 1
        assert scans < 10
    md = SeenFreeModel()
    assert scans <= math.ceil((md.clamp + md.moved_logodds) / md.hit_logodds) + 1


def test_beams_without_a_return_are_no_evidence() -> None:
    grid = SeenFree()
    blind = _scan_to_wall(3.0)
    blind = Scan(0.0, blind.angle_min_rad, blind.angle_increment_rad, 0.02, 5.6, np.full(181, np.nan))
    for _ in range(10):
        grid.observe(Pose2D(), blind)
    assert not grid.moved(np.array([[1.5, 0.0]]))[0]


def test_a_wall_seen_at_grazing_angles_is_not_eaten() -> None:
    # a long wall along y = 1 seen from the origin: the far beams graze it
    grid = SeenFree()
    angles = np.linspace(0.05, math.pi / 2, 300)
    ranges = 1.0 / np.sin(angles)
    scan = Scan(0.0, float(angles[0]), float(angles[1] - angles[0]), 0.02, 30.0, ranges)
    for _ in range(10):
        grid.observe(Pose2D(), scan)
    wall = np.column_stack([np.linspace(0.0, 15.0, 151), np.full(151, 1.0)])
    assert not grid.moved(wall).any()
    assert grid.moved(np.array([[0.0, 0.5], [1.0, 0.5]])).all()  # the space in front of it is free


@settings(max_examples=30, deadline=None)
@given(st.floats(-20.0, 20.0), st.floats(-20.0, 20.0), st.floats(-math.pi, math.pi))
def test_the_grid_grows_wherever_the_robot_goes_and_keeps_what_it_saw(
    x: float, y: float, theta: float
) -> None:
    grid = SeenFree()
    for _ in range(6):
        grid.observe(Pose2D(), _scan_to_wall(3.0))
    far = Pose2D(x, y, theta)
    grid.observe(far, _scan_to_wall(2.0))
    assert grid.moved(np.array([[1.5, 0.0]]))[0]  # still known after the grid grew
    nx, ny = grid.shape
    assert nx * ny * 0.1 * 0.1 <= 40 * (abs(x) + 12) * (abs(y) + 12)  # bounded by the area seen


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_a_person_crossing_right_behind_the_robot_leaves_no_wall(seed: int) -> None:
    """The person crosses the robot's line where the scanner is, then is behind it: no later beam looks
    there again (the per-wall evidence cannot act), but earlier beams passed through."""
    room = np.array(_box(-1.0, -2.5, 7.0, 2.5))
    across = Walker(np.array([[3.2, -2.2], [3.2, 2.2]]), 0.8, start_s=5.25, bounce=False)
    scene = Scene(room, "crossing", np.array([[0.0, 0.0], [6.0, 0.0]]), people=(across,))
    rng = np.random.default_rng(seed)
    pipe = Pipeline(PipelineConfig(scan_matching=None), icp_gate=IcpGate(refine_to_map=False))
    for k in range(150):  # 0.4 m/s along y = 0: at the person's line at 8 s, when the person is there
        scan, _ = simulate_scene_scan(scene, Pose2D(0.04 * k, 0.0, 0.0), k / 10.0, rng, geometry=URG04LX)
        pipe.step(scan)
    segments = pipe.walls()[1]
    assert len(segments) >= 3
    inside = [
        s for s in segments if max(abs(s[0] - 3.2), abs(s[2] - 3.2)) < 0.6 and max(abs(s[1]), abs(s[3])) < 2.3
    ]
    assert inside == []


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_free_share_is_the_share_of_its_samples_that_moved_flags(seed: int) -> None:
    rng = np.random.default_rng(seed)
    grid = SeenFree()
    for distance in rng.uniform(1.0, 5.0, 4):
        pose = Pose2D(float(rng.uniform(-1, 1)), 0.0, float(rng.uniform(-3, 3)))
        grid.observe(pose, _scan_to_wall(distance))
    segs = rng.uniform(-6.0, 6.0, (25, 4))
    segs[0, 2:] = segs[0, :2]  # a zero-length piece: its one sample counted twice
    got = grid.free_share(segs)
    for k, seg in enumerate(segs):  # the samples written out, tested by moved()
        n = max(math.ceil(math.hypot(seg[2] - seg[0], seg[3] - seg[1]) / 0.05), 1) + 1
        t = np.arange(n) / (n - 1)
        pts = seg[:2] + t[:, None] * (seg[2:] - seg[:2])
        assert got[k] == grid.moved(pts).mean()
