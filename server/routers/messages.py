"""``/robots/{id}/messages``: operators queue XML control messages; the robot long-polls and acknowledges.

A message is validated with the shared parser before it is queued (422 with the parser's reason and the
element otherwise), and its settings with the robot's own validation (:mod:`server.msgcheck`: 422 naming
the parameter and its range); kernel operations must name a kernel version the server holds, with its
sha256 (:mod:`server.msgqueue`, the queueing path the rollout driver takes too). Each
robot's messages are numbered 1, 2, ... in the order they were queued; the robot asks for those after the
last one it applied, so a message is delivered in order and, with the robot's own record of applied
numbers, applied once.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import random
from typing import Annotated

from fastapi import APIRouter, Depends, Query, Request, status
from fastapi.concurrency import run_in_threadpool
from sqlalchemy import and_, select

from server.admission import opened
from server.audit import record
from server.deps import (
    AgentChecked,
    AppState,
    OperatorDep,
    Principal,
    RobotSelf,
    StateDep,
    robot_access,
    still_valid,
)
from server.errors import AuthError, ConflictError, InvalidRequestError, NotFoundError, TooLargeError
from server.models import Message, Robot, utcnow
from server.msgqueue import queue_message
from server.pollsweep import message_topic
from server.routers.robots import get_robot
from server.schemas import DB_ID_MAX, AckIn, DbIdPath, MessageList, MessageOut
from shared.control import (
    MAX_MESSAGE_BYTES,
    ControlMessage,
    ControlMessageError,
    parse_message,
)

__all__ = ["WAIT_JITTER", "poll_wait_s", "router"]

log = logging.getLogger(__name__)

router = APIRouter(prefix="/robots/{robot_id}/messages", tags=["messages"])

#: A long-poll's wait ends up to this share early, at random. Polls that began together (robots reconnecting
#: after a restart, a network cut) otherwise all ended, and read again, in the same instant every round:
#: under server_load.py (100 robots, 20 s polls) each such instant held the uploads around it ~200 ms.
WAIT_JITTER = 0.1

XML_BODY = {
    "requestBody": {
        "required": True,
        "content": {"application/xml": {"schema": {"type": "string"}, "example": "<control>...</control>"}},
    }
}


def _out(m: Message) -> dict[str, object]:
    return {
        "seq": m.seq,
        "xml": m.xml,
        "created_at": m.created_at,
        "created_by": m.created_by,
        "status": m.status,
        "reason": m.reason,
        "acked_at": m.acked_at,
    }


def _queue(
    state: AppState, robot_id: int, xml: str, msg: ControlMessage, who: Principal
) -> dict[str, object]:
    with state.db.session() as s:
        return _out(queue_message(s, state.hub, robot_id, xml, msg, who.actor))


@router.post("", status_code=status.HTTP_201_CREATED, response_model=MessageOut, openapi_extra=XML_BODY)
async def post_message(
    robot_id: DbIdPath, request: Request, who: OperatorDep, state: StateDep
) -> dict[str, object]:
    """Queue a control message (XML body, docs/design.md §6); 422 names the element and the reason if it is
    rejected."""
    body = await request.body()
    if len(body) > MAX_MESSAGE_BYTES:
        raise TooLargeError(f"control message of {len(body)} bytes; the limit is {MAX_MESSAGE_BYTES}")
    try:
        msg = parse_message(body)
    except ControlMessageError as exc:
        raise InvalidRequestError(str(exc), element=exc.element, line=exc.line, reason=exc.reason) from None
    try:
        xml = body.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InvalidRequestError(
            f"control message is not UTF-8 (byte {exc.start}): send it encoded as UTF-8",
            element=None,
            line=None,
        ) from None
    out = await run_in_threadpool(_queue, state, robot_id, xml, msg, who)
    state.hub.publish(message_topic(robot_id), out["seq"])
    return out


#: the robot's numbering and map, and its messages above ``after`` (one row with no message when there is
#: none): one statement, so one round trip on PostgreSQL for a poll's read (it was two, after the pool's ping)
_MESSAGE_COLUMNS = (
    Message.seq,
    Message.xml,
    Message.created_at,
    Message.created_by,
    Message.status,
    Message.reason,
    Message.acked_at,
)


def _read(state: AppState, robot_id: int, after: int, limit: int) -> dict[str, object]:
    """One long-poll read: the messages after ``after`` and the robot's numbering and map, in one
    statement (the robot's row left-joined to its messages above ``after``, in order; the row is read as
    three columns, not as the ORM object, whose JSON columns, its configuration and kernels, would be
    decoded at every read of every waiting poll). O(messages returned)."""
    robots, messages = Robot.__table__, Message.__table__
    q = (
        select(Robot.last_seq, Robot.map_version, Robot.map_session, *_MESSAGE_COLUMNS)
        .select_from(robots.outerjoin(messages, and_(Message.robot_id == Robot.id, Message.seq > after)))
        .where(Robot.id == robot_id)
        .order_by(Message.seq)
        .limit(limit)
    )
    with state.db.read() as s:
        rows = s.execute(q).all()
    if not rows:
        raise NotFoundError(f"no robot with id {robot_id}")
    first = rows[0]
    names = [c.key for c in _MESSAGE_COLUMNS]
    return {
        "messages": [dict(zip(names, r[3:], strict=True)) for r in rows if r[3] is not None],
        "last_seq": first[0],
        "map_version": first[1],
        "map_session": first[2],
    }


def _resync(state: AppState, robot_id: int, applied: int, who: Principal) -> None:
    """The robot has applied messages up to ``applied`` but the server's numbering is behind it (its
    database was restored from an older backup): continue the numbering after the robot's, so that no new
    message is skipped by the robot as one it applied. Queued messages numbered at or below ``applied``
    get new numbers after it (in their order); an audit entry ``messages.resync`` says what changed.
    O(queued messages)."""
    with state.db.session() as s:
        robot = get_robot(s, robot_id)
        if robot.last_seq >= applied:
            return  # another request resynchronised first
        queued = list(
            s.scalars(
                select(Message)
                .where(Message.robot_id == robot_id, Message.status == "queued", Message.seq <= applied)
                .order_by(Message.seq)
            )
        )
        moved = []
        for i, m in enumerate(queued, start=1):
            moved.append([m.seq, applied + i])
            m.seq = applied + i
        old, robot.last_seq = robot.last_seq, applied + len(queued)
        record(
            s,
            who,
            "messages.resync",
            f"robot:{robot_id}",
            robot_applied=applied,
            server_last_seq=old,
            renumbered=moved,
        )
    log.warning(
        "robot %d has applied messages up to %d but the server's numbering was at %d (database restored "
        "from a backup?): numbering continues after %d; renumbered %s",
        robot_id,
        applied,
        old,
        applied,
        moved or "none",
    )


@router.get("", response_model=MessageList, dependencies=[AgentChecked])
async def list_messages(
    robot_id: DbIdPath,
    request: Request,
    who: Annotated[Principal, Depends(robot_access)],
    state: StateDep,
    after: Annotated[int, Query(ge=0, le=DB_ID_MAX, description="Return messages with seq above this.")] = 0,
    wait: Annotated[float, Query(ge=0, description="Long-poll: wait up to this many seconds.")] = 0.0,
    limit: Annotated[int, Query(ge=1, le=1000)] = 100,
) -> dict[str, object]:
    """Messages after ``after`` in order; with ``wait`` > 0 the call returns as soon as one is queued
    (long-poll; at most the server's ``long_poll_max_s``), or with an empty list when the wait is over
    (up to 10 % early, at random, so that polls begun together do not stay in step).
    The robot's own ``after`` is the highest message it applied: when the server's numbering is behind it
    (a database restored from a backup) the numbering continues after it (see ``_resync``)."""
    resync = who.kind == "robot" and after > 0  # the robot's own poll: is the server's numbering behind?
    loop = asyncio.get_running_loop()
    deadline = loop.time() + poll_wait_s(wait, state.settings.long_poll_max_s, random.random())
    recheck = state.settings.poll_recheck_s
    # Woken by the hub when a message is queued (any process); the safety net against a missed wake-up is
    # one read for every waiting poll of the process (server.pollsweep), not a re-read per poll.
    # Subscribed before the first read (a wake-up between the read and the wait is not lost); counted by the
    # safety net once the first read found nothing (it reads the numbering itself, whenever that came).
    with state.hub.subscribe(message_topic(robot_id)) as queue, contextlib.ExitStack() as watching:
        waited = False
        while True:
            out = await run_in_threadpool(_read, state, robot_id, after, limit)
            if resync and after > int(out["last_seq"]):  # type: ignore[call-overload]
                await run_in_threadpool(_resync, state, robot_id, after, who)
                state.hub.publish(message_topic(robot_id), after)
                out = await run_in_threadpool(_read, state, robot_id, after, limit)
            resync = False
            if out["messages"] and waited and not await still_valid(request, state):
                raise AuthError("unknown or revoked token")  # revoked while the poll waited
            if out["messages"] or deadline - loop.time() <= 0 or await request.is_disconnected():
                return out
            if not waited:
                watching.enter_context(state.polls.watch(robot_id, after))
                opened(request)  # the next long-poll may open (server.admission)
            waited = True
            if not await _woken(queue, request, deadline, recheck):
                return out  # the client went away (or the server is stopping): no read for nobody


def poll_wait_s(wait_s: float, max_s: float, u: float) -> float:
    """How long a long-poll asking for ``wait_s`` waits at most (s): ``wait_s`` capped at ``max_s`` (the
    server's ``long_poll_max_s``), shortened by up to :data:`WAIT_JITTER` of itself as ``u`` (uniform in
    [0, 1)) goes from 0 to 1. O(1)."""
    return min(wait_s, max_s) * (1.0 - WAIT_JITTER * u)


async def _woken(queue: asyncio.Queue[object], request: Request, deadline: float, recheck_s: float) -> bool:
    """Wait for a wake-up on ``queue`` or the ``deadline`` (loop time): True, then the poll reads again
    (at the deadline, once, so that its answer carries the numbering of now). False as soon as the client
    has gone, checked every ``recheck_s`` (no database read for it)."""
    loop = asyncio.get_running_loop()
    while (remaining := deadline - loop.time()) > 0:
        try:
            await asyncio.wait_for(queue.get(), timeout=min(remaining, recheck_s))
            return True
        except TimeoutError:
            if await request.is_disconnected():
                return False
    return True


@router.get("/{seq}", response_model=MessageOut)
def read_message(
    robot_id: DbIdPath, seq: DbIdPath, who: Annotated[Principal, Depends(robot_access)], state: StateDep
) -> dict[str, object]:
    with state.db.read() as s:
        m = s.scalars(select(Message).where(Message.robot_id == robot_id, Message.seq == seq)).first()
        if m is None:
            raise NotFoundError(f"robot {robot_id} has no message {seq}")
        return _out(m)


def _ack(state: AppState, robot_id: int, seq: int, outcome: str, reason: str | None) -> dict[str, object]:
    with state.db.session() as s:
        m = s.scalars(select(Message).where(Message.robot_id == robot_id, Message.seq == seq)).first()
        if m is None:
            raise NotFoundError(f"robot {robot_id} has no message {seq}")
        if m.status != "queued":
            if m.status == outcome:
                return _out(m)  # a retried acknowledgement
            if m.status == "applied" and outcome == "rolled-back":
                m.status, m.reason, m.acked_at = outcome, reason, utcnow()
                state.hub.announce(s.connection(), f"acks:{robot_id}", seq)
                return _out(m)
            raise ConflictError(
                f"message {seq} was acknowledged as {m.status} already; cannot change it to {outcome}"
            )
        m.status, m.reason, m.acked_at = outcome, reason, utcnow()
        state.hub.announce(s.connection(), f"acks:{robot_id}", seq)
        return _out(m)


@router.post("/{seq}/ack", response_model=MessageOut, dependencies=[AgentChecked])
async def acknowledge(
    robot_id: DbIdPath, seq: DbIdPath, body: AckIn, who: RobotSelf, state: StateDep
) -> dict[str, object]:
    """The robot reports what became of message ``seq``: applied, or rejected with the reason."""
    out = await run_in_threadpool(_ack, state, robot_id, seq, body.outcome, body.reason)
    state.hub.publish(f"acks:{robot_id}", out)
    return out
