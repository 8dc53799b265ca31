"""The server database (docs/design.md §7) as SQLAlchemy 2 declarative models.

The schema itself is owned by the Alembic migrations in ``migrations/server``; these classes must match
them (a test compares the migrated schema with this metadata). Times are UTC, lengths metres, angles
radians. Tokens are stored only as SHA-256 hashes.
"""

from __future__ import annotations

from datetime import datetime
from typing import Any, ClassVar

from sqlalchemy import (
    JSON,
    BigInteger,
    Float,
    ForeignKey,
    Index,
    Integer,
    LargeBinary,
    MetaData,
    String,
    Text,
    UniqueConstraint,
)
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column

from shared.sqltypes import NAMING, UTCDateTime, utcnow

__all__ = [
    "AgentInstance",
    "AuditEntry",
    "AuthFailure",
    "Base",
    "KernelArtifact",
    "MapDeltaRecord",
    "MapSegment",
    "MapSession",
    "MapSessionSegment",
    "MapSessionTrajectoryPoint",
    "MapState",
    "MapUploadRecord",
    "Message",
    "OperatorToken",
    "Robot",
    "Rollout",
    "RolloutRobot",
    "Session",
    "SigningKey",
    "TrajectoryPoint",
    "UTCDateTime",
    "utcnow",
]


class Base(DeclarativeBase):
    metadata = MetaData(naming_convention=NAMING)
    type_annotation_map: ClassVar[dict[Any, Any]] = {datetime: UTCDateTime(), dict[str, Any]: JSON}


class OperatorToken(Base):
    __tablename__ = "operator_tokens"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    name: Mapped[str] = mapped_column(String(100))
    token_hash: Mapped[str] = mapped_column(String(64), unique=True)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    revoked_at: Mapped[datetime | None] = mapped_column(default=None)
    #: The operator token that created this one (None: made by the server or the CLI). Revoking a token
    #: revokes every token it created, transitively.
    created_by_id: Mapped[int | None] = mapped_column(
        ForeignKey("operator_tokens.id", ondelete="SET NULL"), default=None, index=True
    )
    #: When the token stops working (None: never).
    expires_at: Mapped[datetime | None] = mapped_column(default=None)


class Session(Base):
    """A browser session (cookie), opened by logging in with an operator token."""

    __tablename__ = "sessions"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    token_hash: Mapped[str] = mapped_column(String(64), unique=True)
    operator_id: Mapped[int] = mapped_column(ForeignKey("operator_tokens.id", ondelete="CASCADE"))
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    expires_at: Mapped[datetime]


class Robot(Base):
    __tablename__ = "robots"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    name: Mapped[str] = mapped_column(String(100), unique=True)
    token_hash: Mapped[str] = mapped_column(String(64), unique=True)
    #: The operator token that issued the robot's current token (registration or rotation); revoking that
    #: operator token revokes this robot token too.
    token_issued_by_id: Mapped[int | None] = mapped_column(
        ForeignKey("operator_tokens.id", ondelete="SET NULL"), default=None, index=True
    )
    #: When the robot's current token was revoked (None: it works); a rotation gives a new one.
    token_revoked_at: Mapped[datetime | None] = mapped_column(default=None)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    last_seen_at: Mapped[datetime | None] = mapped_column(default=None)
    mode: Mapped[str | None] = mapped_column(String(20), default=None)
    active_kernels: Mapped[dict[str, Any]] = mapped_column(default=dict)
    step_ms: Mapped[float | None] = mapped_column(Float, default=None)
    last_error: Mapped[str | None] = mapped_column(Text, default=None)
    #: The configuration in force (``PipelineConfig`` as JSON), as the robot last reported it.
    config: Mapped[dict[str, Any] | None] = mapped_column(JSON, default=None)
    #: The robot's kernel store: ``[{stage, name, version, state, sha256}]``, as last reported.
    kernels: Mapped[list[dict[str, Any]] | None] = mapped_column(JSON, default=None)
    map_version: Mapped[int] = mapped_column(BigInteger, default=0)
    last_seq: Mapped[int] = mapped_column(Integer, default=0)
    #: The mapping session of the current map (a UUID from the robot; None: a robot from before sessions).
    map_session: Mapped[str | None] = mapped_column(String(36), default=None)
    #: The agent process currently speaking for the robot (its instance id) and since when.
    agent_instance: Mapped[str | None] = mapped_column(String(36), default=None)
    agent_since: Mapped[datetime | None] = mapped_column(default=None)


