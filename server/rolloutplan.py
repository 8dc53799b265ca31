"""The rollout state machine, pure: frozen dataclasses in, frozen dataclasses out (docs/rollouts.md).

:func:`advance` takes a rollout, its robots and what the server knows about each robot now (its
acknowledgement of the update, its last status report) and returns the next state: robots that change
state, update messages to send, rollback messages to send, and the audit events that say why. The driver
(:mod:`server.rolloutdriver`) reads these from the database and writes the result back; unit tests drive
this module with plain data and a clock of their own.

Rules, in order, each tick:

1. a robot whose update was sent: ``applied`` starts its commit window; ``rejected`` fails it with the
   robot's reason; ``rolled-back`` marks it rolled back by the robot itself; no acknowledgement within
   ``ack_timeout_s`` marks it ``timed-out`` (a failure) and *watched*: if it applies the update later it
   is rolled back; ``watch_timeout_s`` after the update was sent the watch ends and a rollback is queued
   behind the update (so a robot that comes back later applies both, in order);
2. a robot in its commit window fails (and is rolled back) on a ``rolled-back`` acknowledgement, a new
   ``last_error`` that mentions a rollback (a guard trip) or a step time above ``max_step_ratio`` x its
   step time before the update; once the window has passed healthy and the robot reports the version
   active it is committed (``installed``); applied but not reported active within the window plus
   ``ack_timeout_s``: rolled back. A committed robot stays judged by the same health rules while the
   rollout is running or paused (its later waves): a failure after the commit counts like any other;
3. the rollout stops when any canary failed or failures / robots tried > ``max_failure_share`` (tried:
   every robot the update was sent to, decided or not): pending robots are skipped, every robot that runs
   the update (in its window or committed) is rolled back, and robots still to acknowledge are rolled
   back when they do;
4. a running rollout sends the current wave's pending robots; when every robot of the wave is decided the
   next wave goes out; after the last wave it is completed. A paused rollout sends nothing new but keeps
   judging the robots in flight (and still stops on failures).

A robot is only sent the update when it has reported the stage's active kernel: that is the version a
rollback goes back to (``<kernel-rollback ... below-floor="allow"/>``, the operator's audited override of
the anti-rollback floor). O(robots) per tick.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from datetime import datetime
from typing import Any

__all__ = [
    "DECIDED",
    "FAILED_STATES",
    "Event",
    "Observation",
    "Outcome",
    "RobotRun",
    "RolloutView",
    "advance",
    "assign_waves",
    "stop",
]

#: Robot states that count as a failure of the update.
FAILED_STATES = frozenset({"failed", "rolled-back", "timed-out"})
#: Robot states with nothing left to wait for (a ``timed-out`` robot may still be watched: ``watch``).
DECIDED = frozenset({"installed", "failed", "rolled-back", "timed-out", "skipped"})
_ACTIONS = {"rolled-back": "rollout.robot.rolled_back", "timed-out": "rollout.robot.timed_out"}
TERMINAL = frozenset({"completed", "stopped", "aborted"})


@dataclass(frozen=True, slots=True)
class RolloutView:
    """The rollout's settings and state (times in seconds; ``max_step_ratio`` None: not checked)."""

    id: int
    stage: str
    name: str
    version: str
    state: str = "running"
    wave: int = 0
    canaries: int = 1
    wave_size: int = 1
    max_failure_share: float = 0.0
    commit_window_s: float = 60.0
    ack_timeout_s: float = 300.0
    watch_timeout_s: float = 3600.0
    max_step_ratio: float | None = None
    fail_on_rollback_error: bool = True
    stop_reason: str | None = None
    active: bool = True

    @property
    def target(self) -> str:
        """The kernel as a robot reports it active: ``name@version``."""
        return f"{self.name}@{self.version}"


@dataclass(frozen=True, slots=True)
class RobotRun:
    """One robot of the rollout (see :class:`server.models.RolloutRobot` for the states)."""

    robot_id: int
    position: int
    wave: int
    state: str = "pending"
    reason: str | None = None
    previous: str | None = None
    baseline_step_ms: float | None = None
    baseline_error: str | None = None
    sent_at: datetime | None = None
    applied_at: datetime | None = None
    finished_at: datetime | None = None
    watch: bool = False


