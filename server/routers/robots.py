"""``/robots``: register robots (operator), list them with their state, rotate their tokens, delete them;
a robot reports its status without a map upload (``PUT /robots/{id}/status``)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, Response, status
from sqlalchemy import func, select, update
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from server.audit import record
from server.deps import AgentChecked, AppState, OperatorDep, Principal, RobotSelf, StateDep, robot_access
from server.errors import ConflictError, NotFoundError
from server.mapstore import status_columns
from server.models import Message, Robot
from server.schemas import DbIdPath, RobotCreate, RobotCreated, RobotOut
from server.security import ROBOT_PREFIX, hash_token, new_token
from server.tokens import lock_live_issuer
from shared.protocol import RobotStatus

__all__ = ["get_robot", "router"]

router = APIRouter(prefix="/robots", tags=["robots"])


def get_robot(s: Session, robot_id: int) -> Robot:
    robot = s.get(Robot, robot_id)
    if robot is None:
        raise NotFoundError(f"no robot with id {robot_id}")
    return robot


def _out(state: AppState, robot: Robot, pending: int) -> RobotOut:
    seen, online = state.presence(robot.id, robot.last_seen_at)  # robust to wall-clock steps
    return RobotOut(
        id=robot.id,
        name=robot.name,
        created_at=robot.created_at,
        last_seen_at=seen,
        online=online,
        mode=robot.mode,
        active_kernels=robot.active_kernels,
        step_ms=robot.step_ms,
        last_error=robot.last_error,
        config=robot.config,
        kernels=robot.kernels,
        map_version=robot.map_version,
        map_session=robot.map_session,
        agent_instance=robot.agent_instance,
        agent_since=robot.agent_since,
        last_seq=robot.last_seq,
        pending_messages=pending,
        token_revoked_at=robot.token_revoked_at,
    )


def _pending(s: Session, robot_ids: list[int]) -> dict[int, int]:
    rows = s.execute(
        select(Message.robot_id, func.count())
        .where(Message.robot_id.in_(robot_ids), Message.status == "queued")
        .group_by(Message.robot_id)
    )
    return {rid: n for rid, n in rows}


@router.post("", status_code=status.HTTP_201_CREATED, response_model=RobotCreated)
def register_robot(body: RobotCreate, who: OperatorDep, state: StateDep) -> RobotCreated:
    """Register a robot; the response holds its token, shown this once."""
    token = new_token(ROBOT_PREFIX)
    try:
        with state.db.session() as s:
            robot = Robot(
                name=body.name, token_hash=hash_token(token), active_kernels={}, token_issued_by_id=who.id
            )
            s.add(robot)
            s.flush()
            lock_live_issuer(s, who)
            record(s, who, "robot.register", f"robot:{robot.id}", name=body.name)
            rid = robot.id
    except IntegrityError:
        raise ConflictError(f"a robot named {body.name!r} exists already") from None
    return RobotCreated(id=rid, name=body.name, token=token)


@router.get("", response_model=list[RobotOut])
def list_robots(who: OperatorDep, state: StateDep) -> list[RobotOut]:
    with state.db.read() as s:
        robots = list(s.scalars(select(Robot).order_by(Robot.id)))
        pending = _pending(s, [r.id for r in robots])
        return [_out(state, r, pending.get(r.id, 0)) for r in robots]


@router.get("/{robot_id}", response_model=RobotOut)
def read_robot(
    robot_id: DbIdPath, who: Annotated[Principal, Depends(robot_access)], state: StateDep
) -> RobotOut:
    with state.db.read() as s:
        robot = get_robot(s, robot_id)
        return _out(state, robot, _pending(s, [robot_id]).get(robot_id, 0))


@router.post("/{robot_id}/token", status_code=status.HTTP_201_CREATED, response_model=RobotCreated)
def rotate_robot_token(robot_id: DbIdPath, who: OperatorDep, state: StateDep) -> RobotCreated:
    """Give the robot a new token (shown this once); the old one stops working at once (on other server
    processes within ``credential_cache_s``), and so do streams opened with it. The robot keeps its map,
    messages and history; its agent needs the new token (``--token`` / ``LINEMAP_ROBOT_TOKEN``) and a
    restart. Also brings back a robot token revoked with the operator token that issued it."""
    token = new_token(ROBOT_PREFIX)
    with state.db.session() as s:
        name = s.scalar(
            update(Robot)
            .where(Robot.id == robot_id)
            .values(token_hash=hash_token(token), token_issued_by_id=who.id, token_revoked_at=None)
            .returning(Robot.name)
        )
        if name is None:
            raise NotFoundError(f"no robot with id {robot_id}")
        lock_live_issuer(s, who)
        record(s, who, "robot.token.rotate", f"robot:{robot_id}", name=name)
    state.forget_credentials()
    return RobotCreated(id=robot_id, name=name, token=token)


@router.delete("/{robot_id}", status_code=status.HTTP_204_NO_CONTENT)
def delete_robot(robot_id: DbIdPath, who: OperatorDep, state: StateDep) -> None:
    """Forget a robot, its messages and its map; its token stops working."""
    with state.db.session() as s:
        robot = get_robot(s, robot_id)
        record(s, who, "robot.delete", f"robot:{robot_id}", name=robot.name)
        s.delete(robot)
    state.forget_credentials()
    state.recent_maps.forget(robot_id)


@router.put(
    "/{robot_id}/status",
    status_code=status.HTTP_204_NO_CONTENT,
    response_class=Response,
    dependencies=[AgentChecked],
)
def report_status(robot_id: DbIdPath, body: RobotStatus, who: RobotSelf, state: StateDep) -> Response:
    """The robot's own status without a map upload (body: the status a map upload carries): a robot
    with nothing to upload reports a changed ``last_error`` this way, e.g. that its recording paused on a
    full disk. Sets the same robot columns as an upload's status (``last_error`` always: null clears
    it)."""
    changes = status_columns(body)
    seen = state.last_seen(robot_id)
    if seen is not None:
        changes["last_seen_at"] = seen
    with state.db.session() as s:
        done = s.scalar(update(Robot).where(Robot.id == robot_id).values(**changes).returning(Robot.id))
        if done is None:
            raise NotFoundError(f"no robot with id {robot_id}")
    return Response(status_code=status.HTTP_204_NO_CONTENT)  # no body, so no Content-Type
