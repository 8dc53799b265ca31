"""The robot agent (docs/design.md §2, §7): maps step by step, keeps everything in the Robot DB, talks to the
server on background threads, applies control messages between steps and hot-swaps kernels.

:class:`Agent` only assembles the parts and runs their threads: the mapping loop
(:mod:`robot_agent.mapping`) on the caller's thread; a poller (:mod:`robot_agent.poller`) that long-polls
messages and prepares them (download and verify kernels: :mod:`robot_agent.preparer`); an uploader
(:mod:`robot_agent.uploader`) that sends acknowledgements and the outbox; the kernel supervisor
(:mod:`robot_agent.supervisor`), called by the mapping loop between steps, applies messages and rolls back
kernels that fail. Mapping never waits on the network: the threads meet only through the Robot DB and a
queue of prepared messages. Every loop runs supervised (:mod:`robot_agent.supervise`): one that dies
unexpectedly is restarted after a backoff and reported in ``last_error``.
"""

from __future__ import annotations

import logging
import queue
import threading

from robot_agent.continuemap import continue_server_map
from robot_agent.control import Prepared, kernels_in_use
from robot_agent.dblock import RobotDBLock
from robot_agent.errors import SupersededError
from robot_agent.health import AgentStats, ErrorReport
from robot_agent.link import ServerLink
from robot_agent.mapping import MappingLoop, PipelineSlot, RecentScans
from robot_agent.poller import Poller
from robot_agent.preparer import KernelLoader, MessagePreparer
from robot_agent.settings import AgentSettings
from robot_agent.sources import laser_offset
from robot_agent.store import RobotDB
from robot_agent.supervise import Supervised, run_supervised, supervise
from robot_agent.supervisor import KernelSupervisor
from robot_agent.uploader import Uploader
from shared.errors import LinemapError
from shared.pipeline import Pipeline
from shared.protocol import RobotKernel, RobotStatus
from shared.signing import load_public_key
from shared.slam import OnlineGraphMapper

__all__ = ["Agent", "AgentSettings"]

log = logging.getLogger(__name__)