@dataclass(frozen=True, slots=True)
class Observation:
    """What the server knows about a robot now: its acknowledgement of the update message (``queued``,
    ``applied``, ``rejected``, ``rolled-back``; None before it is sent) with the reason, and its last
    status report (the stage's active kernel ``name@version``, step time in ms, last error)."""

    ack: str | None = None
    ack_reason: str | None = None
    active: str | None = None
    step_ms: float | None = None
    last_error: str | None = None


@dataclass(frozen=True, slots=True)
class Event:
    """An audit entry: ``action`` like ``rollout.robot.failed``, the robot (None: the whole rollout)."""

    action: str
    robot_id: int | None = None
    detail: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class Outcome:
    """The next state: the rollout, every robot, whom to send the update (robot ids), whom to roll back
    (robot id, ``name@version`` to go back to), and the events."""

    rollout: RolloutView
    robots: tuple[RobotRun, ...]
    sends: tuple[int, ...] = ()
    rollbacks: tuple[tuple[int, str], ...] = ()
    events: tuple[Event, ...] = ()


def assign_waves(robot_ids: list[int], canaries: int, wave_size: int) -> tuple[RobotRun, ...]:
    """Robots in the order given: the first ``canaries`` are wave 0, then waves of ``wave_size``."""
    out = []
    for pos, rid in enumerate(robot_ids):
        wave = 0 if pos < canaries else 1 + (pos - canaries) // wave_size
        out.append(RobotRun(robot_id=rid, position=pos, wave=wave))
    return tuple(out)


class _Tick:
    def __init__(self, rollout: RolloutView, robots: tuple[RobotRun, ...], now: datetime) -> None:
        self.rollout = rollout
        self.robots = {r.robot_id: r for r in robots}
        self.order = [r.robot_id for r in robots]
        self.now = now
        self.sends: list[int] = []
        self.rollbacks: list[tuple[int, str]] = []
        self.events: list[Event] = []

    def set(self, rid: int, **changes: Any) -> RobotRun:
        if changes.get("state") in DECIDED:
            changes.setdefault("finished_at", self.now)
        run = replace(self.robots[rid], **changes)
        self.robots[rid] = run
        return run

    def fail(self, rid: int, reason: str, *, roll_back: bool, state: str = "failed", **more: Any) -> None:
        run = self.robots[rid]
        if roll_back and run.previous is not None:
            self.rollbacks.append((rid, run.previous))
            state = "rolled-back"
        self.set(rid, state=state, reason=reason, **more)
        action = _ACTIONS.get(state, "rollout.robot.failed")
        detail: dict[str, Any] = {"reason": reason}
        if roll_back and run.previous is not None:
            detail["to"] = run.previous
        self.events.append(Event(action, rid, detail))

    def outcome(self) -> Outcome:
        return Outcome(
            self.rollout,
            tuple(self.robots[rid] for rid in self.order),
            tuple(self.sends),
            tuple(self.rollbacks),
            tuple(self.events),
        )


def _kernels(seen: Observation) -> list[str]:
    """The stage's kernels as the robot reports them: ``"a@1.0.0, b@2.0.0"`` (a noise-removal chain)."""
    return [k.strip() for k in (seen.active or "").split(",") if k.strip()]


def _runs(seen: Observation, target: str) -> bool:
    return target in _kernels(seen)


def _of_name(seen: Observation, name: str) -> str | None:
    """The ``name@version`` of kernel ``name`` in the robot's stage, if it runs one."""
    return next((k for k in _kernels(seen) if k.rpartition("@")[0] == name), None)


def _age_s(now: datetime, then: datetime | None) -> float:
    return 0.0 if then is None else (now - then).total_seconds()


def _judge_sent(t: _Tick, run: RobotRun, seen: Observation) -> None:
    stopped = t.rollout.state in TERMINAL
    if seen.ack == "applied" and stopped:
        t.fail(run.robot_id, f"applied after the rollout stopped ({t.rollout.stop_reason})", roll_back=True)
    elif seen.ack == "applied":
        t.set(run.robot_id, state="applied", applied_at=t.now)
        t.events.append(Event("rollout.robot.applied", run.robot_id, {}))
    elif seen.ack == "rejected":
        t.fail(run.robot_id, f"rejected by the robot: {seen.ack_reason}", roll_back=False)
    elif seen.ack == "rolled-back":
        why = f"the robot rolled it back: {seen.ack_reason}"
        t.fail(run.robot_id, why, roll_back=False, state="rolled-back")
    elif _age_s(t.now, run.sent_at) >= t.rollout.ack_timeout_s:
        why = (
            f"no acknowledgement within {t.rollout.ack_timeout_s:g} s (offline or stuck?); watched for a "
            f"late answer until {t.rollout.watch_timeout_s:g} s after it was sent"
        )
        t.fail(run.robot_id, why, roll_back=False, state="timed-out", watch=True)


