"""The mapping pipeline (SPEC §2-§4): one ``step(scan)`` at a time, from scans and odometry to a line map."""

from shared.pipeline.config import KernelChoice, Mode, PipelineConfig, StageSchedule

__all__ = ["KernelChoice", "Mode", "PipelineConfig", "StageSchedule"]
