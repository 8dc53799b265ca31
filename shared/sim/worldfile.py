"""World files: a :class:`World` as a small JSON or TOML file (chosen by the suffix, ``.json``/``.toml``).

Keys (lengths in metres, areas in m^2)::

    name = "lab"                                  # optional
    floor_area_m2 = 45.4                          # optional if `outline` is given
    walls = [[x0, y0, x1, y1], ...]               # free-standing walls
    outline = [[x, y], ...]                       # optional closed polygon (the room's boundary)
    obstacles = [[[x, y], ...], ...]              # optional closed polygons inside the outline
    path = [[x, y], ...]                          # optional knots of the predefined path

The world's walls are ``walls`` plus the edges of ``outline`` and of every obstacle; a missing
``floor_area_m2`` is the outline's area minus the obstacles' (shoelace formula). :func:`save_world`
writes ``name``, ``floor_area_m2``, ``walls`` (all of them) and ``path``.
"""

from __future__ import annotations

import json
import logging
import math
import tomllib
from pathlib import Path
from typing import Any

import numpy as np

from shared.errors import InvalidInputError
from shared.sim.errors import WorldFileError
from shared.sim.world import World, polygon_area, polygon_walls
from shared.types import FloatArray

__all__ = ["load_world", "save_world"]

logger = logging.getLogger(__name__)

_KEYS = ("name", "floor_area_m2", "walls", "outline", "obstacles", "path")
_SUFFIXES = (".json", ".toml")


def _number(value: Any) -> bool:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    try:
        return math.isfinite(float(value))
    except OverflowError:  # an integer too large for a float
        return False


def _row(path: Path, entry: str, value: Any, size: int, what: str) -> list[float]:
    if not (isinstance(value, list) and len(value) == size and all(_number(v) for v in value)):
        raise WorldFileError(path, f"{value!r}: expected {what} ({size} finite numbers, metres)", entry)
    return [float(v) for v in value]


def _polygon(path: Path, entry: str, value: Any) -> FloatArray:
    if not isinstance(value, list):
        raise WorldFileError(path, f"{type(value).__name__}: expected a list of [x, y] vertices", entry)
    v = np.array([_row(path, f"{entry}[{i}]", p, 2, "[x, y]") for i, p in enumerate(value)]).reshape(-1, 2)
    if len(v) >= 2 and np.array_equal(v[0], v[-1]):
        v = v[:-1]  # the polygon was closed explicitly
    if len(v) < 3:
        raise WorldFileError(path, f"{len(v)} distinct vertices: expected a polygon of at least 3", entry)
    if polygon_area(v) <= 0.0:
        raise WorldFileError(path, "encloses no area: expected a closed polygon", entry)
    return v


def _list(path: Path, data: dict[str, Any], key: str) -> list[Any]:
    value = data.get(key, [])
    if not isinstance(value, list):
        raise WorldFileError(path, f"{type(value).__name__}: expected a list", key)
    return value


def _parse(path: Path, text: str) -> dict[str, Any]:
    suffix = path.suffix.lower()
    try:
        data: Any = tomllib.loads(text) if suffix == ".toml" else json.loads(text)
    except json.JSONDecodeError as exc:
        raise WorldFileError(
            path, f"invalid JSON at line {exc.lineno}, column {exc.colno}: {exc.msg}"
        ) from exc
    except tomllib.TOMLDecodeError as exc:
        raise WorldFileError(path, f"invalid TOML: {exc}") from exc
    if not isinstance(data, dict):
        raise WorldFileError(path, f"top level is a {type(data).__name__}: expected a table/object of keys")
    unknown = sorted(set(data) - set(_KEYS))
    if unknown:
        raise WorldFileError(path, f"unknown key(s) {unknown}: expected some of {list(_KEYS)}")
    return data


