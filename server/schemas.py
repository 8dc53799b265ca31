"""Request and response bodies of the REST API (pydantic), one family per resource.

Lengths are metres and angles radians in map bodies (SPEC §3); control messages keep their own units (cm
unless ``unit=``). Map uploads use compact rows (``[id, x0, y0, x1, y1]``) because a robot sends one every
few hundred milliseconds.
"""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any, Literal

from fastapi import Path
from pydantic import AwareDatetime, BaseModel, ConfigDict, Field, model_validator

__all__ = [
    "AckIn",
    "AuditOut",
    "KernelOut",
    "LoginIn",
    "MapOut",
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
DB_INT_MAX = 2**63 - 1
#: An id or sequence number in a URL path.
DbIdPath = Annotated[int, Path(ge=0, le=DB_INT_MAX)]
DbInt = Annotated[int, Field(ge=0, le=DB_INT_MAX)]


# Rows are checked by pydantic-core itself (finite floats, exact length): no Python call per row.
Finite = Annotated[float, Field(allow_inf_nan=False)]
SegmentRow = Annotated[list[Finite], Field(min_length=5, max_length=5)]
PointRow = Annotated[list[Finite], Field(min_length=2, max_length=2)]
PoseRow = Annotated[list[Finite], Field(min_length=3, max_length=3)]
TrajRow = Annotated[list[Finite], Field(min_length=4, max_length=4)]


class _In(BaseModel):
    model_config = ConfigDict(extra="forbid")


class RobotCreate(_In):
    name: str = Field(pattern=NAME_PATTERN, description="Unique robot name (letters, digits, . _ - space).")


class RobotKernel(_In):
    """One kernel in a robot's store (SPEC §7): ``state`` verified | active | retired | failed."""

    stage: str = Field(max_length=32)
    name: str = Field(max_length=64)
    version: str = Field(max_length=32)
    state: str = Field(max_length=16)
    sha256: str = Field(max_length=64)


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
    last_seq: int = Field(description="Sequence number of the newest control message queued.")
    pending_messages: int = Field(description="Messages not yet acknowledged by the robot.")
    token_revoked_at: datetime | None = Field(
        None, description="When the robot's token was revoked (with its issuer); POST /robots/{id}/token."
    )


class RobotCreated(BaseModel):
    id: int
    name: str
    token: str = Field(description="The robot's token. Shown once; the server keeps only its hash.")


class RobotStatus(_In):
    """What a robot reports about itself with each map upload."""

    mode: Literal["online", "offline", "mixed"] | None = None
    active_kernels: dict[str, str] | None = Field(None, description="stage -> 'name@version'")
    step_ms: Finite | None = Field(None, ge=0)
    last_error: str | None = Field(None, max_length=2000, description="The robot's latest problem, if any.")
    config: dict[str, Any] | None = Field(None, description="The configuration in force (PipelineConfig).")
    kernels: list[RobotKernel] | None = Field(None, max_length=1000, description="The robot's kernel store.")


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


class AckIn(_In):
    """``rolled-back``: applied, then undone by the robot (a kernel that failed at run time)."""

    outcome: Literal["applied", "rejected", "rolled-back"]
    reason: str | None = Field(None, max_length=4000, description="Why it was rejected (required then).")

    @model_validator(mode="after")
    def _reason_when_rejected(self) -> AckIn:
        if self.outcome != "applied" and not (self.reason and self.reason.strip()):
            raise ValueError(f"a {self.outcome} message needs a reason")
        return self


class SigningKeyIn(_In):
    name: str = Field(pattern=NAME_PATTERN)
    public_key: str = Field(max_length=2000, description="Ed25519 public key: base64 of 32 bytes, or PEM.")


class SigningKeyOut(BaseModel):
    key_id: str
    name: str
    public_key: str
    created_at: datetime
    revoked: bool


class KernelOut(BaseModel):
    name: str
    version: str
    stage: str
    sha256: str
    size_bytes: int
    signature: str
    key_id: str
    uploaded_at: datetime
    uploaded_by: str
    deleted: bool


class MapUpload(_In):
    """A temporary map from the robot: a full snapshot (``base_version`` null) or a delta since
    ``base_version``. ``segments`` rows are ``[segment_id, x0_m, y0_m, x1_m, y1_m]`` (all walls for a
    snapshot; new or changed walls for a delta); ``removed`` the ids that are gone; ``trajectory`` rows
    ``[stamp_s, x_m, y_m, theta_rad]`` since ``base_version`` (all of them for a snapshot)."""

    version: int = Field(ge=1, le=DB_INT_MAX)
    base_version: int | None = Field(None, ge=0, le=DB_INT_MAX)
    stamp_s: Finite = 0.0
    wall_time_s: Finite | None = Field(
        None, description="Unix time (s) at which the robot finished the step of this version (for latency)."
    )
    segments: list[SegmentRow] = Field(default_factory=list, max_length=200_000)
    removed: list[DbInt] = Field(default_factory=list, max_length=200_000)
    centroids: list[PointRow] = Field(default_factory=list, max_length=100_000)
    pose: PoseRow = Field(default_factory=lambda: [0.0, 0.0, 0.0])
    trajectory: list[TrajRow] = Field(default_factory=list, max_length=1_000_000)
    status: RobotStatus | None = None

    @model_validator(mode="after")
    def _consistent(self) -> MapUpload:
        if self.base_version is not None and self.base_version >= self.version:
            raise ValueError(f"base_version {self.base_version} must be below version {self.version}")
        if self.base_version is None and self.removed:
            raise ValueError("a snapshot (base_version null) cannot remove segments")
        for row in self.segments:
            if row[0] != int(row[0]) or not 0 <= row[0] <= DB_INT_MAX:
                raise ValueError(f"segment id must be an integer in 0..2**63-1, got {row[0]}")
        return self


class MapUploadOut(BaseModel):
    version: int = Field(description="The server's map version after this upload.")
    duplicate: bool = Field(description="True when this idempotency key was seen before (nothing changed).")


class MapOut(BaseModel):
    """A robot's whole current map (also the ``snapshot`` event of the SSE stream)."""

    robot_id: int
    version: int
    stamp_s: float
    segments: list[list[float]]
    centroids: list[list[float]]
    pose: list[float]
    trajectory: list[list[float]]
    wall_time_s: float | None = None


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