def _health(r: RolloutView, run: RobotRun, seen: Observation) -> str | None:
    """Why the robot is unhealthy under the update, or None."""
    err = seen.last_error
    if r.fail_on_rollback_error and err and err != run.baseline_error and "roll" in err.lower():
        return f"health: new error after the update: {err}"
    ratio = r.max_step_ratio
    base = run.baseline_step_ms
    step = seen.step_ms
    if ratio is None or not base or step is None or not _runs(seen, r.target) or step <= ratio * base:
        return None
    return (
        f"health: step time {step:.1f} ms is {step / base:.2f} x the {base:.1f} ms before the update "
        f"(limit {ratio:g} x)"
    )


def _judge_applied(t: _Tick, run: RobotRun, seen: Observation) -> None:
    r = t.rollout
    rid = run.robot_id
    if seen.ack == "rolled-back":
        t.fail(rid, f"the robot rolled it back: {seen.ack_reason}", roll_back=False, state="rolled-back")
        return
    why = _health(r, run, seen)
    if why is not None:
        t.fail(rid, why, roll_back=True)
        return
    age = _age_s(t.now, run.applied_at)
    if age >= r.commit_window_s and _runs(seen, r.target):
        t.set(rid, state="installed", reason=None)
        t.events.append(Event("rollout.robot.committed", rid, {"window_s": r.commit_window_s}))
    elif age >= r.commit_window_s + r.ack_timeout_s:
        why = f"not reported active within {r.commit_window_s + r.ack_timeout_s:g} s of applying it"
        t.fail(rid, why, roll_back=True)


def _judge_installed(t: _Tick, run: RobotRun, seen: Observation) -> None:
    """A committed robot while the rollout goes on (running or paused): the same health rules as in its
    window; a robot committed without being sent the update (it ran the version already) is not judged."""
    if t.rollout.state not in ("running", "paused") or run.sent_at is None or run.previous is None:
        return
    if seen.ack == "rolled-back":
        own = f"after its commit, the robot rolled it back: {seen.ack_reason}"
        t.fail(run.robot_id, own, roll_back=False, state="rolled-back")
        return
    why = _health(t.rollout, run, seen)
    if why is not None:
        t.fail(run.robot_id, f"after its commit, {why}", roll_back=True)


def _judge_watched(t: _Tick, run: RobotRun, seen: Observation) -> None:
    rid = run.robot_id
    if seen.ack == "applied":
        reason = f"{run.reason}; applied later, rolled back"
        t.fail(rid, reason, roll_back=True, watch=False)
    elif seen.ack in ("rejected", "rolled-back"):
        t.set(rid, watch=False, reason=f"{run.reason}; answered later: {seen.ack} ({seen.ack_reason})")
    elif _age_s(t.now, run.sent_at) >= t.rollout.watch_timeout_s:
        why = f"{run.reason}; no answer within {t.rollout.watch_timeout_s:g} s: no longer watched"
        if run.previous is not None:
            t.rollbacks.append((rid, run.previous))
            why += f"; a rollback to {run.previous} is queued behind its update"
        t.set(rid, watch=False, reason=why)
        t.events.append(Event("rollout.robot.unwatched", rid, {"reason": why, "to": run.previous}))


