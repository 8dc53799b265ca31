"""A snapshot written as a diff against the stored map (server.snapdiff, server.parsepool.read_stored,
server.mapstore) stores exactly what the full replace stores, on SQLite and PostgreSQL: the same map
through GET /maps/latest and the exports, the same versions. When the stored map moved between the diff
and the write (another upload of the robot), the writer replaces the map whole. Through the real server
(uvicorn and its parser process) a near-limit-sized snapshot that repeats the stored map keeps the stored
trajectory rows and appends the new poses."""

from __future__ import annotations

import json
import logging
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from sqlalchemy import select

from server.mapstore import apply_upload, prepare_rows, read_map
from server.models import MapUploadRecord, TrajectoryPoint
from server.parsepool import read_stored
from server.schemas import MapOut, MapUpload
from server.snapdiff import diff_snapshot
from tests.server.live import Live


def _snapshot(version: int, walls: list[list[float]], traj: list[list[float]]) -> MapUpload:
    return MapUpload.model_validate(
        {
            "version": version,
            "base_version": None,
            "segments": walls,
            "trajectory": traj,
            "pose": [1.0, 2.0, 0.5],
        }
    )


def _write(live: Live, rid: int, up: MapUpload, diffed: bool, key: str | None = None) -> None:
    """``up`` written as the server writes a big upload: rows prepared first (from the diff against what
    the parser process would read now, when ``diffed``), then the write transaction."""
    diff = None
    if diffed:
        stored = read_stored(live.state.settings.database_url, rid)
        assert stored is not None
        segs = np.array(up.segments, dtype=np.float64).reshape(-1, 5)
        diff = diff_snapshot(stored, segs, np.array(up.trajectory, dtype=np.float64).reshape(-1, 4))
    rows = prepare_rows(rid, up, diff)
    with live.state.db.write_conn() as conn:
        apply_upload(conn, rid, up, key or f"version-{up.version}", None, 20_000, rows)


def _stored(live: Live, rid: int) -> tuple[dict[str, Any], list[tuple[Any, ...]]]:
    """The map as GET /maps/latest gives it (less the robot id), and the upload records."""
    with live.state.db.read() as s:
        m: MapOut = read_map(s, rid)
        ups = s.execute(
            select(
                MapUploadRecord.version,
                MapUploadRecord.base_version,
                MapUploadRecord.n_segments,
                MapUploadRecord.idempotency_key,
            )
            .where(MapUploadRecord.robot_id == rid)
            .order_by(MapUploadRecord.id)
        ).all()
    return m.model_dump(exclude={"robot_id"}), [tuple(u) for u in ups]


