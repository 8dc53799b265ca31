"""Request and response bodies of ``/rollouts`` (pydantic): a kernel version rolled out in waves."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field

from server.schemas import DB_ID_MAX
from shared.kernels import Stage
from shared.protocol import KERNEL_NAME_MAX_LENGTH

__all__ = ["RolloutIn", "RolloutOut", "RolloutRobotOut"]

SHA256_PATTERN = r"^[0-9a-f]{64}$"


class RolloutIn(BaseModel):
    """A rollout to start. Robots in the order given: the first ``canaries`` go first, then waves of
    ``wave_size``; without ``robots``, every registered robot in id order."""

    model_config = ConfigDict(extra="forbid")

    stage: Stage
    name: str = Field(min_length=1, max_length=KERNEL_NAME_MAX_LENGTH)
    version: str = Field(min_length=1, max_length=32)
    sha256: str = Field(pattern=SHA256_PATTERN, description="The uploaded artifact's sha256 (64 hex digits).")
    robots: list[Annotated[int, Field(ge=0, le=DB_ID_MAX)]] | None = Field(
        None, min_length=1, max_length=10_000, description="Robot ids in rollout order; null: all robots."
    )
    canaries: int = Field(1, ge=1, le=10_000, description="Robots updated first, alone; any failure stops.")
    wave_size: int = Field(5, ge=1, le=10_000, description="Robots per wave after the canaries.")
    max_failure_share: float = Field(
        0.2, ge=0, le=1, description="Stop when failed / tried robots exceeds this (0.2 = 20 %)."
    )
    commit_window_s: float = Field(
        60.0, gt=0, le=86_400, description="A robot stays healthy this long after applying it to commit."
    )
    ack_timeout_s: float = Field(
        300.0, gt=0, le=86_400, description="A robot that does not acknowledge within this fails (s)."
    )
    watch_timeout_s: float = Field(
        3600.0,
        gt=0,
        le=7 * 86_400,
        description="A timed-out robot is watched for a late answer until this long after it was sent (s); "
        "then the rollout gives up on it (queues its rollback) and can finish.",
    )
    max_step_ratio: float | None = Field(
        2.0,
        gt=1,
        le=1000,
        description="Fail a robot whose step time exceeds this x its time before; null: off.",
    )
    fail_on_rollback_error: bool = Field(
        True, description="Fail a robot whose last_error newly mentions a rollback (a guard trip)."
    )


class RolloutRobotOut(BaseModel):
    robot_id: int
    robot_name: str
    position: int
    wave: int = Field(description="0: canary; 1, 2, ...: the waves after.")
    state: str = Field(
        description="pending | sent | applied | installed | rolled-back | failed | timed-out | skipped"
    )
    reason: str | None
    previous: str | None = Field(description="The stage's kernel before the update (name@version).")
    seq: int | None = Field(description="The update message's number in the robot's sequence.")
    rollback_seq: int | None
    sent_at: datetime | None
    applied_at: datetime | None
    finished_at: datetime | None
    watched: bool = Field(description="Timed out, but still watched for a late answer.")


class RolloutOut(BaseModel):
    id: int
    stage: str
    name: str
    version: str
    sha256: str
    state: str = Field(description="running | paused | completed | stopped | aborted")
    active: bool = Field(description="The driver still has something to do (robots in flight).")
    wave: int
    canaries: int
    wave_size: int
    max_failure_share: float
    commit_window_s: float
    ack_timeout_s: float
    watch_timeout_s: float
    max_step_ratio: float | None
    fail_on_rollback_error: bool
    stop_reason: str | None
    created_at: datetime
    created_by: str
    finished_at: datetime | None
    counts: dict[str, int] = Field(description="Robots per state.")
    robots: list[RolloutRobotOut] | None = Field(None, description="Each robot (GET /rollouts/{id} only).")
