"""The mapping pipeline (docs/design.md §2-§4): one ``step(scan)`` at a time, from scans and odometry to a
line map."""

from shared.pipeline.config import KernelChoice, Mode, PipelineConfig, StageSchedule
from shared.pipeline.gate import IcpGate
from shared.pipeline.pipeline import Pipeline, StepResult
from shared.pipeline.snapshot import MapSnapshot
from shared.pipeline.state import MapperState
from shared.pipeline.wallmap import MergeTolerances, WallMap

__all__ = [
    "IcpGate",
    "KernelChoice",
    "MapSnapshot",
    "MapperState",
    "MergeTolerances",
    "Mode",
    "Pipeline",
    "PipelineConfig",
    "StageSchedule",
    "StepResult",
    "WallMap",
]
