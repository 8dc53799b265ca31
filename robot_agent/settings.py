"""How one robot agent runs (:class:`AgentSettings`): its source, Robot DB, server, pace, kernel limits and
retry timings. Times are seconds, budgets of a kernel call milliseconds, memory megabytes. Built by the
command line (:mod:`robot_agent.cli`, TOML and flags) and read by the agent's parts."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from robot_agent.link import DEFAULT_MAX_RETRY_AFTER_S
from shared.pipeline import PipelineConfig
from shared.slam import LoopClosureSettings
from shared.types import Pose2D

__all__ = ["AgentSettings"]


@dataclass(frozen=True)
class AgentSettings:
    """How the agent runs. ``rate_hz`` None: the source's own pace (10 Hz simulated, log time stamps);
    0: as fast as possible. ``server_urls``: the server, or the processes of one fleet's server to fail over
    between (:class:`~robot_agent.link.ServerLink`); empty: map alone (no link)."""

    source: str
    db_path: Path
    server_urls: tuple[str, ...] = ()
    robot_id: int = 0
    token: str = ""
    rate_hz: float | None = None
    trusted_keys: tuple[str, ...] = ()
    allow_unsigned: bool = False
    config: PipelineConfig | None = None
    upload_period_s: float = 0.5
    poll_wait_s: float = 20.0
    upload_batch: int = 50
    probation_steps: int = 20
    kernel_budget_ms: float = 200.0
    # A call of a downloaded kernel longer than this is stuck (guard.py); with the ~0.1-0.2 s it takes to kill
    # its worker and answer, a hang is detected within 5 s (docs/reliability/sandbox.md).
    kernel_hang_s: float = 4.5
    kernel_memory_mb: float = 256.0  # ... and so is one that grows the process by more than this
    dry_run_budget_s: float = 4.5  # import + dry run, and the conformance battery, each (same reason)
    max_steps: int | None = None
    stay: bool = True
    seed: int = 0
    laps: int = 1
    encoders: str | None = None  # serial device of the wheel-encoder bridge (a ``urg:`` source only)
    retry_base_s: float = 0.5  # first delay after a network fault (doubles per failure up to retry_cap_s)
    retry_cap_s: float = 30.0  # longest delay between two tries after network faults (full jitter below it)
    stop_grace_s: float = 10.0  # after a stop, the uploader keeps retrying this long to empty the outbox
    max_retry_after_s: float = DEFAULT_MAX_RETRY_AFTER_S  # a longer Retry-After is capped to this
    error_clear_s: float = 60.0  # last_error is cleared after this long without a new one (health.py)
    laser_offset: Pose2D | None = None  # scanner pose in the robot frame; None: the source's own (sources.py)
    # loop closure under a keyframe pose graph (shared.slam.online); None: the front end alone
    loop_closure: LoopClosureSettings | None = None
    # a new Robot DB continues the map the server holds for this robot (robot_agent.continuemap)
    continue_map: bool = False
    # the mapping state is saved with a step every this many steps or seconds (robot_agent.resume)
    checkpoint_steps: int = 50
    checkpoint_s: float = 5.0
