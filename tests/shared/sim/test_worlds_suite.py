"""The scenario suite's worlds: valid geometry for every kind and seed, determinism, ground truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.errors import InvalidInputError
from shared.metrics.distance import nearest_segment, sample_segments
from shared.sim.path import plan_path
from shared.sim.scene import GLASS, MATTE
from shared.sim.worlds import DRIVES, KINDS, build_scene, drive_knots, simulate_case
from shared.sim.worlds.geometry import path_segments

ROBOT_RADIUS_M = 0.25


def _crosses(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether segment ``a`` properly crosses any of the segments ``b`` ``(N, 4)``."""
    p, r = a[:2], a[2:] - a[:2]
    q, s = b[:, :2], b[:, 2:] - b[:, :2]
    denom = r[0] * s[:, 1] - r[1] * s[:, 0]
    ok = np.abs(denom) > 1e-12
    qp = q - p
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (qp[:, 0] * s[:, 1] - qp[:, 1] * s[:, 0]) / denom
        u = (qp[:, 0] * r[1] - qp[:, 1] * r[0]) / denom
    return bool(np.any(ok & (t >= 0) & (t <= 1) & (u >= 0) & (u <= 1)))


def test_there_are_at_least_ten_kinds_and_each_names_its_defaults() -> None:
    assert len(KINDS) >= 10
    for kind in KINDS.values():
        assert kind.drive in DRIVES and kind.summary
    odometry = {k.odometry for k in KINDS.values()}
    assert {"slip", "worn", "bursts"} <= odometry
    assert {k.drive for k in KINDS.values()} == set(DRIVES)


@pytest.mark.parametrize("kind", list(KINDS))
@settings(max_examples=8, deadline=None)
@given(seed=st.integers(0, 10_000))
def test_every_kind_builds_valid_geometry_with_a_drivable_path(kind: str, seed: int) -> None:
    scene = build_scene(kind, seed)
    walls = scene.walls
    lengths = np.hypot(walls[:, 2] - walls[:, 0], walls[:, 3] - walls[:, 1])
    assert np.all(np.isfinite(walls)) and np.all(lengths > 0.01), "walls have a length"
    assert scene.floor_area_m2 > 0
    # the robot's path stays clear of every wall that ever exists, and crosses none
    legs = path_segments(drive_knots(scene.knots, "single"))
    pts, _, _ = sample_segments(legs, 0.05)
    dist, _ = nearest_segment(pts, walls)
    assert dist.min() >= ROBOT_RADIUS_M, f"{kind} seed {seed}: the path passes {dist.min():.2f} m from a wall"
    assert not any(_crosses(leg, walls) for leg in legs)
    # people keep clear of the walls too: their legs are inside the free space
    for walker in scene.people:
        for t_s in np.linspace(0.0, 60.0, 25):
            legs_xy = walker.legs(float(t_s))
            if len(legs_xy):
                assert nearest_segment(legs_xy, walls)[0].min() > 0.06


@pytest.mark.parametrize("kind", list(KINDS))
def test_each_kind_is_seen_by_the_laser_and_its_ground_truth_is_consistent(kind: str) -> None:
    case = simulate_case(kind, 0, max_scans=40)
    returns = np.mean([np.isfinite(s.ranges_m).mean() for s in case.run.scans])
    assert returns > 0.2, f"{kind}: the laser sees almost nothing ({returns:.0%} returns)"
    assert 1 <= case.walls_seen <= len(case.truth.walls)
    # the seen parts lie on true walls
    seen_pts, _, _ = sample_segments(case.seen_walls, 0.05)
    assert nearest_segment(seen_pts, case.truth.walls)[0].max() < 1e-9
    assert len(case.run) == 40 and case.run.world is case.truth


@settings(max_examples=5, deadline=None)
@given(seed=st.integers(0, 10_000), kind=st.sampled_from(list(KINDS)))
def test_a_case_is_deterministic_for_its_seed(seed: int, kind: str) -> None:
    a, b = simulate_case(kind, seed, max_scans=6), simulate_case(kind, seed, max_scans=6)
    assert np.array_equal(a.scene.walls, b.scene.walls)
    for sa, sb in zip(a.run.scans, b.run.scans, strict=True):
        assert np.array_equal(sa.ranges_m, sb.ranges_m, equal_nan=True) and sa.odometry == sb.odometry
    assert a.run.true_poses == b.run.true_poses and np.array_equal(a.seen_walls, b.seen_walls)


@pytest.mark.parametrize("kind", list(KINDS))
def test_seeds_draw_different_worlds(kind: str) -> None:
    worlds = {build_scene(kind, seed).walls.tobytes() for seed in range(4)}
    assert len(worlds) == 4


