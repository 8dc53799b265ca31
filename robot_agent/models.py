"""The Robot DB (docs/design.md §7): a SQLite file in WAL mode on the robot, schema owned by
``migrations/robot``.

Tables: ``meta`` (key -> JSON: robot id, versions, the configuration in force), ``kernels`` (downloaded
kernel artifacts and their state), ``config_history``, ``map_versions`` (each step's map change),
``walls`` (the current map, for restarts), ``poses`` (trajectory), ``outbox`` (map versions not yet
acknowledged by the server), ``applied_messages`` (control messages applied or rejected, and whether the
server has the acknowledgement), ``kernels_run`` (the highest version of each kernel ever put in force: the
anti-rollback floor of docs/design.md §9). ``kernels.installed_by_seq`` ties a downloaded kernel to the
message that installed it. ``mapping_state`` (one row: the pipeline's learned state at a recorded version)
and ``scan_journal`` (the scans mapped since) let a restarted agent go on with the same map at the same
pose (:mod:`robot_agent.resume`). Lengths metres, angles radians, times UTC.
"""

from __future__ import annotations

from datetime import datetime
from typing import Any, ClassVar

from sqlalchemy import JSON, Float, Integer, LargeBinary, MetaData, String, Text, UniqueConstraint
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column

from shared.sqltypes import NAMING, UTCDateTime, utcnow

__all__ = [
    "AppliedMessage",
    "ConfigRecord",
    "JournalScan",
    "KernelRecord",
    "MapVersion",
    "MappingState",
    "Meta",
    "OutboxEntry",
    "PoseRecord",
    "RobotBase",
    "RunFloor",
    "Wall",
    "utcnow",
]


class RobotBase(DeclarativeBase):
    metadata = MetaData(naming_convention=NAMING)
    type_annotation_map: ClassVar[dict[Any, Any]] = {datetime: UTCDateTime(), dict[str, Any]: JSON}


class Meta(RobotBase):
    __tablename__ = "meta"

    key: Mapped[str] = mapped_column(String(50), primary_key=True)
    value: Mapped[dict[str, Any]] = mapped_column()


