"""The rollout driver: a background task of the server that advances every active rollout each tick.

Each tick re-reads the rollouts from the database (a restarted server resumes them), and advances each one
in a transaction of its own: :func:`server.rolloutplan.advance` decides, this module queues the update and
rollback messages through :func:`server.msgqueue.queue_message`, the path ``POST /robots/{id}/messages``
takes (the same checks, numbering, ``message.post`` audit entry and cross-process ``NOTIFY``), and writes
the rollout's audit entries in that same transaction. A message the checks refuse (say the kernel version
was deleted since the rollout began) fails that robot with the server's reason; nothing is queued for it.

One process drives a rollout at a time, across processes sharing the database: the transaction begins by
taking the rollout's lease (``UPDATE rollouts SET lease_owner = me, lease_until = now + lease WHERE id = ..
AND (lease_owner IS NULL OR lease_owner = me OR lease_until < now)``). On PostgreSQL that UPDATE also holds
the row lock until the transaction commits, so a second process's UPDATE waits, then sees the lease held
and skips the rollout; on SQLite write transactions are serialised anyway. A process that dies leaves its
lease to run out (``rollout_lease_s``), then another process takes over. Operator actions (pause, resume,
abort) lock the same row (``SELECT ... FOR UPDATE``) so they never interleave with a tick.
See docs/rollouts.md.
"""

from __future__ import annotations

import asyncio
import logging
import os
import socket
import uuid
from datetime import datetime, timedelta
from typing import Any

from fastapi.concurrency import run_in_threadpool
from sqlalchemy import or_, select, update
from sqlalchemy.orm import Session

from server.deps import AppState
from server.errors import NotFoundError, ServerError
from server.hub import Hub
from server.models import AuditEntry, Message, Robot, Rollout, RolloutRobot, utcnow
from server.msgqueue import queue_message
from server.rolloutplan import Observation, Outcome, RobotRun, RolloutView, advance
from shared.control import parse_message

__all__ = [
    "RolloutDriver",
    "apply_outcome",
    "drive_forever",
    "load",
    "observe",
    "rollback_xml",
    "update_xml",
    "wake",
]

log = logging.getLogger(__name__)
TERMINAL = ("completed", "stopped", "aborted")


def update_xml(r: Rollout) -> str:
    """The ``<kernel-update>`` message of the rollout."""
    return (
        f'<xml><message><kernel-update stage="{r.stage}" name="{r.name}" version="{r.version}" '
        f'sha256="{r.sha256}"/></message></xml>'
    )


def rollback_xml(stage: str, previous: str) -> str:
    """The ``<kernel-rollback ... below-floor="allow"/>`` back to ``previous`` (``name@version``)."""
    name, _, version = previous.rpartition("@")
    return (
        f'<xml><message><kernel-rollback stage="{stage}" name="{name}" version="{version}" '
        f'below-floor="allow"/></message></xml>'
    )


def load(s: Session, row: Rollout) -> tuple[RolloutView, list[RolloutRobot]]:
    """The rollout as the state machine sees it, and its robot rows in order."""
    view = RolloutView(
        id=row.id,
        stage=row.stage,
        name=row.name,
        version=row.version,
        state=row.state,
        wave=row.wave,
        canaries=row.canaries,
        wave_size=row.wave_size,
        max_failure_share=row.max_failure_share,
        commit_window_s=row.commit_window_s,
        ack_timeout_s=row.ack_timeout_s,
        watch_timeout_s=row.watch_timeout_s,
        max_step_ratio=row.max_step_ratio,
        fail_on_rollback_error=row.fail_on_rollback_error,
        stop_reason=row.stop_reason,
        active=row.active,
    )
    rows = list(
        s.scalars(
            select(RolloutRobot).where(RolloutRobot.rollout_id == row.id).order_by(RolloutRobot.position)
        )
    )
    return view, rows