def stop(t_or: Outcome, reason: str, now: datetime, *, state: str = "stopped") -> Outcome:
    """Stop the rollout (``stopped`` by its thresholds, ``aborted`` by an operator): pending robots are
    skipped, robots running the update are rolled back, robots yet to acknowledge are rolled back when
    they do. O(robots)."""
    t = _Tick(t_or.rollout, t_or.robots, now)
    t.sends, t.rollbacks, t.events = list(t_or.sends), list(t_or.rollbacks), list(t_or.events)
    if t.rollout.state in TERMINAL:
        return t.outcome()
    t.rollout = replace(t.rollout, state=state, stop_reason=reason)
    t.events.append(Event(f"rollout.{state}", None, {"reason": reason}))
    for rid in t.order:
        run = t.robots[rid]
        if run.state == "pending":
            t.set(rid, state="skipped", reason=f"rollout {state} before its wave: {reason}")
        elif run.state in ("applied", "installed"):
            t.fail(rid, f"rollout {state}: {reason}", roll_back=True)
    return _settle(t)


def _stop_reason(t: _Tick) -> str | None:
    runs = list(t.robots.values())
    for run in runs:
        if run.wave == 0 and run.state in FAILED_STATES:
            return f"canary robot {run.robot_id} failed: {run.reason}"
    tried = [r for r in runs if r.state not in ("pending", "skipped")]
    failed = [r for r in tried if r.state in FAILED_STATES]
    share = len(failed) / len(tried) if tried else 0.0
    if share > t.rollout.max_failure_share:
        return (
            f"{len(failed)} of {len(tried)} robots tried failed ({share:.0%}, more than the "
            f"{t.rollout.max_failure_share:.0%} allowed)"
        )
    return None


def _send_wave(t: _Tick, observations: Mapping[int, Observation]) -> None:
    r = t.rollout
    pending = [rid for rid in t.order if t.robots[rid].wave == r.wave and t.robots[rid].state == "pending"]
    if pending:
        t.events.append(Event("rollout.wave", None, {"wave": r.wave, "robots": pending}))
    for rid in pending:
        seen = observations.get(rid, Observation())
        same = _of_name(seen, r.name)
        if seen.active is None:
            why = f"has not reported its active {r.stage} kernel: nothing to roll back to, so not updated"
            t.fail(rid, why, roll_back=False)
        elif _runs(seen, r.target):
            t.set(rid, state="installed", reason=f"already running {r.target}")
            t.events.append(Event("rollout.robot.committed", rid, {"already": True}))
        elif same is None:
            why = (
                f"runs no {r.name} in {r.stage} ({seen.active}): an update switches only the uses of "
                f"{r.name}, so it would change nothing in force; not updated"
            )
            t.fail(rid, why, roll_back=False)
        else:
            t.set(
                rid,
                state="sent",
                sent_at=t.now,
                previous=same,
                baseline_step_ms=seen.step_ms,
                baseline_error=seen.last_error,
            )
            t.sends.append(rid)


def _settle(t: _Tick) -> Outcome:
    busy = any(run.state in ("sent", "applied") or run.watch for run in t.robots.values())
    t.rollout = replace(t.rollout, active=t.rollout.state not in TERMINAL or busy)
    return t.outcome()


def advance(
    rollout: RolloutView,
    robots: tuple[RobotRun, ...],
    observations: Mapping[int, Observation],
    now: datetime,
) -> Outcome:
    """One tick of the driver (the rules in the module docstring). O(robots)."""
    t = _Tick(rollout, robots, now)
    for rid in t.order:
        run = t.robots[rid]
        seen = observations.get(rid, Observation())
        if run.state == "sent":
            _judge_sent(t, run, seen)
            run = t.robots[rid]
        if run.state == "applied":
            _judge_applied(t, run, seen)
        elif run.state == "installed":
            _judge_installed(t, run, seen)
        elif run.watch:
            _judge_watched(t, run, seen)
    if t.rollout.state in ("running", "paused"):
        why = _stop_reason(t)
        if why is not None:
            return stop(_settle(t), why, now)
    if t.rollout.state == "running":
        # the current wave goes out; a decided wave hands over to the next
        while True:
            _send_wave(t, observations)
            wave = [run for run in t.robots.values() if run.wave == t.rollout.wave]
            if not all(run.state in DECIDED for run in wave):
                break
            why = _stop_reason(t)
            if why is not None:
                return stop(_settle(t), why, now)
            later = [run.wave for run in t.robots.values() if run.wave > t.rollout.wave]
            if not later:
                t.rollout = replace(t.rollout, state="completed")
                t.events.append(Event("rollout.completed", None, {}))
                break
            t.rollout = replace(t.rollout, wave=min(later))
    return _settle(t)