class KernelRecord(RobotBase):
    """A downloaded kernel artifact. ``state``: verified (passed every check), active (in use), retired
    (replaced or rolled back), rejected (failed a check or failed at run time; ``reason`` says why),
    deleted."""

    __tablename__ = "kernels"
    __table_args__ = (UniqueConstraint("stage", "name", "version"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    stage: Mapped[str] = mapped_column(String(32))
    name: Mapped[str] = mapped_column(String(64))
    version: Mapped[str] = mapped_column(String(32))
    sha256: Mapped[str] = mapped_column(String(64))
    source: Mapped[bytes] = mapped_column(LargeBinary)
    signature: Mapped[str | None] = mapped_column(String(100), default=None)
    key_id: Mapped[str | None] = mapped_column(String(16), default=None)
    state: Mapped[str] = mapped_column(String(16))
    reason: Mapped[str | None] = mapped_column(Text, default=None)
    installed_at: Mapped[datetime] = mapped_column(default=utcnow)
    #: The control message whose configuration put this version in force (an automatic rollback is
    #: reported as that message's outcome, also after a restart); null once reported or never applied.
    installed_by_seq: Mapped[int | None] = mapped_column(Integer, default=None)


class ConfigRecord(RobotBase):
    """Each configuration put in force, with the message that did it (``seq`` null: start-up or rollback)."""

    __tablename__ = "config_history"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    at: Mapped[datetime] = mapped_column(default=utcnow)
    seq: Mapped[int | None] = mapped_column(Integer, default=None)
    config: Mapped[dict[str, Any]] = mapped_column()
    note: Mapped[str] = mapped_column(String(200), default="")


class MapVersion(RobotBase):
    """One step's change of the temporary map: ``change`` holds ``segments`` (new or changed walls, rows
    ``[id, x0, y0, x1, y1]``), ``removed`` ids, ``centroids`` and ``pose``."""

    __tablename__ = "map_versions"

    version: Mapped[int] = mapped_column(Integer, primary_key=True)
    stamp_s: Mapped[float] = mapped_column(Float)
    source_index: Mapped[int] = mapped_column(Integer)
    change: Mapped[dict[str, Any]] = mapped_column()
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class Wall(RobotBase):
    """The current map's walls (kept in step with ``map_versions``; a restart resumes from them)."""

    __tablename__ = "walls"

    segment_id: Mapped[int] = mapped_column(Integer, primary_key=True)
    x0_m: Mapped[float] = mapped_column(Float)
    y0_m: Mapped[float] = mapped_column(Float)
    x1_m: Mapped[float] = mapped_column(Float)
    y1_m: Mapped[float] = mapped_column(Float)


class PoseRecord(RobotBase):
    __tablename__ = "poses"

    version: Mapped[int] = mapped_column(Integer, primary_key=True)
    stamp_s: Mapped[float] = mapped_column(Float)
    x_m: Mapped[float] = mapped_column(Float)
    y_m: Mapped[float] = mapped_column(Float)
    theta_rad: Mapped[float] = mapped_column(Float)


class OutboxEntry(RobotBase):
    """A map version the server has not acknowledged yet."""

    __tablename__ = "outbox"

    version: Mapped[int] = mapped_column(Integer, primary_key=True)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    attempts: Mapped[int] = mapped_column(Integer, default=0)


class AppliedMessage(RobotBase):
    """A control message the robot has dealt with (exactly once): ``outcome`` applied / rejected."""

    __tablename__ = "applied_messages"

    seq: Mapped[int] = mapped_column(Integer, primary_key=True)
    outcome: Mapped[str] = mapped_column(String(16))
    reason: Mapped[str | None] = mapped_column(Text, default=None)
    applied_at: Mapped[datetime] = mapped_column(default=utcnow)
    acked_at: Mapped[datetime | None] = mapped_column(default=None)


class RunFloor(RobotBase):
    """The highest version of kernel ``stage``/``name`` this robot has ever put in force (docs/design.md §9:
    it never runs a lower one unless a message says rollback). Only ever raised; ``seq`` is the message whose
    configuration raised it (null: start-up or automatic rollback)."""

    __tablename__ = "kernels_run"

    stage: Mapped[str] = mapped_column(String(32), primary_key=True)
    name: Mapped[str] = mapped_column(String(64), primary_key=True)
    version: Mapped[str] = mapped_column(String(32))
    seq: Mapped[int | None] = mapped_column(Integer, default=None)
    at: Mapped[datetime] = mapped_column(default=utcnow)


class MappingState(RobotBase):
    """The pipeline's learned state after step ``version`` (one row, ``id`` 1): ``state`` is the bytes form
    of :class:`shared.pipeline.MapperState` (never a pickle), ``id_offset`` what the agent adds to the
    pipeline's wall ids (walls of an earlier map that could not be restored keep theirs)."""

    __tablename__ = "mapping_state"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    version: Mapped[int] = mapped_column(Integer)
    kind: Mapped[str] = mapped_column(String(16))
    format: Mapped[int] = mapped_column(Integer)
    id_offset: Mapped[int] = mapped_column(Integer)
    state: Mapped[bytes] = mapped_column(LargeBinary)
    saved_at: Mapped[datetime] = mapped_column(default=utcnow)


class JournalScan(RobotBase):
    """A scan mapped at step ``version`` after the last saved state (its odometry included): re-stepped on
    a restart. Rows up to the saved state's version are dropped when it is saved."""

    __tablename__ = "scan_journal"

    version: Mapped[int] = mapped_column(Integer, primary_key=True)
    scan: Mapped[bytes] = mapped_column(LargeBinary)