_X = st.sampled_from([0.0, 0.5, 1.0, -3.25, 7.125])
_WALLS = st.lists(st.tuples(st.integers(0, 30), _X, _X, _X, _X).map(list), max_size=25)
_TRAJ = st.lists(st.tuples(st.sampled_from([0.0, 1.0]), _X, _X, _X).map(list), max_size=8)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(first=_WALLS, first_traj=_TRAJ, second=_WALLS, extra=_TRAJ, extends=st.booleans())
def test_a_snapshot_written_as_a_diff_stores_what_the_full_replace_stores(
    live: Live,
    first: list[list[float]],
    first_traj: list[list[float]],
    second: list[list[float]],
    extra: list[list[float]],
    extends: bool,
) -> None:
    mixed = first[: len(first) // 2] + second  # half the walls repeated, some moved, some new
    traj = first_traj + extra if extends else extra
    (a, _), (b, _) = live.new_robot(), live.new_robot()
    for rid, diffed in ((a, True), (b, False)):
        _write(live, rid, _snapshot(3, first, first_traj), diffed=False)
        _write(live, rid, _snapshot(5, mixed, traj), diffed=diffed)
    assert _stored(live, a) == _stored(live, b)
    assert _stored(live, a)[0]["version"] == 5


def test_a_diff_of_a_map_that_moved_since_falls_back_to_the_full_replace(
    live: Live, caplog: pytest.LogCaptureFixture
) -> None:
    rid, _ = live.new_robot()
    walls = [[float(i), float(i), 0.0, i + 0.5, 1.0] for i in range(10)]
    _write(live, rid, _snapshot(1, walls, [[0.0, 1.0, 1.0, 0.0]]), diffed=False)
    stored = read_stored(live.state.settings.database_url, rid)  # the parser process reads version 1 ...
    assert stored is not None and stored.version == 1
    snap = _snapshot(3, walls[:8], [[0.0, 1.0, 1.0, 0.0], [1.0, 2.0, 2.0, 0.0]])
    segs = np.array(snap.segments).reshape(-1, 5)
    diff = diff_snapshot(stored, segs, np.array(snap.trajectory).reshape(-1, 4))
    delta = MapUpload.model_validate(  # ... then another upload adds wall 77 before the snapshot's write
        {
            "version": 2,
            "base_version": 1,
            "segments": [[77.0, 5.0, 5.0, 6.0, 6.0]],
            "trajectory": [[0.5, 3, 3, 0]],
        }
    )
    with live.state.db.write_conn() as conn:
        apply_upload(conn, rid, delta, "delta-2")
    with caplog.at_level(logging.INFO, logger="server.mapstore"), live.state.db.write_conn() as conn:
        apply_upload(conn, rid, snap, "version-3", None, 20_000, prepare_rows(rid, snap, diff))
    m, _ = _stored(live, rid)
    # the stale diff would have kept wall 77 and the delta's pose; the full replace stores the snapshot
    assert m["version"] == 3 and m["segments"] == snap.segments and m["trajectory"] == snap.trajectory
    assert "moved (version 1 -> 2)" in caplog.text


def _big(version: int, walls: list[list[float]], poses: int) -> dict[str, Any]:
    traj = [[0.1 * j, 1.0, 2.0, 0.0] for j in range(poses)]
    return {"version": version, "base_version": None, "segments": walls, "trajectory": traj}


def test_big_snapshots_through_the_server_are_written_as_diffs_with_the_full_replaces_result(
    live: Live,
) -> None:
    """Bodies over INLINE_BODY_BYTES: the parser process reads the stored map and diffs. A snapshot that
    extends the trajectory keeps the stored pose rows (their ids); one whose trajectory differs replaces
    them. Each time the latest map is exactly the snapshot."""
    from server.routers.maps import INLINE_BODY_BYTES

    rid, token = live.new_robot()
    walls = [[float(i), i * 0.01, 1.0, i * 0.01 + 0.5, 2.0] for i in range(3000)]
    bodies = [_big(1, walls, 1000)]
    changed = [list(w) for w in walls[5:]] + [[9000.0, 1.0, 1.0, 2.0, 2.0]]
    changed[0][4] = 3.5
    bodies.append(_big(2, changed, 1200))  # 5 walls gone, 1 moved, 1 new, 200 poses more
    third = _big(3, changed, 900)
    third["trajectory"][0][1] = 9.0  # another start: the trajectory is replaced
    bodies.append(third)

    def pose_versions() -> list[int]:  # the version that wrote each stored pose row
        with live.state.db.read() as s:
            q = (
                select(TrajectoryPoint.version)
                .where(TrajectoryPoint.robot_id == rid)
                .order_by(TrajectoryPoint.id)
            )
            return list(s.execute(q).scalars())

    with live.client(token) as robot, live.operator() as op:
        for body in bodies:
            assert len(json.dumps(body)) > INLINE_BODY_BYTES
            r = robot.post(f"/robots/{rid}/maps", json=body)
            assert r.status_code == 200, r.text
            m = op.get(f"/robots/{rid}/maps/latest").json()
            want = sorted(body["segments"], key=lambda w: w[0])
            assert (m["version"], m["segments"], m["trajectory"]) == (
                body["version"],
                want,
                body["trajectory"],
            )
            geo = op.get(f"/robots/{rid}/maps/export", params={"format": "geojson"})
            assert geo.status_code == 200 and len(geo.json()["features"]) >= len(want)
            if body["version"] == 2:  # appended: version 1's 1000 pose rows stayed
                assert pose_versions() == [1] * 1000 + [2] * 200
        assert pose_versions() == [3] * 900  # replaced


def test_the_parser_diffs_against_its_last_snapshot_only_while_that_is_what_is_stored(live: Live) -> None:
    """The worker remembers the last snapshot it parsed per robot (server.parsepool): used only when the
    server process says it wrote that version and the stored map is still at it; otherwise the map is read."""
    from server import parsepool

    url = live.state.settings.database_url
    rid, _ = live.new_robot()
    walls = [[float(i), float(i), 0.0, i + 0.5, 1.0] for i in range(50)]
    raw = json.dumps(_big(1, walls, 20)).encode()
    kind, fields, diff = parsepool._parse_packed(raw, rid, 20_000, 1e5, url, None)
    assert kind == "ok" and diff is not None and diff.rows == 70  # against the empty map, read
    up = parsepool._unpack(fields)
    with live.state.db.write_conn() as conn:
        apply_upload(conn, rid, up, "version-1", None, 20_000, prepare_rows(rid, up, diff))
    remembered = parsepool._LAST[(url, rid)]
    assert parsepool._remembered(url, rid, 1) is remembered  # written and still stored: no read needed
    assert parsepool._remembered(url, rid, None) is None  # not confirmed written by the server process
    stored = read_stored(url, rid)
    assert stored is not None and stored.wall_ids.tolist() == remembered.wall_ids.tolist()
    assert _bits_equal(stored.trajectory, remembered.trajectory) and _bits_equal(
        stored.walls, remembered.walls
    )
    delta = MapUpload.model_validate({"version": 2, "base_version": 1, "segments": [[99.0, 1, 1, 2, 2]]})
    with live.state.db.write_conn() as conn:
        apply_upload(conn, rid, delta, "delta-2")
    assert parsepool._remembered(url, rid, 1) is None  # the map moved on: read it
    kind, fields, diff = parsepool._parse_packed(
        json.dumps(_big(3, walls, 20)).encode(), rid, 20_000, 1e5, url, 1
    )
    assert diff is not None and diff.base_version == 2 and diff.removed.tolist() == [99]


def _bits_equal(a: np.ndarray, b: np.ndarray) -> bool:
    return bool(
        np.array_equal(np.ascontiguousarray(a).view(np.int64), np.ascontiguousarray(b).view(np.int64))
    )
