"""``/control/xml``: turn the dashboard's tuning form (a JSON draft) into a canonical control message.

The browser never writes XML itself: the one XML writer is :func:`shared.control.build_message`, and the
message is validated with the robot's own function (:func:`shared.control.to_config`, via
:mod:`server.msgcheck`) against the built-in kernels' parameter models, so the form shows "kmeans.n_clusters
..." before anything is queued. Parameters of kernel versions the server does not have built in (uploaded
ones) are left to the robot, which validates them on load.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from fastapi import APIRouter
from pydantic import BaseModel, ConfigDict, Field

from server.deps import OperatorDep, StateDep
from server.errors import InvalidRequestError
from server.msgcheck import check_declared, server_checkable, uploaded_artifacts
from shared.control import (
    NO_SCAN_MATCHING,
    ControlMessage,
    ControlMessageError,
    KernelOperation,
    KernelSpec,
    OperationKind,
    ParamValue,
    build_message,
    parse_message,
    to_config,
)
from shared.kernels import Stage
from shared.kernels.stages import STAGES
from shared.pipeline.config import Mode, PipelineConfig
from shared.protocol import (
    KERNEL_NAME_MAX_LENGTH,
    KERNEL_NAME_PATTERN,
    SHA256_PATTERN,
    VERSION_PATTERN,
    anchored,
)

__all__ = ["ControlDraft", "KernelDraft", "LoopClosureDraft", "OperationDraft", "router"]

router = APIRouter(prefix="/control", tags=["control"])

ParamScalar = bool | int | float | str | list[int]


class KernelDraft(BaseModel):
    model_config = ConfigDict(extra="forbid")

    name: str = Field(pattern=anchored(KERNEL_NAME_PATTERN), max_length=KERNEL_NAME_MAX_LENGTH)
    version: str | None = Field(None, pattern=anchored(VERSION_PATTERN))
    params: dict[str, ParamScalar] = Field(
        default_factory=dict, description="Parameter -> value, in the units of the kernel's schema (SI)."
    )


class OperationDraft(BaseModel):
    model_config = ConfigDict(extra="forbid")

    kind: Literal["install", "update", "delete", "rollback"]
    stage: Stage
    name: str = Field(pattern=anchored(KERNEL_NAME_PATTERN), max_length=KERNEL_NAME_MAX_LENGTH)
    version: str = Field(pattern=anchored(VERSION_PATTERN))
    sha256: str | None = Field(None, pattern=anchored(SHA256_PATTERN))
    below_floor: bool = Field(
        False, description="Rollback only: the operator's override of the robot's anti-rollback floor."
    )


class LoopClosureDraft(BaseModel):
    """Loop closure stated whole (what is left out takes the defaults); the ranges are checked as the
    robot checks them (:class:`shared.slam.settings.LoopClosureSettings`), naming the element."""

    model_config = ConfigDict(extra="forbid")

    enabled: bool = True
    search_radius_m: float | None = Field(None, description="Earlier places within this distance (m).")
    min_inlier_share: float | None = Field(None, description="Share of returns a match needs (0..1).")
    params: dict[str, ParamScalar] = Field(
        default_factory=dict, description="Any other loop-closure setting by its own name (SI units)."
    )


class ControlDraft(BaseModel):
    """What the tuning form sends; every field is optional (what is left out stays as the robot has it)."""

    model_config = ConfigDict(extra="forbid")

    mode: Literal["online", "offline", "mixed"] | None = None
    n_smax: int | None = Field(None, ge=1, le=10_000)
    heading_flush_deg: float | None = Field(None, gt=0, le=180)
    segmentation: KernelDraft | None = None
    noise_removal: Annotated[list[KernelDraft], Field(max_length=8)] | None = None
    clustering: KernelDraft | None = None
    straight_line: KernelDraft | None = None
    scan_matching: KernelDraft | Literal["none"] | None = None
    loop_closure: LoopClosureDraft | None = None
    operations: list[OperationDraft] = Field(default_factory=list, max_length=32)


class ControlXml(BaseModel):
    xml: str


def _spec(draft: KernelDraft, stage: Stage) -> KernelSpec:
    params = {k: tuple(v) if isinstance(v, list) else v for k, v in draft.params.items()}
    return KernelSpec(draft.name, tuple(sorted(params.items())), draft.version)


def _loop_closure(draft: LoopClosureDraft) -> KernelSpec:
    params: dict[str, ParamValue] = {
        k: tuple(v) if isinstance(v, list) else v for k, v in draft.params.items()
    }
    params["enabled"] = draft.enabled
    if draft.search_radius_m is not None:
        params["search_radius_m"] = draft.search_radius_m
    if draft.min_inlier_share is not None:
        params["min_inlier_share"] = draft.min_inlier_share
    return KernelSpec.of("loop-closure", params)


def _stage_spec(given: Any, stage: Stage) -> Any:
    """A stage's part of a draft as the message states it: absent, a chain, the "none" switch, or one
    kernel (the stage's description says which it may be)."""
    if given is None:
        return None
    if isinstance(given, list | tuple):
        return tuple(_spec(d, stage) for d in given)
    if given == NO_SCAN_MATCHING:
        return NO_SCAN_MATCHING
    return _spec(given, stage)


def draft_message(draft: ControlDraft) -> ControlMessage:
    """The control message a draft describes (its values are checked by :func:`control_xml`)."""
    return ControlMessage(
        mode=Mode(draft.mode) if draft.mode else None,
        n_smax=draft.n_smax,
        heading_flush_deg=draft.heading_flush_deg,
        **{spec.field: _stage_spec(getattr(draft, spec.field), spec.stage) for spec in STAGES.values()},
        loop_closure=_loop_closure(draft.loop_closure) if draft.loop_closure else None,
        operations=tuple(
            KernelOperation(
                OperationKind(op.kind),
                Stage(op.stage),
                op.name,
                op.version,
                op.sha256.lower() if op.sha256 else None,
                below_floor=op.below_floor,
            )
            for op in draft.operations
        ),
    )


@router.post("/xml", response_model=ControlXml)
def control_xml(draft: ControlDraft, who: OperatorDep, state: StateDep) -> ControlXml:
    """Canonical XML for a tuning-form draft (lengths written in metres with ``unit="m"``); 422 names the
    parameter or element that is wrong. Nothing is queued: post the XML to ``/robots/{id}/messages``."""
    if draft.noise_removal is not None and not draft.noise_removal:
        raise InvalidRequestError("noise_removal: the chain needs at least one kernel")
    for op in draft.operations:
        if op.below_floor and op.kind != "rollback":
            raise InvalidRequestError(f"operations: below_floor is for a rollback only, not {op.kind}")
    msg = draft_message(draft)
    try:
        xml = build_message(msg)
        with state.db.session() as s:
            artifacts = uploaded_artifacts(s)
            # what the robot will read must be what we meant, and valid as the robot will check it
            to_config(parse_message(xml), PipelineConfig(), checkable=server_checkable(artifacts, msg))
            check_declared(artifacts, msg)
    except ControlMessageError as exc:
        raise InvalidRequestError(str(exc)) from None
    return ControlXml(xml=xml.decode("utf-8"))
