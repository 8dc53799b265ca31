"""The kernel supervisor: applies control messages between two mapping steps and watches downloaded
kernels in service (hot swap, probation, rollback).

Between two steps (mapping thread) it applies each prepared message (:mod:`robot_agent.preparer`) exactly
once: registers its verified kernels, computes the new configuration and swaps it in (milliseconds; a
message that fails changes nothing and is rejected with the reason). Each downloaded kernel runs guarded
(:mod:`robot_agent.guard`): one that fails, hangs or exceeds its budget answers with its fallback for that
step and is rolled back after it: taken out of the registry (its worker killed), the version it replaced (or
a built-in one) put back in the configuration, every other setting kept. At start-up the stored
configuration and its kernels are restored, a kernel that no longer loads falling back the same way. See
docs/reliability/agent.md. Each swap or rollback is O(kernels) plus building the changed kernels.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from typing import Any

from robot_agent.control import (
    Prepared,
    apply_message,
    choices,
    fallback_choice,
    kernels_run,
    pin_versions,
    registered,
    replace_choice,
    swap_version,
)
from robot_agent.errors import AgentError, KernelRejected
from robot_agent.guard import guarded
from robot_agent.health import AgentStats
from robot_agent.mapping import PipelineSlot
from robot_agent.preparer import KernelLoader
from robot_agent.recover import repair_config
from robot_agent.settings import AgentSettings
from robot_agent.store import RobotDB
from shared.errors import LinemapError
from shared.kernels import REGISTRY, Kernel, Stage
from shared.pipeline import PipelineConfig

__all__ = ["KernelSupervisor"]

log = logging.getLogger(__name__)

#: A kernel version: ``(stage, name, version)``.
Key = tuple[str, str, str]


class KernelSupervisor:
    """Collaborators: ``slot`` (the pipeline in force), ``db`` (the Robot DB: configurations, outcomes,
    kernel states), ``loader`` (workers of downloaded kernels), ``inbox`` (prepared messages, from the
    poller), ``stats`` (rollbacks, swap times, last_error), ``wake`` (set when there is an outcome to
    acknowledge)."""

    def __init__(
        self,
        settings: AgentSettings,
        slot: PipelineSlot,
        db: RobotDB,
        loader: KernelLoader,
        inbox: queue.Queue[Prepared],
        stats: AgentStats,
        wake: threading.Event,
    ) -> None:
        self.s = settings
        self.slot, self.db, self.loader, self.inbox = slot, db, loader, inbox
        self.stats, self._wake = stats, wake
        self._failures: list[tuple[type[Kernel[Any]], str]] = []
        self._probation: dict[Key, int] = {}
        self._installed_by: dict[Key, int] = {}
        # the configuration each downloaded kernel was installed over
        self._came_over: dict[Key, PipelineConfig | None] = {}

    # ------------------------------------------------------------------ start-up
    def start_config(self) -> PipelineConfig:
        """The configuration in force at start-up: the stored one, with its downloaded kernels registered
        again. A stored kernel that no longer loads is marked rejected and, in the stored configuration,
        only its own use falls back (to a built-in version of that kernel with the same parameters, else
        the stage's default): every other stage and parameter is kept, and the fallback is reported
        (log line, ``last_error``, the kernel's state). See docs/reliability/agent.md."""
        broken: list[str] = []
        for rec in self.db.kernels(["active", "verified", "retired"]):
            try:
                self._register(self.loader.load_stored(rec))
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

    # ------------------------------------------------------------------ registry
    def _register(self, cls: type[Kernel[Any]]) -> None:
        key = (str(cls.stage), cls.name, cls.version)
        try:
            REGISTRY.get(cls.stage, cls.name, cls.version)
            _close_worker(cls)  # registered already (built in, or installed earlier in this process)
            return
        except LinemapError:
            pass
        prev = self.slot.config
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

    # ------------------------------------------------------------------ after each step
    def after_step(self) -> None:
        """Roll back a kernel that failed during the step; else count down the probations."""
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
        pipeline = self.slot.pipeline
        previous = pipeline.config
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
            pipeline.reconfigure(previous)
        except LinemapError as exc:
            log.error("rollback configuration failed to build (%s); using the defaults", exc)
            previous = pin_versions(PipelineConfig())
            pipeline.reconfigure(previous)
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
            self._wake.set()

    # ------------------------------------------------------------------ control messages
    def apply_pending(self) -> None:
        """Apply every message the poller has prepared (between two steps)."""
        while True:
            try:
                prepared = self.inbox.get_nowait()
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
        before = self.slot.pipeline.config
        try:
            config = apply_message(
                prepared,
                before,
                self._register,
                _unregister,
                self.slot.reconfigure,
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
        self._wake.set()

    def _reject(self, seq: int, reason: str) -> None:
        """Record message ``seq`` as rejected (acknowledged with ``reason``); it is also the last error."""
        self.stats.last_error = f"message {seq} rejected: {reason}"
        log.warning("message %d rejected: %s", seq, reason)
        self.db.record_message(seq, "rejected", reason, None)
        self._wake.set()

    def _refresh_kernel_states(self, config: PipelineConfig) -> None:
        """Every downloaded kernel that passed its checks is ``active`` if ``config`` uses it, else
        ``verified`` (a version rolled back from stays on the robot, ready, but no longer runs)."""
        for rec in self.db.kernels(["active", "verified"]):
            state = "active" if _used(config, rec.stage, rec.name, rec.version) else "verified"
            if state != rec.state:
                self.db.set_kernel_state(rec.stage, rec.name, rec.version, state)


def _used(config: PipelineConfig, stage: str, name: str, version: str) -> bool:
    return any(c.name == name and c.version == version for c in choices(config, Stage(stage)))


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
