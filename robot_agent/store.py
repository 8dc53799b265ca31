"""The Robot DB as the agent uses it: each method is one transaction, so what belongs together commits
together (a step's map version, walls, pose and outbox entry; a message's outcome and the configuration it
put in force). SQLite in WAL mode with ``synchronous=FULL``: a committed step survives kill -9 and power
loss.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from alembic import command
from alembic.config import Config
from sqlalchemy import Engine, create_engine, delete, event, func, select
from sqlalchemy.dialects.sqlite import insert as sqlite_insert
from sqlalchemy.exc import SQLAlchemyError
from sqlalchemy.orm import Session, sessionmaker

from robot_agent.errors import AgentError
from robot_agent.models import (
    AppliedMessage,
    ConfigRecord,
    KernelRecord,
    MapVersion,
    Meta,
    OutboxEntry,
    PoseRecord,
    RunFloor,
    Wall,
    utcnow,
)
from shared.kernels.versions import parse_version

__all__ = ["MIGRATIONS_DIR", "PendingUpload", "Ran", "RobotDB", "StepRecord"]

#: Kernel versions a configuration puts in force: ``(stage, name, version)``.
Ran = Sequence[tuple[str, str, str]]

log = logging.getLogger(__name__)

_PACKAGED = Path(__file__).resolve().parent / "migrations"
MIGRATIONS_DIR = (
    _PACKAGED
    if (_PACKAGED / "env.py").is_file()
    else Path(__file__).resolve().parent.parent / "migrations" / "robot"
)


@dataclass(frozen=True, slots=True)
class StepRecord:
    """What one step changed: new or changed walls ``[id, x0, y0, x1, y1]``, removed ids, the pose row
    ``[stamp_s, x_m, y_m, theta_rad]``, the latest centroids, and the source position (scans consumed)."""

    version: int
    stamp_s: float
    source_index: int
    segments: list[list[float]]
    removed: list[int]
    pose: list[float]
    centroids: list[list[float]]


@dataclass(frozen=True, slots=True)
class PendingUpload:
    """Consecutive outbox versions folded into one delta."""

    first_version: int
    version: int
    stamp_s: float
    segments: list[list[float]]
    removed: list[int]
    centroids: list[list[float]]
    pose: list[float]
    trajectory: list[list[float]]


class RobotDB:
    """The Robot DB at ``path`` (created and migrated to the newest schema on open)."""

    def __init__(self, path: Path | str) -> None:
        self.path = Path(path)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self.engine: Engine = create_engine(
                f"sqlite:///{self.path}", connect_args={"check_same_thread": False, "timeout": 30}
            )
            event.listen(self.engine, "connect", _pragmas)
            self._migrate()
        except (OSError, SQLAlchemyError) as exc:
            raise AgentError(f"cannot open the Robot DB {self.path}: {exc}") from None
        self._factory = sessionmaker(self.engine, expire_on_commit=False)
        self._lock = threading.Lock()

    def _migrate(self) -> None:
        cfg = Config()
        cfg.set_main_option("script_location", str(MIGRATIONS_DIR))
        with self.engine.begin() as conn:
            cfg.attributes["connection"] = conn
            command.upgrade(cfg, "head")

    @contextmanager
    def tx(self) -> Iterator[Session]:
        """One transaction (writers of this process queue on a lock: SQLite has one writer)."""
        with self._lock, self._factory() as s, s.begin():
            yield s

    def close(self) -> None:
        self.engine.dispose()

    def integrity_ok(self) -> bool:
        with self.engine.connect() as conn:
            return conn.exec_driver_sql("PRAGMA integrity_check").scalar() == "ok"

    # ------------------------------------------------------------------ meta
    def get(self, key: str, default: Any = None) -> Any:
        with self._factory() as s:
            row = s.get(Meta, key)
            return default if row is None else row.value.get("v", default)

    def put(self, key: str, value: Any) -> None:
        with self.tx() as s:
            _put(s, key, value)

    # ------------------------------------------------------------------ steps and outbox
    def record_step(self, rec: StepRecord) -> None:
        """Store one step's map version, walls, pose and outbox entry in one transaction."""
        with self.tx() as s:
            s.add(
                MapVersion(
                    version=rec.version,
                    stamp_s=rec.stamp_s,
                    source_index=rec.source_index,
                    change={"segments": rec.segments, "removed": rec.removed, "centroids": rec.centroids},
                )
            )
            if rec.removed:
                s.execute(delete(Wall).where(Wall.segment_id.in_(rec.removed)))
            if rec.segments:
                stmt = sqlite_insert(Wall)
                stmt = stmt.on_conflict_do_update(
                    index_elements=["segment_id"],
                    set_={c: getattr(stmt.excluded, c) for c in ("x0_m", "y0_m", "x1_m", "y1_m")},
                )
                s.execute(
                    stmt,
                    [
                        {"segment_id": int(r[0]), "x0_m": r[1], "y0_m": r[2], "x1_m": r[3], "y1_m": r[4]}
                        for r in rec.segments
                    ],
                )
            s.add(
                PoseRecord(
                    version=rec.version,
                    stamp_s=rec.pose[0],
                    x_m=rec.pose[1],
                    y_m=rec.pose[2],
                    theta_rad=rec.pose[3],
                )
            )
            s.add(OutboxEntry(version=rec.version))
            _put(s, "map_version", rec.version)
            _put(s, "source_index", rec.source_index)

    def walls(self) -> list[list[float]]:
        """The current map's walls ``[id, x0, y0, x1, y1]`` by id."""
        with self._factory() as s:
            rows = s.execute(
                select(Wall.segment_id, Wall.x0_m, Wall.y0_m, Wall.x1_m, Wall.y1_m).order_by(Wall.segment_id)
            )
            return [[float(i), a, b, c, d] for i, a, b, c, d in rows]

    def trajectory(self, after_version: int = 0) -> list[list[float]]:
        with self._factory() as s:
            rows = s.execute(
                select(PoseRecord.stamp_s, PoseRecord.x_m, PoseRecord.y_m, PoseRecord.theta_rad)
                .where(PoseRecord.version > after_version)
                .order_by(PoseRecord.version)
            )
            return [list(r) for r in rows]

    def snapshot(self) -> dict[str, Any] | None:
        """The whole map at the latest recorded version (a snapshot upload), consistent with that version.

        pysqlite runs SELECTs outside a transaction, so each statement here would see the newest commit:
        a step recorded in between put its pose into a snapshot labelled one version earlier, and the next
        delta sent that pose again (the server held one pose more than map versions). So the read holds the
        writers' lock (this process is the Robot DB's only writer) and the trajectory stops at the
        snapshot's version."""
        with self._lock, self._factory() as s, s.begin():
            latest = s.scalar(select(func.max(MapVersion.version)))
            if latest is None:
                return None
            mv = s.get(MapVersion, latest)
            pose = s.get(PoseRecord, latest)
            assert mv is not None and pose is not None
            walls = s.execute(
                select(Wall.segment_id, Wall.x0_m, Wall.y0_m, Wall.x1_m, Wall.y1_m).order_by(Wall.segment_id)
            )
            traj = s.execute(
                select(PoseRecord.stamp_s, PoseRecord.x_m, PoseRecord.y_m, PoseRecord.theta_rad)
                .where(PoseRecord.version <= latest)
                .order_by(PoseRecord.version)
            )
            return {
                "version": int(latest),
                "stamp_s": mv.stamp_s,
                "segments": [[float(i), a, b, c, d] for i, a, b, c, d in walls],
                "centroids": mv.change.get("centroids", []),
                "pose": [pose.x_m, pose.y_m, pose.theta_rad],
                "trajectory": [list(r) for r in traj],
            }

    def outbox_size(self) -> int:
        with self._factory() as s:
            return int(s.scalar(select(func.count()).select_from(OutboxEntry)) or 0)

    def pending_upload(self, limit: int = 50) -> PendingUpload | None:
        """The oldest ``limit`` outbox versions folded into one delta (later changes win), or ``None``."""
        with self._factory() as s:
            rows = list(
                s.execute(
                    select(MapVersion, PoseRecord)
                    .join(OutboxEntry, OutboxEntry.version == MapVersion.version)
                    .join(PoseRecord, PoseRecord.version == MapVersion.version)
                    .order_by(MapVersion.version)
                    .limit(limit)
                )
            )
        if not rows:
            return None
        segments: dict[int, list[float]] = {}
        removed: set[int] = set()
        for mv, _pose in rows:
            for sid in mv.change.get("removed", []):
                segments.pop(int(sid), None)
                removed.add(int(sid))
            for row in mv.change.get("segments", []):
                segments[int(row[0])] = row
                removed.discard(int(row[0]))
        last_mv, last_pose = rows[-1]
        traj = [[p.stamp_s, p.x_m, p.y_m, p.theta_rad] for _, p in rows]
        return PendingUpload(
            first_version=rows[0][0].version,
            version=last_mv.version,
            stamp_s=last_mv.stamp_s,
            segments=[segments[k] for k in sorted(segments)],
            removed=sorted(removed),
            centroids=last_mv.change.get("centroids", []),
            pose=[last_pose.x_m, last_pose.y_m, last_pose.theta_rad],
            trajectory=traj,
        )

    def mark_uploaded(self, up_to_version: int) -> None:
        """The server holds every version up to ``up_to_version``: drop them from the outbox."""
        with self.tx() as s:
            s.execute(delete(OutboxEntry).where(OutboxEntry.version <= up_to_version))
            _put(s, "uploaded_version", up_to_version)

    def note_attempt(self, version: int) -> None:
        with self.tx() as s:
            row = s.get(OutboxEntry, version)
            if row is not None:
                row.attempts += 1

    # ------------------------------------------------------------------ control messages
    def applied_seq(self) -> int:
        """The highest message number dealt with (applied or rejected)."""
        with self._factory() as s:
            return int(s.scalar(select(func.max(AppliedMessage.seq))) or 0)

    def outcome_of(self, seq: int) -> AppliedMessage | None:
        with self._factory() as s:
            return s.get(AppliedMessage, seq)

    def record_message(
        self,
        seq: int,
        outcome: str,
        reason: str | None,
        config: dict[str, Any] | None,
        note: str = "",
        ran: Ran = (),
        installed: Ran = (),
    ) -> None:
        """A message's outcome, the configuration it put in force and the kernel versions that configuration
        runs (``ran``, raising their anti-rollback floors), and the downloaded kernels it brought in
        (``installed``: their ``installed_by_seq`` becomes ``seq``), in one transaction."""
        with self.tx() as s:
            s.add(AppliedMessage(seq=seq, outcome=outcome, reason=reason))
            if config is not None:
                s.add(ConfigRecord(seq=seq, config=config, note=note))
                _put(s, "config", config)
                _raise_floors(s, ran, seq)
            for stage, name, version in installed:
                row = _kernel(s, stage, name, version)
                if row is not None:
                    row.installed_by_seq = seq

    def take_installed_by(self, stage: str, name: str, version: str) -> int | None:
        """The message that installed this downloaded kernel (None if none is recorded), forgotten in the
        same transaction: its rollback is reported once."""
        with self.tx() as s:
            row = _kernel(s, stage, name, version)
            if row is None or row.installed_by_seq is None:
                return None
            seq, row.installed_by_seq = row.installed_by_seq, None
            return int(seq)

    def record_config(self, config: dict[str, Any], note: str, ran: Ran = ()) -> None:
        """A configuration put in force without a message (start-up, automatic rollback), and the kernel
        versions it runs."""
        with self.tx() as s:
            s.add(ConfigRecord(seq=None, config=config, note=note))
            _put(s, "config", config)
            _raise_floors(s, ran, None)

    def run_floors(self) -> dict[tuple[str, str], str]:
        """``(stage, name) -> version``: the highest version of each kernel this robot has put in force
        (SPEC §9 anti-rollback floor; kept across restarts). One read of a table with a row per kernel name.
        """
        with self._factory() as s:
            return {(r.stage, r.name): r.version for r in s.scalars(select(RunFloor))}

    def mark_rolled_back(self, seq: int, reason: str) -> None:
        """The kernel message ``seq`` brought in failed at run time: report it again as rolled back."""
        with self.tx() as s:
            row = s.get(AppliedMessage, seq)
            if row is not None:
                row.outcome, row.reason, row.acked_at = "rolled-back", reason, None

    def unacked(self) -> list[AppliedMessage]:
        with self._factory() as s:
            return list(
                s.scalars(
                    select(AppliedMessage)
                    .where(AppliedMessage.acked_at.is_(None))
                    .order_by(AppliedMessage.seq)
                )
            )

    def mark_acked(self, seq: int) -> None:
        with self.tx() as s:
            row = s.get(AppliedMessage, seq)
            if row is not None and row.acked_at is None:
                row.acked_at = utcnow()

    # ------------------------------------------------------------------ kernels
    def save_kernel(self, rec: KernelRecord) -> None:
        with self.tx() as s:
            old = s.scalars(
                select(KernelRecord).where(
                    KernelRecord.stage == rec.stage,
                    KernelRecord.name == rec.name,
                    KernelRecord.version == rec.version,
                )
            ).first()
            if old is not None:
                s.delete(old)
                s.flush()
            s.add(rec)

    def set_kernel_state(
        self, stage: str, name: str, version: str, state: str, reason: str | None = None
    ) -> None:
        with self.tx() as s:
            row = s.scalars(
                select(KernelRecord).where(
                    KernelRecord.stage == stage, KernelRecord.name == name, KernelRecord.version == version
                )
            ).first()
            if row is not None:
                row.state, row.reason = state, reason

    def kernels(self, states: Sequence[str] | None = None) -> list[KernelRecord]:
        with self._factory() as s:
            q = select(KernelRecord).order_by(KernelRecord.id)
            if states is not None:
                q = q.where(KernelRecord.state.in_(list(states)))
            return list(s.scalars(q))


