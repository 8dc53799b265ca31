"""Wall map: segments' point scatter and the side they were seen from (docs/worlds.md).

Two overlapping copies of one face within a few standard deviations of their combined scatter are one
wall; the two faces of a thin wall, seen from opposite sides, stay two; a noisy short piece across a wall
seen from its side joins it instead of standing as a hatch.
"""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import linregress

from shared.pipeline import MergeTolerances, WallMap
from shared.pipeline.stages import Chunk, line_sigmas, line_uncertainty

ALL = MergeTolerances(min_observations=1)
ABOVE = (2.0, 3.0)  # a scanner 3 m above the walls along y = 0
BELOW = (2.0, -3.0)


def test_two_parallel_copies_two_sigma_apart_merge() -> None:
    sigma = 0.04
    m = WallMap(ALL)
    m.add_segments([[0.0, 0.0, 4.0, 0.0]], viewpoint=ABOVE, sigmas_m=[sigma])
    sep = 2.0 * np.hypot(sigma, sigma)  # 2 sigma of the pair's combined scatter, beyond offset_tol_m
    assert sep > ALL.offset_tol_m
    m.add_segments([[0.5, sep, 3.5, sep]], viewpoint=ABOVE, sigmas_m=[sigma])
    segs = m.segments()
    assert len(segs) == 1
    assert 0.0 < segs[0, 1] < sep and 0.0 < segs[0, 3] < sep


def test_precise_parallel_walls_as_far_apart_stay_two() -> None:
    m = WallMap(ALL)
    sep = 2.0 * np.hypot(0.04, 0.04)
    m.add_segments([[0.0, 0.0, 4.0, 0.0], [0.5, sep, 3.5, sep]], viewpoint=ABOVE, sigmas_m=[0.005, 0.005])
    assert len(m) == 2


def test_copies_that_do_not_overlap_are_not_merged_by_scatter() -> None:
    m = WallMap(ALL)
    m.add_segments([[0.0, 0.0, 2.0, 0.0], [2.1, 0.12, 4.0, 0.12]], viewpoint=ABOVE, sigmas_m=[0.04, 0.04])
    assert len(m) == 2


def test_the_two_faces_of_a_thin_wall_stay_two() -> None:
    m = WallMap(ALL)
    for _ in range(3):  # each face seen from its own side, noisy enough that scatter alone would merge
        m.add_segments([[0.0, 0.0, 4.0, 0.0]], viewpoint=BELOW, sigmas_m=[0.04])
        m.add_segments([[0.0, 0.10, 4.0, 0.10]], viewpoint=ABOVE, sigmas_m=[0.04])
    segs = m.segments()
    assert len(segs) == 2
    assert sorted(np.round(segs[:, 1], 2)) == [0.0, 0.1]


def test_a_face_seen_from_both_ends_of_its_side_is_one_wall() -> None:
    m = WallMap(ALL)
    m.add_segments([[0.0, 0.0, 4.0, 0.0]], viewpoint=(-1.0, 2.0))
    m.add_segments([[4.0, 0.01, 0.5, 0.01]], viewpoint=(5.0, 1.0))  # drawn the other way round
    assert len(m) == 1


def test_without_viewpoint_or_scatter_the_old_rule_holds() -> None:
    m = WallMap(ALL)
    m.add_segments([[0.0, 0.0, 4.0, 0.0], [0.0, 0.10, 4.0, 0.10]])
    assert len(m) == 2
    off = WallMap(MergeTolerances(min_observations=1, merge_sigmas=0.0))
    off.add_segments([[0.0, 0.0, 4.0, 0.0], [0.5, 0.11, 3.5, 0.11]], viewpoint=ABOVE, sigmas_m=[0.04, 0.04])
    assert len(off) == 2


def test_a_noisy_short_tilted_piece_joins_the_wall_it_lies_on() -> None:
    # what a wall 3 m away gives: a 25 cm piece tilted 20 deg by 4 cm range noise, 6 cm off the wall's
    # line, so one end lies 10 cm from it (beyond offset_tol_m)
    piece = [[2.0, 0.06 - 0.043, 2.235, 0.06 + 0.043]]
    old = WallMap(MergeTolerances(min_observations=1, merge_sigmas=0.0))
    old.add_segments([[0.0, 0.0, 5.0, 0.0]])
    old.add_segments(piece)
    assert len(old) == 2  # a hatch across the wall
    m = WallMap(ALL)
    m.add_segments([[0.0, 0.0, 5.0, 0.0]], viewpoint=ABOVE, sigmas_m=[0.04])
    m.add_segments(piece, viewpoint=ABOVE, sigmas_m=[0.04])
    assert len(m) == 1


