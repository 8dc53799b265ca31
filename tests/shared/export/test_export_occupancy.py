"""ROS map_server occupancy maps: rasterising walls, free space, PGM/YAML codecs and file round trips."""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy import ndimage

from shared.errors import InvalidInputError, LinemapError
from shared.export import (
    EmptyMapError,
    ExportIOError,
    OccupancyFormatError,
    OccupancyGrid,
    occupancy_paths,
    rasterise_segments,
    read_occupancy,
    write_occupancy,
)
from shared.export.mapserver import MapYaml, decode_map_yaml, decode_pgm, encode_map_yaml, encode_pgm
from shared.export.occupancy import FREE, OCCUPIED, UNKNOWN
from shared.pipeline.snapshot import MapSnapshot
from shared.sim import default_world
from shared.types import Pose2D

# What ROS map_saver writes (map_saver.cpp: "%f" numbers, free_thresh/occupied_thresh as given)
MAP_SAVER_YAML = """image: map.pgm
resolution: 0.050000
origin: [-10.000000, -10.000000, 0.000000]
negate: 0
occupied_thresh: 0.65
free_thresh: 0.196

"""


def _samples(segments: np.ndarray, step_m: float) -> np.ndarray:
    """Points along every segment, at most ``step_m`` apart, end points included."""
    out = []
    for x0, y0, x1, y1 in segments:
        n = max(math.ceil(math.hypot(x1 - x0, y1 - y0) / step_m), 1) + 1
        t = np.linspace(0.0, 1.0, n)
        out.append(np.column_stack([x0 + t * (x1 - x0), y0 + t * (y1 - y0)]))
    return np.vstack(out)


def _near_occupied(grid: OccupancyGrid, xy: np.ndarray) -> np.ndarray:
    """Per point: is there an occupied pixel within one cell (its own or one of the 8 around it)?"""
    occupied = np.pad(grid.pixels == OCCUPIED, 1)
    row, col = grid.world_to_pixel(xy)
    assert ((row >= 0) & (row < grid.height) & (col >= 0) & (col < grid.width)).all(), "points off the map"
    near = np.zeros(len(xy), dtype=bool)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            near |= occupied[row + 1 + dr, col + 1 + dc]
    return near


def test_written_map_reads_back_with_the_same_pixels_origin_and_resolution(
    tmp_path: Path, snapshot: MapSnapshot
) -> None:
    pgm, yaml = write_occupancy(tmp_path / "room", snapshot, resolution_m=0.05)
    assert (pgm, yaml) == (tmp_path / "room.pgm", tmp_path / "room.yaml")
    grid = rasterise_segments(snapshot.segments, resolution_m=0.05, inside_xy=snapshot.trajectory[:, 1:3])
    back = read_occupancy(yaml)
    assert back.resolution_m == 0.05 and back.origin == grid.origin
    np.testing.assert_array_equal(back.pixels, grid.pixels)
    assert (back.negate, back.occupied_thresh, back.free_thresh) == (0, 0.65, 0.196)
    text = yaml.read_text(encoding="utf-8")
    assert "image: room.pgm\n" in text and "negate: 0\n" in text and "mode: trinary\n" in text
    assert "occupied_thresh: 0.65\n" in text and "free_thresh: 0.196\n" in text
    assert pgm.read_bytes().startswith(b"P5\n# CREATOR: linemap 0.050 m/pix\n")
    # the image is whole pixels of the three map_saver values, rows top to bottom
    assert set(np.unique(back.pixels).tolist()) == {OCCUPIED, FREE, UNKNOWN}


def test_every_wall_sample_falls_on_an_occupied_cell(snapshot: MapSnapshot) -> None:
    for res in (0.02, 0.05, 0.1, 0.37):
        grid = rasterise_segments(snapshot.segments, resolution_m=res, inside_xy=snapshot.trajectory[:, 1:3])
        assert _near_occupied(grid, _samples(snapshot.segments, res / 10)).all(), res
        # and the cell of every sample itself is occupied: walls are the cells the segment passes through
        row, col = grid.world_to_pixel(_samples(snapshot.segments, res / 10))
        assert (grid.pixels[row, col] == OCCUPIED).mean() > 0.999, res


