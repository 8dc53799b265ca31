"""GeoJSON export: the output contract, round trips and reader errors."""

from __future__ import annotations

import json
import math
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from shared.errors import InvalidInputError, LinemapError
from shared.export import ExportIOError, GeoJSONFormatError, read_geojson_segments, write_geojson
from shared.pipeline.snapshot import MapSnapshot
from shared.types import Pose2D


def _segments_only(segments: np.ndarray, ids: np.ndarray | None = None) -> MapSnapshot:
    n = segments.shape[0]
    return MapSnapshot(
        1,
        0.0,
        segments,
        np.arange(n, dtype=np.intp) if ids is None else ids,
        np.zeros((0, 2)),
        Pose2D(),
        np.zeros((0, 4)),
    )


def _features(path: Path, kind: str) -> list[dict[str, Any]]:
    doc = json.loads(path.read_text(encoding="utf-8"))
    return [f for f in doc["features"] if f["properties"]["kind"] == kind]


def test_contract_every_segment_feature(tmp_path: Path, snapshot: MapSnapshot) -> None:
    out = tmp_path / "map.geojson"
    write_geojson(out, snapshot)
    doc = json.loads(out.read_text(encoding="utf-8"))
    assert doc["type"] == "FeatureCollection"
    assert "crs" not in doc
    assert doc["properties"]["version"] == 3
    assert all(f["type"] == "Feature" for f in doc["features"])
    segs = [f for f in doc["features"] if f["properties"].get("kind") == "segment"]
    assert len(segs) == 4
    for feature, row, seg_id in zip(segs, snapshot.segments, snapshot.segment_ids, strict=True):
        assert feature["properties"] == {"kind": "segment", "id": int(seg_id)}
        geometry = feature["geometry"]
        assert geometry["type"] == "LineString"
        coords = geometry["coordinates"]
        assert len(coords) == 2
        for pos in coords:
            assert len(pos) == 2
            assert all(isinstance(v, float | int) and not isinstance(v, bool) for v in pos)
        np.testing.assert_allclose(np.ravel(coords), row, rtol=0.0, atol=1e-9)
    # segments come first, in snapshot order
    assert [f["properties"]["kind"] for f in doc["features"][:4]] == ["segment"] * 4


def test_other_feature_kinds(tmp_path: Path, snapshot: MapSnapshot) -> None:
    out = tmp_path / "map.geojson"
    write_geojson(out, snapshot)
    centroids = _features(out, "centroid")
    assert [f["geometry"]["type"] for f in centroids] == ["Point"] * 3
    np.testing.assert_allclose([f["geometry"]["coordinates"] for f in centroids], snapshot.centroids)
    (traj,) = _features(out, "trajectory")
    assert traj["geometry"]["type"] == "LineString"
    np.testing.assert_allclose(traj["geometry"]["coordinates"], snapshot.trajectory[:, 1:3])
    assert traj["properties"]["stamps_s"] == [90.239599, 90.719599, 91.321399]
    (pose,) = _features(out, "pose")
    assert pose["geometry"] == {"type": "Point", "coordinates": [2.0, 1.5]}
    assert pose["properties"]["theta"] == pytest.approx(math.pi / 2, abs=1e-9)
    assert pose["properties"]["stamp_s"] == 91.321399


def test_numbers_are_written_short_and_exact(tmp_path: Path) -> None:
    out = tmp_path / "m.geojson"
    write_geojson(out, _segments_only(np.array([[0.1, -0.2, 1e-12, -0.0]])))
    text = out.read_text(encoding="utf-8")
    assert '"coordinates": [[0.1, -0.2], [0.0, 0.0]]' in text  # 1e-12 rounds to 0, -0.0 is written 0.0
    assert text.endswith("\n")