def test_a_perpendicular_wall_at_a_corner_stays_apart() -> None:
    m = WallMap(ALL)
    for _ in range(3):
        m.add_segments(
            [[0.0, 0.0, 4.0, 0.0], [4.0, 0.0, 4.0, 3.0]], viewpoint=(2.0, 2.0), sigmas_m=[0.04, 0.04]
        )
    assert len(m) == 2


def test_line_sigmas_measure_the_points_scatter() -> None:
    rng = np.random.default_rng(3)
    x = np.linspace(0.0, 2.0, 400)
    pts = np.column_stack([x, rng.normal(0.0, 0.03, len(x))])
    quiet = np.column_stack([np.linspace(0.0, 1.0, 100), 1.0 + rng.normal(0.0, 0.005, 100)])
    chunk = Chunk.of(np.vstack([pts, quiet]), np.repeat(np.array([4, 7]), [400, 100]))
    sig = line_sigmas(np.array([[0.0, 0.0, 2.0, 0.0], [0.0, 1.0, 1.0, 1.0]]), np.array([4, 7]), chunk)
    assert abs(sig[0] - 0.03) < 0.006
    assert abs(sig[1] - 0.005) < 0.002


@settings(max_examples=40, deadline=None)
@given(
    st.floats(-0.06, 0.06),
    st.floats(0.0, 3.0),
    st.booleans(),
)
def test_two_copies_merge_whichever_comes_first(offset: float, shift: float, flip: bool) -> None:
    a = [0.0, 0.0, 4.0, 0.0]
    b = [shift, 0.05 + offset, shift + 2.0, 0.05 + offset]
    if flip:
        b = [b[2], b[3], b[0], b[1]]
    counts = []
    for order in ((a, b), (b, a)):
        m = WallMap(ALL)
        for seg in order:
            m.add_segments([seg], viewpoint=ABOVE, sigmas_m=[0.04])
        counts.append(len(m))
    assert counts[0] == counts[1] == 1


def test_line_directions_are_as_uncertain_as_a_least_squares_fit_says() -> None:
    rng = np.random.default_rng(5)
    for length, sigma, n in ((0.5, 0.03, 15), (2.0, 0.01, 200), (0.2, 0.005, 8)):
        x = np.sort(rng.uniform(0.0, length, n))
        y = rng.normal(0.0, sigma, n)
        chunk = Chunk.of(np.column_stack([x, y]), np.zeros(n, dtype=np.int64))
        want = linregress(x, y).stderr  # the reference: scipy's slope standard error
        _, dir_sd = line_uncertainty(np.array([[0.0, 0.0, length, 0.0]]), np.array([0]), chunk)
        assert 0.5 * want < dir_sd[0] < 2.0 * want
    few = Chunk.of(np.array([[0.0, 0.0], [1.0, 0.0]]), np.zeros(2, dtype=np.int64))
    assert line_uncertainty(np.array([[0.0, 0.0, 1.0, 0.0]]), np.array([0]), few)[1][0] == 0.0


def _short_wall_seen(times: int, dir_sd: float, known_sigmas: float = 3.0) -> WallMap:
    """A 1 m wall along x = 0 (shorter than the angle test can bound), seen ``times`` times."""
    m = WallMap(MergeTolerances(min_observations=1, known_direction_sigmas=known_sigmas))
    for _ in range(times):
        m.add_segments(
            [[0.0, 3.0, 0.0, 4.0]], viewpoint=(-3.0, 3.5), sigmas_m=[0.01], direction_sds_rad=[dir_sd]
        )
    return m


def _tilted_piece(m: WallMap, dir_sd: float) -> None:
    """A 0.7 m piece 5.5 degrees off that wall, both ends within its band (a noisy fit at 5 m range)."""
    m.add_segments(
        [[-0.045, 3.3, 0.022, 4.0]], viewpoint=(-3.0, 3.5), sigmas_m=[0.03], direction_sds_rad=[dir_sd]
    )


def test_a_short_wall_seen_many_times_takes_a_tilted_piece_within_its_band() -> None:
    m = _short_wall_seen(40, math.radians(2.0))  # 40 x 2 degrees: known to 0.3 degrees
    _tilted_piece(m, math.radians(3.0))
    assert len(m) == 1
    (seg,) = m.segments()
    assert abs(seg[0]) < 0.01 and abs(seg[2]) < 0.01  # still along x = 0


def test_a_short_wall_whose_direction_is_not_known_keeps_the_angle_test() -> None:
    once = _short_wall_seen(1, math.radians(2.0))  # seen once: known to 2 degrees, not enough
    _tilted_piece(once, math.radians(3.0))
    off = _short_wall_seen(40, math.radians(2.0), known_sigmas=0.0)  # the rule turned off
    _tilted_piece(off, math.radians(3.0))
    unknown = _short_wall_seen(40, 0.0)  # no direction information given
    _tilted_piece(unknown, 0.0)
    assert len(once) == len(off) == len(unknown) == 2