def test_pixel_row_zero_is_the_top_and_the_origin_the_lower_left_corner() -> None:
    # an L of walls mid-cell (0.05 m off the 0.1 m grid lines): along x at y = 0.05, along y at x = 0.05
    walls = [[0.05, 0.05, 1.05, 0.05], [0.05, 0.05, 0.05, 0.55]]
    grid = rasterise_segments(walls, resolution_m=0.1, mark_free=False)
    ox, oy, yaw = grid.origin
    assert (ox, oy, yaw) == (-0.3, -0.3, 0.0)  # three cells of margin, a whole number of cells from 0
    assert (grid.height, grid.width) == (3 + 6 + 3, 3 + 11 + 3)
    low = grid.height - 1 - 3  # y = 0.05 is in the 4th row from the BOTTOM
    assert (grid.pixels[low, 3:14] == OCCUPIED).all() and (grid.pixels[low, 14:] == UNKNOWN).all()
    assert (grid.pixels[low - 5 : low + 1, 3] == OCCUPIED).all()  # the wall up along y, rows going up
    assert (grid.pixels[: low - 5] == UNKNOWN).all() and (grid.pixels[low + 1 :] == UNKNOWN).all()
    assert int((grid.pixels == OCCUPIED).sum()) == 11 + 5
    row, col = grid.world_to_pixel([[ox + 0.01, oy + 0.01], [ox + 0.01, oy + grid.height * 0.1 - 0.01]])
    assert (row.tolist(), col.tolist()) == ([grid.height - 1, 0], [0, 0])


@settings(max_examples=200, deadline=None)
@given(
    height=st.integers(1, 500),
    width=st.integers(1, 500),
    res=st.floats(1e-3, 2.0),
    ox=st.floats(-1e3, 1e3),
    oy=st.floats(-1e3, 1e3),
    yaw=st.floats(-math.pi, math.pi),
    data=st.data(),
)
def test_world_pixel_transform_round_trips(
    height: int, width: int, res: float, ox: float, oy: float, yaw: float, data: st.DataObject
) -> None:
    grid = OccupancyGrid(np.zeros((height, width), dtype=np.uint8), res, (ox, oy, yaw))
    row = data.draw(st.integers(0, height - 1))
    col = data.draw(st.integers(0, width - 1))
    centre = grid.pixel_to_world([row], [col])
    back = grid.world_to_pixel(centre)
    assert (int(back[0][0]), int(back[1][0])) == (row, col)
    # any point strictly inside the pixel maps to it; the lower-left corner of the image is the origin
    fu, fv = data.draw(st.floats(0.05, 0.95)), data.draw(st.floats(0.05, 0.95))
    u, v = (col + fu) * res, (height - 1 - row + fv) * res
    c, s = math.cos(yaw), math.sin(yaw)
    inside = np.array([[ox + c * u - s * v, oy + s * u + c * v]])
    assert tuple(int(a[0]) for a in grid.world_to_pixel(inside)) == (row, col)


@settings(max_examples=150, deadline=None)
@given(
    seg=arrays(np.float64, 4, elements=st.floats(-20.0, 20.0)),
    res=st.floats(0.02, 0.5),
)
def test_one_wall_is_four_connected_and_covers_its_samples(seg: np.ndarray, res: float) -> None:
    grid = rasterise_segments(seg[None, :], resolution_m=res, mark_free=False)
    occupied = grid.pixels == OCCUPIED
    _, components = ndimage.label(occupied)  # default structure: 4-connectivity
    assert components == 1, "a wall must not break into diagonal steps a planner could slip through"
    assert _near_occupied(grid, _samples(seg[None, :], res / 7)).all()
    # a thin line, not a blob: one cell per grid line crossed, plus both cells where it passes a corner
    dx, dy = abs(seg[2] - seg[0]), abs(seg[3] - seg[1])
    assert occupied.sum() <= (dx + dy + min(dx, dy)) / res + 4


