"""The Robot DB's resume tables as the agent uses them (:mod:`robot_agent.resume`): the mapping state saved
at a recorded version (one row) and the journal of the scans mapped since. Both are written inside the
step's own transaction (:meth:`robot_agent.store_map.MapTables.record_step` calls :func:`write_resume`),
so the saved state, the journal and the recorded map versions always agree. Saving a state drops the
journal up to it: the tables hold one state and at most one checkpoint interval of scans.
"""

from __future__ import annotations

from dataclasses import dataclass

from sqlalchemy import delete, insert, select
from sqlalchemy.dialects.sqlite import insert as sqlite_insert
from sqlalchemy.orm import Session

from robot_agent.models import JournalScan, MappingState, utcnow
from robot_agent.store_db import RobotDBFile, table_of

__all__ = ["ResumeTables", "SavedState", "write_resume"]


@dataclass(frozen=True, slots=True)
class SavedState:
    """The mapping state after step ``version``: its ``kind`` and ``format`` (as its bytes say), the wall
    id offset the agent adds, and the bytes (:meth:`shared.pipeline.MapperState.to_bytes`)."""

    version: int
    kind: str
    format: int
    id_offset: int
    state: bytes


def write_resume(s: Session, version: int, scan: bytes | None, saved: SavedState | None) -> None:
    """Within the step's transaction ``s``: journal step ``version``'s ``scan``; with ``saved`` (the state
    after this step or an earlier one), replace the saved state and drop the journal up to it."""
    if saved is not None:
        values = {
            "version": saved.version,
            "kind": saved.kind,
            "format": saved.format,
            "id_offset": saved.id_offset,
            "state": saved.state,
            "saved_at": utcnow(),
        }
        stmt = sqlite_insert(table_of(MappingState)).values(id=1, **values)
        s.execute(stmt.on_conflict_do_update(index_elements=["id"], set_=values))
        s.execute(delete(JournalScan).where(JournalScan.version <= saved.version))
    if scan is not None and (saved is None or version > saved.version):
        s.execute(_INSERT_SCAN, {"version": version, "scan": scan})


_INSERT_SCAN = insert(table_of(JournalScan))  # the step's statement, built once


class ResumeTables(RobotDBFile):
    """The resume methods of :class:`robot_agent.store.RobotDB`."""

    def saved_state(self) -> SavedState | None:
        """The mapping state saved last, or None (a new Robot DB, or one from before states were kept)."""
        with self._factory() as s:
            row = s.get(MappingState, 1)
            if row is None:
                return None
            return SavedState(row.version, row.kind, row.format, row.id_offset, row.state)

    def journal(self, after_version: int) -> list[tuple[int, bytes]]:
        """The journaled scans of the steps after ``after_version``, in step order: ``(version, bytes)``."""
        with self._factory() as s:
            rows = s.execute(
                select(JournalScan.version, JournalScan.scan)
                .where(JournalScan.version > after_version)
                .order_by(JournalScan.version)
            )
            return [(int(v), bytes(b)) for v, b in rows]

    def journal_size(self) -> int:
        """How many scans the journal holds (tests, the soak)."""
        with self._factory() as s:
            return len(list(s.execute(select(JournalScan.version))))

    def forget_state(self) -> None:
        """Drop the saved state and the journal (the state did not load: a new map starts)."""
        with self.tx() as s:
            s.execute(delete(MappingState))
            s.execute(delete(JournalScan))
