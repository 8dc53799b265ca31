"""An upload's rows (server.pgwrite on PostgreSQL: one statement; server.maprows' separate statements on
SQLite, the reference): on both backends of the shared live server, a snapshot and then a delta leave the
walls, poses, map state, robot row, upload record and delta log that the upload says, whatever optional
parts it has (removed walls, also sent again; a status with any of its fields; a last-seen time; the pose
graph's columns); the log's entry carries the notice to other server processes (PostgreSQL), heard at
commit only."""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from sqlalchemy import select

from server import maplog, pgdriver
from server.mapstore import apply_upload
from server.models import MapDeltaRecord, MapSegment, MapState, MapUploadRecord, Robot, TrajectoryPoint
from server.notices import CHANNEL, encode_notice
from server.schemas import MapUpload
from tests.server.live import Live

_COORD = st.floats(min_value=-100.0, max_value=100.0, allow_nan=False, allow_infinity=False)
_WALL = st.tuples(_COORD, _COORD, _COORD, _COORD)
_STATUS = st.fixed_dictionaries(
    {},
    optional={
        "mode": st.sampled_from(["online", "offline", "mixed"]),
        "step_ms": st.floats(0.0, 1e3),
        "last_error": st.text(max_size=20),
        "active_kernels": st.dictionaries(st.sampled_from(["noise", "clustering"]), st.just("k@1.0.0")),
        "config": st.dictionaries(st.text(max_size=5), st.integers(-5, 5) | st.text(max_size=5), max_size=3),
        "kernels": st.lists(
            st.fixed_dictionaries(
                {
                    "stage": st.just("noise"),
                    "name": st.text("abc", min_size=1, max_size=5),
                    "version": st.just("1.0.0"),
                    "state": st.sampled_from(["verified", "active"]),
                    "sha256": st.just("0" * 64),
                }
            ),
            max_size=2,
        ),
    },
)


def _read(live: Live, rid: int) -> dict[str, Any]:
    with live.state.db.read() as s:
        walls = s.execute(
            select(MapSegment.segment_id, MapSegment.x0_m, MapSegment.y0_m, MapSegment.x1_m, MapSegment.y1_m)
            .where(MapSegment.robot_id == rid)
            .order_by(MapSegment.segment_id)
        ).all()
        poses = s.execute(
            select(TrajectoryPoint.version, TrajectoryPoint.stamp_s, TrajectoryPoint.x_m)
            .where(TrajectoryPoint.robot_id == rid)
            .order_by(TrajectoryPoint.id)
        ).all()
        state = s.get(MapState, rid)
        robot = s.get(Robot, rid)
        records = s.execute(
            select(MapUploadRecord.idempotency_key, MapUploadRecord.version, MapUploadRecord.base_version)
            .where(MapUploadRecord.robot_id == rid)
            .order_by(MapUploadRecord.version)
        ).all()
        logged = s.execute(
            select(MapDeltaRecord.version, MapDeltaRecord.base_version)
            .where(MapDeltaRecord.robot_id == rid)
            .order_by(MapDeltaRecord.version)
        ).all()
        assert state is not None and robot is not None
        return {
            "walls": {int(r[0]): tuple(r[1:]) for r in walls},
            "poses": [tuple(r) for r in poses],
            "state": (state.version, state.stamp_s, state.centroids, state.pose, state.wall_time_s),
            "counts": (state.n_walls, state.n_poses),
            "graph": (state.keyframes, state.pose_covariance),
            "robot": robot,
            "records": [tuple(r) for r in records],
            "logged": [tuple(r) for r in logged],
        }


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    walls=st.dictionaries(st.integers(0, 2**40), _WALL, min_size=1, max_size=20),
    new=st.dictionaries(st.integers(2**41, 2**42), _WALL, max_size=5),
    status=st.none() | _STATUS,
    seen=st.booleans(),
    graph=st.booleans(),
    data=st.data(),
)
def test_a_delta_leaves_the_rows_it_says_on_both_backends(
    live: Live,
    walls: dict[int, tuple[float, float, float, float]],
    new: dict[int, tuple[float, float, float, float]],
    status: dict[str, Any] | None,
    seen: bool,
    graph: bool,
    data: st.DataObject,
) -> None:
    rid, _ = live.new_robot()
    keys = sorted(walls)
    removed = data.draw(st.lists(st.sampled_from(keys), unique=True))
    resent = data.draw(st.lists(st.sampled_from(keys), unique=True))  # some of them removed as well
    moved = {k: (walls[k][2], walls[k][3], walls[k][0], walls[k][1]) for k in resent if k % 2}
    sent = {**{k: moved.get(k, walls[k]) for k in resent}, **new}
    snap = MapUpload.model_validate(
        {
            "version": 1,
            "base_version": None,
            "stamp_s": 1.0,
            "segments": [[k, *v] for k, v in walls.items()],
            "trajectory": [[0.5, 1.0, 0.0, 0.0]],
            "pose": [0, 0, 0],
        }
    )
    body: dict[str, Any] = {
        "version": 2,
        "base_version": 1,
        "stamp_s": 2.5,
        "segments": [[k, *v] for k, v in sent.items()],
        "removed": removed,
        "centroids": [[0.25, -0.5]],
        "trajectory": [[2.0, 2.0, 0.0, 0.0], [2.5, 3.0, 0.0, 0.0]],
        "pose": [3.0, -1.0, 0.5],
        "wall_time_s": 1234.5,
    }
    if status is not None:
        body["status"] = status
    if graph:
        body["pose_covariance"] = [[0.01, 0.0, 0.0], [0.0, 0.01, 0.0], [0.0, 0.0, 0.001]]
    delta = MapUpload.model_validate(body)
    at = datetime(2026, 12, 7, 12, 0, 0, 250_000, tzinfo=UTC) if seen else None
    with live.state.db.write_conn() as conn:
        apply_upload(conn, rid, snap, "version-1", None, 20_000)
    with live.state.db.write_conn() as conn:
        applied = apply_upload(conn, rid, delta, "version-2", at, 20_000)
        assert applied.event is not None
        maplog.append(conn, rid, applied.event, undo=applied.undo)
    got = _read(live, rid)

    after = {k: v for k, v in walls.items() if k not in removed} | sent
    assert got["walls"] == after
    assert got["poses"] == [(1, 0.5, 1.0), (2, 2.0, 2.0), (2, 2.5, 3.0)]
    assert got["state"] == (
        2,
        2.5,
        {"xy": [[0.25, -0.5]]},
        {"x_m": 3.0, "y_m": -1.0, "theta_rad": 0.5},
        1234.5,
    )
    assert got["counts"] == (len(after), 3)
    assert got["graph"] == (None, body["pose_covariance"] if graph else None)
    assert got["records"] == [("version-1", 1, None), ("version-2", 2, 1)]
    assert got["logged"] == [(2, 1)]
    robot = got["robot"]
    assert (robot.map_version, robot.map_session) == (2, None)
    assert robot.last_seen_at == at
    sent_status = status or {}
    for name in ("mode", "step_ms", "config", "kernels"):
        assert getattr(robot, name) == sent_status.get(name)
    assert robot.active_kernels == sent_status.get("active_kernels", {})
    assert robot.last_error == (sent_status.get("last_error") if status is not None else None)


