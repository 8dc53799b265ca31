"""The map as GeoJSON (RFC 7946 structure, local metric frame), and reading its segments back.

Output contract (other tools rely on it): a ``FeatureCollection`` in which every map segment is a ``Feature``
with a ``LineString`` geometry of exactly two ``[x, y]`` positions in metres in the log's world frame and
properties ``{"kind": "segment", "id": <segment id>}``, in snapshot order. Then, optionally: one ``Point``
per cluster centroid (``{"kind": "centroid"}``), the trajectory as one ``LineString``
(``{"kind": "trajectory", "stamps_s": [...]}``, only when it has two or more poses, as GeoJSON requires) and
the final pose as a ``Point`` (``{"kind": "pose", "theta": <rad>, "stamp_s": <s>}``).

The coordinates are NOT WGS84 longitude/latitude: they are metres in the local world frame of the log (REP
103, x forward/east, y left/north at the start pose), so the file has no ``crs`` member; GIS tools will show
the map at the wrong place on Earth but with the right shape if told the units are metres. Snapshot
metadata (``version``, ``stamp_s``, ``units``, ``frame``) and the caller's ``extra_properties`` go into a
top-level ``properties`` object (a GeoJSON foreign member). Numbers are rounded to 1e-9 (nm, nrad), far
below the 1e-6 m the contract asks; the file holds one feature per line for readable diffs.
"""

from __future__ import annotations

import json
import logging
import math
import os
from collections.abc import Mapping
from typing import Any

import numpy as np

from shared.errors import InvalidInputError
from shared.export.atomic import atomic_write_text, read_text
from shared.export.errors import GeoJSONFormatError
from shared.export.validate import check_snapshot
from shared.pipeline.snapshot import MapSnapshot
from shared.types import FloatArray

__all__ = ["COORDINATE_DECIMALS", "read_geojson_segments", "write_geojson"]

_log = logging.getLogger(__name__)

COORDINATE_DECIMALS = 9
"""Decimal places kept for coordinates and angles in the GeoJSON file (1e-9 m / rad)."""

_STAMP_DECIMALS = 6


def _num(value: float, decimals: int = COORDINATE_DECIMALS) -> float:
    return round(float(value), decimals) + 0.0  # + 0.0 turns -0.0 into 0.0


def _xy(x: float, y: float) -> list[float]:
    return [_num(x), _num(y)]


def _feature(geometry: dict[str, Any], properties: dict[str, Any]) -> dict[str, Any]:
    return {"type": "Feature", "geometry": geometry, "properties": properties}


def _build_features(snapshot: MapSnapshot) -> list[dict[str, Any]]:
    checked = check_snapshot(snapshot)
    features: list[dict[str, Any]] = []
    for row, seg_id in zip(checked.segments.tolist(), checked.segment_ids.tolist(), strict=True):
        geometry = {"type": "LineString", "coordinates": [_xy(row[0], row[1]), _xy(row[2], row[3])]}
        features.append(_feature(geometry, {"kind": "segment", "id": int(seg_id)}))
    for cx, cy in checked.centroids.tolist():
        features.append(_feature({"type": "Point", "coordinates": _xy(cx, cy)}, {"kind": "centroid"}))
    traj = checked.trajectory
    if traj.shape[0] >= 2:
        coords = [_xy(x, y) for x, y in traj[:, 1:3].tolist()]
        stamps = [_num(s, _STAMP_DECIMALS) for s in traj[:, 0].tolist()]
        features.append(
            _feature(
                {"type": "LineString", "coordinates": coords}, {"kind": "trajectory", "stamps_s": stamps}
            )
        )
    x, y, theta = checked.pose_xy_theta
    features.append(
        _feature(
            {"type": "Point", "coordinates": _xy(x, y)},
            {"kind": "pose", "theta": _num(theta), "stamp_s": _num(snapshot.stamp_s, _STAMP_DECIMALS)},
        )
    )
    return features