_RUN_FIELDS = (
    "state",
    "reason",
    "previous",
    "baseline_step_ms",
    "baseline_error",
    "sent_at",
    "applied_at",
    "finished_at",
    "watch",
)


def run_of(row: RolloutRobot) -> RobotRun:
    return RobotRun(
        robot_id=row.robot_id,
        position=row.position,
        wave=row.wave,
        **{f: getattr(row, f) for f in _RUN_FIELDS},
    )


def observe(s: Session, stage: str, rows: list[RolloutRobot]) -> dict[int, Observation]:
    """Each robot's acknowledgement of its update message and its last status report. Two queries."""
    ids = [r.robot_id for r in rows]
    robots = {r.id: r for r in s.scalars(select(Robot).where(Robot.id.in_(ids)))}
    wanted = [(r.robot_id, r.seq) for r in rows if r.seq is not None]
    acks: dict[int, tuple[str, str | None]] = {}
    if wanted:
        msgs = s.execute(
            select(Message.robot_id, Message.seq, Message.status, Message.reason)
            .where(Message.robot_id.in_([rid for rid, _ in wanted]))
            .where(Message.seq.in_([seq for _, seq in wanted]))
        )
        want = set(wanted)
        for rid, seq, status, reason in msgs:
            if (rid, seq) in want:
                acks[rid] = (status, reason)
    out = {}
    for r in rows:
        robot = robots.get(r.robot_id)
        if robot is None:
            continue
        ack, why = acks.get(r.robot_id, (None, None))
        active = (robot.active_kernels or {}).get(stage)
        out[r.robot_id] = Observation(
            ack=ack,
            ack_reason=why,
            active=str(active) if active else None,
            step_ms=robot.step_ms,
            last_error=robot.last_error,
        )
    return out


def _queue(s: Session, hub: Hub, row: Rollout, robot_id: int, xml: str) -> int | str | None:
    """Queue ``xml`` for the robot as an operator's message is queued: its number, the server's reason
    when the checks refuse it, or None when the robot was deleted meanwhile."""
    try:
        m = queue_message(s, hub, robot_id, xml, parse_message(xml), f"rollout:{row.id}", rollout=row.id)
    except NotFoundError:
        return None
    except ServerError as exc:
        log.warning("rollout %d: message for robot %d refused: %s", row.id, robot_id, exc.detail)
        return exc.detail
    return int(m.seq)


def apply_outcome(
    s: Session, hub: Hub, row: Rollout, rows: list[RolloutRobot], out: Outcome, now: datetime
) -> list[tuple[int, int]]:
    """Write ``out`` back: the rollout, its robots, the queued messages and the audit entries. Returns the
    ``(robot_id, seq)`` of the messages queued (to wake this process's long-polls after the commit; the
    other processes hear of them through ``hub``'s notices)."""
    actor = f"rollout:{row.id}"
    was_terminal = row.state in TERMINAL
    row.state, row.wave, row.stop_reason, row.active = (
        out.rollout.state,
        out.rollout.wave,
        out.rollout.stop_reason,
        out.rollout.active,
    )
    if row.state in TERMINAL and not was_terminal:
        row.finished_at = now
    by_id = {r.robot_id: r for r in rows}
    for run in out.robots:
        target = by_id[run.robot_id]
        for f in _RUN_FIELDS:
            setattr(target, f, getattr(run, f))
    events = [(ev.action, ev.robot_id, dict(ev.detail)) for ev in out.events]
    queued: list[tuple[int, int]] = []
    for rid in out.sends:
        got = _queue(s, hub, row, rid, update_xml(row))
        if isinstance(got, int):
            by_id[rid].seq = got
            queued.append((rid, got))
        elif isinstance(got, str):  # refused: failed, with the server's reason (counted next tick)
            why = f"the server refused the update: {got}"
            by_id[rid].state, by_id[rid].reason, by_id[rid].finished_at = "failed", why, now
            events.append(("rollout.robot.failed", rid, {"reason": why}))
    for rid, previous in out.rollbacks:
        got = _queue(s, hub, row, rid, rollback_xml(row.stage, previous))
        if isinstance(got, int):
            by_id[rid].rollback_seq = got
            queued.append((rid, got))
        elif isinstance(got, str):
            by_id[rid].reason = f"{by_id[rid].reason}; the server refused its rollback: {got}"
            events.append(("rollout.robot.rollback_refused", rid, {"reason": got, "to": previous}))
    for action, robot_id, more in events:
        where = f"robot:{robot_id}" if robot_id is not None else f"rollout:{row.id}"
        detail: dict[str, Any] = {"rollout": row.id, **more}
        s.add(AuditEntry(actor=actor, action=action, target=where, detail=detail))
    return queued