def test_a_wall_removed_and_sent_again_in_one_delta_is_stored_with_its_sent_row(live: Live) -> None:
    rid, _ = live.new_robot()
    snap = {
        "version": 1,
        "base_version": None,
        "segments": [[k, 0, 0, k, k] for k in (1, 2, 3)],
        "pose": [0, 0, 0],
    }
    delta = {
        "version": 2,
        "base_version": 1,
        "segments": [[2, 5, 5, 6, 6], [3, 0, 0, 3, 3]],  # 2 moved, 3 as stored; both also removed
        "removed": [1, 2, 3],
        "pose": [0, 0, 0],
    }
    for up in (snap, delta):
        with live.state.db.write_conn() as conn:
            apply_upload(conn, rid, MapUpload.model_validate(up), f"version-{up['version']}", None, 20_000)
    got = _read(live, rid)
    assert got["walls"] == {2: (5.0, 5.0, 6.0, 6.0), 3: (0.0, 0.0, 3.0, 3.0)}
    assert got["counts"] == (2, 0)


def test_the_logs_entry_carries_the_notice_to_other_processes_at_commit_only(live: Live) -> None:
    rid, _ = live.new_robot()
    event = {"kind": "delta", "robot_id": rid, "version": 2, "base_version": 1, "segments": []}
    topic = f"maps:{rid}"
    notice = encode_notice("0123abcd", topic, 2)
    if live.state.db.is_sqlite:  # one process: nobody to tell, and no NOTIFY
        with live.state.db.write_conn() as conn, pytest.raises(ValueError, match="PostgreSQL"):
            maplog.append(conn, rid, event, notice=notice)
        return
    with live.state.db.engine.connect() as listening:
        pg = pgdriver.driver(listening)
        listening.commit()
        pg.autocommit = True
        pg.execute(f"LISTEN {CHANNEL}")

        def rolled_back() -> None:  # no notice from it
            with live.state.db.write_conn() as conn:
                maplog.append(conn, rid, {**event, "version": 3}, notice=encode_notice("0123abcd", topic, 3))
                raise RuntimeError("roll back")

        with pytest.raises(RuntimeError):
            rolled_back()
        with live.state.db.write_conn() as conn:
            maplog.append(conn, rid, event, notice=notice)
        heard = [n.payload for n in pg.notifies(timeout=10.0, stop_after=1)]
        pg.execute(f"UNLISTEN {CHANNEL}")
        pg.autocommit = False
    assert heard == [notice]
    with live.state.db.read() as s:
        logged = s.execute(select(MapDeltaRecord.version).where(MapDeltaRecord.robot_id == rid)).all()
    assert [v for (v,) in logged] == [2]
