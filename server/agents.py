"""Which agent process speaks for a robot (docs/reliability/identity.md).

Every agent sends its process's instance id (a UUID it makes at start) in the ``X-Linemap-Agent-Instance``
header. The robot's current instance is ``robots.agent_instance``; a request from a new instance takes over
(so an agent restarted after kill -9 is never kept waiting) and the previous one is marked superseded; a
request from a superseded instance is refused (409 ``agent_superseded``, naming when the other agent took
over), so two agents running with one robot token (a cloned SD card, a stale instance left running) never
both upload. Takeovers and refusals are written to the audit log. A request without the header (an agent
from before instance ids) is not checked. The dependency the robot's routes use is
:func:`server.deps.check_instance`.

:class:`InstanceCheck` keeps the answer "this instance is current" for ``CONFIRM_S`` per process: one
database read per robot and second instead of one per request; a takeover on another server process is
therefore seen by this one within ``CONFIRM_S``.
"""

from __future__ import annotations

import logging
import threading
import time

from sqlalchemy import select

from server.database import Database
from server.errors import AgentSupersededError
from server.models import AgentInstance, AuditEntry, Robot, utcnow

__all__ = ["CONFIRM_S", "InstanceCheck"]

log = logging.getLogger(__name__)

#: How long a confirmed (robot, instance) is taken as current without a database read (s).
CONFIRM_S = 1.0


class InstanceCheck:
    """The robot's current agent instance, confirmed against the database at most every ``CONFIRM_S``."""

    def __init__(self, db: Database, confirm_s: float = CONFIRM_S) -> None:
        self._db = db
        self._confirm_s = confirm_s
        self._confirmed: dict[int, tuple[str, float]] = {}
        self._lock = threading.Lock()

    def fresh(self, robot_id: int, instance: str) -> bool:
        """Whether ``instance`` was confirmed as the robot's current one within ``confirm_s`` (no I/O)."""
        with self._lock:
            got = self._confirmed.get(robot_id)
        return got is not None and got[0] == instance and time.monotonic() - got[1] < self._confirm_s

    def check(self, robot_id: int, instance: str, actor: str) -> None:
        """Accept ``instance`` for ``robot_id`` (taking over from another one) or refuse it (superseded).
        Blocking: one read, and a write on a takeover or a refusal."""
        with self._db.read() as s:
            current = s.scalar(select(Robot.agent_instance).where(Robot.id == robot_id))
        if current != instance:
            self._change(robot_id, instance, actor)
        with self._lock:
            self._confirmed[robot_id] = (instance, time.monotonic())

    def _change(self, robot_id: int, instance: str, actor: str) -> None:
        refused: str | None = None
        with self._db.session() as s:
            robot = s.get(Robot, robot_id)
            if robot is None or robot.agent_instance == instance:
                return  # no such robot (the route answers 404) or another request of it took over first
            mine = s.scalar(
                select(AgentInstance).where(
                    AgentInstance.robot_id == robot_id, AgentInstance.instance_id == instance
                )
            )
            now = utcnow()
            if mine is not None and mine.superseded_at is not None:
                since = robot.agent_since.isoformat() if robot.agent_since else "an unknown time"
                refused = (
                    f"another agent with robot {robot_id}'s token took over at {since} (instance "
                    f"{robot.agent_instance}); this agent (instance {instance}) was superseded at "
                    f"{mine.superseded_at.isoformat()} and may no longer upload or poll: stop it (only one "
                    "agent may run per robot token)"
                )
                s.add(
                    AuditEntry(
                        actor=actor,
                        action="agent.refused",
                        target=f"robot:{robot_id}",
                        detail={
                            "instance": instance,
                            "current_instance": robot.agent_instance,
                            "since": since,
                        },
                    )
                )
            else:
                previous = robot.agent_instance
                if previous is not None:
                    prev = s.scalar(
                        select(AgentInstance).where(
                            AgentInstance.robot_id == robot_id, AgentInstance.instance_id == previous
                        )
                    )
                    if prev is None:
                        prev = AgentInstance(robot_id=robot_id, instance_id=previous, first_seen_at=now)
                        s.add(prev)
                    prev.superseded_at = now
                    s.add(
                        AuditEntry(
                            actor=actor,
                            action="agent.takeover",
                            target=f"robot:{robot_id}",
                            detail={
                                "instance": instance,
                                "previous_instance": previous,
                                "previous_since": robot.agent_since.isoformat()
                                if robot.agent_since
                                else None,
                            },
                        )
                    )
                    log.warning("robot %d: agent instance %s took over from %s", robot_id, instance, previous)
                if mine is None:
                    s.add(AgentInstance(robot_id=robot_id, instance_id=instance, first_seen_at=now))
                robot.agent_instance, robot.agent_since = instance, now
        if refused is not None:
            log.warning("robot %d: refused superseded agent instance %s", robot_id, instance)
            raise AgentSupersededError(refused)