def write_geojson(
    path: str | os.PathLike[str],
    snapshot: MapSnapshot,
    *,
    extra_properties: Mapping[str, Any] | None = None,
) -> None:
    """Write ``snapshot`` to ``path`` as a GeoJSON FeatureCollection (contract in the module docstring).

    ``extra_properties`` (JSON-serialisable, string keys) are merged into the collection's top-level
    ``properties`` after ``version``, ``stamp_s``, ``units`` and ``frame`` (so they may override them). The
    file is written atomically (temp file + rename), UTF-8. O(L + C + T).

    Raises :class:`InvalidInputError` for bad snapshot arrays or unserialisable ``extra_properties`` and
    :class:`~shared.export.errors.ExportIOError` when the file cannot be written.
    """
    if not math.isfinite(snapshot.stamp_s):
        raise InvalidInputError(
            f"snapshot.stamp_s = {snapshot.stamp_s!r}: expected a finite number of seconds"
        )
    features = _build_features(snapshot)
    meta: dict[str, Any] = {
        "version": int(snapshot.version),
        "stamp_s": _num(snapshot.stamp_s, _STAMP_DECIMALS),
        "units": "m",
        "frame": "world (local metric, not WGS84)",
    }
    if extra_properties is not None:
        for key in extra_properties:
            if not isinstance(key, str):
                raise InvalidInputError(f"extra_properties key {key!r}: expected a string")
        meta.update(extra_properties)
    try:
        head = json.dumps(
            {"type": "FeatureCollection", "properties": meta}, ensure_ascii=False, allow_nan=False
        )
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(
            f"extra_properties cannot be written as JSON ({exc}): expected str/int/finite float/bool/None, "
            "lists and string-keyed dicts"
        ) from exc
    body = ",\n".join(json.dumps(f, ensure_ascii=False, allow_nan=False) for f in features)
    text = f'{head[:-1]}, "features": [\n{body}\n]}}\n'
    atomic_write_text(path, text)
    _log.debug("wrote GeoJSON map %s: %d features", path, len(features))


def _is_number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _segment_row(feature: Mapping[str, Any], where: str) -> list[float]:
    geometry = feature.get("geometry")
    if not isinstance(geometry, dict):
        raise GeoJSONFormatError(f"{where}: geometry is {geometry!r}: expected a LineString object")
    if geometry.get("type") != "LineString":
        raise GeoJSONFormatError(f"{where}: geometry type is {geometry.get('type')!r}: expected 'LineString'")
    coords = geometry.get("coordinates")
    if not isinstance(coords, list) or len(coords) != 2:
        count = f"{len(coords)} positions" if isinstance(coords, list) else repr(coords)
        raise GeoJSONFormatError(f"{where}: coordinates has {count}: expected exactly 2 [x, y] positions")
    row: list[float] = []
    for k, pos in enumerate(coords):
        if not isinstance(pos, list) or len(pos) != 2 or not all(_is_number(v) for v in pos):
            raise GeoJSONFormatError(
                f"{where}: position {k} is {pos!r}: expected [x, y], two finite numbers in metres"
            )
        row.extend(float(v) for v in pos)
    return row


def read_geojson_segments(path: str | os.PathLike[str]) -> FloatArray:
    """Read the map segments of a GeoJSON file as an ``(L, 4)`` ``[x0, y0, x1, y1]`` metre array.

    Only features whose ``properties.kind == "segment"`` are read, in file order; other features are
    skipped. Each of those must follow the contract (module docstring); otherwise
    :class:`GeoJSONFormatError` names the file, the feature index and what was expected.
    :class:`~shared.export.errors.ExportIOError` if the file cannot be read. O(file size).
    """
    text = read_text(path, GeoJSONFormatError)
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise GeoJSONFormatError(
            f"{path}: line {exc.lineno} column {exc.colno}: {exc.msg}: expected valid JSON"
        ) from exc
    except RecursionError as exc:
        raise GeoJSONFormatError(
            f"{path}: JSON nested too deeply: expected a GeoJSON FeatureCollection"
        ) from exc
    if not isinstance(doc, dict) or doc.get("type") != "FeatureCollection":
        found = doc.get("type") if isinstance(doc, dict) else type(doc).__name__
        raise GeoJSONFormatError(f"{path}: top level is {found!r}: expected a GeoJSON 'FeatureCollection'")
    features = doc.get("features")
    if not isinstance(features, list):
        raise GeoJSONFormatError(f"{path}: 'features' is {type(features).__name__}: expected a list")
    rows: list[list[float]] = []
    for index, feature in enumerate(features):
        where = f"{path}: feature {index}"
        if not isinstance(feature, dict) or feature.get("type") != "Feature":
            raise GeoJSONFormatError(f"{where}: expected an object with type 'Feature'")
        props = feature.get("properties")
        if props is not None and not isinstance(props, dict):
            raise GeoJSONFormatError(f"{where}: properties is {type(props).__name__}: expected an object")
        if props is None or props.get("kind") != "segment":
            continue
        rows.append(_segment_row(feature, where))
    out = np.array(rows, dtype=np.float64).reshape(-1, 4)
    _log.debug("read %d segments from %s", out.shape[0], path)
    return out