def _kernel(s: Session, stage: str, name: str, version: str) -> KernelRecord | None:
    return s.scalars(
        select(KernelRecord).where(
            KernelRecord.stage == stage, KernelRecord.name == name, KernelRecord.version == version
        )
    ).first()


def _raise_floors(s: Session, ran: Ran, seq: int | None) -> None:
    """Raise each ``(stage, name)`` floor to ``version`` if that is higher (never lowers one)."""
    for stage, name, version in ran:
        row = s.get(RunFloor, (stage, name))
        if row is None:
            s.add(RunFloor(stage=stage, name=name, version=version, seq=seq))
            s.flush()
        elif parse_version(version) > parse_version(row.version):
            row.version, row.seq, row.at = version, seq, utcnow()


def _put(s: Session, key: str, value: Any) -> None:
    row = s.get(Meta, key)
    if row is None:
        s.add(Meta(key=key, value={"v": value}))
    else:
        row.value = {"v": value}


def _pragmas(dbapi_connection: Any, _record: Any) -> None:
    cur = dbapi_connection.cursor()
    cur.execute("PRAGMA journal_mode=WAL")
    cur.execute("PRAGMA synchronous=FULL")
    cur.execute("PRAGMA foreign_keys=ON")
    cur.execute("PRAGMA busy_timeout=30000")
    cur.close()
