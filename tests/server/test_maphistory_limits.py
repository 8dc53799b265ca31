"""Where the map history (server.maphistory) ends, on a real SQLite file: at the oldest version the delta
log still holds (its ``keep`` bound), and at a delta logged without an undo record (by a server from before
undo records); each answer says which stopped it, and the versions inside are rebuilt exactly."""

from __future__ import annotations

import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import text

from server.database import Database
from server.errors import GoneError
from server.maphistory import read_history, read_version
from server.maplog import append
from server.mapstore import apply_upload
from server.migrate import upgrade
from server.models import Robot
from server.schemas import MapUpload


@pytest.fixture
def db(tmp_path: Path) -> Iterator[Database]:
    database = Database(f"sqlite:///{tmp_path / 'history.db'}")
    upgrade(database.engine)
    yield database
    database.dispose()


def _robot(db: Database) -> int:
    with db.session() as s:
        robot = Robot(name=f"h-{uuid.uuid4().hex[:8]}", token_hash=uuid.uuid4().hex)
        s.add(robot)
        s.flush()
        return int(robot.id)


def _upload(version: int, base: int | None) -> MapUpload:
    body: dict[str, Any] = {
        "version": version,
        "base_version": base,
        "stamp_s": float(version),
        "segments": [[version, float(version), 0.0, float(version), 1.0], [0, 0.0, 0.0, float(version), 0.0]],
        "removed": [],
        "centroids": [[float(version), 0.5]],
        "pose": [float(version), 0.0, 0.0],
        "trajectory": [[float(version), float(version), 0.0, 0.0]],
    }
    return MapUpload.model_validate(body)


def _apply(db: Database, rid: int, up: MapUpload, keep: int) -> None:
    with db.write_conn() as conn:
        applied = apply_upload(conn, rid, up, f"v{up.version}")
        assert applied.event is not None
        append(conn, rid, applied.event, keep=keep, undo=applied.undo)


def test_the_history_ends_where_the_log_does(db: Database) -> None:
    rid = _robot(db)
    _apply(db, rid, _upload(1, None), keep=3)
    for v in range(2, 8):
        _apply(db, rid, _upload(v, v - 1), keep=3)
    with db.read() as s:
        hist = read_history(s, rid)
        # deltas 5..7 kept: those versions (version 4's centroids left with its entry: the undo records
        # do not repeat them, server.maphistory.capture_undo)
        assert [v.version for v in hist.versions] == [5, 6, 7]
        assert "left the delta log" in hist.older
        m = read_version(s, rid, 5, None)
        # wall 0 as version 5 set it; walls 1..5 (6 and 7 added later are gone)
        assert {int(r[0]): r[1:] for r in m.segments} == {
            0: [0.0, 0.0, 5.0, 0.0],
            **{i: [float(i), 0.0, float(i), 1.0] for i in range(1, 6)},
        }
        assert m.pose == [5.0, 0.0, 0.0] and [p[0] for p in m.trajectory] == [1.0, 2.0, 3.0, 4.0, 5.0]
        assert m.centroids == [[5.0, 0.5]], "version 5's centroids, from its own log entry"
        with pytest.raises(GoneError, match=r"5\.\.7.*left the delta log"):
            read_version(s, rid, 4, None)


def test_a_delta_without_an_undo_record_ends_the_history(db: Database) -> None:
    rid = _robot(db)
    _apply(db, rid, _upload(1, None), keep=256)
    for v in range(2, 6):
        _apply(db, rid, _upload(v, v - 1), keep=256)
    with db.write_conn() as conn:  # as a server from before undo records logged version 3
        conn.execute(
            text("UPDATE map_deltas SET undo = NULL WHERE robot_id = :r AND version = 3"), {"r": rid}
        )
    with db.read() as s:
        hist = read_history(s, rid)
        assert [v.version for v in hist.versions] == [3, 4, 5]
        assert "before undo records were kept" in hist.older
        assert read_version(s, rid, 3, 1).trajectory == [[3.0, 3.0, 0.0, 0.0]]
