"""``GET /robots/{id}/maps/export``: the latest map as GeoJSON, SVG, DXF or a ROS map_server map, through a
real server, read back with the project's own readers."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np

from shared.export import (
    rasterise_segments,
    read_dxf,
    read_geojson_segments,
    read_map_mcap,
    read_occupancy,
    read_svg_segments,
)
from shared.export.mapserver import decode_pgm
from shared.export.occupancy import FREE, OCCUPIED
from tests.server.live import Live

# a closed 4 m x 3 m room with the robot inside it
ROOM = [[1, 0.0, 0.0, 4.0, 0.0], [2, 4.0, 0.0, 4.0, 3.0], [3, 4.0, 3.0, 0.0, 3.0], [4, 0.0, 3.0, 0.0, 0.0]]
TRAJECTORY = [[9.9, 1.0, 1.0, 0.0], [10.0, 2.0, 1.5, 0.5]]


def _upload(live: Live, segments: list[list[float]] | None = None) -> tuple[int, str]:
    rid, token = live.new_robot()
    body: dict[str, Any] = {
        "version": 1,
        "base_version": None,
        "stamp_s": 10.0,
        "segments": ROOM if segments is None else segments,
        "centroids": [[2.0, 0.0], [4.0, 1.5]],
        "pose": [2.0, 1.5, 0.5],
        "trajectory": TRAJECTORY,
    }
    with live.client(token) as robot:
        r = robot.post(f"/robots/{rid}/maps", json=body)
        assert r.status_code == 200, r.text
    return rid, token


def _filename(headers: Any) -> str:
    match = re.fullmatch(r'attachment; filename="([^"/]+)"', headers["content-disposition"])
    assert match, headers["content-disposition"]
    return match.group(1)


def test_every_format_round_trips(live: Live, tmp_path: Path) -> None:
    rid, _ = _upload(live)
    room = np.array(ROOM)[:, 1:]
    files: dict[str, Path] = {}
    with live.operator() as op:
        for fmt, media in [
            ("geojson", "application/geo+json"),
            ("svg", "image/svg+xml"),
            ("dxf", "image/vnd.dxf"),
            ("mcap", "application/x-mcap"),
            ("pgm", "image/x-portable-graymap"),
            ("yaml", "application/yaml"),
        ]:
            r = op.get(f"/robots/{rid}/maps/export", params={"format": fmt})
            assert r.status_code == 200, (fmt, r.text)
            assert r.headers["content-type"].split(";")[0] == media
            assert r.headers["x-map-version"] == "1"
            files[fmt] = tmp_path / _filename(r.headers)
            files[fmt].write_bytes(r.content)
    assert files["geojson"].name == f"robot-{rid}-map-v1.geojson"
    np.testing.assert_array_equal(read_geojson_segments(files["geojson"]), room)
    np.testing.assert_array_equal(read_svg_segments(files["svg"]).segments, room)
    dxf = read_dxf(files["dxf"])
    np.testing.assert_array_equal(dxf.segments, room)
    assert dxf.segment_ids.tolist() == [1, 2, 3, 4]
    np.testing.assert_array_equal(dxf.trajectory, np.array(TRAJECTORY)[:, 1:3])
    mcap = read_map_mcap(files["mcap"])  # the same messages as `linemap map --mcap` writes
    np.testing.assert_allclose(mcap.segments, room, atol=1e-9)
    np.testing.assert_allclose(mcap.trajectory[:, 1:3], np.array(TRAJECTORY)[:, 1:3], atol=1e-9)
    # the YAML names the PGM it was downloaded beside
    assert files["pgm"].name == f"robot-{rid}-map-v1-0.05m.pgm"
    assert f"image: {files['pgm'].name}\n" in files["yaml"].read_text()
    grid = read_occupancy(files["yaml"])
    assert grid.resolution_m == 0.05
    t = np.linspace(0.0, 1.0, 101)[:, None]
    samples = np.vstack([w[:2] + t * (w[2:] - w[:2]) for w in room])  # every 4 cm or closer along the walls
    row, col = grid.world_to_pixel(samples)
    occupied = np.pad(grid.pixels == OCCUPIED, 1)
    near = np.zeros(len(row), dtype=bool)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            near |= occupied[row + 1 + dr, col + 1 + dc]
    assert near.all(), "every wall sample within one cell of an occupied cell"
    inside = grid.world_to_pixel([[2.0, 1.5]])
    assert grid.pixels[inside[0][0], inside[1][0]] == FREE  # the enclosed floor around the trajectory


def test_default_format_is_geojson_and_robots_reach_their_own_map(live: Live) -> None:
    rid, token = _upload(live)
    with live.client(token) as robot:
        r = robot.get(f"/robots/{rid}/maps/export")
    assert r.status_code == 200 and r.headers["content-type"].startswith("application/geo+json")
    assert r.json()["type"] == "FeatureCollection" and r.json()["properties"]["robot_id"] == rid
    other, _ = live.new_robot()
    with live.client(token) as robot:
        denied = robot.get(f"/robots/{other}/maps/export", params={"format": "dxf"})
    assert denied.status_code == 403 and denied.json()["error"] == "forbidden"


def test_resolution_sets_the_grid(live: Live) -> None:
    rid, _ = _upload(live)
    with live.operator() as op:
        fine = op.get(f"/robots/{rid}/maps/export", params={"format": "pgm", "resolution": 0.02})
        coarse = op.get(f"/robots/{rid}/maps/export", params={"format": "yaml", "resolution": 0.25})
    assert fine.status_code == 200 and coarse.status_code == 200
    expected = rasterise_segments(
        np.array(ROOM)[:, 1:], resolution_m=0.02, inside_xy=np.array(TRAJECTORY)[:, 1:3]
    )
    np.testing.assert_array_equal(decode_pgm(fine.content), expected.pixels)  # the CLI's rasteriser
    assert expected.width > 200 and expected.height > 150  # 4 m x 3 m in 2 cm cells
    assert "resolution: 0.25\n" in coarse.text and _filename(coarse.headers).endswith("-0.25m.yaml")


def test_empty_map_gives_geojson_but_no_occupancy_map(live: Live) -> None:
    rid, _ = live.new_robot()
    with live.operator() as op:
        geo = op.get(f"/robots/{rid}/maps/export", params={"format": "geojson"})
        dxf = op.get(f"/robots/{rid}/maps/export", params={"format": "dxf"})
        pgm = op.get(f"/robots/{rid}/maps/export", params={"format": "pgm"})
    assert geo.status_code == 200 and dxf.status_code == 200
    assert pgm.status_code == 409
    assert pgm.json()["error"] == "conflict" and "no walls yet" in pgm.json()["detail"]


def test_bad_requests_are_json_errors(live: Live) -> None:
    rid, _ = _upload(live, [[1, 0.0, 0.0, 1000.0, 0.0], [2, 0.0, 0.0, 0.0, 1000.0]])
    with live.operator() as op:
        fmt = op.get(f"/robots/{rid}/maps/export", params={"format": "png"})
        zero = op.get(f"/robots/{rid}/maps/export", params={"format": "pgm", "resolution": 0})
        nan = op.get(f"/robots/{rid}/maps/export", params={"format": "pgm", "resolution": "nan"})
        huge = op.get(f"/robots/{rid}/maps/export", params={"format": "pgm", "resolution": 0.01})
        nobody = op.get("/robots/999999/maps/export")
    assert fmt.status_code == 422 and fmt.json()["error"] == "invalid" and "format" in fmt.json()["detail"]
    assert zero.status_code == 422 and "resolution" in zero.json()["detail"]
    assert nan.status_code == 422 and "resolution" in nan.json()["detail"]
    assert huge.status_code == 422 and "use a larger resolution" in huge.json()["detail"]
    assert nobody.status_code == 404 and nobody.json()["error"] == "not_found"


def test_a_pgm_and_its_yaml_pair_up_though_the_map_moved_on(live: Live) -> None:
    """The PGM of version 1, then the robot sends version 2 (a wall moved), then the YAML asked for with
    ``version=1``: it names that PGM and its origin is version 1's; the current map is version 2. A
    version never served here is refused with the current one named."""
    rid, token = _upload(live)
    with live.operator() as op:
        pgm = op.get(f"/robots/{rid}/maps/export", params={"format": "pgm"})
        assert pgm.status_code == 200 and pgm.headers["x-map-version"] == "1"
        moved = [[4, -2.0, 3.0, -2.0, 0.0], [1, -2.0, 0.0, 4.0, 0.0], [3, 4.0, 3.0, -2.0, 3.0]]
        delta = {
            "version": 2,
            "base_version": 1,
            "stamp_s": 11.0,
            "segments": moved,
            "removed": [],
            "centroids": [],
            "pose": [2.0, 1.5, 0.5],
            "trajectory": [[11.0, 2.0, 1.5, 0.5]],
        }
        with live.client(token) as robot:
            r = robot.post(f"/robots/{rid}/maps", json=delta)
            assert r.status_code == 200, r.text
        yaml_now = op.get(f"/robots/{rid}/maps/export", params={"format": "yaml"})
        assert yaml_now.headers["x-map-version"] == "2"
        yaml_then = op.get(f"/robots/{rid}/maps/export", params={"format": "yaml", "version": 1})
        assert yaml_then.status_code == 200, yaml_then.text
        assert yaml_then.headers["x-map-version"] == "1"
        assert f"image: {_filename(pgm.headers)}" in yaml_then.text
        assert yaml_then.text != yaml_now.text  # version 2's origin moved 2 m west
        latest_then = op.get(f"/robots/{rid}/maps/latest", params={"version": 1, "trajectory": 1})
        assert latest_then.status_code == 200 and latest_then.json()["version"] == 1
        assert latest_then.json()["trajectory"] == [TRAJECTORY[-1]]
        gone = op.get(f"/robots/{rid}/maps/export", params={"format": "yaml", "version": 7})
        assert gone.status_code == 409
        assert gone.json()["current_version"] == 2
        assert "version 7 of robot" in gone.text and "the current is 2" in gone.text
