"""Scenes of the scenario suite: people in the beams, glass and black surfaces, walls that come and go,
mixed pixels. Noise-free scans have known answers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from shared.errors import InvalidInputError
from shared.sim import RangeNoise
from shared.sim.scene import BLACK, GLASS, MATTE, Scene, Walker, scene_raycast, simulate_scene_scan
from shared.types import URG04LX, Pose2D

QUIET = RangeNoise(near_accuracy_m=0.0, far_accuracy_ratio=0.0, outlier_rate=0.0)
KNOTS = np.array([[0.0, 0.0], [1.0, 0.0]])
ROOM = np.array(
    [[4.0, -3.0, 4.0, 3.0], [-3.0, -3.0, -3.0, 3.0], [-3.0, 3.0, 4.0, 3.0], [-3.0, -3.0, 4.0, -3.0]]
)


def _beam_at(target: np.ndarray, origin: np.ndarray, k: int = 341) -> Pose2D:
    """A laser pose at ``origin`` turned so that beam ``k`` points exactly at ``target``."""
    angle = math.atan2(target[1] - origin[1], target[0] - origin[0])
    return Pose2D(float(origin[0]), float(origin[1]), angle - float(URG04LX.angles_rad()[k]))


def test_a_walking_person_is_in_the_ranges_where_the_legs_are() -> None:
    walker = Walker(np.array([[2.0, -2.0], [2.0, 2.0]]), speed_mps=1.0, start_s=0.0)
    scene = Scene(ROOM, "room", KNOTS, people=(walker,))
    origin = np.array([0.0, 0.0])
    for t_s in (0.5, 1.7, 2.2, 3.1):
        for leg in walker.legs(t_s):
            pose = _beam_at(leg, origin)
            scan, hits = simulate_scene_scan(scene, pose, t_s, np.random.default_rng(0), QUIET)
            expected = float(np.hypot(*(leg - origin))) - 0.06
            assert scan.ranges_m[341] == pytest.approx(expected, abs=1e-9)
            assert hits.person[341] and hits.wall[341] == -1
            # the leg is where the person walks: on the walk line, within hip width and stride
            assert abs(leg[0] - 2.0) <= 0.26


def test_a_person_walks_at_the_given_speed_bounces_and_is_absent_before_the_start() -> None:
    walker = Walker(np.array([[0.0, 0.0], [3.0, 0.0]]), speed_mps=1.5, start_s=2.0)
    assert walker.position(1.9) is None and len(walker.legs(1.9)) == 0
    xy, heading = walker.position(3.0)  # type: ignore[misc]
    assert xy[0] == pytest.approx(1.5) and heading == pytest.approx(0.0)
    xy, heading = walker.position(2.0 + 3.0 / 1.5 + 1.0)  # type: ignore[misc]
    assert xy[0] == pytest.approx(1.5) and abs(heading) == pytest.approx(math.pi)
    gone = Walker(np.array([[0.0, 0.0], [3.0, 0.0]]), speed_mps=1.0, bounce=False)
    assert gone.position(3.5) is None


def test_after_the_person_left_the_beam_returns_the_wall() -> None:
    walker = Walker(np.array([[2.0, -0.5], [2.0, 0.5]]), speed_mps=1.0, bounce=False)
    scene = Scene(ROOM, "room", KNOTS, people=(walker,))
    hits = scene_raycast(scene, (0.0, 0.0), np.array([0.0]), t_s=5.0)
    assert hits.range_m[0] == pytest.approx(4.0) and hits.wall[0] == 0 and not hits.person[0]


def test_glass_gives_no_return_and_shows_what_is_behind_it() -> None:
    glass = np.array([[1.0, -5.0, 1.0, 5.0]])
    alone = Scene(glass, "glass", KNOTS, surface=np.array([GLASS]))
    scan, hits = simulate_scene_scan(alone, Pose2D(0.0, 0.0, 0.0), 0.0, np.random.default_rng(0), QUIET)
    assert np.all(np.isnan(scan.ranges_m))
    assert np.all(hits.wall == -1)
    behind = Scene(
        np.vstack([glass, [[3.0, -5.0, 3.0, 5.0]]]), "glass", KNOTS, surface=np.array([GLASS, MATTE])
    )
    hits = scene_raycast(behind, (0.0, 0.0), np.array([0.0, 0.3]), 0.0)
    np.testing.assert_allclose(hits.range_m, [3.0, 3.0 / math.cos(0.3)])
    assert np.all(hits.wall == 1)


def test_black_absorbs_the_beam_and_hides_what_is_behind_it() -> None:
    walls = np.array([[1.0, -0.5, 1.0, 0.5], [3.0, -5.0, 3.0, 5.0]])
    scene = Scene(walls, "black", KNOTS, surface=np.array([BLACK, MATTE]))
    angles = np.array([0.0, 0.2, math.atan2(2.0, 3.0)])
    hits = scene_raycast(scene, (0.0, 0.0), angles, 0.0)
    assert math.isinf(hits.range_m[0]) and math.isinf(hits.range_m[1])  # 0.2 rad still hits the panel
    assert hits.wall[0] == 0
    assert hits.range_m[2] == pytest.approx(math.hypot(3.0, 2.0)) and hits.wall[2] == 1


def test_a_wall_exists_only_in_its_time_window() -> None:
    closed, opened = [2.0, -0.5, 2.0, 0.5], [2.0, 0.5, 2.9, 0.5]
    walls = np.array([closed, opened, [5.0, -5.0, 5.0, 5.0]])
    times = np.array([[-np.inf, 10.0], [10.0, np.inf], [-np.inf, np.inf]])
    scene = Scene(walls, "door", KNOTS, wall_times=times)
    before = scene_raycast(scene, (0.0, 0.0), np.array([0.0]), 9.9)
    after = scene_raycast(scene, (0.0, 0.0), np.array([0.0]), 10.0)
    assert before.range_m[0] == pytest.approx(2.0) and before.wall[0] == 0
    assert after.range_m[0] == pytest.approx(5.0) and after.wall[0] == 2
    truth, idx = scene.truth(20.0)
    assert idx.tolist() == [1, 2] and truth.walls.tolist() == [opened, [5.0, -5.0, 5.0, 5.0]]


def test_mixed_pixels_fall_between_the_near_and_the_far_surface_at_edges_only() -> None:
    # a post 1 m away in front of a wall 4 m away: its two edges are depth jumps of ~3 m
    walls = np.vstack([ROOM, [[1.0, -0.1, 1.0, 0.1]]])
    pose = Pose2D(0.0, 0.0, 0.0)
    plain = Scene(walls, "edges", KNOTS)
    mixed = Scene(walls, "edges", KNOTS, mixed_pixel_rate=1.0)
    clean, _ = simulate_scene_scan(plain, pose, 0.0, np.random.default_rng(3), QUIET)
    scan, hits = simulate_scene_scan(mixed, pose, 0.0, np.random.default_rng(3), QUIET)
    changed = np.flatnonzero(~np.isclose(scan.ranges_m, clean.ranges_m, equal_nan=True))
    assert 1 <= len(changed) <= 4  # the beams straddling the post's two edges
    for k in changed:
        assert 1.0 < scan.ranges_m[k] < 4.0 / math.cos(abs(URG04LX.angles_rad()[k])) + 1e-9
        assert abs(URG04LX.angles_rad()[k]) == pytest.approx(
            math.atan2(0.1, 1.0), abs=URG04LX.angle_increment_rad
        )
    assert np.array_equal(hits.range_m, scene_raycast(plain, (0.0, 0.0), URG04LX.angles_rad(), 0.0).range_m)


@pytest.mark.parametrize(
    ("kwargs", "what"),
    [
        ({"surface": np.array([7, 0, 0, 0])}, "surface"),
        ({"wall_times": np.array([[1.0, 0.0]] * 4)}, "wall_times"),
        ({"mixed_pixel_rate": 1.5}, "mixed_pixel_rate"),
        ({"knots": np.zeros((1, 2))}, "knots"),
    ],
)
def test_bad_scenes_are_refused_naming_the_field(kwargs: dict[str, object], what: str) -> None:
    args: dict[str, object] = {"walls": ROOM, "name": "bad", "knots": KNOTS, **kwargs}
    with pytest.raises(InvalidInputError, match=what):
        Scene(**args)  # type: ignore[arg-type]


def test_bad_walkers_are_refused() -> None:
    with pytest.raises(InvalidInputError, match="speed_mps"):
        Walker(np.array([[0.0, 0.0], [1.0, 0.0]]), speed_mps=0.0)
    with pytest.raises(InvalidInputError, match="waypoints"):
        Walker(np.array([[0.0, 0.0]]), speed_mps=1.0)
