"""Area enclosed by a map and the area error (docs/design.md §5, paper Table 3): known answers and
properties."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.errors import InvalidInputError, LinemapError
from shared.metrics import (
    MapLeakError,
    MetricError,
    MetricInputError,
    area_error_pct,
    enclosed_area,
    map_area_m2,
)
from shared.metrics.gaps import gap_bridges
from shared.sim import default_path, default_world
from shared.types import FloatArray


def polygon(vertices: list[tuple[float, float]] | FloatArray) -> FloatArray:
    v = np.asarray(vertices, dtype=np.float64)
    return np.hstack([v, np.roll(v, -1, axis=0)])


def rect(x0: float, y0: float, x1: float, y1: float) -> FloatArray:
    return polygon([(x0, y0), (x1, y0), (x1, y1), (x0, y1)])


def shoelace(vertices: FloatArray) -> float:
    x, y = vertices[:, 0], vertices[:, 1]
    return float(0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def rotate(points: FloatArray, angle: float) -> FloatArray:
    c, s = math.cos(angle), math.sin(angle)
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2) @ np.array([[c, s], [-s, c]])
    return np.asarray(p)


CENTRE = np.array([[5.0, 2.0]])
# marching squares cut a wall corner lying inside a square between four centres: at most c^2 / 8 for a right
# angle away from the centres (5e-5 m^2 with 2 cm cells), c^2 / 2 for a right angle on a centre, up to about
# c^2 for a sharp corner (measured on 3,000 random polygons: at most 0.84 c^2 per vertex); straight walls
# are exact
RIGHT_CORNER_M2 = 0.02**2 / 8
ANY_CORNER_M2 = 0.02**2


# --- bias of the method on perfect maps -------------------------------------------------------------------


def test_perfect_rectangle_is_exact() -> None:
    area = map_area_m2(rect(0, 0, 10, 4), CENTRE)
    assert 40.0 - 4 * RIGHT_CORNER_M2 - 1e-9 <= area <= 40.0  # convex corners can only lose
    assert area_error_pct(rect(0, 0, 10, 4), 40.0, CENTRE) < 1e-3  # measured: 5e-4 %


@pytest.mark.parametrize(
    ("x0", "y0", "width", "height"),
    [
        (0.013, 0.007, 10.0, 4.0),
        (0.0, 0.0, 10.011, 3.997),
        (-3.3331, 7.1234, 6.789, 2.345),
        (0.01, 0.01, 5, 3),
    ],
)
def test_rectangle_off_the_grid_has_no_raster_bias(x0: float, y0: float, width: float, height: float) -> None:
    # walls between cell centres, on cell centres (0.01 with 2 cm cells) or anywhere: sub-cell measurement
    area = map_area_m2(rect(x0, y0, x0 + width, y0 + height), [[x0 + width / 2, y0 + height / 2]])
    # right-angle corners on cell centres lose c^2 / 2 each: 15 m^2 - 8e-4 m^2
    assert area == pytest.approx(width * height, abs=4 * 0.02**2 / 2 + 1e-9)


@pytest.mark.parametrize("angle_deg", [3.0, 17.0, 30.0, 45.0, 60.0, 89.0])
def test_rotated_rectangle_bias_below_1e_4_percent(angle_deg: float) -> None:
    a = math.radians(angle_deg)
    seg = rotate(rect(0, 0, 10, 4)[:, :2], a)
    seg = np.hstack([seg, np.roll(seg, -1, axis=0)])
    area = map_area_m2(seg, rotate(CENTRE, a))
    assert area == pytest.approx(40.0, abs=4 * ANY_CORNER_M2)  # measured: at most 3.3e-4 m^2 on 40 m^2
    assert area_error_pct(seg, 40.0, rotate(CENTRE, a)) < 2e-3


def test_l_shaped_world_with_obstacles_matches_floor_area() -> None:
    # the default world: L-shaped room with two boxes; their interiors are not reachable
    world = default_world()
    path = np.array([[p.x_m, p.y_m] for p in default_path()])
    area = map_area_m2(world.walls, path)
    # 8 outline corners (6 convex lose, 2 reflex gain) and 8 box corners (reflex for the floor: gain)
    assert area == pytest.approx(world.floor_area_m2, abs=16 * RIGHT_CORNER_M2)
    assert area_error_pct(world.walls, world.floor_area_m2, path) < 1e-3  # measured: 4.4e-4 %


def test_obstacle_inside_room_is_excluded_and_trajectory_inside_it_adds_it() -> None:
    room = rect(0, 0, 6, 4)
    box = rect(2, 1, 3, 2)
    segs = np.vstack([room, box])
    tol = 8 * RIGHT_CORNER_M2
    assert map_area_m2(segs, [[5.0, 3.0]]) == pytest.approx(24.0 - 1.0, abs=tol)
    # a trajectory point inside the box counts its interior too (union of the seeded regions)
    assert map_area_m2(segs, [[5.0, 3.0], [2.5, 1.5]]) == pytest.approx(24.0, abs=tol)
    assert map_area_m2(segs, [[2.5, 1.5]]) == pytest.approx(1.0, abs=tol)


def test_two_rooms_only_the_visited_one_counts() -> None:
    segs = np.vstack([rect(0, 0, 4, 4), rect(4, 0, 10, 4)])
    assert map_area_m2(segs, [[1.0, 1.0]]) == pytest.approx(16.0, abs=4 * RIGHT_CORNER_M2)
    assert map_area_m2(segs, [[1.0, 1.0], [9.0, 3.0]]) == pytest.approx(40.0, abs=8 * RIGHT_CORNER_M2)


def test_split_and_duplicated_segments_do_not_change_the_area() -> None:
    segs = rect(0, 0, 10, 4)
    pieces = []
    for x0, y0, x1, y1 in segs:
        t = np.linspace(0.0, 1.0, 7)
        xs, ys = x0 + t * (x1 - x0), y0 + t * (y1 - y0)
        pieces.append(np.stack([xs[:-1], ys[:-1], xs[1:], ys[1:]], axis=1))
    split = np.vstack([*pieces, segs])
    assert map_area_m2(split, CENTRE) == pytest.approx(map_area_m2(segs, CENTRE), abs=1e-12)


# --- map errors with known answers ------------------------------------------------------------------------


def test_translated_map_keeps_its_area() -> None:
    # a whole-cell shift moves the grid with the map: identical to the last bit
    assert map_area_m2(rect(0.02, 0.02, 10.02, 4.02), CENTRE) == pytest.approx(
        map_area_m2(rect(0, 0, 10, 4), CENTRE), abs=1e-12
    )


def test_one_wall_shifted_by_2_cm_changes_area_by_its_strip() -> None:
    # right wall 2 cm too far out: +0.02 m x 4 m
    area = map_area_m2(rect(0, 0, 10.02, 4), CENTRE)
    assert area == pytest.approx(40.08, abs=4 * RIGHT_CORNER_M2)
    assert area_error_pct(rect(0, 0, 10.02, 4), 40.0, CENTRE) == pytest.approx(0.2, abs=1e-3)


def test_20_cm_gap_is_closed_exactly() -> None:
    segs = np.array([[0, 0, 4.9, 0], [5.1, 0, 10, 0], [10, 0, 10, 4], [10, 4, 0, 4], [0, 4, 0, 0]], float)
    result = enclosed_area(segs, CENTRE)
    assert result.area_m2 == pytest.approx(map_area_m2(rect(0, 0, 10, 4), CENTRE), abs=1e-9)
    assert len(result.bridges) >= 1
    assert np.all(np.isin(np.round(result.bridges[:, [0, 2]], 9), [4.9, 5.1]))
    # the same gap with gap closing below its width leaks
    with pytest.raises(MapLeakError, match=r"gaps up to 0\.1 m"):
        map_area_m2(segs, CENTRE, close_gaps_m=0.1)


def test_corner_gap_is_cut_by_a_chord() -> None:
    # bottom wall stops 10 cm before the corner, right wall starts 10 cm above it:
    # the bridge is a chord, losing the 0.1 x 0.1 / 2 triangle
    segs = np.array([[0, 0, 9.9, 0], [10, 0.1, 10, 4], [10, 4, 0, 4], [0, 4, 0, 0]], float)
    assert map_area_m2(segs, CENTRE) == pytest.approx(40.0 - 0.005, abs=5 * ANY_CORNER_M2)


def test_missing_wall_leaks() -> None:
    segs = rect(0, 0, 10, 4)[1:]
    with pytest.raises(MapLeakError) as info:
        area_error_pct(segs, 40.0, CENTRE)
    assert info.value.seed_xy == (5.0, 2.0)
    assert info.value.close_gaps_m == 0.3
    assert "does not enclose" in str(info.value)
    assert isinstance(info.value, LinemapError)


def test_inside_point_outside_the_map_leaks() -> None:
    with pytest.raises(MapLeakError, match="outside the map's bounding box"):
        map_area_m2(rect(0, 0, 10, 4), [[5.0, 2.0], [20.0, 2.0]])


def test_trajectory_partly_outside_a_closed_room_leaks() -> None:
    with pytest.raises(MapLeakError, match="1 of 2 inside points leak"):
        map_area_m2(np.vstack([rect(0, 0, 10, 4), rect(20, 0, 21, 1)]), [[5.0, 2.0], [15.0, 0.5]])


def test_region_mask_matches_the_room() -> None:
    result = enclosed_area(rect(0, 0, 1, 1), [[0.5, 0.5]], cell_m=0.1)
    assert result.region.sum() == 100
    assert not result.region.flags.writeable
    gx0, gy0 = result.origin_xy
    rows, cols = np.nonzero(result.region)
    xs, ys = gx0 + (cols + 0.5) * 0.1, gy0 + (rows + 0.5) * 0.1
    assert xs.min() > 0 and xs.max() < 1 and ys.min() > 0 and ys.max() < 1


def test_gap_bridges_close_only_gaps_up_to_the_limit() -> None:
    segs = np.array([[0, 0, 1, 0], [1.2, 0, 2, 0], [2.5, 0, 3, 0]], float)
    bridges = gap_bridges(segs, 0.3)
    lengths = np.hypot(bridges[:, 2] - bridges[:, 0], bridges[:, 3] - bridges[:, 1])
    np.testing.assert_allclose(lengths, 0.2)
    assert len(gap_bridges(segs, 0.0)) == 0


# --- bad input ---------------------------------------------------------------------------------------------


def test_bad_input_is_named() -> None:
    with pytest.raises(MetricInputError, match=r"inside_points has shape \(1, 3\)"):
        map_area_m2(rect(0, 0, 1, 1), [[0.5, 0.5, 0.0]])
    with pytest.raises(InvalidInputError, match=r"segments has shape \(4, 3\)"):
        map_area_m2(np.zeros((4, 3)), CENTRE)
    with pytest.raises(MetricInputError, match=r"segments\[1\]"):
        map_area_m2(np.array([[0, 0, 1, 0], [0, 0, np.nan, 1]]), CENTRE)
    with pytest.raises(MetricInputError, match="cell_m"):
        map_area_m2(rect(0, 0, 1, 1), [[0.5, 0.5]], cell_m=0.0)
    with pytest.raises(MetricInputError, match="close_gaps_m"):
        map_area_m2(rect(0, 0, 1, 1), [[0.5, 0.5]], close_gaps_m=-1.0)
    with pytest.raises(MetricInputError, match="floor_area_m2"):
        area_error_pct(rect(0, 0, 1, 1), 0.0, [[0.5, 0.5]])
    with pytest.raises(MetricError, match="no segments"):
        map_area_m2(np.zeros((0, 4)), CENTRE)
    with pytest.raises(MetricError, match="max_cells"):
        enclosed_area(rect(0, 0, 100, 100), [[50, 50]], cell_m=0.01, max_cells=1000)


# --- properties --------------------------------------------------------------------------------------------


@st.composite
def star_polygons(draw: st.DrawFn) -> FloatArray:
    """Simple polygons star-shaped around the origin, vertices on a 1 cm lattice (hits cell-centre lines)."""
    n = draw(st.integers(3, 10))
    base = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
    jitter = np.array(draw(st.lists(st.floats(-0.25, 0.25), min_size=n, max_size=n)))
    radii = np.array(draw(st.lists(st.floats(0.6, 3.0), min_size=n, max_size=n)))
    angles = base + jitter * (2.0 * math.pi / n)
    v = np.stack([radii * np.cos(angles), radii * np.sin(angles)], axis=1)
    return np.asarray(np.round(v, 2))


@settings(max_examples=60, deadline=None)
@given(star_polygons(), st.floats(-50, 50), st.floats(-50, 50))
def test_polygon_area_matches_shoelace_anywhere(vertices: FloatArray, dx: float, dy: float) -> None:
    # a perfect closed map never leaks, and its area error is tiny wherever it lies on the grid
    true = shoelace(vertices)
    offset = np.array([dx, dy])
    area = map_area_m2(polygon(vertices + offset), offset[None, :], close_gaps_m=0.0)
    assert area == pytest.approx(true, abs=len(vertices) * ANY_CORNER_M2)
    assert area > 0.0


@settings(max_examples=30, deadline=None)
@given(star_polygons(), st.floats(-20, 20), st.floats(-20, 20), st.sampled_from([0.0, math.pi / 2, math.pi]))
def test_rigid_motion_keeps_the_area(vertices: FloatArray, dx: float, dy: float, angle: float) -> None:
    base = map_area_m2(polygon(vertices), [[0.0, 0.0]])
    moved = rotate(vertices, angle) + np.array([dx, dy])
    area = map_area_m2(polygon(moved), [[dx, dy]])
    assert area == pytest.approx(base, abs=2 * len(vertices) * ANY_CORNER_M2)
    assert area_error_pct(polygon(moved), base, [[dx, dy]]) >= 0.0
