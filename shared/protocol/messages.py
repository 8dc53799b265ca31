"""What the robot and the server send each other (docs/design.md §9), as pydantic models both sides use.

The robot builds its bodies from these models (``model_dump(mode="json")``) and the server validates them
with the same models, which also make up the OpenAPI document (:mod:`server.schemas` reuses or subclasses
them). Units: lengths in metres, angles in radians, times in seconds (``stamp_s`` the robot's clock,
``wall_time_s`` Unix time). Map rows are compact lists because a robot uploads every few hundred
milliseconds: ``segments`` ``[segment_id, x0_m, y0_m, x1_m, y1_m]``, ``centroids`` ``[x_m, y_m]``, ``pose``
``[x_m, y_m, theta_rad]``, ``trajectory`` ``[stamp_s, x_m, y_m, theta_rad]``. Rows are checked by
pydantic-core itself (finite floats, exact length): validation is O(rows) with no Python call per row.

The JSON is the wire format: field names and types here must stay as older robots and servers send and
read them.
"""

from __future__ import annotations

import math
from datetime import datetime
from typing import Annotated, Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    SerializerFunctionWrapHandler,
    ValidationInfo,
    field_validator,
    model_serializer,
    model_validator,
)

from shared.protocol.patterns import MAP_SESSION_PATTERN, anchored
from shared.protocol.posegraph import MAX_KEYFRAMES, MAX_LOOP_CLOSURES, check_covariance

__all__ = [
    "AGENT_INSTANCE_HEADER",
    "ARTIFACT_KEY_ID_HEADER",
    "ARTIFACT_SHA256_HEADER",
    "ARTIFACT_SIGNATURE_HEADER",
    "ARTIFACT_STAGE_HEADER",
    "INT64_MAX",
    "MAP_FIELDS",
    "STATUS_FIELDS",
    "CovRow",
    "EdgeRow",
    "Finite",
    "Int64",
    "KernelMeta",
    "KeyframeRow",
    "MapDelta",
    "MapSnapshot",
    "MapUpload",
    "MessageAck",
    "Outcome",
    "PointRow",
    "PoseRow",
    "RobotKernel",
    "RobotStatus",
    "SegmentRow",
    "TrajRow",
]

#: Largest integer on the wire (signed 64 bits, what a database column holds): ids, sequence numbers,
#: versions and counts are bounded by it, so an oversized number is refused, not overflowed.
INT64_MAX = 2**63 - 1
Int64 = Annotated[int, Field(ge=0, le=INT64_MAX)]
Finite = Annotated[float, Field(allow_inf_nan=False)]
SegmentRow = Annotated[list[Finite], Field(min_length=5, max_length=5)]
PointRow = Annotated[list[Finite], Field(min_length=2, max_length=2)]
PoseRow = Annotated[list[Finite], Field(min_length=3, max_length=3)]
TrajRow = Annotated[list[Finite], Field(min_length=4, max_length=4)]
#: ``[keyframe_id, stamp_s, x_m, y_m, theta_rad]`` (:mod:`shared.protocol.posegraph`)
KeyframeRow = Annotated[list[Finite], Field(min_length=5, max_length=5)]
#: ``[keyframe_id_a, keyframe_id_b]``: a loop closure between two keyframes
EdgeRow = Annotated[list[Annotated[int, Field(ge=0, le=2**53)]], Field(min_length=2, max_length=2)]
#: one row of the 3x3 pose covariance over ``(x_m, y_m, theta_rad)``
CovRow = Annotated[list[Finite], Field(min_length=3, max_length=3)]
#: What became of a control message; ``rolled-back``: applied, then undone by the robot (a kernel that
#: failed at run time).
Outcome = Literal["applied", "rejected", "rolled-back"]

#: Headers of a kernel artifact download (``GET /kernels/{name}/{version}/artifact``), whose body is the
#: module's source.
ARTIFACT_SHA256_HEADER = "X-Linemap-Sha256"
ARTIFACT_SIGNATURE_HEADER = "X-Linemap-Signature"
ARTIFACT_KEY_ID_HEADER = "X-Linemap-Key-Id"
ARTIFACT_STAGE_HEADER = "X-Linemap-Stage"
#: Header of every request an agent makes: its process's instance id (a UUID, :data:`MAP_SESSION_PATTERN`'s
#: spelling), so the server can tell two agents running with one robot token apart.
AGENT_INSTANCE_HEADER = "X-Linemap-Agent-Instance"


class _Body(BaseModel):
    """A body the robot sends: unknown fields are refused."""

    model_config = ConfigDict(extra="forbid")


