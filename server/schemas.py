"""Request and response bodies of the REST API (pydantic), one family per resource.

Lengths are metres and angles radians in map bodies (docs/design.md §3); control messages keep their own units
(cm unless ``unit=``). Map uploads use compact rows (``[id, x0, y0, x1, y1]``) because a robot sends one every
few hundred milliseconds. The bodies a robot sends (map upload, status, acknowledgement) and the kernel
metadata are :mod:`shared.protocol`'s models, reused or subclassed here, so the robot and the OpenAPI document
use the same definitions.
"""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any, Literal

from fastapi import Path
from pydantic import AwareDatetime, BaseModel, ConfigDict, Field

from shared.protocol.messages import (
    INT64_MAX,
    KernelMeta,
    MapUpload,
    MessageAck,
    RobotKernel,
    RobotStatus,
)

__all__ = [
    "AckIn",
    "AuditOut",
    "KernelOut",
    "LoginIn",
    "MapHistoryOut",
    "MapHistoryVersion",
    "MapOut",
    "MapSessionOut",
    "MapUpload",
    "MapUploadOut",
    "MessageList",
    "MessageOut",
    "RobotCreate",
    "RobotCreated",
    "RobotKernel",
    "RobotOut",
    "RobotStatus",
    "SigningKeyIn",
    "SigningKeyOut",
    "TokenCreate",
    "TokenCreated",
    "WhoAmI",
]

NAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9._ -]{0,99}$"

#: Largest integer a database column holds (signed 64 bits). Ids, sequence numbers, versions and counts in
#: requests are bounded by it, so an oversized number is a 422, not a database driver's overflow (500).
DB_INT_MAX = INT64_MAX
#: Largest id or message number: those columns are ``Integer`` (signed 32 bits on PostgreSQL), and a larger
#: one in a request was the driver's overflow, a 500 (GET /robots/1099511627776 on PostgreSQL).
DB_ID_MAX = 2**31 - 1
#: An id or sequence number in a URL path.
DbIdPath = Annotated[int, Path(ge=0, le=DB_ID_MAX)]


class _In(BaseModel):
    model_config = ConfigDict(extra="forbid")


class RobotCreate(_In):
    name: str = Field(pattern=NAME_PATTERN, description="Unique robot name (letters, digits, . _ - space).")


class RobotOut(BaseModel):
    id: int
    name: str
    created_at: datetime
    last_seen_at: datetime | None
    online: bool
    mode: str | None
    active_kernels: dict[str, Any]
    step_ms: float | None
    last_error: str | None
    config: dict[str, Any] | None = Field(
        None, description="The configuration in force (PipelineConfig JSON), as the robot last reported it."
    )
    kernels: list[RobotKernel] | None = Field(None, description="The robot's kernel store and its states.")
    map_version: int
    map_session: str | None = Field(None, description="The mapping session of the current map.")
    agent_instance: str | None = Field(None, description="The agent process that speaks for the robot.")
    agent_since: datetime | None = None
    last_seq: int = Field(description="Sequence number of the newest control message queued.")
    pending_messages: int = Field(description="Messages not yet acknowledged by the robot.")
    token_revoked_at: datetime | None = Field(
        None, description="When the robot's token was revoked (with its issuer); POST /robots/{id}/token."
    )


class RobotCreated(BaseModel):
    id: int
    name: str
    token: str = Field(description="The robot's token. Shown once; the server keeps only its hash.")


class MessageOut(BaseModel):
    seq: int
    xml: str
    created_at: datetime
    created_by: str
    status: Literal["queued", "applied", "rejected", "rolled-back"]
    reason: str | None
    acked_at: datetime | None


class MessageList(BaseModel):
    messages: list[MessageOut]
    last_seq: int = Field(description="Newest sequence number queued for this robot.")
    map_version: int = Field(
        0,
        description="The newest map version the server holds for this robot (0: none). A robot that was "
        "told it holds a later one in the same session sends its map again (the server was restored from "
        "an older copy).",
    )
    map_session: str | None = Field(None, description="The map session of ``map_version`` (None: no map).")


