"""Streams woken by one notice share one read of the delta log (server.mapstream); streams woken otherwise
read for themselves. A real SQLite database; the streams' reads are called as the streams call them."""

from __future__ import annotations

import asyncio
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from sqlalchemy import event

from server.database import Database
from server.mapstream import read_log
from server.migrate import upgrade
from server.models import Robot


def _state(tmp_path: Path) -> tuple[Any, int, list[str]]:
    db = Database(f"sqlite:///{tmp_path / 'reads.db'}")
    upgrade(db.engine)
    with db.session() as s:
        robot = Robot(name="reads", token_hash="0" * 64)
        s.add(robot)
        s.flush()
        rid = robot.id
    statements: list[str] = []
    event.listen(db.engine, "before_cursor_execute", lambda *a: statements.append(a[2]))
    return SimpleNamespace(db=db), rid, statements


def _log_reads(statements: list[str]) -> int:
    return sum(1 for sql in statements if "FROM map_deltas" in sql)


def test_streams_woken_by_one_notice_share_a_read(tmp_path: Path) -> None:
    state, rid, statements = _state(tmp_path)

    async def go() -> list[tuple[tuple[str | None, int], list[Any]]]:
        return list(await asyncio.gather(*(read_log(state, rid, 0, 5) for _ in range(4))))

    results = asyncio.run(go())
    assert results == [((None, 0), [])] * 4  # (no map session, version 0), nothing logged
    assert _log_reads(statements) == 1
    state.db.dispose()


def test_streams_woken_otherwise_or_at_other_versions_read_alone(tmp_path: Path) -> None:
    state, rid, statements = _state(tmp_path)

    async def go() -> None:
        await asyncio.gather(
            read_log(state, rid, 0, None),
            read_log(state, rid, 0, None),  # OVERFLOW, a delta out of step: no notice to share
            read_log(state, rid, 0, 6),  # another notice
            read_log(state, rid, 1, 5),  # another version
        )
        await read_log(state, rid, 0, 5)  # the same notice, after the first read ended: a new read

    asyncio.run(go())
    assert _log_reads(statements) == 5
    state.db.dispose()