class RobotKernel(_Body):
    """One kernel in a robot's store (docs/design.md §7): ``state`` verified | active | retired | failed."""

    stage: str = Field(max_length=32)
    name: str = Field(max_length=64)
    version: str = Field(max_length=32)
    state: str = Field(max_length=16)
    sha256: str = Field(max_length=64)


def _check_finite(value: Any, path: str) -> None:
    """Raise ValueError naming the first non-finite float in nested dicts and lists ``value``."""
    if isinstance(value, float) and not math.isfinite(value):
        raise ValueError(f"{path} = {value!r}: expected a finite number (JSON has no NaN or infinity)")
    if isinstance(value, dict):
        for key, item in value.items():
            _check_finite(item, f"{path}.{key}")
    elif isinstance(value, list):
        for i, item in enumerate(value):
            _check_finite(item, f"{path}[{i}]")


class RobotStatus(_Body):
    """What a robot reports about itself with each map upload."""

    mode: Literal["online", "offline", "mixed"] | None = None
    active_kernels: dict[str, str] | None = Field(None, description="stage -> 'name@version'")
    step_ms: Finite | None = Field(None, ge=0)
    last_error: str | None = Field(None, max_length=2000, description="The robot's latest problem, if any.")
    config: dict[str, Any] | None = Field(None, description="The configuration in force (PipelineConfig).")
    kernels: list[RobotKernel] | None = Field(None, max_length=1000, description="The robot's kernel store.")

    @field_validator("config")
    @classmethod
    def _config_finite(cls, config: dict[str, Any] | None, info: ValidationInfo) -> dict[str, Any] | None:
        """Refuse a NaN or infinity anywhere in ``config`` read from JSON text that spells one (``NaN``,
        ``Infinity``: not JSON, and the server's JSON columns have no such numbers), naming where. Python
        values are left alone: the robot's own status is written as JSON by pydantic, which writes them as
        null. O(size of config)."""
        if config is not None and info.mode == "json":
            _check_finite(config, "config")
        return config


#: Largest keyframe id: a row of floats holds integers exactly up to 2**53 (so does a browser's JSON).
_KEYFRAME_ID_MAX = 2**53
#: The optional fields of an upload (its map session, the pose graph's rows); left out of the JSON when
#: absent, so a robot that has none talks to a server from before them as it did.
_OPTIONAL_FIELDS = ("map_session", "map_session_reason", "keyframes", "loop_closures", "pose_covariance")