def load_world(path: Path | str) -> World:
    """Read and validate a world file (JSON or TOML, see the module docstring). O(file size).

    Raises :class:`WorldFileError` naming the file and the bad entry (e.g. ``walls[2]``).
    """
    path = Path(path)
    if path.suffix.lower() not in _SUFFIXES:
        raise WorldFileError(path, f"unknown suffix {path.suffix!r}: expected one of {list(_SUFFIXES)}")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise WorldFileError(path, f"cannot read the file: {exc}") from exc
    data = _parse(path, text)
    name = data.get("name", path.stem)
    if not isinstance(name, str) or not name:
        raise WorldFileError(path, f"{name!r}: expected a non-empty string", "name")
    walls = [
        _row(path, f"walls[{i}]", w, 4, "[x0, y0, x1, y1]") for i, w in enumerate(_list(path, data, "walls"))
    ]
    for i, w in enumerate(walls):
        if w[0] == w[2] and w[1] == w[3]:
            raise WorldFileError(
                path, f"{w!r} has zero length: expected two distinct end points", f"walls[{i}]"
            )
    parts = [np.array(walls, dtype=np.float64).reshape(-1, 4)]
    outline = _polygon(path, "outline", data["outline"]) if "outline" in data else None
    obstacles = [_polygon(path, f"obstacles[{i}]", o) for i, o in enumerate(_list(path, data, "obstacles"))]
    parts += [polygon_walls(p) for p in ([] if outline is None else [outline]) + obstacles]
    all_walls = np.vstack(parts)
    if len(all_walls) == 0:
        raise WorldFileError(path, "no walls: expected 'walls', 'outline' or 'obstacles'")
    area = data.get("floor_area_m2")
    if area is None:
        if outline is None:
            raise WorldFileError(
                path, "missing: give it, or an 'outline' polygon to compute it", "floor_area_m2"
            )
        area = polygon_area(outline) - sum(polygon_area(o) for o in obstacles)
        if area <= 0.0:
            raise WorldFileError(path, f"obstacles cover the outline ({area:.3f} m^2 left)", "floor_area_m2")
    elif not (_number(area) and area > 0):
        raise WorldFileError(path, f"{area!r}: expected a positive number of m^2", "floor_area_m2")
    knots = None
    if "path" in data:
        knots = np.array(
            [_row(path, f"path[{i}]", k, 2, "[x, y]") for i, k in enumerate(_list(path, data, "path"))]
        )
        if len(knots) < 2:
            raise WorldFileError(path, f"{len(knots)} knots: expected at least 2", "path")
    try:
        world = World(all_walls, float(area), name, knots)
    except InvalidInputError as exc:
        raise WorldFileError(path, str(exc)) from exc
    logger.debug(
        "loaded world %r from %s: %d walls, %.2f m^2", name, path, len(all_walls), world.floor_area_m2
    )
    return world


def _toml_string(text: str) -> str:
    # A JSON string literal without \u escapes of non-ASCII (TOML refuses surrogate pairs) is a TOML basic
    # string, except that TOML wants DEL escaped too.
    return json.dumps(text, ensure_ascii=False).replace("\x7f", "\\u007f")


def _toml_rows(rows: FloatArray) -> str:
    return "[\n" + "".join(f"  [{', '.join(repr(float(v)) for v in r)}],\n" for r in rows) + "]"


def save_world(world: World, path: Path | str) -> Path:
    """Write ``world`` to ``path`` (JSON or TOML by suffix) so that :func:`load_world` reads it back exactly.

    Floats are written with ``repr`` (shortest round-trip form). Returns the path written.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in _SUFFIXES:
        raise WorldFileError(path, f"unknown suffix {path.suffix!r}: expected one of {list(_SUFFIXES)}")
    if suffix == ".json":
        data: dict[str, Any] = {
            "name": world.name,
            "floor_area_m2": world.floor_area_m2,
            "walls": world.walls.tolist(),
        }
        if world.knots is not None:
            data["path"] = world.knots.tolist()
        text = json.dumps(data, indent=1) + "\n"
    else:
        lines = [
            f"name = {_toml_string(world.name)}",
            f"floor_area_m2 = {world.floor_area_m2!r}",
            f"walls = {_toml_rows(world.walls)}",
        ]
        if world.knots is not None:
            lines.append(f"path = {_toml_rows(world.knots)}")
        text = "\n".join(lines) + "\n"
    try:
        path.write_text(text, encoding="utf-8")
    except (OSError, UnicodeEncodeError) as exc:
        raise WorldFileError(path, f"cannot write the file: {exc}") from exc
    return path
