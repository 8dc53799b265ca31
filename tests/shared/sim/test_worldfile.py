"""World files: loading, saving, computed floor areas and the errors for bad entries."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.errors import LinemapError
from shared.sim import World, WorldFileError, default_world, load_world, save_world

EXAMPLE = Path(__file__).resolve().parent / "data" / "example_world.toml"


def _write(tmp_path: Path, data: object, name: str = "w.json") -> Path:
    path = tmp_path / name
    path.write_text(json.dumps(data), encoding="utf-8")
    return path


def test_example_file_computes_area_and_walls() -> None:
    world = load_world(EXAMPLE)
    assert world.name == "example-room"
    assert world.floor_area_m2 == pytest.approx(47.0)  # 8 x 6 outline minus the 1 m^2 box
    assert world.walls.shape == (1 + 4 + 4, 4)
    np.testing.assert_array_equal(world.walls[0], [3.0, 6.0, 3.0, 4.0])
    # the outline closes on itself: its last edge runs from (0, 6) back to (0, 0)
    np.testing.assert_array_equal(world.walls[4], [0.0, 6.0, 0.0, 0.0])
    assert world.knots is not None
    np.testing.assert_array_equal(world.knots[-1], [7.0, 4.5])


@pytest.mark.parametrize("suffix", [".json", ".toml"])
def test_round_trip_is_exact(tmp_path: Path, suffix: str) -> None:
    world = default_world()
    path = save_world(world, tmp_path / f"world{suffix}")
    back = load_world(path)
    np.testing.assert_array_equal(back.walls, world.walls)
    assert back.floor_area_m2 == world.floor_area_m2 and back.name == world.name
    assert back.knots is not None and world.knots is not None
    np.testing.assert_array_equal(back.knots, world.knots)


def test_explicit_area_wins_and_closed_outline_accepted(tmp_path: Path) -> None:
    square = [[0, 0], [2, 0], [2, 2], [0, 2], [0, 0]]  # explicitly closed
    world = load_world(_write(tmp_path, {"outline": square}))
    assert world.floor_area_m2 == pytest.approx(4.0) and world.walls.shape == (4, 4)
    assert world.name == "w" and world.knots is None  # name defaults to the file's stem
    given_area = load_world(_write(tmp_path, {"outline": square, "floor_area_m2": 3.5}))
    assert given_area.floor_area_m2 == 3.5


@pytest.mark.parametrize(
    ("data", "entry", "fragment"),
    [
        ({"walls": [[0, 0, 1, 0], [0, 0, 1]], "floor_area_m2": 1}, "walls[1]", "[x0, y0, x1, y1]"),
        ({"walls": [[0, 0, 1, "a"]], "floor_area_m2": 1}, "walls[0]", "4 finite numbers"),
        ({"walls": [[0, 0, 1, True]], "floor_area_m2": 1}, "walls[0]", "4 finite numbers"),
        ({"walls": [[1, 1, 1, 1]], "floor_area_m2": 1}, "walls[0]", "zero length"),
        ({"walls": "none", "floor_area_m2": 1}, "walls", "expected a list"),
        ({"walls": [[0, 0, 1, 0]]}, "floor_area_m2", "outline"),
        ({"walls": [[0, 0, 1, 0]], "floor_area_m2": -2}, "floor_area_m2", "positive"),
        ({"outline": [[0, 0], [1, 0]]}, "outline", "at least 3"),
        ({"outline": [[0, 0], [1, 0], [2, 0]]}, "outline", "no area"),
        ({"outline": [[0, 0], [1, 0], [1, 1]], "obstacles": [[[0, 0], [1]]]}, "obstacles[0][1]", "[x, y]"),
        (
            {"outline": [[0, 0], [1, 0], [0, 1]], "obstacles": [[[0, 0], [1, 0], [0, 1]]]},
            "floor_area_m2",
            "cover",
        ),
        ({"walls": [[0, 0, 1, 0]], "floor_area_m2": 1, "path": [[0, 0]]}, "path", "at least 2"),
        ({"walls": [[0, 0, 1, 0]], "floor_area_m2": 1, "path": [[0, 0], [1, 2, 3]]}, "path[1]", "[x, y]"),
        ({"walls": [[0, 0, 1, 0]], "floor_area_m2": 1, "name": 7}, "name", "string"),
        ({"walls": [[0, 0, 1, 1e400]], "floor_area_m2": 1}, "walls[0]", "finite"),
    ],
)
def test_bad_entries_are_named(tmp_path: Path, data: dict[str, object], entry: str, fragment: str) -> None:
    path = _write(tmp_path, data)
    with pytest.raises(WorldFileError) as info:
        load_world(path)
    message = str(info.value)
    assert str(path) in message and f"{entry}:" in message and fragment in message
    assert info.value.entry == entry and info.value.path == path


@pytest.mark.parametrize(
    ("name", "text", "fragment"),
    [
        ("bad.json", '{"walls": [[0, 0, 1, 0]],\n "floor_area_m2": }', "line 2"),
        ("bad.toml", "walls = [[0, 0, 1, 0]\nfloor_area_m2 = 1", "invalid TOML"),
        ("list.json", "[[0, 0, 1, 0]]", "top level is a list"),
        ("typo.json", '{"wals": [[0, 0, 1, 0]], "floor_area_m2": 1}', "unknown key(s) ['wals']"),
        ("empty.json", "{}", "no walls"),
        ("world.yaml", "walls: []", "unknown suffix"),
    ],
)
def test_whole_file_errors(tmp_path: Path, name: str, text: str, fragment: str) -> None:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    with pytest.raises(WorldFileError, match=r".*") as info:
        load_world(path)
    assert str(path) in str(info.value) and fragment in str(info.value)


def test_missing_file_is_a_linemap_error(tmp_path: Path) -> None:
    with pytest.raises(LinemapError, match="cannot read"):
        load_world(tmp_path / "absent.json")


_coord = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)


@settings(max_examples=50, deadline=None)
@given(
    walls=st.lists(st.tuples(_coord, _coord, _coord, _coord), min_size=1, max_size=8).filter(
        lambda ws: all((w[0], w[1]) != (w[2], w[3]) for w in ws)
    ),
    area=st.floats(1e-6, 1e6),
    name=st.text(min_size=1, max_size=12),
    suffix=st.sampled_from([".json", ".toml"]),
)
def test_round_trip_property(
    tmp_path_factory: pytest.TempPathFactory,
    walls: list[tuple[float, ...]],
    area: float,
    name: str,
    suffix: str,
) -> None:
    world = World(np.array(walls), area, name)
    back = load_world(save_world(world, tmp_path_factory.mktemp("rt") / f"w{suffix}"))
    np.testing.assert_array_equal(back.walls, world.walls)
    assert back.floor_area_m2 == area and back.name == name and back.knots is None


_json = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=3),
    lambda inner: st.lists(inner, max_size=5) | st.dictionaries(st.text(max_size=3), inner, max_size=3),
    max_leaves=20,
)


@settings(max_examples=150, deadline=None)
@given(
    walls=_json,
    outline=_json,
    area=_json,
    path=_json,
)
def test_junk_gives_world_or_world_file_error(
    tmp_path_factory: pytest.TempPathFactory, walls: object, outline: object, area: object, path: object
) -> None:
    file = tmp_path_factory.mktemp("junk") / "w.json"
    file.write_text(json.dumps({"walls": walls, "outline": outline, "floor_area_m2": area, "path": path}))
    message = ""
    try:
        world = load_world(file)
    except WorldFileError as exc:
        message = str(exc)
    if message:
        assert str(file) in message
    else:
        assert world.walls.shape[1] == 4 and world.floor_area_m2 > 0
