"""Absurd but finite map data through a real server: uploads outside the declared bounds are refused (422
naming the field, the value and the bound), and every export of a map whose stored rows are absurd (written
into the database directly, as an older server would have stored them) answers without a 5xx and says
what is wrong."""

from __future__ import annotations

import json
import math
from typing import Any

import pytest
from sqlalchemy import text

from server.mapbounds import ID_MAX
from server.models import Robot
from tests.server.live import Live

FORMATS = ["geojson", "svg", "dxf", "pgm", "yaml"]


def _snapshot(**changes: Any) -> dict[str, Any]:
    body: dict[str, Any] = {
        "version": 1,
        "base_version": None,
        "stamp_s": 10.0,
        "segments": [[1, 0.0, 0.0, 4.0, 0.0], [2, 4.0, 0.0, 4.0, 3.0]],
        "centroids": [[2.0, 0.0]],
        "pose": [2.0, 1.5, 0.5],
        "trajectory": [[9.9, 1.0, 1.0, 0.0], [10.0, 2.0, 1.5, 0.5]],
    }
    body.update(changes)
    return body


@pytest.mark.parametrize(
    ("changes", "field", "bound"),
    [
        (
            {"segments": [[1, 0.0, 0.0, 1.0, 0.0], [2, 1e20, 0.0, 1.0, 0.0]]},
            "segments[1][1]",
            "world_extent_m",
        ),
        ({"segments": [[1, 0.0, 0.0, 1.0, -10_000.5]]}, "segments[0][4]", "world_extent_m"),
        ({"segments": [[2**40, 0.0, 0.0, 1.0, 0.0]]}, "segments[0][0]", "32-bit"),
        ({"segments": [[ID_MAX + 1, 0.0, 0.0, 1.0, 0.0]]}, "segments[0][0]", "32-bit"),
        ({"centroids": [[0.0, 0.0], [3e7, 0.0]]}, "centroids[1][0]", "world_extent_m"),
        ({"pose": [0.0, -1e20, 0.0]}, "pose[1]", "world_extent_m"),
        ({"pose": [0.0, 0.0, 1e6]}, "pose[2]", "2 pi"),
        ({"trajectory": [[1.0, 0.0, 0.0, 0.0], [2.0, 0.0, 0.0, 99.0]]}, "trajectory[1][3]", "2 pi"),
        ({"trajectory": [[1e12, 0.0, 0.0, 0.0]]}, "trajectory[0][0]", "MCAP"),
        ({"trajectory": [[-1.0, 0.0, 0.0, 0.0]]}, "trajectory[0][0]", "MCAP"),
        ({"stamp_s": 1e15}, "stamp_s", "MCAP"),
        ({"wall_time_s": -5.0}, "wall_time_s", "Unix time"),
        ({"wall_time_s": 1e300}, "wall_time_s", "Unix time"),
    ],
)
def test_an_upload_outside_the_bounds_is_refused_naming_field_value_and_bound(
    live: Live, changes: dict[str, Any], field: str, bound: str
) -> None:
    rid, token = live.new_robot()
    with live.client(token) as robot:
        r = robot.post(f"/robots/{rid}/maps", json=_snapshot(**changes))
        assert r.status_code == 422, r.text
        body = r.json()
        assert body["field"] == field, body
        assert body["detail"].startswith(field), body
        assert bound in body["detail"] and "expected" in body["detail"], body
        assert "min" in body["bound"] and "max" in body["bound"], body
        # nothing was stored: the robot's map is still empty
        with live.operator() as op:
            assert op.get(f"/robots/{rid}/maps/latest").json()["version"] == 0


def test_a_removed_id_beyond_the_bound_is_refused(live: Live) -> None:
    rid, token = live.new_robot()
    with live.client(token) as robot:
        assert robot.post(f"/robots/{rid}/maps", json=_snapshot()).status_code == 200
        delta = {"version": 2, "base_version": 1, "removed": [1, 2**62]}
        r = robot.post(f"/robots/{rid}/maps", json=delta)
        assert r.status_code == 422, r.text
        assert r.json()["field"] == "removed[1]"


def test_a_status_config_with_nan_is_refused_naming_where_and_the_robot_row_keeps_its_config(
    live: Live,
) -> None:
    rid, token = live.new_robot()
    with live.client(token) as robot:
        good = json.dumps({**_snapshot(), "status": {"config": {"noise": {"eps_m": 0.05}}}})
        headers = {"Content-Type": "application/json"}
        assert robot.post(f"/robots/{rid}/maps", content=good, headers=headers).status_code == 200
        bad = json.dumps(
            {**_snapshot(), "version": 2, "status": {"config": {"noise": {"eps_m": float("nan")}}}}
        )
        r = robot.post(f"/robots/{rid}/maps", content=bad, headers=headers)  # json.dumps spells NaN
        assert r.status_code == 422, r.text
        assert "config.noise.eps_m" in r.text and "finite" in r.text
    with live.operator() as op:
        assert op.get(f"/robots/{rid}/maps/latest").json()["version"] == 1
    with live.state.db.read() as s:
        robot_row = s.get(Robot, rid)
        assert robot_row is not None and robot_row.config == {"noise": {"eps_m": 0.05}}


