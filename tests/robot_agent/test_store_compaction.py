"""The Robot DB grows with the map, not with the run (robot_agent/store_map.py, compaction): delivered map
versions are dropped but the newest delivered one, delivered poses are thinned past the limit while an
undelivered one is never dropped, a snapshot carries the thinned trajectory, and the file stops growing
once the run is long enough, on a real SQLite file."""

from __future__ import annotations

from pathlib import Path

from sqlalchemy import select

from robot_agent.models import MapVersion, PoseRecord
from robot_agent.store import RobotDB
from robot_agent.store_db import RobotDBFile
from tests.robot_agent.records import step_record


def _versions(db: RobotDBFile, model: type[MapVersion] | type[PoseRecord]) -> list[int]:
    with db._factory() as s:
        return [int(v) for v in s.scalars(select(model.version).order_by(model.version))]


def test_delivered_versions_are_dropped_but_the_newest_delivered_one(tmp_path: Path) -> None:
    db = RobotDB(tmp_path / "robot.db")
    try:
        for v in range(1, 31):
            db.record_step(step_record(v))
        db.mark_uploaded(20)
        assert _versions(db, MapVersion) == list(range(20, 31))
        assert db.stamp_of(20) == 2.0 and db.stamp_of(19) is None  # a lost answer at 20 is still told
        up = db.pending_upload()
        assert up is not None and (up.first_version, up.version) == (21, 30)
        snap = db.snapshot()
        assert snap is not None and snap["version"] == 30 and len(snap["trajectory"]) == 30
        assert snap["segments"] == [[30.0, 0.0, 0.0, 1.0, 30.0]]
    finally:
        db.close()


def test_delivered_poses_are_thinned_past_the_limit_and_undelivered_ones_kept(tmp_path: Path) -> None:
    db = RobotDB(tmp_path / "robot.db")
    db.max_poses = 40
    try:
        for v in range(1, 101):
            db.record_step(step_record(v))
        db.mark_uploaded(30)  # 70 versions not delivered: none of their poses may go
        poses = _versions(db, PoseRecord)
        assert set(range(31, 101)) <= set(poses), "an undelivered pose was dropped"
        assert 1 in poses and len(poses) < 100
        up = db.pending_upload(limit=100)
        assert up is not None and len(up.trajectory) == 70
        snap = db.snapshot()
        assert snap is not None and len(snap["trajectory"]) <= 40, "a snapshot carries the thinned path"
        assert snap["trajectory"][-1][0] == 10.0 and snap["trajectory"][0][0] == 0.1
        db.mark_uploaded(100)
        poses = _versions(db, PoseRecord)
        assert len(poses) <= 40 and poses[-20:] == list(range(81, 101)) and poses[0] == 1
    finally:
        db.close()


def test_the_file_stops_growing_once_the_run_is_long_enough(tmp_path: Path) -> None:
    """Steps with 200 centroids each (the agent's ~8 KB a step), delivered every 50 steps: the file's
    size after 3,000 steps is what it was after 1,500 (freed pages are reused), within 10 %."""
    db = RobotDB(tmp_path / "robot.db")
    db.max_poses = 500
    cents = [[0.01 * i, 0.02 * i] for i in range(200)]
    sizes: dict[int, int] = {}
    try:
        for v in range(1, 3001):
            r = step_record(v)
            db.record_step(
                type(r)(r.version, r.stamp_s, r.source_index, r.segments, r.removed, r.pose, cents)
            )
            if v % 50 == 0:
                db.mark_uploaded(v)
            if v in (1500, 3000):
                sizes[v] = db.size_bytes()
        assert sizes[3000] <= 1.1 * sizes[1500], sizes
        assert len(_versions(db, MapVersion)) == 1 and len(_versions(db, PoseRecord)) <= 500
    finally:
        db.close()
