"""Walls do not pass through walls (shared.pipeline.crossings): of two walls crossing through both
interiors the shorter is not shown; corners, T-junctions and near-parallel copies are not crossings."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.metrics import line_accuracy
from shared.pipeline import Pipeline, PipelineConfig
from shared.pipeline.crossings import crossing_walls
from shared.pipeline.wallmap import WallMap
from shared.sim import default_world, patrol_scans
from shared.types import Pose2D

MARGIN, ANGLE = 0.2, 10.0


def test_a_short_piece_through_a_long_wall_is_hidden() -> None:
    segs = np.array([[0.0, 0.0, 6.0, 0.0], [2.0, -0.4, 2.4, 0.4]])  # a 0.9 m piece across, 27 degrees off
    assert crossing_walls(segs, MARGIN, ANGLE).tolist() == [False, True]
    assert crossing_walls(segs[::-1], MARGIN, ANGLE).tolist() == [True, False]


def test_corners_t_junctions_and_parallel_copies_are_not_crossings() -> None:
    corner = np.array([[0.0, 0.0, 4.08, 0.0], [4.0, -0.08, 4.0, 3.0]])  # ends overshoot by 8 cm
    # an angled wall meeting a straight one at 30 degrees, both overshooting the corner by 30 cm
    angled = np.array([[-0.07, 6.74, 7.79, 6.75], [8.78, 6.04, 7.29, 6.9]])
    tee = np.array([[0.0, 0.0, 4.0, 0.0], [2.0, -0.1, 2.0, 3.0]])  # the stem starts 10 cm past the wall
    parallel = np.array([[0.0, 0.0, 4.0, 0.0], [0.5, -0.2, 3.5, 0.17]])  # 7 degrees: a sloppy copy
    apart = np.array([[0.0, 0.0, 4.0, 0.0], [5.0, -1.0, 5.0, 1.0]])
    for segs in (corner, angled, tee, parallel, apart):
        assert not crossing_walls(segs, MARGIN, ANGLE).any(), segs


@settings(max_examples=100, deadline=None)
@given(
    st.lists(
        st.tuples(*[st.floats(-5.0, 5.0, allow_nan=False)] * 4).filter(
            lambda s: np.hypot(s[2] - s[0], s[3] - s[1]) > 0.01
        ),
        min_size=0,
        max_size=12,
    ),
    st.randoms(use_true_random=False),
)
def test_the_longest_wall_is_never_hidden_and_order_does_not_matter(segments, rnd) -> None:  # type: ignore[no-untyped-def]
    segs = np.array(segments, dtype=np.float64).reshape(-1, 4)
    hidden = crossing_walls(segs, MARGIN, ANGLE)
    if len(segs):
        lengths = np.hypot(segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1])
        assert not hidden[int(np.argmax(lengths))]
    order = list(range(len(segs)))
    rnd.shuffle(order)
    np.testing.assert_array_equal(crossing_walls(segs[order], MARGIN, ANGLE), hidden[order])


def test_the_wall_map_hides_a_crossing_piece_and_shows_it_again_when_the_wall_goes() -> None:
    walls = WallMap()
    for _ in range(3):
        walls.add_segments([[0.0, 0.0, 6.0, 0.0]])
        walls.add_segments([[2.0, -0.4, 2.4, 0.4]])
    ids, segs = walls.ids, walls.segments()
    assert len(ids) == 1 and np.allclose(segs[0], [0.0, 0.0, 6.0, 0.0])
    long_id = int(ids[0])
    walls.cut(long_id, [])  # the long wall seen through: gone
    assert len(walls.ids) == 1 and np.allclose(walls.segments()[0], [2.0, -0.4, 2.4, 0.4])


@pytest.mark.soak  # 95-150 s: make soak
def test_the_room_patrolled_half_an_hour_stays_as_accurate_as_after_one_lap() -> None:
    """The demo's room, 18,000 steps (30 minutes at 10 Hz) of patrol by the front end: the map at the end
    is within 10 % of the first lap's wall error (it rose 31 % while confirmed noisy pieces crossing the
    walls were shown) and holds at most 1.5x the true walls."""
    world = default_world()
    pipe = Pipeline(PipelineConfig(), laser_offset=_offset())
    errors = {}
    for i, scan in enumerate(itertools.islice(patrol_scans(world, seed=0, laps=0), 18_000), 1):
        pipe.step(scan)
        if i in (1_093, 18_000):  # the end of the first lap (out and back), the end
            errors[i] = line_accuracy(pipe.walls()[1], world.walls).mean_distance_m
    assert errors[18_000] <= 1.1 * errors[1_093], errors
    assert len(pipe.walls()[1]) <= 1.5 * len(world.walls)


def _offset() -> Pose2D:
    from shared.odometry import MINES_ROVER  # the simulated robot patrol_scans drives

    return MINES_ROVER.laser_offset