def test_an_upload_at_the_edge_of_the_bounds_is_stored(live: Live) -> None:
    extent = live.state.settings.world_extent_m
    rid, token = live.new_robot()
    body = _snapshot(
        segments=[[ID_MAX, -extent, -extent, extent, extent]],
        pose=[extent, -extent, -2 * math.pi],
        trajectory=[[0.0, extent, extent, 2 * math.pi]],
    )
    with live.client(token) as robot:
        assert robot.post(f"/robots/{rid}/maps", json=body).status_code == 200, body
    with live.operator() as op:
        for fmt in FORMATS:
            r = op.get(f"/robots/{rid}/maps/export", params={"format": fmt, "resolution": 10.0})
            assert r.status_code == 200, (fmt, r.text)


def _store_absurd(live: Live, rid: int) -> None:
    """Rows an older server accepted: a wall at x = 1e20 m, a 62-bit id, a centroid at 1e300 m, a
    trajectory pose with a 1e18 s stamp and a heading of 1e9 rad, the pose at -1e20 m."""
    with live.state.db.write_conn() as conn:
        rows = [(1, 0.0, 0.0, 4.0, 0.0), (2, 1e20, 0.0, 1e20 + 5.0, 1.0), (2**62, 0.0, 0.0, 1.0, 1.0)]
        for sid, x0, y0, x1, y1 in rows:
            conn.execute(
                text(
                    "INSERT INTO map_segments (robot_id, segment_id, x0_m, y0_m, x1_m, y1_m, version) "
                    "VALUES (:r, :s, :x0, :y0, :x1, :y1, 3)"
                ),
                {"r": rid, "s": sid, "x0": x0, "y0": y0, "x1": x1, "y1": y1},
            )
        for stamp, x, y, th in [(1.0, 0.0, 0.0, 0.0), (1e18, 2.0, 1.0, 1e9)]:
            conn.execute(
                text(
                    "INSERT INTO trajectory_points (robot_id, version, stamp_s, x_m, y_m, theta_rad) "
                    "VALUES (:r, 3, :t, :x, :y, :th)"
                ),
                {"r": rid, "t": stamp, "x": x, "y": y, "th": th},
            )
        conn.execute(
            text("UPDATE map_states SET centroids = :c, pose = :p, version = 3 WHERE robot_id = :r"),
            {
                "r": rid,
                "c": '{"xy": [[1.0, 1.0], [1e300, 0.0]]}',
                "p": '{"x_m": -1e20, "y_m": 0.0, "theta_rad": 0.0}',
            },
        )
        conn.execute(text("UPDATE robots SET map_version = 3 WHERE id = :r"), {"r": rid})


def test_every_export_of_absurd_stored_rows_answers_without_5xx(live: Live) -> None:
    rid, token = live.new_robot()
    with live.client(token) as robot:
        assert (
            robot.post(f"/robots/{rid}/maps", json=_snapshot(segments=[], trajectory=[])).status_code == 200
        )
    _store_absurd(live, rid)
    with live.operator() as op:
        assert op.get(f"/robots/{rid}/maps/latest").status_code == 200
        for fmt in FORMATS:
            r = op.get(f"/robots/{rid}/maps/export", params={"format": fmt})
            assert r.status_code == 409, (fmt, r.status_code, r.text)
            detail = r.json()["detail"]
            assert "outside the declared bounds" in detail and "out_of_bounds=skip" in detail, detail
            assert "2 walls" in detail and "1 centroid" in detail and "1 trajectory pose" in detail, detail
            assert r.json()["skipped"] == {"walls": 2, "centroids": 1, "trajectory": 1, "pose": 1}
            r = op.get(
                f"/robots/{rid}/maps/export",
                params={"format": fmt, "out_of_bounds": "skip", "resolution": 0.05},
            )
            assert r.status_code == 200, (fmt, r.status_code, r.text)
            assert r.headers["x-map-skipped"] == "walls=2, centroids=1, trajectory=1, pose=1"
            assert r.content, fmt


def test_non_finite_stored_rows_are_read_and_exported_without_5xx(live: Live) -> None:
    """Infinity (SQLite and PostgreSQL) and NaN (PostgreSQL) in stored rows: reads and exports answer."""
    rid, token = live.new_robot()
    with live.client(token) as robot:
        assert robot.post(f"/robots/{rid}/maps", json=_snapshot()).status_code == 200
    bad = [float("inf")] + ([float("nan")] if live.backend == "postgresql" else [])
    with live.state.db.write_conn() as conn:
        for i, value in enumerate(bad):
            conn.execute(
                text(
                    "INSERT INTO map_segments (robot_id, segment_id, x0_m, y0_m, x1_m, y1_m, version) "
                    "VALUES (:r, :s, :x, 0.0, 1.0, 1.0, 1)"
                ),
                {"r": rid, "s": 100 + i, "x": value},
            )
    with live.operator() as op:
        r = op.get(f"/robots/{rid}/maps/latest")
        assert r.status_code < 500, r.text
        for fmt in FORMATS:
            r = op.get(f"/robots/{rid}/maps/export", params={"format": fmt})
            assert r.status_code == 409, (fmt, r.text)
            assert f"{len(bad)} wall" in r.json()["detail"]
            r = op.get(f"/robots/{rid}/maps/export", params={"format": fmt, "out_of_bounds": "skip"})
            assert r.status_code == 200, (fmt, r.text)