def test_another_odometry_model_leaves_the_world_and_the_scans_alone() -> None:
    slip = simulate_case("corridor-doors", 3, odometry="slip", max_scans=30)
    worn = simulate_case("corridor-doors", 3, odometry="worn", max_scans=30)
    assert np.array_equal(slip.truth.walls, worn.truth.walls)
    for a, b in zip(slip.run.scans, worn.run.scans, strict=True):
        assert np.array_equal(a.ranges_m, b.ranges_m, equal_nan=True)
    assert slip.run.odometry_poses[-1] != worn.run.odometry_poses[-1]


def test_driving_patterns() -> None:
    open_path = np.array([[0.0, 0.0], [5.0, 0.0], [5.0, 3.0]])
    assert np.array_equal(drive_knots(open_path, "single"), open_path)
    back = drive_knots(open_path, "out-back")
    assert np.array_equal(back[0], back[-1]) and len(back) == 5
    assert len(drive_knots(open_path, "laps", laps=3)) == 1 + 3 * 4
    loop = np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 4.0], [0.0, 4.0], [0.0, 0.0]])
    laps = drive_knots(loop, "laps", laps=2)
    assert len(laps) == 9 and np.array_equal(laps[4], laps[0]) and np.array_equal(laps[-1], laps[0])
    with pytest.raises(InvalidInputError, match="drive"):
        drive_knots(open_path, "zigzag")


def test_laps_around_the_block_drive_the_loop_twice() -> None:
    scene = build_scene("loop-block", 0)
    one = len(plan_path(drive_knots(scene.knots, "single")))
    case = simulate_case("loop-block", 0)
    assert case.drive == "laps" and len(case.run) > 1.9 * one
    start, end = case.run.true_poses[0], case.run.true_poses[-1]
    assert (start.x_m, start.y_m) == pytest.approx((end.x_m, end.y_m))


def test_glass_and_black_walls_are_true_walls_that_are_never_seen() -> None:
    case = simulate_case("glass-black", 1)
    surface = case.scene.surface
    assert surface is not None
    dark = case.scene.walls[surface != MATTE]
    assert np.any(surface == GLASS) and len(dark)
    # every dark wall is in the ground truth, and no seen piece lies on one
    truth = {tuple(w) for w in case.truth.walls.tolist()}
    assert all(tuple(w) in truth for w in dark.tolist())
    mid = 0.5 * (case.seen_walls[:, :2] + case.seen_walls[:, 2:])
    on_dark = nearest_segment(mid, dark)[0] < 1e-6
    on_matte = nearest_segment(mid, case.scene.walls[surface == MATTE])[0] < 1e-6
    assert not np.any(on_dark & ~on_matte)


def test_the_truth_is_the_world_at_the_end_doors_open_furniture_moved_people_absent() -> None:
    door = simulate_case("door-opens", 2)
    assert door.drive == "out-back"
    assert len(door.truth.walls) == len(door.scene.walls) - 2  # the two closed leaves are gone
    moved = simulate_case("furniture-moved", 2)
    assert len(moved.truth.walls) < len(moved.scene.walls)
    single = simulate_case("furniture-moved", 2, drive="single")
    assert not np.array_equal(single.truth.walls, moved.truth.walls)  # old places before the turn
    people = simulate_case("people-along", 2, max_scans=20)
    assert len(people.truth.walls) == len(people.scene.walls) and len(people.scene.people) == 3


def test_the_long_corridor_is_longer_than_twice_the_range_and_its_start_is_never_seen() -> None:
    for seed in range(3):
        case = simulate_case("corridor-long", seed)
        walls = case.truth.walls
        assert walls[:, [0, 2]].max() - walls[:, [0, 2]].min() > 2 * 5.6
        start_wall = walls[0]  # x = 0, behind the robot when it sets off
        mid = 0.5 * (case.seen_walls[:, :2] + case.seen_walls[:, 2:])
        assert not np.any(nearest_segment(mid, start_wall[None, :])[0] < 1e-6)
        assert case.walls_seen == 3


def test_unknown_names_are_clear_errors() -> None:
    with pytest.raises(InvalidInputError, match="unknown world kind 'moon'"):
        build_scene("moon", 0)
    with pytest.raises(InvalidInputError, match="odometry model"):
        simulate_case("corridor-long", 0, odometry="teleport")
    with pytest.raises(InvalidInputError, match="seed"):
        simulate_case("corridor-long", -1)


def test_the_docs_describe_every_kind() -> None:
    text = (Path(__file__).resolve().parents[3] / "docs" / "worlds.md").read_text(encoding="utf-8")
    for kind in KINDS.values():
        assert f"| `{kind.name}` |" in text and f"| {kind.odometry} | {kind.drive} |" in text