class RolloutDriver:
    """Advances the active rollouts of one database; ``owner`` names this process in the leases."""

    def __init__(self, state: AppState, owner: str | None = None) -> None:
        self.state = state
        self.owner = owner or f"{socket.gethostname()[:30]}:{os.getpid()}:{uuid.uuid4().hex[:8]}"

    def tick(self) -> list[tuple[int, int]]:
        """Advance every active rollout whose lease this process holds or can take; returns the messages
        queued, ``(robot_id, seq)``, for :func:`wake` on the event loop. Blocking (database): run it in a
        worker thread. O(rollouts x robots)."""
        with self.state.db.read() as s:
            ids = list(s.scalars(select(Rollout.id).where(Rollout.active.is_(True)).order_by(Rollout.id)))
        queued: list[tuple[int, int]] = []
        for rid in ids:
            queued += self.drive(rid) or []
        return queued

    def release(self) -> int:
        """Give up this process's leases (at shutdown), so a restarted server takes its rollouts over at
        once instead of after ``rollout_lease_s``; returns how many."""
        with self.state.db.session() as s:
            done = s.execute(
                update(Rollout)
                .where(Rollout.lease_owner == self.owner)
                .values(lease_owner=None, lease_until=None)
                .returning(Rollout.id)
            ).all()
        return len(done)

    def drive(self, rollout_id: int) -> list[tuple[int, int]] | None:
        """One tick of one rollout under its lease: the messages queued, or None when another process
        holds the lease."""
        lease = timedelta(seconds=self.state.settings.rollout_lease_s)
        with self.state.db.session() as s:
            now = utcnow()
            took = s.execute(
                update(Rollout)
                .where(
                    Rollout.id == rollout_id,
                    Rollout.active.is_(True),
                    or_(
                        Rollout.lease_owner.is_(None),
                        Rollout.lease_owner == self.owner,
                        Rollout.lease_until < now,
                    ),
                )
                .values(lease_owner=self.owner, lease_until=now + lease)
                .returning(Rollout.id)
            ).first()
            if took is None:
                return None
            row = s.get(Rollout, rollout_id)
            assert row is not None
            view, rows = load(s, row)
            out = advance(view, tuple(run_of(r) for r in rows), observe(s, row.stage, rows), now)
            queued = apply_outcome(s, self.state.hub, row, rows, out, now)
            if not row.active:
                row.lease_owner, row.lease_until = None, None
        return queued


def wake(hub: Hub, queued: list[tuple[int, int]]) -> None:
    """Wake this process's long-polls of the robots just sent a message (on the event loop: the hub is not
    thread-safe); the other server processes were told at commit (PostgreSQL ``NOTIFY``)."""
    for rid, seq in queued:
        hub.publish(f"messages:{rid}", seq)


async def drive_forever(driver: RolloutDriver) -> None:
    """The background task: a tick every ``rollout_tick_s``; an error is logged and retried next tick."""
    every_s = driver.state.settings.rollout_tick_s
    while True:
        try:
            wake(driver.state.hub, await run_in_threadpool(driver.tick))
        except Exception:  # never kill the task: the next tick re-reads everything
            log.exception("rollout driver tick failed")
        await asyncio.sleep(every_s)
