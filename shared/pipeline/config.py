"""The pipeline's configuration: mode, kernel per stage and their parameters (docs/design.md §4, §6).

This is the object the XML control message sets (docs/design.md §6): a message is parsed into a new
:class:`PipelineConfig`, validated whole (kernel names, parameters), and only then swapped in, so a bad
message never leaves the robot half-configured. It round-trips through a plain dict / JSON.
"""

from __future__ import annotations

from enum import StrEnum
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from shared.errors import KernelParameterError, LinemapError, UnknownKernelError
from shared.kernels import REGISTRY, Kernel, Stage
from shared.kernels.stages import SCHEDULED, STAGES
from shared.slam.errors import LoopClosureSettingsError
from shared.slam.settings import LoopClosureSettings

__all__ = ["SCHEDULED", "KernelChoice", "Mode", "PipelineConfig", "StageSchedule"]


class Mode(StrEnum):
    """When noise removal, clustering and line extraction run (paper §3)."""

    ONLINE = "online"  # every step, on that step's new data only
    OFFLINE = "offline"  # on N_smax accumulated steps (flushed early when the heading changes)
    MIXED = "mixed"  # per stage, see PipelineConfig.schedule


class KernelChoice(BaseModel):
    """One kernel by name (and optionally version) with its parameters as a plain dict."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    name: str
    version: str | None = None
    params: dict[str, Any] = Field(default_factory=dict)

    def build(self, stage: Stage) -> Kernel[Any]:
        """Look the kernel up in the registry and validate its parameters."""
        return REGISTRY.create(stage, self.name, self.params, self.version)


class StageSchedule(BaseModel):
    """In mixed mode: whether a stage runs online or offline, and its own N_smax."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    mode: Mode = Mode.ONLINE
    n_smax: int = Field(9, ge=1, le=10_000)


class PipelineConfig(BaseModel):
    """Everything that decides how scans become a map. Validated whole on construction."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    mode: Mode = Mode.ONLINE
    n_smax: int = Field(9, ge=1, le=10_000, description="Steps accumulated in offline mode (paper §3)")
    heading_flush_deg: float = Field(
        15.0, gt=0.0, le=360.0, description="Offline batches flush early once the heading turned this much"
    )
    segmentation: KernelChoice = KernelChoice(name="abd-iepf")
    noise_removal: tuple[KernelChoice, ...] = (KernelChoice(name="dbscan"),)
    clustering: KernelChoice = KernelChoice(name="kmeans")
    straight_line: KernelChoice = KernelChoice(name="hough-cluster", params={"min_points": 8})
    scan_matching: KernelChoice | None = KernelChoice(name="icp")
    schedule: dict[Stage, StageSchedule] = Field(
        default_factory=dict, description="Mixed mode: online/offline and N_smax per scheduled stage"
    )
    loop_closure: dict[str, Any] | None = Field(
        None,
        description=(
            "Loop closure under a keyframe pose graph (shared.slam.settings.LoopClosureSettings, every "
            "field stated); None: off, the front end's map alone"
        ),
    )

    @field_validator("loop_closure")
    @classmethod
    def _loop_closure_settings(cls, value: dict[str, Any] | None) -> dict[str, Any] | None:
        """Validate against :class:`~shared.slam.settings.LoopClosureSettings` and state every field, so
        two configurations that mean the same compare equal; ``enabled = false`` is the same as None."""
        if value is None:
            return None
        try:
            settings = LoopClosureSettings.parse(value)
        except LoopClosureSettingsError as exc:
            raise ValueError(str(exc)) from None
        return settings.as_dict() if settings.enabled else None

    @model_validator(mode="after")
    def _kernels_exist(self) -> PipelineConfig:
        try:
            self.build()
        except (UnknownKernelError, KernelParameterError) as exc:
            raise ValueError(str(exc)) from None
        for stage in self.schedule:
            if stage not in SCHEDULED:
                allowed = ", ".join(SCHEDULED)
                raise ValueError(f"schedule for stage {stage!s}: only {allowed} can be scheduled")
        return self

    def build(self) -> dict[Stage, list[Kernel[Any]]]:
        """Instantiate every kernel (validated), per stage in order; noise removal may chain several and
        scan matching may be off (an empty list)."""
        return {stage: [c.build(stage) for c in self.choices(stage)] for stage in STAGES}

    def choices(self, stage: Stage) -> list[KernelChoice]:
        """The kernel choices for ``stage``: the chain for a chained stage, none for a stage switched off
        (the stage's field in :data:`~shared.kernels.stages.STAGES`)."""
        value = getattr(self, STAGES[stage].field)
        if value is None:
            return []
        return list(value) if isinstance(value, tuple) else [value]

    def loop_closure_settings(self) -> LoopClosureSettings | None:
        """The loop-closure settings in force, or None when loop closure is off."""
        return None if self.loop_closure is None else LoopClosureSettings.parse(self.loop_closure)

    def stage_schedule(self, stage: Stage) -> StageSchedule:
        """How ``stage`` runs: from ``mode`` unless mixed, where ``schedule`` decides (default online)."""
        if self.mode == Mode.MIXED:
            return self.schedule.get(stage, StageSchedule())
        return StageSchedule(mode=self.mode, n_smax=self.n_smax)

    @classmethod
    def parse(cls, data: dict[str, Any]) -> PipelineConfig:
        """Validate a plain dict; errors become :class:`LinemapError` naming the field and the reason."""
        from pydantic import ValidationError

        try:
            return cls.model_validate(data)
        except ValidationError as exc:
            problems = "; ".join(
                f"{'.'.join(str(p) for p in e['loc']) or 'config'}: {e['msg']}" for e in exc.errors()
            )
            raise LinemapError(f"invalid pipeline configuration: {problems}") from None