class Agent:
    """One robot's daemon. ``run(stop)`` blocks until the source ends (or ``stop`` is set).

    Downloaded kernels run in confined worker processes (:mod:`robot_agent.kernels.dryrun`,
    docs/reliability/sandbox.md): one that hangs or dies in service is killed and rolled back, and the
    agent goes on; nothing needs a restart."""

    def __init__(self, settings: AgentSettings, link: ServerLink | None = None) -> None:
        self.s = settings
        self._db_lock = RobotDBLock(settings.db_path)  # a second agent on this Robot DB stops here
        try:
            self.db = RobotDB(settings.db_path)
        except BaseException:
            self._db_lock.release()
            raise
        self.link = link
        if link is None and settings.server_urls:
            self.link = ServerLink(
                settings.server_urls,
                settings.robot_id,
                settings.token,
                max_retry_after_s=settings.max_retry_after_s,
            )
        self.trusted = [load_public_key(k) for k in settings.trusted_keys]
        self.stats = AgentStats(ErrorReport(settings.error_clear_s))
        self.threads: dict[str, Supervised] = {}
        inbox: queue.Queue[Prepared] = queue.Queue()
        recent = RecentScans()
        wake_uploader = threading.Event()
        self._wake_uploader = wake_uploader
        self._mapping_over = threading.Event()  # set once the mapping thread recorded its last step
        #: what --continue-map did (the CLI says it), None without the flag
        self.continued: str | None = None
        if settings.continue_map:
            try:
                self.continued = continue_server_map(self.link, self.db)
                log.info("%s", self.continued)
            except BaseException:
                self.db.close()
                self._db_lock.release()
                raise
        offset = settings.laser_offset if settings.laser_offset is not None else laser_offset(settings.source)
        self.slot = PipelineSlot(offset)
        loader = KernelLoader(settings, self.trusted)
        self.supervisor = KernelSupervisor(
            settings, self.slot, self.db, loader, inbox, self.stats, wake_uploader
        )
        self.slot.start(self.supervisor.start_config())
        self.mapping = MappingLoop(
            settings,
            self.slot,
            self.db,
            self.stats,
            recent,
            self.supervisor.apply_pending,
            self.supervisor.after_step,
            wake_uploader,
        )
        self.poller: Poller | None = None
        self.uploader: Uploader | None = None
        if self.link is not None:
            preparer = MessagePreparer(settings, self.link, self.db, loader, recent.latest)
            self.uploader = uploader = Uploader(
                self.link,
                self.db,
                self.status,
                self.mapping.wall_time,
                wake_uploader,
                self._mapping_over,
                self.stats.errors,
                robot_id=settings.robot_id,
                upload_period_s=settings.upload_period_s,
                upload_batch=settings.upload_batch,
                retry_base_s=settings.retry_base_s,
                retry_cap_s=settings.retry_cap_s,
                stop_grace_s=settings.stop_grace_s,
            )
            self.poller = Poller(
                self.link,
                self.db.applied_seq,
                preparer.prepare,
                inbox,
                self.stats.errors,
                poll_wait_s=settings.poll_wait_s,
                retry_base_s=settings.retry_base_s,
                retry_cap_s=settings.retry_cap_s,
                delivered_map=self.db.delivered_map,
                map_lost=uploader.resend_map,
            )

    @property
    def pipeline(self) -> Pipeline | OnlineGraphMapper:
        """The pipeline in force (an :class:`OnlineGraphMapper` once loop closure is on)."""
        return self.slot.pipeline

    def run(self, stop: threading.Event) -> None:
        """Map until the source ends (then keep serving the link if ``stay``) or ``stop`` is set. The
        mapping loop runs supervised on this thread: a deliberate error (:class:`LinemapError`, e.g. the
        source cannot be opened) ends the agent with its message; anything else restarts it."""
        if self.poller is not None and self.uploader is not None:
            for name, loop in (("poller", self.poller.run), ("uploader", self.uploader.run)):
                self.threads[name] = supervise(
                    name,
                    loop,
                    stop,
                    self._thread_died,
                    retry_base_s=self.s.retry_base_s,
                    fatal=(SupersededError,),
                )
        mapping = self.threads["mapping"] = Supervised("mapping", threading.current_thread())
        try:
            run_supervised(
                mapping,
                self.mapping.run,
                stop,
                self._thread_died,
                retry_base_s=self.s.retry_base_s,
                fatal=(LinemapError,),
            )
        finally:
            self.mapping.checkpoints.close()
            self.slot.close()
            self._mapping_over.set()
            stop.set()
            self._wake_uploader.set()
            for name, sup in self.threads.items():
                # The uploader finishes its round (acknowledgements and map versions reach the server); the
                # poller may sit in a long-poll for poll_wait_s: what it would fetch is fetched again at the
                # next start, so it is not waited for (a daemon thread, gone with the process).
                if name != "mapping":
                    sup.join(2.0 if name == "poller" else self.s.poll_wait_s + 15)
            self.db.close()
            self._db_lock.release()
            if self.link is not None:
                self.link.close()
        for sup in self.threads.values():
            if sup.name != "mapping" and sup.fatal_error is not None:
                raise sup.fatal_error  # another agent took over this robot: the CLI shows why, exit status 2

    def _thread_died(self, name: str, exc: BaseException) -> None:
        """A supervised loop died unexpectedly (restarted after a backoff): report it."""
        self.stats.last_error = f"thread {name} died and was restarted: {type(exc).__name__}: {exc}"

    def status(self) -> RobotStatus:
        """What the robot reports about itself with each upload."""
        median_ms, _p99 = self.pipeline.timing_ms()
        config = self.pipeline.config
        return RobotStatus.model_validate(
            {
                "mode": str(config.mode),
                "active_kernels": kernels_in_use(config),
                "step_ms": median_ms if median_ms == median_ms else None,
                "last_error": _clip(self.stats.errors.status(), 2000),  # the server takes at most 2000
                "config": config.model_dump(mode="json"),
                "kernels": [
                    RobotKernel(stage=k.stage, name=k.name, version=k.version, state=k.state, sha256=k.sha256)
                    for k in self.db.kernels()
                ],
            }
        )


def _clip(text: str | None, limit: int) -> str | None:
    return text if text is None or len(text) <= limit else text[: limit - 3] + "..."