class AckIn(MessageAck):
    """A robot's acknowledgement of a control message: ``rolled-back`` means applied, then undone by the
    robot (a kernel that failed at run time)."""


class SigningKeyIn(_In):
    name: str = Field(pattern=NAME_PATTERN)
    public_key: str = Field(max_length=2000, description="Ed25519 public key: base64 of 32 bytes, or PEM.")


class SigningKeyOut(BaseModel):
    key_id: str
    name: str
    public_key: str
    created_at: datetime
    revoked: bool


class KernelOut(KernelMeta):
    """A kernel artifact (:class:`shared.protocol.KernelMeta`) and its declared parameter schema."""

    parameters: dict[str, Any] | None = Field(
        default=None,
        description="The kernel's parameters as a JSON Schema, as declared at upload (null: not declared); "
        "messages choosing this kernel are checked against it before they are queued.",
    )


class MapUploadOut(BaseModel):
    version: int = Field(description="The server's map version after this upload.")
    duplicate: bool = Field(description="True when this idempotency key was seen before (nothing changed).")
    map_session: str | None = Field(None, description="The mapping session the server holds this version in.")


class MapSessionOut(BaseModel):
    """One of a robot's maps (a mapping session): the current one or one a new session replaced."""

    map_session: str | None = Field(description="The session id (None: a map from before map sessions).")
    current: bool
    first_version: int | None
    last_version: int | None
    started_at: datetime | None
    last_upload_at: datetime | None
    ended_at: datetime | None
    wall_count: int
    reason: str | None = Field(None, description="Why the robot started this session, as it said.")


class MapOut(BaseModel):
    """A robot's whole current map (also the ``snapshot`` event of the SSE stream)."""

    robot_id: int
    version: int
    map_session: str | None = None
    stamp_s: float
    segments: list[list[float]]
    centroids: list[list[float]]
    pose: list[float]
    trajectory: list[list[float]]
    wall_time_s: float | None = None
    keyframes: list[list[float]] | None = Field(
        None,
        description="The pose graph's keyframes [keyframe_id, stamp_s, x_m, y_m, theta_rad] as last "
        "corrected (absent: the robot sent none).",
    )
    loop_closures: list[list[int]] | None = Field(
        None, description="Accepted loop closures [keyframe_id_a, keyframe_id_b] (absent: none sent)."
    )
    pose_covariance: list[list[float]] | None = Field(
        None,
        description="Covariance of pose over (x_m, y_m, theta_rad), 3x3, world frame (m^2, m*rad, rad^2); "
        "absent when the robot's pipeline has none.",
    )


class MapHistoryVersion(BaseModel):
    """One replayable version of a robot's map: its number and the scan time stamp (s) it was made at."""

    version: int
    stamp_s: float


class MapHistoryOut(BaseModel):
    """The versions of a robot's current mapping session that ``?version=N`` can replay, oldest first
    (``first_version`` .. ``current_version``, numbers the robot skipped left out), and why older versions
    cannot be (``older``)."""

    robot_id: int
    map_session: str | None = None
    current_version: int
    first_version: int
    versions: list[MapHistoryVersion]
    older: str


class TokenCreate(_In):
    name: str = Field(pattern=NAME_PATTERN)
    expires_in_s: float | None = Field(
        None,
        gt=0,
        le=10 * 365 * 86_400,
        allow_inf_nan=False,
        description="The token stops working this many seconds from now (at most 10 years).",
    )
    expires_at: AwareDatetime | None = Field(
        None, description="The token stops working at this time (with a time zone, e.g. ...Z)."
    )


class TokenCreated(BaseModel):
    id: int
    name: str
    token: str = Field(description="Shown once; the server keeps only its hash.")
    expires_at: datetime | None = Field(None, description="When the token stops working (null: never).")


class LoginIn(_In):
    token: str = Field(min_length=1, max_length=200)


class WhoAmI(BaseModel):
    kind: Literal["operator", "robot"]
    id: int
    name: str


class AuditOut(BaseModel):
    id: int
    at: datetime
    actor: str
    action: str
    target: str
    detail: dict[str, Any]
