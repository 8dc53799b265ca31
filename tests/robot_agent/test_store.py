"""The Robot DB (robot_agent/store.py): migrations match the models, a step's records commit together, and
the anti-rollback floors (the versions a robot has run) only rise, survive a reopen and are backfilled by
the migration."""

from __future__ import annotations

import sqlite3
from pathlib import Path

from alembic import command
from alembic.autogenerate import compare_metadata
from alembic.config import Config
from alembic.runtime.migration import MigrationContext
from sqlalchemy import create_engine

from robot_agent.models import RobotBase
from robot_agent.store import RobotDB
from robot_agent.store_db import MIGRATIONS_DIR
from tests.robot_agent.records import step_record


def test_migrated_schema_matches_the_models(tmp_path: Path) -> None:
    db = RobotDB(tmp_path / "robot.db")
    try:
        with db.engine.connect() as conn:
            diff = compare_metadata(MigrationContext.configure(conn), RobotBase.metadata)
        assert diff == [], f"robot models and migrations differ: {diff}"
        assert db.integrity_ok()
    finally:
        db.close()


def test_steps_fold_into_one_delta_and_survive_reopening(tmp_path: Path) -> None:
    path = tmp_path / "robot.db"
    db = RobotDB(path)
    for v in (1, 2, 3):
        db.record_step(step_record(v))
    db.close()
    db = RobotDB(path)  # reopened, as after a restart
    try:
        up = db.pending_upload()
        assert up is not None and (up.first_version, up.version) == (1, 3)
        assert [r[0] for r in up.segments] == [3.0], "walls 1 and 2 were replaced within the batch"
        assert up.removed == [1, 2] and len(up.trajectory) == 3
        db.mark_uploaded(2)
        rest = db.pending_upload()
        assert rest is not None and (rest.first_version, rest.version) == (3, 3)
        assert db.walls() == [[3.0, 0.0, 0.0, 1.0, 3.0]]
        assert db.get("map_version") == 3 and db.get("source_index") == 3
    finally:
        db.close()
    with sqlite3.connect(path) as conn:
        assert conn.execute("PRAGMA journal_mode").fetchone()[0] == "wal"


def test_message_outcome_and_config_commit_together(tmp_path: Path) -> None:
    db = RobotDB(tmp_path / "robot.db")
    try:
        db.record_message(4, "applied", None, {"mode": "offline"})
        db.record_message(5, "rejected", "line 1 <mode>: bad", None)
        assert db.applied_seq() == 5 and db.get("config") == {"mode": "offline"}
        assert [(m.seq, m.outcome) for m in db.unacked()] == [(4, "applied"), (5, "rejected")]
        db.mark_acked(4)
        db.mark_rolled_back(4, "raised RuntimeError")
        assert [(m.seq, m.outcome) for m in db.unacked()] == [(4, "rolled-back"), (5, "rejected")]
    finally:
        db.close()


def test_a_snapshot_holds_exactly_its_versions_while_a_step_lands(tmp_path: Path) -> None:
    """A step committed while a snapshot is read (found by the kill -9 soak: the server ended with one
    pose more than map versions): the snapshot's trajectory stops at its own version, so the next delta
    does not send that pose twice. pysqlite runs SELECTs outside a transaction, so each of the snapshot's
    statements sees the newest commit; here a second writer commits between two of them."""
    from sqlalchemy import event

    path = tmp_path / "robot.db"
    db, other = RobotDB(path), RobotDB(path)
    try:
        for v in range(1, 6):
            db.record_step(step_record(v))
        landed: list[int] = []

        def step_lands(_conn: object, _cursor: object, statement: str, *_args: object) -> None:
            if not landed and "FROM poses" in statement and "max(" not in statement:
                other.record_step(step_record(6))
                landed.append(6)

        event.listen(db.engine, "before_cursor_execute", step_lands)
        snap = db.snapshot()
        event.remove(db.engine, "before_cursor_execute", step_lands)
        assert landed == [6], "the step was not committed during the snapshot"
        assert snap is not None
        assert len(snap["trajectory"]) == snap["version"], (snap["version"], len(snap["trajectory"]))
        assert [p[0] for p in snap["trajectory"]] == [v * 0.1 for v in range(1, snap["version"] + 1)]
    finally:
        other.close()
        db.close()


