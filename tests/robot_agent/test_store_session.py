"""The Robot DB's map session (robot_agent/store_map.py, migration r0004): a new Robot DB gets a session id
of its own, one from before sessions gets one on upgrade (its map goes on under it), the id survives
reopening, and a new session clears what counts as uploaded. Also the one-agent-per-Robot-DB lock
(robot_agent/dblock.py)."""

from __future__ import annotations

import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest
from alembic import command
from alembic.config import Config
from sqlalchemy import create_engine

from robot_agent.dblock import RobotDBLock
from robot_agent.errors import SupersededError
from robot_agent.store import RobotDB
from robot_agent.store_db import MIGRATIONS_DIR
from shared.protocol import MAP_SESSION_RE
from tests.robot_agent.records import step_record


def test_each_new_robot_db_has_its_own_session_kept_across_reopening(tmp_path: Path) -> None:
    a, b = RobotDB(tmp_path / "a.db"), RobotDB(tmp_path / "b.db")
    try:
        assert MAP_SESSION_RE.fullmatch(a.map_session()) and a.map_session() != b.map_session()
        assert a.map_session_reason() == "new Robot DB"
        session = a.map_session()
    finally:
        a.close()
        b.close()
    again = RobotDB(tmp_path / "a.db")
    try:
        assert again.map_session() == session
    finally:
        again.close()


def test_a_robot_db_from_before_sessions_gets_one_on_upgrade(tmp_path: Path) -> None:
    path = tmp_path / "robot.db"
    engine = create_engine(f"sqlite:///{path}")
    cfg = Config()
    cfg.set_main_option("script_location", str(MIGRATIONS_DIR))
    with engine.begin() as conn:
        cfg.attributes["connection"] = conn
        command.upgrade(cfg, "r0003")
    engine.dispose()
    with sqlite3.connect(path) as conn:  # a map recorded by an agent from before sessions
        conn.execute(
            "INSERT INTO map_versions (version, stamp_s, source_index, change, created_at) "
            "VALUES (1, 0.1, 1, '{}', '2026-01-01 00:00:00')"
        )
    db = RobotDB(path)  # migrates to head
    try:
        assert MAP_SESSION_RE.fullmatch(db.map_session())
        assert db.map_session_reason() == "map recorded before map sessions"
    finally:
        db.close()


def test_a_new_session_changes_the_id_and_nothing_counts_as_uploaded(tmp_path: Path) -> None:
    db = RobotDB(tmp_path / "robot.db")
    try:
        for v in (1, 2, 3):
            db.record_step(step_record(v))
        db.mark_uploaded(2)
        first = db.map_session()
        new = db.new_map_session("the server is ahead")
        assert new != first and db.map_session() == new
        assert db.map_session_reason() == "the server is ahead"
        assert db.get("uploaded_version") is None
        assert db.outbox_size() == 1  # version 3 still to send: in a snapshot of the whole map
        assert db.snapshot() is not None and db.snapshot()["version"] == 3  # type: ignore[index]
    finally:
        db.close()


def test_a_second_holder_of_the_robot_db_lock_is_refused_with_the_holders_pid(tmp_path: Path) -> None:
    db = tmp_path / "robot.db"
    held = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys, time; from robot_agent.dblock import RobotDBLock; RobotDBLock(sys.argv[1]); "
            "print('held', flush=True); time.sleep(600)",
            str(db),
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert held.stdout is not None and held.stdout.readline().strip() == "held"
        with pytest.raises(SupersededError, match=f"another agent \\(pid {held.pid}\\) is running"):
            RobotDBLock(db)
    finally:
        held.kill()
        held.wait(30)
    lock = RobotDBLock(db)  # the holder is gone (killed): the lock is free at once
    lock.release()
    lock.release()  # idempotent