def test_free_space_is_the_enclosed_floor() -> None:
    world = default_world()
    assert world.knots is not None
    res = 0.05
    grid = rasterise_segments(world.walls, resolution_m=res, inside_xy=world.knots)
    free = grid.pixels == FREE
    perimeter = float(
        np.hypot(world.walls[:, 2] - world.walls[:, 0], world.walls[:, 3] - world.walls[:, 1]).sum()
    )
    free_area = free.sum() * res**2
    assert world.floor_area_m2 - 1.5 * perimeter * res <= free_area <= world.floor_area_m2
    # the robot's path is on free cells; outside the outline and inside the boxes is unknown
    row, col = grid.world_to_pixel(world.knots)
    assert (grid.pixels[row, col] == FREE).all()
    for x, y in [(6.0, 6.0), (2.4, 1.6), (7.3, 2.7), (-0.1, 2.0)]:
        r, c = grid.world_to_pixel([[x, y]])
        assert grid.pixels[r[0], c[0]] == UNKNOWN, (x, y)
    # map_server's reading of the grey values (negate 0, thresholds 0.65 / 0.196) gives the same classes
    np.testing.assert_array_equal(grid.occupied(), grid.pixels == OCCUPIED)
    np.testing.assert_array_equal(grid.free(), free)


def test_open_map_or_no_trajectory_marks_no_free_space() -> None:
    open_walls = [[0.0, 0.0, 4.0, 0.0], [4.0, 0.0, 4.0, 3.0]]  # two walls enclose nothing
    for grid in (
        rasterise_segments(open_walls, inside_xy=[[2.0, 1.0]]),
        rasterise_segments(default_world().walls),
        rasterise_segments(default_world().walls, inside_xy=default_world().knots, mark_free=False),
    ):
        assert not (grid.pixels == FREE).any()
        assert (grid.pixels == OCCUPIED).any()


def test_the_map_covers_the_trajectory_too() -> None:
    grid = rasterise_segments([[0.0, 0.0, 1.0, 0.0]], resolution_m=0.1, inside_xy=[[5.0, 3.0]])
    row, col = grid.world_to_pixel([[5.0, 3.0]])
    assert 0 <= row[0] < grid.height and 0 <= col[0] < grid.width


@pytest.mark.parametrize("bad", [0.0, -0.05, math.nan, math.inf, "0.05", True])
def test_bad_resolution_is_named(bad: object, snapshot: MapSnapshot, tmp_path: Path) -> None:
    with pytest.raises(InvalidInputError, match=r"resolution_m = .*: expected a (positive )?number"):
        write_occupancy(tmp_path / "m", snapshot, resolution_m=bad)  # type: ignore[arg-type]
    assert list(tmp_path.iterdir()) == []


def test_too_fine_a_resolution_is_refused_before_allocating(snapshot: MapSnapshot) -> None:
    with pytest.raises(InvalidInputError, match=r"more than max_cells = 16000000: use a larger resolution"):
        rasterise_segments(snapshot.segments, resolution_m=1e-4)
    with pytest.raises(InvalidInputError, match="use a larger resolution"):
        rasterise_segments([[0.0, 0.0, 1e300, 1e300]], resolution_m=1e-300)


def test_empty_map_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(EmptyMapError, match="no walls"):
        write_occupancy(tmp_path / "m", MapSnapshot.empty())
    assert issubclass(EmptyMapError, LinemapError)
    assert list(tmp_path.iterdir()) == []


def test_unwritable_folder_is_named(tmp_path: Path, snapshot: MapSnapshot) -> None:
    target = tmp_path / "missing" / "m"
    with pytest.raises(ExportIOError, match=r"missing/m\.pgm"):
        write_occupancy(target, snapshot)


@pytest.mark.parametrize(
    ("given", "pgm", "yaml"),
    [
        ("m", "m.pgm", "m.yaml"),
        ("m.yaml", "m.pgm", "m.yaml"),
        ("m.YML", "m.pgm", "m.YML"),
        ("m.pgm", "m.pgm", "m.yaml"),
        ("run.v2", "run.v2.pgm", "run.v2.yaml"),
    ],
)
def test_occupancy_paths(given: str, pgm: str, yaml: str, tmp_path: Path) -> None:
    assert occupancy_paths(tmp_path / given) == (tmp_path / pgm, tmp_path / yaml)