@settings(max_examples=60, deadline=None)
@given(
    segments=arrays(
        np.float64,
        st.tuples(st.integers(0, 25), st.just(4)),
        elements=st.floats(-1e5, 1e5, allow_nan=False, allow_infinity=False),
    ),
    id_offset=st.integers(-(2**40), 2**40),
)
def test_round_trip(segments: np.ndarray, id_offset: int) -> None:
    ids = np.arange(segments.shape[0], dtype=np.intp) * 3 + id_offset
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "map.geojson"
        write_geojson(out, _segments_only(segments, ids))
        back = read_geojson_segments(out)
        assert back.shape == (segments.shape[0], 4)
        assert back.dtype == np.float64
        np.testing.assert_allclose(back, segments, rtol=0.0, atol=1e-6)
        assert [f["properties"]["id"] for f in _features(out, "segment")] == ids.tolist()


def test_empty_snapshot(tmp_path: Path) -> None:
    out = tmp_path / "empty.geojson"
    write_geojson(out, MapSnapshot.empty())
    doc = json.loads(out.read_text(encoding="utf-8"))
    assert [f["properties"]["kind"] for f in doc["features"]] == ["pose"]
    assert read_geojson_segments(out).shape == (0, 4)


def test_single_pose_trajectory_is_not_a_linestring(tmp_path: Path, snapshot: MapSnapshot) -> None:
    one = MapSnapshot(
        1,
        90.2,
        snapshot.segments,
        snapshot.segment_ids,
        snapshot.centroids,
        Pose2D(),
        snapshot.trajectory[:1],
    )
    out = tmp_path / "m.geojson"
    write_geojson(out, one)
    assert _features(out, "trajectory") == []  # GeoJSON LineStrings need two positions


def test_extra_properties(tmp_path: Path, snapshot: MapSnapshot) -> None:
    out = tmp_path / "m.geojson"
    write_geojson(out, snapshot, extra_properties={"log": "aces", "kernels": {"lines": "svd@1"}})
    props = json.loads(out.read_text(encoding="utf-8"))["properties"]
    assert props["log"] == "aces"
    assert props["kernels"] == {"lines": "svd@1"}
    assert props["units"] == "m"
    with pytest.raises(InvalidInputError, match="extra_properties"):
        write_geojson(out, snapshot, extra_properties={"bad": object()})
    with pytest.raises(InvalidInputError, match="extra_properties"):
        write_geojson(out, snapshot, extra_properties={"nan": math.nan})


def test_bad_snapshot_arrays(tmp_path: Path, snapshot: MapSnapshot) -> None:
    out = tmp_path / "m.geojson"
    bad = snapshot.segments.copy()
    bad[2, 1] = np.nan
    with pytest.raises(InvalidInputError, match=r"snapshot.segments row 2"):
        write_geojson(out, _segments_only(bad))
    with pytest.raises(InvalidInputError, match=r"segment_ids has shape \(3,\): expected \(4,\)"):
        write_geojson(out, _segments_only(snapshot.segments, np.arange(3, dtype=np.intp)))
    with pytest.raises(InvalidInputError, match=r"expected \(N, 4\)"):
        write_geojson(out, _segments_only(np.zeros((2, 3))))
    assert not out.exists()


def test_write_is_atomic_and_replaces(tmp_path: Path, snapshot: MapSnapshot) -> None:
    out = tmp_path / "m.geojson"
    out.write_text("old", encoding="utf-8")
    write_geojson(out, snapshot)
    assert read_geojson_segments(out).shape == (4, 4)
    assert [p.name for p in tmp_path.iterdir()] == ["m.geojson"]  # no temporary file left behind


def test_write_into_missing_folder(tmp_path: Path, snapshot: MapSnapshot) -> None:
    with pytest.raises(ExportIOError, match="missing"):
        write_geojson(tmp_path / "missing" / "m.geojson", snapshot)


def _write(tmp_path: Path, doc: Any) -> Path:
    path = tmp_path / "in.geojson"
    path.write_text(doc if isinstance(doc, str) else json.dumps(doc), encoding="utf-8")
    return path