class MapUpload(_Body):
    """A temporary map from the robot: a full snapshot (``base_version`` null) or a delta since
    ``base_version``. ``segments`` rows are ``[segment_id, x0_m, y0_m, x1_m, y1_m]`` (all walls for a
    snapshot; new or changed walls for a delta); ``removed`` the ids that are gone; ``trajectory`` rows
    ``[stamp_s, x_m, y_m, theta_rad]`` since ``base_version`` (all of them for a snapshot).

    ``map_session``: the id of the mapping session the versions belong to (a UUID the robot creates when
    its Robot DB starts a new map); versions count within a session. A snapshot of a session the server has
    not seen starts a new map there (the old one is kept); a delta must be of the server's current session.
    Absent: a robot from before map sessions, whose uploads all go to one legacy session.

    The pose graph's rows (:mod:`shared.protocol.posegraph`; each absent when the robot has none):
    ``keyframes`` ``[keyframe_id, stamp_s, x_m, y_m, theta_rad]``, for a snapshot all of them, for a delta
    the new ones and those an optimisation moved (a loop closure's correction: the server and viewers move
    the trajectory they hold with them, :func:`~shared.protocol.posegraph.correct_trajectory`);
    ``loop_closures`` ``[keyframe_id_a, keyframe_id_b]``, all (snapshot) or the new ones (delta);
    ``pose_covariance`` the 3x3 covariance of ``pose`` (m^2, m*rad, rad^2, world frame)."""

    map_session: str | None = Field(
        None, pattern=anchored(MAP_SESSION_PATTERN), description="The mapping session (a lower-case UUID)."
    )
    map_session_reason: str | None = Field(
        None, max_length=300, description="Why the robot started this session (sent with its snapshots)."
    )
    version: int = Field(ge=1, le=INT64_MAX)
    base_version: int | None = Field(None, ge=0, le=INT64_MAX)
    stamp_s: Finite = 0.0
    wall_time_s: Finite | None = Field(
        None, description="Unix time (s) at which the robot finished the step of this version (for latency)."
    )
    segments: list[SegmentRow] = Field(default_factory=list, max_length=200_000)
    removed: list[Int64] = Field(default_factory=list, max_length=200_000)
    centroids: list[PointRow] = Field(default_factory=list, max_length=100_000)
    pose: PoseRow = Field(default_factory=lambda: [0.0, 0.0, 0.0])
    trajectory: list[TrajRow] = Field(default_factory=list, max_length=1_000_000)
    keyframes: list[KeyframeRow] | None = Field(
        None,
        max_length=MAX_KEYFRAMES,
        description="Keyframes [keyframe_id, stamp_s, x_m, y_m, theta_rad]: all (snapshot) or new and "
        "corrected ones (delta).",
    )
    loop_closures: list[EdgeRow] | None = Field(
        None,
        max_length=MAX_LOOP_CLOSURES,
        description="Loop closures [keyframe_id_a, keyframe_id_b]: all (snapshot) or new ones (delta).",
    )
    pose_covariance: list[CovRow] | None = Field(
        None,
        min_length=3,
        max_length=3,
        description="Covariance of pose over (x_m, y_m, theta_rad), 3x3, world frame (m^2, m*rad, rad^2).",
    )
    status: RobotStatus | None = None

    @model_serializer(mode="wrap")
    def _without_absent_session(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        """An upload without a map session or pose-graph rows serialises as before them (the legacy
        fields only). O(1) beyond the fields' own serialisation."""
        out: dict[str, Any] = handler(self)
        for name in _OPTIONAL_FIELDS:
            if name in out and out[name] is None:
                del out[name]
        return out

    @model_validator(mode="after")
    def _consistent(self) -> MapUpload:
        if self.base_version is not None and self.base_version >= self.version:
            raise ValueError(f"base_version {self.base_version} must be below version {self.version}")
        if self.base_version is None and self.removed:
            raise ValueError("a snapshot (base_version null) cannot remove segments")
        for row in self.segments:
            if row[0] != int(row[0]) or not 0 <= row[0] <= INT64_MAX:
                raise ValueError(f"segment id must be an integer in 0..2**63-1, got {row[0]}")
        self._check_graph()
        return self

    def _check_graph(self) -> None:
        """The pose graph's rows: integer keyframe ids, each once; a snapshot's loop closures between its
        own keyframes; the covariance symmetric and positive semi-definite. O(keyframes + closures)."""
        ids: set[int] = set()
        for row in self.keyframes or ():
            if row[0] != int(row[0]) or not 0 <= row[0] <= _KEYFRAME_ID_MAX:
                raise ValueError(f"keyframe id must be an integer in 0..2**53, got {row[0]}")
            if int(row[0]) in ids:
                raise ValueError(f"keyframe {int(row[0])} is listed twice")
            ids.add(int(row[0]))
        if self.base_version is None and self.loop_closures:
            for a, b in self.loop_closures:
                if a not in ids or b not in ids:
                    raise ValueError(
                        f"loop closure [{a}, {b}] names a keyframe the snapshot does not list "
                        "(a snapshot lists every keyframe its loop closures join)"
                    )
        if self.pose_covariance is not None:
            check_covariance(self.pose_covariance)


class MapDelta(MapUpload):
    """The map's changes since ``base_version`` (the version the server has)."""

    base_version: int = Field(ge=0, le=INT64_MAX)


class MapSnapshot(MapUpload):
    """The whole map (sent when the server's version is not the delta's base)."""

    base_version: None = None


#: The map's own fields of an upload (all but ``status``), in the model's order.
MAP_FIELDS: tuple[str, ...] = tuple(name for name in MapUpload.model_fields if name != "status")
#: The fields of a robot's status, in the model's order.
STATUS_FIELDS: tuple[str, ...] = tuple(RobotStatus.model_fields)


class MessageAck(_Body):
    """The robot's acknowledgement of control message ``seq`` (in the URL): its outcome, and why when it
    was not applied."""

    outcome: Outcome
    reason: str | None = Field(None, max_length=4000, description="Why it was rejected (required then).")

    @model_validator(mode="after")
    def _reason_when_rejected(self) -> MessageAck:
        if self.outcome != "applied" and not (self.reason and self.reason.strip()):
            raise ValueError(f"a {self.outcome} message needs a reason")
        return self


class KernelMeta(BaseModel):
    """A kernel artifact as the server describes it (``GET /kernels``). ``sha256`` is of the module's
    bytes and ``signature`` the base64 Ed25519 signature over it by key ``key_id``; a download of the
    module carries them in the ``ARTIFACT_*_HEADER`` headers. No patterns here: versions stored before the
    canonical spelling are still listed."""

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