def test_yaml_path_given_writes_the_pair_and_reads_back(tmp_path: Path, snapshot: MapSnapshot) -> None:
    pgm, yaml = write_occupancy(tmp_path / "office.yaml", snapshot, resolution_m=0.1)
    assert pgm == tmp_path / "office.pgm" and pgm.is_file() and yaml.is_file()
    for name in ("office", "office.pgm", "office.yaml"):
        assert read_occupancy(tmp_path / name).resolution_m == 0.1
    # an existing file keeps its permissions when replaced (atomic write)
    os.chmod(pgm, 0o600)
    write_occupancy(tmp_path / "office.yaml", snapshot, resolution_m=0.1)
    assert pgm.stat().st_mode & 0o777 == 0o600
    assert sorted(p.name for p in tmp_path.iterdir()) == ["office.pgm", "office.yaml"]


def test_reads_a_map_saver_map(tmp_path: Path) -> None:
    pixels = np.full((4, 6), UNKNOWN, dtype=np.uint8)
    pixels[0, :] = OCCUPIED
    pixels[1:, 1:5] = FREE
    (tmp_path / "map.pgm").write_bytes(
        b"P5\n# CREATOR: map_saver.cpp 0.050 m/pix\n6 4\n255\n" + pixels.tobytes()
    )
    (tmp_path / "map.yaml").write_text(MAP_SAVER_YAML)
    grid = read_occupancy(tmp_path / "map.yaml")
    assert grid.origin == (-10.0, -10.0, 0.0) and grid.resolution_m == 0.05
    np.testing.assert_array_equal(grid.pixels, pixels)
    assert grid.occupied()[0].all() and grid.free()[1:, 1:5].all() and not grid.free()[:, 0].any()
    # the top row is the highest y
    assert grid.pixel_to_world([0], [0])[0, 1] == pytest.approx(-10.0 + 3.5 * 0.05)


def test_missing_image_is_named(tmp_path: Path) -> None:
    (tmp_path / "map.yaml").write_text(MAP_SAVER_YAML)
    with pytest.raises(ExportIOError, match=r"map\.pgm \(named by .*map\.yaml\)"):
        read_occupancy(tmp_path / "map.yaml")
    (tmp_path / "other.yaml").write_text(MAP_SAVER_YAML.replace("map.pgm", "map.png"))
    with pytest.raises(OccupancyFormatError, match=r"image 'map\.png': expected a \.pgm image"):
        read_occupancy(tmp_path / "other.yaml")


# --- PGM codec -------------------------------------------------------------------------------------------


@settings(max_examples=100, deadline=None)
@given(
    pixels=arrays(np.uint8, st.tuples(st.integers(1, 40), st.integers(1, 40))),
    comment=st.none() | st.text(st.characters(min_codepoint=32, max_codepoint=126), max_size=30),
)
def test_pgm_round_trip(pixels: np.ndarray, comment: str | None) -> None:
    np.testing.assert_array_equal(decode_pgm(encode_pgm(pixels, comment=comment)), pixels)


def test_pgm_header_may_hold_comments_anywhere() -> None:
    data = b"P5 # a comment\n3\n# another\r2 255\n" + bytes(range(6))
    np.testing.assert_array_equal(decode_pgm(data), np.arange(6, dtype=np.uint8).reshape(2, 3))


@pytest.mark.parametrize(
    ("data", "message"),
    [
        (b"P2\n2 2\n255\n0 0 0 0\n", r"starts with b'P2': expected b'P5'"),
        (b"P5\n2 2\n65535\n" + bytes(8), "maxval 65535: expected 255"),
        (b"P5\n2 2\n255\n" + bytes(3), r"raster has 3 bytes: expected 2 x 2 = 4"),
        (b"P5\n2 2\n255\n" + bytes(5), r"raster has 5 bytes"),
        (b"P5\nx 2\n255\n", "width is b'x 2"),
        (b"P5\n0 2\n255\n", r"size 0 x 2"),
        (b"P5\n2 2\n255", "one whitespace byte after the maxval"),
        (b"P52 2 255\n", "whitespace before the width"),
    ],
)
def test_bad_pgm_is_named(data: bytes, message: str) -> None:
    with pytest.raises(OccupancyFormatError, match=message):
        decode_pgm(data, "x.pgm")


