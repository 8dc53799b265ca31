"""The robot agent (SPEC §8): maps step by step, keeps everything in the Robot DB, talks to the server on
background threads, applies control messages between steps and hot-swaps kernels.

Threads: the caller's thread maps (``run``); a poller (:mod:`robot_agent.poller`) long-polls messages and
prepares them (download and verify kernels); an uploader (:mod:`robot_agent.uploader`) sends
acknowledgements and the outbox. Mapping never waits on the network: the threads meet only through the
Robot DB and a queue of prepared messages. Every loop runs supervised (:mod:`robot_agent.supervise`): one
that dies unexpectedly is restarted after a backoff and reported in ``last_error``.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from robot_agent.control import (
    Prepared,
    apply_message,
    choices,
    fallback_choice,
    kernels_in_use,
    kernels_run,
    pin_versions,
    refuse_downgrades,
    registered,
    replace_choice,
    swap_version,
)
from robot_agent.errors import AgentError, KernelRejected, LinkError
from robot_agent.guard import guarded
from robot_agent.health import AgentStats, ErrorReport
from robot_agent.link import DEFAULT_MAX_RETRY_AFTER_S, ServerLink
from robot_agent.models import KernelRecord
from robot_agent.poller import Poller
from robot_agent.recover import repair_config
from robot_agent.sources import is_live, laser_offset, open_scans
from robot_agent.store import RobotDB, StepRecord
from robot_agent.supervise import Supervised, run_supervised, supervise
from robot_agent.uploader import Uploader
from shared.control import ControlMessageError, OperationKind, parse_message
from shared.errors import LinemapError
from shared.kernels import REGISTRY, Kernel, Stage
from shared.pipeline import Pipeline, PipelineConfig
from shared.protocol import RobotKernel, RobotStatus
from shared.signing import load_public_key
from shared.slam import LoopClosureSettings, OnlineGraphMapper
from shared.types import Pose2D, Scan

__all__ = ["Agent", "AgentSettings"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class AgentSettings:
    """How the agent runs. ``rate_hz`` None: the source's own pace (10 Hz simulated, log time stamps);
    0: as fast as possible. ``server_url`` None: map alone (no link)."""

    source: str
    db_path: Path
    server_url: str | None = None
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
    retry_base_s: float = 0.5  # first delay after a network fault (doubles per failure, capped at 30 s)
    stop_grace_s: float = 10.0  # after a stop, the uploader keeps retrying this long to empty the outbox
    max_retry_after_s: float = DEFAULT_MAX_RETRY_AFTER_S  # a longer Retry-After is capped to this
    error_clear_s: float = 60.0  # last_error is cleared after this long without a new one (health.py)
    laser_offset: Pose2D | None = None  # scanner pose in the robot frame; None: the source's own (sources.py)
    # loop closure under a keyframe pose graph (shared.slam.online); None: the front end alone
    loop_closure: LoopClosureSettings | None = None


class Agent:
    """One robot's daemon. ``run(stop)`` blocks until the source ends (or ``stop`` is set).

    Downloaded kernels run in confined worker processes (:mod:`robot_agent.dryrun`,
    docs/reliability/sandbox.md): one that hangs or dies in service is killed and rolled back, and the
    agent goes on; nothing needs a restart."""

    def __init__(self, settings: AgentSettings, link: ServerLink | None = None) -> None:
        self.s = settings
        self.db = RobotDB(settings.db_path)
        self.link = link
        if link is None and settings.server_url:
            self.link = ServerLink(
                settings.server_url,
                settings.robot_id,
                settings.token,
                max_retry_after_s=settings.max_retry_after_s,
            )
        self.trusted = [load_public_key(k) for k in settings.trusted_keys]
        self.stats = AgentStats(ErrorReport(settings.error_clear_s))
        self.threads: dict[str, Supervised] = {}
        self._inbox: queue.Queue[Prepared] = queue.Queue()
        self._recent: deque[Scan] = deque(maxlen=10)
        self._recent_lock = threading.Lock()
        self._failures: list[tuple[type[Kernel[Any]], str]] = []
        self._probation: dict[tuple[str, str, str], int] = {}
        self._installed_by: dict[tuple[str, str, str], int] = {}
        # the configuration each downloaded kernel was installed over
        self._came_over: dict[tuple[str, str, str], PipelineConfig | None] = {}
        self._wake_uploader = threading.Event()
        self._mapping_over = threading.Event()  # set once the mapping thread recorded its last step
        self._stepped: tuple[int, float] = (0, 0.0)
        offset = settings.laser_offset if settings.laser_offset is not None else laser_offset(settings.source)
        self._offset = offset
        self.pipeline: Pipeline | OnlineGraphMapper
        config = self._initial_config()
        if config.loop_closure is not None:
            self.pipeline = OnlineGraphMapper(self._make_pipeline, config)
        else:
            self.pipeline = Pipeline(config, laser_offset=offset)
        self._prev_walls: dict[int, tuple[float, float, float, float]] = {}
        stored = self.db.walls()
        self._id_offset = int(max((w[0] for w in stored), default=-1)) + 1
        self.poller: Poller | None = None
        self.uploader: Uploader | None = None
        if self.link is not None:
            self.poller = Poller(
                self.link,
                self.db.applied_seq,
                self._prepare,
                self._inbox,
                self.stats.errors,
                poll_wait_s=settings.poll_wait_s,
                retry_base_s=settings.retry_base_s,
            )
            self.uploader = Uploader(
                self.link,
                self.db,
                self.status,
                self._wall_time,
                self._wake_uploader,
                self._mapping_over,
                self.stats.errors,
                robot_id=settings.robot_id,
                upload_period_s=settings.upload_period_s,
                upload_batch=settings.upload_batch,
                retry_base_s=settings.retry_base_s,
                stop_grace_s=settings.stop_grace_s,
            )

    # ------------------------------------------------------------------ start-up
    def _initial_config(self) -> PipelineConfig:
        """The configuration in force at start-up: the stored one, with its downloaded kernels registered
        again. A stored kernel that no longer loads is marked rejected and, in the stored configuration,
        only its own use falls back (to a built-in version of that kernel with the same parameters, else
        the stage's default): every other stage and parameter is kept, and the fallback is reported
        (log line, ``last_error``, the kernel's state). See docs/reliability/agent.md."""
        broken: list[str] = []
        for rec in self.db.kernels(["active", "verified", "retired"]):
            try:
                self._register_record(rec)
            except Exception as exc:  # whatever the stored module does on import, the agent starts
                why = exc.reason if isinstance(exc, KernelRejected) else f"{type(exc).__name__}: {exc}"
                log.error("stored kernel %s %s no longer loads: %s", rec.name, rec.version, why)
                self.db.set_kernel_state(rec.stage, rec.name, rec.version, "rejected", f"at start-up: {why}")
                broken.append(f"{rec.stage} kernel {rec.name} {rec.version} no longer loads ({why})")
        stored = self.db.get("config")
        config = self.s.config or PipelineConfig()
        if stored is not None:
            try:
                config = PipelineConfig.parse(stored)
            except LinemapError as exc:
                config, notes = repair_config(stored, PipelineConfig())
                for note in notes:
                    log.error("stored configuration: %s", note)
                if not notes:
                    log.error("stored configuration is invalid (%s); starting from the defaults", exc)
                    notes = [f"the stored configuration was invalid ({exc}); started from the defaults"]
                broken.extend(notes)
        if broken:
            self.stats.last_error = "at start-up: " + "; ".join(broken)
        if self.s.loop_closure is not None:  # given at start (command line, TOML): over the stored choice
            lc = self.s.loop_closure
            config = config.model_copy(update={"loop_closure": lc.as_dict() if lc.enabled else None})
        config = pin_versions(config)
        self.db.record_config(config.model_dump(mode="json"), "start-up", kernels_run(config))
        return config

    def _make_pipeline(self, config: PipelineConfig) -> Pipeline:
        return Pipeline(config, laser_offset=self._offset)

    def _reconfigure(self, config: PipelineConfig) -> None:
        """Swap ``config`` in between two steps. Loop closure switched on over the front end alone starts
        the pose graph here, at the pose the robot has, over the map drawn so far (which stays as drawn);
        switched off, the graph stays and stops searching (:class:`OnlineGraphMapper`)."""
        if isinstance(self.pipeline, Pipeline) and config.loop_closure is not None:
            self.pipeline.reconfigure(config)  # raises with the old configuration kept
            self.pipeline = OnlineGraphMapper(self._make_pipeline, config, front=self.pipeline)
            log.info("loop closure switched on at step %d", self.pipeline.version)
            return
        self.pipeline.reconfigure(config)

    def _register_record(self, rec: KernelRecord) -> None:
        from robot_agent.kernels import verify_artifact

        verify_artifact(rec.source, rec.sha256, rec.signature, self.trusted, self.s.allow_unsigned)
        self._register(self._load_in_worker(rec.source, Stage(rec.stage), rec.name, rec.version))

    def _load_in_worker(self, source: bytes, stage: Stage, name: str, version: str) -> type[Kernel[Any]]:
        """The class of a downloaded kernel running in its own confined worker process."""
        from robot_agent.dryrun import load_in_worker

        try:
            return load_in_worker(
                source,
                stage,
                name,
                version,
                memory_mb=self.s.kernel_memory_mb,
                call_s=self.s.kernel_hang_s,
                import_s=self.s.dry_run_budget_s,
            )
        except KernelRejected:
            raise
        except AgentError as exc:  # not the kernel's fault, but it cannot run: refused with the reason
            raise KernelRejected(f"could not start its worker process: {exc}") from None

    def _register(self, cls: type[Kernel[Any]]) -> None:
        key = (str(cls.stage), cls.name, cls.version)
        try:
            REGISTRY.get(cls.stage, cls.name, cls.version)
            _close_worker(cls)  # registered already (built in, or installed earlier in this process)
            return
        except LinemapError:
            pass
        prev = self.pipeline.config if hasattr(self, "pipeline") else None
        self._came_over[key] = prev
        REGISTRY.register(
            guarded(
                cls,
                self._fallback_for(cls, prev),
                self._on_kernel_failure,
                self.s.kernel_budget_ms,
            )
        )
        self._probation[key] = self.s.probation_steps

    def _fallback_for(self, cls: type[Kernel[Any]], prev: PipelineConfig | None) -> Any:
        cache: list[Kernel[Any]] = []

        def make() -> Kernel[Any]:
            # Never an error out of the step loop: the version it replaced, else a built-in kernel of its
            # stage (refuse_deletions keeps built-ins and last fallbacks registered).
            if not cache:
                pick = fallback_choice(cls.stage, cls.name, cls.version, prev, registered())
                if pick is None:
                    raise AgentError(f"no fallback for {cls.name} {cls.version}: stage {cls.stage} is empty")
                if pick[0] != cls.name:
                    log.error(
                        "%s %s has no version to fall back to: %s %s answers", cls.name, cls.version, *pick
                    )
                cache.append(REGISTRY.create(cls.stage, pick[0], None, pick[1]))
            return cache[0]

        return make

    def _on_kernel_failure(self, cls: type[Kernel[Any]], reason: str) -> None:
        self._failures.append((cls, reason))

    # ------------------------------------------------------------------ main loop
    def run(self, stop: threading.Event) -> None:
        """Map until the source ends (then keep serving the link if ``stay``) or ``stop`` is set. The
        mapping loop runs supervised on this thread: a deliberate error (:class:`LinemapError`, e.g. the
        source cannot be opened) ends the agent with its message; anything else restarts it."""
        if self.poller is not None and self.uploader is not None:
            for name, loop in (("poller", self.poller.run), ("uploader", self.uploader.run)):
                self.threads[name] = supervise(
                    name, loop, stop, self._thread_died, retry_base_s=self.s.retry_base_s
                )
        mapping = self.threads["mapping"] = Supervised("mapping", threading.current_thread())
        try:
            run_supervised(
                mapping,
                self._mapping_loop,
                stop,
                self._thread_died,
                retry_base_s=self.s.retry_base_s,
                fatal=(LinemapError,),
            )
        finally:
            if isinstance(self.pipeline, OnlineGraphMapper):
                self.pipeline.close()
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
            if self.link is not None:
                self.link.close()

    def _mapping_loop(self, stop: threading.Event) -> None:
        self._map(stop)
        while self.s.stay and not stop.is_set():  # the source ended: keep serving the link
            self._apply_pending()
            stop.wait(0.05)

    def _thread_died(self, name: str, exc: BaseException) -> None:
        """A supervised loop died unexpectedly (restarted after a backoff): report it."""
        self.stats.last_error = f"thread {name} died and was restarted: {type(exc).__name__}: {exc}"

    def _map(self, stop: threading.Event) -> None:
        resume = int(self.db.get("source_index", 0) or 0)
        version = int(self.db.get("map_version", 0) or 0)
        own_pace = self.s.rate_hz is None  # the scans' own time stamps (logs) or 10 Hz (simulator)
        period = 0.1 if own_pace else (1.0 / self.s.rate_hz if self.s.rate_hz else None)
        next_at, last_stamp = time.monotonic(), None
        # A replayable source (simulator, log) skips what was mapped before a restart; a live sensor
        # cannot be replayed, so its scans are all new and its count goes on from there.
        live = is_live(self.s.source)
        for index, scan in self._scans(stop):
            if live:
                index += resume
            if stop.is_set() or (self.s.max_steps is not None and self.stats.steps >= self.s.max_steps):
                return
            if index < resume:
                continue
            if own_pace and last_stamp is not None:
                period = min(max(scan.stamp_s - last_stamp, 0.0), 5.0)  # a gap in a log: wait at most 5 s
            last_stamp = scan.stamp_s
            if period is not None:
                stop.wait(max(0.0, next_at - time.monotonic()))
                next_at = max(next_at + period, time.monotonic() - period)
            self._apply_pending()
            result = self.pipeline.step(scan)
            with self._recent_lock:
                self._recent.append(scan)
            version += 1
            self.db.record_step(self._record(version, index + 1, scan, result.pose))
            self._stepped = (version, time.time())
            self.stats.steps += 1
            self._after_step()
            self._wake_uploader.set()

    def _scans(self, stop: threading.Event) -> Iterator[tuple[int, Scan]]:
        if is_live(self.s.source):
            scans = open_scans(self.s.source, encoders=self.s.encoders, stop=stop)
        else:
            scans = open_scans(self.s.source, seed=self.s.seed, laps=self.s.laps, encoders=self.s.encoders)
        yield from enumerate(scans)

    def _record(self, version: int, source_index: int, scan: Scan, pose: Any) -> StepRecord:
        ids, segments = self.pipeline.walls()
        now = {
            int(i) + self._id_offset: tuple(float(v) for v in seg)
            for i, seg in zip(ids, segments, strict=True)
        }
        changed = [[float(i), *seg] for i, seg in now.items() if self._prev_walls.get(i) != seg]
        removed = [i for i in self._prev_walls if i not in now]
        self._prev_walls = now  # type: ignore[assignment]
        cents = self.pipeline.recent_centroids(200).tolist()
        return StepRecord(
            version,
            scan.stamp_s,
            source_index,
            changed,
            removed,
            [scan.stamp_s, pose.x_m, pose.y_m, pose.theta_rad],
            cents,
        )

    def _after_step(self) -> None:
        if self._failures:
            cls, reason = self._failures[0]
            self._failures.clear()
            self._roll_back(cls, reason)
            return
        for key in list(self._probation):
            self._probation[key] -= 1
            if self._probation[key] <= 0:
                del self._probation[key]

    def _roll_back(self, cls: type[Kernel[Any]], reason: str) -> None:
        """Take ``cls`` out (between two steps): the configuration in force, with the version it replaced
        (or a built-in one) instead of it; every other setting stays, also those of messages applied after
        the kernel's. The kernel leaves the registry first, so nothing below can pick it again."""
        self.stats.rollbacks += 1
        self.stats.last_error = f"rolled back: {reason}"
        log.error("kernel %s %s failed, rolling back: %s", cls.name, cls.version, reason)
        key = (str(cls.stage), cls.name, cls.version)
        _unregister(*key)  # and its worker process is killed
        _close_worker(cls)
        previous = self.pipeline.config
        if key in kernels_run(previous):
            version = _replaced_version(cls, self._came_over.get(key))
            pick = fallback_choice(cls.stage, cls.name, cls.version, self._came_over.get(key), registered())
            if version is not None:
                previous = swap_version(previous, Stage(cls.stage), cls.name, cls.version, version)
            elif pick is not None:  # no version of its own: that stage only goes to a built-in kernel
                previous = replace_choice(previous, Stage(cls.stage), cls.name, cls.version, *pick)
            else:
                previous = pin_versions(PipelineConfig())
        try:
            self.pipeline.reconfigure(previous)
        except LinemapError as exc:
            log.error("rollback configuration failed to build (%s); using the defaults", exc)
            previous = pin_versions(PipelineConfig())
            self.pipeline.reconfigure(previous)
        self.db.record_config(
            previous.model_dump(mode="json"), f"automatic rollback: {reason}"[:200], kernels_run(previous)
        )
        self.db.set_kernel_state(*key, "rejected", reason)
        self._refresh_kernel_states(previous)
        self._probation.pop(key, None)
        stored_seq = self.db.take_installed_by(*key)  # kept in the Robot DB: also after a restart
        seq = self._installed_by.pop(key, stored_seq)
        if seq is not None:
            self.db.mark_rolled_back(seq, reason)
            self._wake_uploader.set()

    # ------------------------------------------------------------------ control messages
    def _apply_pending(self) -> None:
        while True:
            try:
                prepared = self._inbox.get_nowait()
            except queue.Empty:
                return
            self._apply(prepared)

    def _apply(self, prepared: Prepared) -> None:
        if self.db.outcome_of(prepared.seq) is not None:
            for cls in prepared.classes.values():
                _close_worker(cls)
            return  # dealt with already (exactly once)
        if prepared.error is not None:
            for cls in prepared.classes.values():  # kernels of the message checked before the refusal
                _close_worker(cls)
            self._reject(prepared.seq, prepared.error)
            return
        t0 = time.perf_counter()
        before = self.pipeline.config
        try:
            config = apply_message(
                prepared,
                before,
                self._register,
                _unregister,
                self._reconfigure,
                floors=self.db.run_floors(),
            )
        except Exception as exc:  # anything the message caused: reject it, keep mapping as before
            for cls in prepared.classes.values():  # registered ones were undone: their workers serve nobody
                _close_worker(cls)
            self._reject(
                prepared.seq, str(exc) if isinstance(exc, LinemapError) else f"{type(exc).__name__}: {exc}"
            )
            return
        self.stats.swaps_ms.append((time.perf_counter() - t0) * 1e3)
        self.db.record_message(
            prepared.seq,
            "applied",
            None,
            config.model_dump(mode="json"),
            ran=kernels_run(config),
            installed=list(prepared.classes),
        )
        for key in prepared.classes:
            self._installed_by[key] = prepared.seq
        self._refresh_kernel_states(config)
        self._wake_uploader.set()

    def _reject(self, seq: int, reason: str) -> None:
        """Record message ``seq`` as rejected (acknowledged with ``reason``); it is also the last error."""
        self.stats.last_error = f"message {seq} rejected: {reason}"
        log.warning("message %d rejected: %s", seq, reason)
        self.db.record_message(seq, "rejected", reason, None)
        self._wake_uploader.set()

    def _refresh_kernel_states(self, config: PipelineConfig) -> None:
        """Every downloaded kernel that passed its checks is ``active`` if ``config`` uses it, else
        ``verified`` (a version rolled back from stays on the robot, ready, but no longer runs)."""
        for rec in self.db.kernels(["active", "verified"]):
            state = "active" if _used(config, rec.stage, rec.name, rec.version) else "verified"
            if state != rec.state:
                self.db.set_kernel_state(rec.stage, rec.name, rec.version, state)

    def _prepare(self, raw: dict[str, Any]) -> Prepared:
        """Parse a message and download/verify its kernels (network thread; may take seconds). A download
        that fails in transit (no answer, 408, 429, 5xx) raises :class:`LinkError`: the poller fetches the
        message again after a backoff instead of rejecting it for a network fault."""
        seq = int(raw["seq"])
        try:
            msg = parse_message(str(raw["xml"]).encode("utf-8"))
        except ControlMessageError as exc:
            return Prepared(seq, None, str(exc))
        prepared = Prepared(seq, msg)
        downgrade = refuse_downgrades(msg, self.db.run_floors())  # before downloading anything
        if downgrade is not None:
            prepared.error = downgrade
            return prepared
        installs = [op for op in msg.operations if op.kind in (OperationKind.INSTALL, OperationKind.UPDATE)]
        if not installs:
            return prepared
        self._verify_all(prepared, installs)
        return prepared

    def _verify_all(self, prepared: Prepared, installs: list[Any]) -> None:
        """Download and check each installed kernel of ``prepared``; the first refusal sets its error."""
        for op in installs:
            try:
                prepared.classes[(op.stage.value, op.name, op.version)] = self._fetch_and_verify(op)
            except KernelRejected as exc:
                prepared.error = f"<kernel-{op.kind.value}> {op.name} {op.version}: {exc.reason}"
                return
            except LinkError as exc:
                if _transient(exc):
                    raise  # a network fault: the poller fetches the message again after a backoff
                prepared.error = f"<kernel-{op.kind.value}> {op.name} {op.version}: download failed: {exc}"
                return

    def _fetch_and_verify(self, op: Any) -> type[Kernel[Any]]:
        from robot_agent.dryrun import verify_in_worker
        from robot_agent.kernels import verify_artifact

        assert self.link is not None
        got = self.link.fetch_kernel(op.name, op.version)
        sha = op.sha256 or ""
        if got.stage and got.stage != op.stage.value:
            raise KernelRejected(
                f"the server has it as a {got.stage} kernel, the message says {op.stage.value}"
            )
        record = KernelRecord(
            stage=op.stage.value,
            name=op.name,
            version=op.version,
            sha256=sha,
            source=got.source,
            signature=got.signature,
            state="rejected",
        )
        try:
            record.key_id = verify_artifact(
                got.source, sha, got.signature, self.trusted, self.s.allow_unsigned
            )
            # The kernel's code never runs in this process: the dry run and the conformance battery run in
            # a confined worker with time, CPU and memory limits (killed at them), and a kernel that passed
            # is served by a long-lived worker of its own.
            with self._recent_lock:
                scans = list(self._recent)
            try:
                verify_in_worker(
                    got.source,
                    op.stage,
                    op.name,
                    op.version,
                    None,
                    scans,
                    self.s.dry_run_budget_s,
                    conformance_s=self.s.dry_run_budget_s,
                )
            except KernelRejected:
                raise
            except AgentError as exc:  # the checks could not run: the kernel is not installed
                raise KernelRejected(f"its checks could not run: {exc}") from None
            cls = self._load_in_worker(got.source, op.stage, op.name, op.version)
        except KernelRejected as exc:
            record.reason = exc.reason
            self.db.save_kernel(record)
            raise
        record.state = "verified"
        self.db.save_kernel(record)
        return cls

    # ------------------------------------------------------------------ status
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

    def _wall_time(self, version: int) -> float | None:
        """When the step of map ``version`` finished (Unix s), if it is the newest step; else None."""
        stepped_version, at = self._stepped
        return at if stepped_version == version else None


def _used(config: PipelineConfig, stage: str, name: str, version: str) -> bool:
    return any(c.name == name and c.version == version for c in choices(config, Stage(stage)))


def _clip(text: str | None, limit: int) -> str | None:
    return text if text is None or len(text) <= limit else text[: limit - 3] + "..."


def _transient(exc: LinkError) -> bool:
    """A link failure the next attempt may not meet: no answer at all, 408, 429 or a 5xx."""
    return exc.status is None or exc.status in (408, 429) or exc.status >= 500


def _unregister(stage: str, name: str, version: str) -> None:
    """Take a kernel version out of the registry; a downloaded one's worker process is killed."""
    try:
        cls = REGISTRY.get(stage, name, version)
    except LinemapError:
        cls = None
    REGISTRY.unregister(stage, name, version)
    if cls is not None:
        _close_worker(cls)


def _close_worker(cls: type[Kernel[Any]]) -> None:
    """Kill the worker process behind a downloaded kernel's class (nothing for a built-in)."""
    close = getattr(cls, "close_worker", None)
    if close is not None:
        close()


def _replaced_version(cls: type[Kernel[Any]], prev: PipelineConfig | None) -> str | None:
    """A registered version of kernel ``cls`` to go back to: the one ``prev`` (the configuration it was
    installed over) ran, if it is still registered, else a built-in one; None when there is none."""
    for c in choices(prev, Stage(cls.stage)):
        if c.name == cls.name and c.version not in (None, cls.version):
            try:
                REGISTRY.get(cls.stage, c.name, c.version)
                return c.version
            except LinemapError:
                break  # taken out meanwhile (rolled back itself)
    builtin = [i for i in REGISTRY.list(cls.stage) if i.name == cls.name and i.version != cls.version]
    return builtin[0].version if builtin else None