class Message(Base):
    """A control message queued for one robot; ``seq`` counts 1, 2, ... per robot."""

    __tablename__ = "messages"
    __table_args__ = (UniqueConstraint("robot_id", "seq"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    robot_id: Mapped[int] = mapped_column(ForeignKey("robots.id", ondelete="CASCADE"))
    seq: Mapped[int] = mapped_column(Integer)
    xml: Mapped[str] = mapped_column(Text)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    created_by: Mapped[str] = mapped_column(String(100))
    status: Mapped[str] = mapped_column(String(20), default="queued")
    reason: Mapped[str | None] = mapped_column(Text, default=None)
    acked_at: Mapped[datetime | None] = mapped_column(default=None)


class SigningKey(Base):
    """An Ed25519 public key whose signatures the server accepts on kernel uploads."""

    __tablename__ = "signing_keys"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    key_id: Mapped[str] = mapped_column(String(16), unique=True)
    name: Mapped[str] = mapped_column(String(100))
    public_key: Mapped[str] = mapped_column(String(64))
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    revoked_at: Mapped[datetime | None] = mapped_column(default=None)


class KernelArtifact(Base):
    """One immutable kernel version; a deleted version keeps its row (not its source): never reused."""

    __tablename__ = "kernels"
    __table_args__ = (UniqueConstraint("name", "version"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    name: Mapped[str] = mapped_column(String(64))
    version: Mapped[str] = mapped_column(String(32))
    stage: Mapped[str] = mapped_column(String(32))
    sha256: Mapped[str] = mapped_column(String(64))
    size_bytes: Mapped[int] = mapped_column(Integer)
    source: Mapped[bytes | None] = mapped_column(LargeBinary, default=None)
    signature: Mapped[str] = mapped_column(String(100))
    key_id: Mapped[str] = mapped_column(String(16))
    uploaded_at: Mapped[datetime] = mapped_column(default=utcnow)
    uploaded_by: Mapped[str] = mapped_column(String(100))
    deleted_at: Mapped[datetime | None] = mapped_column(default=None)
    #: The kernel's parameters as a JSON Schema, as declared at upload (``linemap kernels describe``):
    #: what the server checks a message's parameters for this kernel against before queueing it (the
    #: robot checks them again against the code). None: not declared.
    parameters: Mapped[dict[str, Any] | None] = mapped_column(JSON, default=None)


class MapState(Base):
    """The robot's current temporary map apart from its walls: centroids, pose, time (one row per robot)."""

    __tablename__ = "map_states"

    robot_id: Mapped[int] = mapped_column(ForeignKey("robots.id", ondelete="CASCADE"), primary_key=True)
    version: Mapped[int] = mapped_column(BigInteger)
    stamp_s: Mapped[float] = mapped_column(Float)
    centroids: Mapped[dict[str, Any]] = mapped_column()
    pose: Mapped[dict[str, Any]] = mapped_column()
    #: Unix time (s) at which the robot finished the step of ``version`` (None if it did not say).
    wall_time_s: Mapped[float | None] = mapped_column(Float, default=None)
    updated_at: Mapped[datetime] = mapped_column(default=utcnow)
    #: The pose graph's keyframes ``{"rows": [[keyframe_id, stamp_s, x_m, y_m, theta_rad], ...]}`` by id, as
    #: last corrected (None: the robot sent none).
    keyframes: Mapped[dict[str, Any] | None] = mapped_column(JSON, default=None)
    #: The loop closures ``{"rows": [[keyframe_id_a, keyframe_id_b], ...]}`` (None: none sent).
    loop_closures: Mapped[dict[str, Any] | None] = mapped_column(JSON, default=None)
    #: The covariance of ``pose``, 3x3 over (x_m, y_m, theta_rad) (None: the robot did not send one).
    pose_covariance: Mapped[list[list[float]] | None] = mapped_column(JSON, default=None)
    #: The robot's rows in ``map_segments`` and ``trajectory_points``, kept with every write of them in the
    #: same transaction (:mod:`server.mapcounts`): the wall cap and the trajectory's cap read them in O(1)
    #: where counting the rows cost O(rows) at every upload (6 ms at a full trajectory).
    n_walls: Mapped[int] = mapped_column(BigInteger, default=0, server_default="0")
    n_poses: Mapped[int] = mapped_column(BigInteger, default=0, server_default="0")


class MapSegment(Base):
    """One wall of a robot's current map, by the robot's stable segment id; metres, world frame."""

    __tablename__ = "map_segments"

    robot_id: Mapped[int] = mapped_column(ForeignKey("robots.id", ondelete="CASCADE"), primary_key=True)
    segment_id: Mapped[int] = mapped_column(BigInteger, primary_key=True)
    x0_m: Mapped[float] = mapped_column(Float)
    y0_m: Mapped[float] = mapped_column(Float)
    x1_m: Mapped[float] = mapped_column(Float)
    y1_m: Mapped[float] = mapped_column(Float)
    #: The map version that last wrote it (a wall a delta sends again unchanged keeps its version).
    version: Mapped[int] = mapped_column(BigInteger)


class TrajectoryPoint(Base):
    __tablename__ = "trajectory_points"
    __table_args__ = (Index("ix_trajectory_points_robot_version", "robot_id", "version"),)

    id: Mapped[int] = mapped_column(BigInteger().with_variant(Integer, "sqlite"), primary_key=True)
    robot_id: Mapped[int] = mapped_column(ForeignKey("robots.id", ondelete="CASCADE"))
    version: Mapped[int] = mapped_column(BigInteger)
    stamp_s: Mapped[float] = mapped_column(Float)
    x_m: Mapped[float] = mapped_column(Float)
    y_m: Mapped[float] = mapped_column(Float)
    theta_rad: Mapped[float] = mapped_column(Float)


class MapUploadRecord(Base):
    """Each accepted upload, by its idempotency key: a retried upload finds its record and changes nothing."""

    __tablename__ = "map_uploads"
    __table_args__ = (UniqueConstraint("robot_id", "idempotency_key"),)

    id: Mapped[int] = mapped_column(BigInteger().with_variant(Integer, "sqlite"), primary_key=True)
    robot_id: Mapped[int] = mapped_column(ForeignKey("robots.id", ondelete="CASCADE"))
    idempotency_key: Mapped[str] = mapped_column(String(100))
    version: Mapped[int] = mapped_column(BigInteger)
    base_version: Mapped[int | None] = mapped_column(BigInteger, default=None)
    #: The map session the upload was applied in (a retry is answered with it).
    map_session: Mapped[str | None] = mapped_column(String(36), default=None)
    n_segments: Mapped[int] = mapped_column(Integer)
    n_removed: Mapped[int] = mapped_column(Integer)
    received_at: Mapped[datetime] = mapped_column(default=utcnow)


class MapDeltaRecord(Base):
    """The last few uploads of each robot's map as its stream sends them, so that any server process can
    send a viewer the deltas it missed (server.maplog): a delta's event as JSON, or for a snapshot no
    body (the stream reads the whole map instead); a delta also keeps what it replaced, so that the history
    slider can replay earlier versions (server.maphistory)."""

    __tablename__ = "map_deltas"

    robot_id: Mapped[int] = mapped_column(ForeignKey("robots.id", ondelete="CASCADE"), primary_key=True)
    version: Mapped[int] = mapped_column(BigInteger, primary_key=True)
    #: None for a snapshot
    base_version: Mapped[int | None] = mapped_column(BigInteger, default=None)
    body: Mapped[str | None] = mapped_column(Text, default=None)
    #: for a delta: what it replaced (server.maphistory: the walls it changed or removed as they were,
    #: the ids it added, and the map state before it), as JSON; None for a snapshot or an older row
    undo: Mapped[str | None] = mapped_column(Text, default=None)


class AuthFailure(Base):
    """Failed authentications of one source (client address, or IPv6 /64) in its current window, shared by
    every server process; written on failures only. Times are Unix seconds of the limiter's clock."""

    __tablename__ = "auth_failures"

    source: Mapped[str] = mapped_column(String(64), primary_key=True)
    window_start_s: Mapped[float] = mapped_column(Float)
    failures: Mapped[int] = mapped_column(Integer)
    blocked_until_s: Mapped[float | None] = mapped_column(Float, default=None)


class AuditEntry(Base):
    """One operator action: who, what, on which resource, with details (never a secret)."""

    __tablename__ = "audit_log"

    id: Mapped[int] = mapped_column(BigInteger().with_variant(Integer, "sqlite"), primary_key=True)
    at: Mapped[datetime] = mapped_column(default=utcnow, index=True)
    actor: Mapped[str] = mapped_column(String(100))
    action: Mapped[str] = mapped_column(String(50))
    target: Mapped[str] = mapped_column(String(200))
    detail: Mapped[dict[str, Any]] = mapped_column(default=dict)


class Rollout(Base):
    """A kernel version rolled out to many robots: canaries, then waves (docs/rollouts.md).

    ``state``: running | paused | completed | stopped | aborted. ``active`` is true while the driver has
    something to do (a wave to send, a robot in its commit window, a late acknowledgement to watch);
    ``lease_owner``/``lease_until`` name the server process driving it (one at a time, across processes).
    Thresholds: ``max_failure_share`` of the robots tried, ``max_step_ratio`` of a robot's step time
    before the rollout; times in seconds."""

    __tablename__ = "rollouts"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    stage: Mapped[str] = mapped_column(String(32))
    name: Mapped[str] = mapped_column(String(64))
    version: Mapped[str] = mapped_column(String(32))
    sha256: Mapped[str] = mapped_column(String(64))
    state: Mapped[str] = mapped_column(String(20), default="running")
    active: Mapped[bool] = mapped_column(default=True, index=True)
    canaries: Mapped[int] = mapped_column(Integer)
    wave_size: Mapped[int] = mapped_column(Integer)
    max_failure_share: Mapped[float] = mapped_column(Float)
    commit_window_s: Mapped[float] = mapped_column(Float)
    ack_timeout_s: Mapped[float] = mapped_column(Float)
    watch_timeout_s: Mapped[float] = mapped_column(Float, default=3600.0, server_default="3600")
    max_step_ratio: Mapped[float | None] = mapped_column(Float, default=None)
    fail_on_rollback_error: Mapped[bool] = mapped_column(default=True)
    wave: Mapped[int] = mapped_column(Integer, default=0)
    stop_reason: Mapped[str | None] = mapped_column(Text, default=None)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    created_by: Mapped[str] = mapped_column(String(100))
    finished_at: Mapped[datetime | None] = mapped_column(default=None)
    lease_owner: Mapped[str | None] = mapped_column(String(64), default=None)
    lease_until: Mapped[datetime | None] = mapped_column(default=None)


class RolloutRobot(Base):
    """One robot of a rollout: its place (``position``; wave 0 = canaries), state and the reason.

    ``state``: pending | sent | applied (in its commit window) | installed | rolled-back | failed |
    timed-out | skipped. ``previous`` is the stage's kernel (``name@version``) before the update: what a
    rollback goes back to. ``watch``: a ``timed-out`` robot (no acknowledgement in time) whose queued
    update may still be applied later; the driver rolls it back if it is, until the rollout's
    ``watch_timeout_s`` after it was sent."""

    __tablename__ = "rollout_robots"
    __table_args__ = (UniqueConstraint("rollout_id", "robot_id"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    rollout_id: Mapped[int] = mapped_column(ForeignKey("rollouts.id", ondelete="CASCADE"), index=True)
    robot_id: Mapped[int] = mapped_column(ForeignKey("robots.id", ondelete="CASCADE"), index=True)
    position: Mapped[int] = mapped_column(Integer)
    wave: Mapped[int] = mapped_column(Integer)
    state: Mapped[str] = mapped_column(String(20), default="pending")
    reason: Mapped[str | None] = mapped_column(Text, default=None)
    seq: Mapped[int | None] = mapped_column(Integer, default=None)
    rollback_seq: Mapped[int | None] = mapped_column(Integer, default=None)
    previous: Mapped[str | None] = mapped_column(String(100), default=None)
    baseline_step_ms: Mapped[float | None] = mapped_column(Float, default=None)
    baseline_error: Mapped[str | None] = mapped_column(Text, default=None)
    sent_at: Mapped[datetime | None] = mapped_column(default=None)
    applied_at: Mapped[datetime | None] = mapped_column(default=None)
    finished_at: Mapped[datetime | None] = mapped_column(default=None)
    watch: Mapped[bool] = mapped_column(default=False)


class MapSession(Base):
    """One mapping session of a robot (docs/reliability/identity.md): the current one
    (``ended_at`` None; its walls are in ``map_segments``) or an ended one, whose map was moved to
    ``map_session_segments`` / ``map_session_trajectory`` when a new session began. ``session_id`` None:
    the map of a robot from before sessions. ``last_version``, ``last_upload_at``, ``wall_count`` and
    ``state`` (stamp_s, pose, centroids, wall_time_s) are filled when the session ends."""

    __tablename__ = "map_sessions"
    __table_args__ = (Index("ix_map_sessions_robot_session", "robot_id", "session_id"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    robot_id: Mapped[int] = mapped_column(ForeignKey("robots.id", ondelete="CASCADE"))
    session_id: Mapped[str | None] = mapped_column(String(36), default=None)
    started_at: Mapped[datetime] = mapped_column(default=utcnow)
    first_version: Mapped[int | None] = mapped_column(BigInteger, default=None)
    reason: Mapped[str | None] = mapped_column(String(300), default=None)
    ended_at: Mapped[datetime | None] = mapped_column(default=None)
    last_version: Mapped[int | None] = mapped_column(BigInteger, default=None)
    last_upload_at: Mapped[datetime | None] = mapped_column(default=None)
    wall_count: Mapped[int | None] = mapped_column(Integer, default=None)
    state: Mapped[dict[str, Any] | None] = mapped_column(JSON, default=None)


class MapSessionSegment(Base):
    """One wall of an ended session's map (as it was when the session ended)."""

    __tablename__ = "map_session_segments"

    session_pk: Mapped[int] = mapped_column(
        ForeignKey("map_sessions.id", ondelete="CASCADE"), primary_key=True
    )
    segment_id: Mapped[int] = mapped_column(BigInteger, primary_key=True)
    x0_m: Mapped[float] = mapped_column(Float)
    y0_m: Mapped[float] = mapped_column(Float)
    x1_m: Mapped[float] = mapped_column(Float)
    y1_m: Mapped[float] = mapped_column(Float)
    version: Mapped[int] = mapped_column(BigInteger)


class MapSessionTrajectoryPoint(Base):
    """One pose of an ended session's trajectory."""

    __tablename__ = "map_session_trajectory"
    __table_args__ = (Index("ix_map_session_trajectory_session", "session_pk", "id"),)

    id: Mapped[int] = mapped_column(BigInteger().with_variant(Integer, "sqlite"), primary_key=True)
    session_pk: Mapped[int] = mapped_column(ForeignKey("map_sessions.id", ondelete="CASCADE"))
    version: Mapped[int] = mapped_column(BigInteger)
    stamp_s: Mapped[float] = mapped_column(Float)
    x_m: Mapped[float] = mapped_column(Float)
    y_m: Mapped[float] = mapped_column(Float)
    theta_rad: Mapped[float] = mapped_column(Float)


class AgentInstance(Base):
    """An agent process that spoke for a robot (its instance id, a UUID it makes at start): the robot's
    current one is ``robots.agent_instance``; one that another took over from gets ``superseded_at`` and
    is refused from then on (409 ``agent_superseded``)."""

    __tablename__ = "agent_instances"
    __table_args__ = (UniqueConstraint("robot_id", "instance_id"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    robot_id: Mapped[int] = mapped_column(ForeignKey("robots.id", ondelete="CASCADE"))
    instance_id: Mapped[str] = mapped_column(String(36))
    first_seen_at: Mapped[datetime] = mapped_column(default=utcnow)
    superseded_at: Mapped[datetime | None] = mapped_column(default=None)