# --- map_server YAML -------------------------------------------------------------------------------------


def test_map_saver_yaml_parses() -> None:
    meta = decode_map_yaml(MAP_SAVER_YAML + "# a comment\nextra_key: ignored  # trailing comment\n")
    assert meta == MapYaml("map.pgm", 0.05, (-10.0, -10.0, 0.0), 0, 0.65, 0.196, "trinary")
    assert decode_map_yaml("image: 'a b.pgm'\nresolution: 1\norigin: [1, 2, 3]\nmode: raw").image == "a b.pgm"


_names = st.text(st.characters(min_codepoint=32, max_codepoint=0x2FF), min_size=1, max_size=20)
_floats = st.floats(allow_nan=False, allow_infinity=False, min_value=-1e12, max_value=1e12)


@settings(max_examples=200, deadline=None)
@given(
    image=_names,
    res=st.floats(1e-9, 1e6),
    origin=st.tuples(_floats, _floats, st.floats(-math.pi, math.pi)),
    negate=st.integers(0, 1),
    thresholds=st.tuples(st.floats(0.0, 1.0), st.floats(0.0, 1.0)).map(sorted),
    mode=st.sampled_from(["trinary", "scale", "raw"]),
)
def test_map_yaml_round_trip(
    image: str,
    res: float,
    origin: tuple[float, float, float],
    negate: int,
    thresholds: list[float],
    mode: str,
) -> None:
    meta = MapYaml(image, res, origin, negate, thresholds[1], thresholds[0], mode)
    text = encode_map_yaml(meta)
    assert "e" not in text.split("resolution: ")[1].split("\n")[0]  # positional numbers only
    assert decode_map_yaml(text) == meta


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("resolution: 0.05\norigin: [0, 0, 0]\n", "no 'image'"),
        ("image: m.pgm\norigin: [0, 0, 0]\n", "no 'resolution'"),
        ("image: m.pgm\nresolution: fine\norigin: [0, 0, 0]\n", "line 2: resolution is 'fine'"),
        ("image: m.pgm\nresolution: -1\norigin: [0, 0, 0]\n", r"resolution -1.0: expected > 0"),
        ("image: m.pgm\nresolution: 0.05\norigin: [0, 0]\n", r"line 3: origin is \['0', '0'\]"),
        ("image: m.pgm\nresolution: 0.05\norigin: [0, nan, 0]\n", "three finite numbers"),
        ("image: m.pgm\nresolution: 0.05\n", "no 'origin'"),
        ("image: m.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nnegate: 2\n", "negate is 2: expected 0 or 1"),
        ("image: m.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nmode: fuzzy\n", "mode is 'fuzzy'"),
        ("image: m.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nfree_thresh: 0.9\n", "free_thresh 0.9"),
        ("image: m.pgm\nimage: n.pgm\n", "line 2: key 'image' given twice"),
        ("image: m.pgm\n  nested: 1\n", "line 2: .* expected 'key: value'"),
        ("just text\n", "line 1: 'just text'"),
        ("image: 'm.pgm\n", "unterminated ' string"),
        ("image: m.pgm\nresolution: 0.05\norigin: [0, 0, 0\n", "closed by ']'"),
    ],
)
def test_bad_yaml_is_named(text: str, message: str) -> None:
    with pytest.raises(OccupancyFormatError, match=message):
        decode_map_yaml(text, "m.yaml")


def test_snapshot_with_one_pose_only_rasterises(tmp_path: Path) -> None:
    snap = MapSnapshot(
        1,
        0.0,
        np.array([[0.0, 0.0, 2.0, 0.0]]),
        np.array([1], dtype=np.intp),
        np.zeros((0, 2)),
        Pose2D(),
        np.array([[0.0, 1.0, 1.0, 0.0]]),
    )
    pgm, _ = write_occupancy(tmp_path / "m", snap, resolution_m=0.25)
    # x 0..2 m and y 0..1 m (the pose) in 0.25 m cells, both ends inclusive, plus 3 cells each side
    assert decode_pgm(pgm.read_bytes()).shape == (3 + 5 + 3, 3 + 9 + 3)