def test_the_installing_message_of_a_kernel_survives_reopening_and_is_taken_once(tmp_path: Path) -> None:
    from robot_agent.models import KernelRecord

    key = ("noise-removal", "dbscan", "1.2.0")
    db = RobotDB(tmp_path / "robot.db")
    try:
        db.save_kernel(
            KernelRecord(
                stage=key[0], name=key[1], version=key[2], sha256="0" * 64, source=b"", state="verified"
            )
        )
        db.record_message(7, "applied", None, {"mode": "online"}, installed=[key])
    finally:
        db.close()
    again = RobotDB(tmp_path / "robot.db")  # a restart
    try:
        assert again.take_installed_by(*key) == 7
        assert again.take_installed_by(*key) is None, "a rollback is reported once"
        assert again.take_installed_by("noise-removal", "dbscan", "9.9.9") is None
    finally:
        again.close()


def test_floors_only_rise_and_survive_reopening(tmp_path: Path) -> None:
    path = tmp_path / "robot.db"
    db = RobotDB(path)
    try:
        db.record_config({"mode": "online"}, "start-up", [("noise-removal", "dbscan", "1.0.0")])
        db.record_message(3, "applied", None, {"mode": "online"}, ran=[("noise-removal", "dbscan", "1.10.0")])
        db.record_message(4, "applied", None, {"mode": "online"}, ran=[("noise-removal", "dbscan", "1.9.0")])
        db.record_message(5, "rejected", "why", None, ran=[("noise-removal", "dbscan", "9.0.0")])  # not run
        db.record_config({"mode": "online"}, "automatic rollback", [("noise-removal", "dbscan", "1.0.0")])
    finally:
        db.close()
    db = RobotDB(path)
    try:
        assert db.run_floors() == {("noise-removal", "dbscan"): "1.10.0"}  # numeric order, not text
    finally:
        db.close()
    with sqlite3.connect(path) as conn:
        assert conn.execute("SELECT seq FROM kernels_run").fetchall() == [(3,)]


def test_the_migration_backfills_floors_from_the_configuration_history(tmp_path: Path) -> None:
    path = tmp_path / "robot.db"
    engine = create_engine(f"sqlite:///{path}")
    cfg = Config()
    cfg.set_main_option("script_location", str(MIGRATIONS_DIR))
    with engine.begin() as conn:
        cfg.attributes["connection"] = conn
        command.upgrade(cfg, "r0001")  # a Robot DB from before the floors existed
    engine.dispose()
    history = [
        '{"noise_removal": [{"name": "dbscan", "version": "1.1.0"}], "clustering": {"name": "kmeans"}}',
        '{"noise_removal": [{"name": "dbscan", "version": "1.0.0"}, {"name": "erosion", "version": "1.0.0"}],'
        ' "segmentation": {"name": "abd-iepf", "version": "1.0.0"}, "scan_matching": null}',
        '"not a configuration"',
        "{broken json",
    ]
    with sqlite3.connect(path) as conn:
        conn.executemany(
            "INSERT INTO config_history (at, seq, config, note) VALUES ('2026-01-01 00:00:00', NULL, ?, '')",
            [(h,) for h in history],
        )
    db = RobotDB(path)  # migrates to head
    try:
        assert db.run_floors() == {
            ("noise-removal", "dbscan"): "1.1.0",
            ("noise-removal", "erosion"): "1.0.0",
            ("segmentation", "abd-iepf"): "1.0.0",
        }
        assert db.integrity_ok()
    finally:
        db.close()