def _segment(coords: Any, geometry_type: str = "LineString") -> dict[str, Any]:
    return {
        "type": "Feature",
        "geometry": {"type": geometry_type, "coordinates": coords},
        "properties": {"kind": "segment", "id": 0},
    }


def _collection(*features: Any) -> dict[str, Any]:
    return {"type": "FeatureCollection", "features": list(features)}


def test_reader_takes_only_segment_features(tmp_path: Path) -> None:
    other = [
        {
            "type": "Feature",
            "geometry": {"type": "Point", "coordinates": [1, 2]},
            "properties": {"kind": "centroid"},
        },
        {"type": "Feature", "geometry": None, "properties": None},
        {"type": "Feature", "geometry": {"type": "Point", "coordinates": [1, 2]}, "properties": {}},
    ]
    path = _write(tmp_path, _collection(other[0], _segment([[0, 1], [2.5, 3]]), *other[1:]))
    np.testing.assert_array_equal(read_geojson_segments(path), [[0.0, 1.0, 2.5, 3.0]])


@pytest.mark.parametrize(
    ("doc", "pattern"),
    [
        ('{"type": "FeatureCollection",\n "features": [}', r"line 2 column \d+: .*expected valid JSON"),
        ([1, 2], r"top level is 'list': expected a GeoJSON 'FeatureCollection'"),
        ({"type": "Feature"}, r"top level is 'Feature'"),
        ({"type": "FeatureCollection"}, r"'features' is NoneType: expected a list"),
        (
            _collection(_segment([[0, 0], [1, 1]]), {"type": "Point"}),
            r"feature 1: expected an object with type 'Feature'",
        ),
        (
            _collection(_segment([[0, 0], [1, 1], [2, 2]])),
            r"feature 0: coordinates has 3 positions: expected exactly 2",
        ),
        (_collection(_segment([[0, 0]])), r"coordinates has 1 positions"),
        (
            _collection(_segment([[0, 0, 0], [1, 1]])),
            r"feature 0: position 0 is \[0, 0, 0\]: expected \[x, y\]",
        ),
        (_collection(_segment([[0, 0], [1, "1"]])), r"position 1 is \[1, '1'\]"),
        (_collection(_segment([[0, 0], [1, True]])), r"position 1 is \[1, True\]"),
        (_collection(_segment([0, 1], "Point")), r"geometry type is 'Point': expected 'LineString'"),
        (
            _collection({"type": "Feature", "geometry": None, "properties": {"kind": "segment"}}),
            r"geometry is None",
        ),
        (_collection({"type": "Feature", "geometry": None, "properties": [1]}), r"properties is list"),
        (
            '{"type": "FeatureCollection", "features": [{"type": "Feature", '
            '"properties": {"kind": "segment"}, '
            '"geometry": {"type": "LineString", "coordinates": [[0, 0], [NaN, 1]]}}]}',
            r"position 1 is \[nan, 1\]",
        ),
    ],
)
def test_reader_errors(tmp_path: Path, doc: Any, pattern: str) -> None:
    path = _write(tmp_path, doc)
    with pytest.raises(GeoJSONFormatError, match=pattern) as info:
        read_geojson_segments(path)
    assert str(path) in str(info.value)
    assert isinstance(info.value, LinemapError)


def test_reader_missing_file_and_bad_encoding(tmp_path: Path) -> None:
    with pytest.raises(ExportIOError, match=r"cannot read .*nope.geojson") as info:
        read_geojson_segments(tmp_path / "nope.geojson")
    assert isinstance(info.value, LinemapError)
    bad = tmp_path / "latin1.geojson"
    bad.write_bytes(b'{"type": "\xe9"}')
    with pytest.raises(GeoJSONFormatError, match="not UTF-8"):
        read_geojson_segments(bad)
