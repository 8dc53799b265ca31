"""``/rollouts``: roll a kernel version out to many robots, canaries first, then in waves (operators only).

Creating a rollout checks what it names (the kernel version held by the server with that sha256 and stage,
the robots registered, none of them in another active rollout of the same stage) and hands it to the
driver (:mod:`server.rolloutdriver`), which sends the updates and judges each robot's health; the state
machine is :mod:`server.rolloutplan`. Pause stops new waves (robots in flight are still judged); resume
goes on; abort stops and rolls back every robot that got the update. See docs/rollouts.md.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import replace

from fastapi import APIRouter, Request, status
from fastapi.concurrency import run_in_threadpool
from sqlalchemy import select
from sqlalchemy.orm import Session

from server.audit import record
from server.deps import AppState, OperatorDep, Principal, StateDep
from server.errors import ConflictError, InvalidRequestError, NotFoundError
from server.models import KernelArtifact, Robot, Rollout, RolloutRobot, utcnow
from server.rolloutdriver import RolloutDriver, apply_outcome, load, observe, run_of, wake
from server.rolloutplan import advance, assign_waves, stop
from server.rolloutschemas import RolloutIn, RolloutOut, RolloutRobotOut
from server.schemas import DbIdPath

__all__ = ["router"]

router = APIRouter(prefix="/rollouts", tags=["rollouts"])


def _out(s: Session, row: Rollout, *, robots: bool) -> RolloutOut:
    _view, rows = load(s, row)
    names = dict(
        s.execute(select(Robot.id, Robot.name).where(Robot.id.in_([r.robot_id for r in rows]))).all()
    )
    listed = None
    if robots:
        listed = [
            RolloutRobotOut(
                robot_id=r.robot_id,
                robot_name=names.get(r.robot_id, "?"),
                position=r.position,
                wave=r.wave,
                state=r.state,
                reason=r.reason,
                previous=r.previous,
                seq=r.seq,
                rollback_seq=r.rollback_seq,
                sent_at=r.sent_at,
                applied_at=r.applied_at,
                finished_at=r.finished_at,
                watched=r.watch,
            )
            for r in rows
        ]
    return RolloutOut(
        id=row.id,
        stage=row.stage,
        name=row.name,
        version=row.version,
        sha256=row.sha256,
        state=row.state,
        active=row.active,
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
        created_at=row.created_at,
        created_by=row.created_by,
        finished_at=row.finished_at,
        counts=dict(Counter(r.state for r in rows)),
        robots=listed,
    )


def _check_kernel(s: Session, body: RolloutIn) -> None:
    art = s.scalars(
        select(KernelArtifact).where(KernelArtifact.name == body.name, KernelArtifact.version == body.version)
    ).first()
    if art is None or art.deleted_at is not None:
        state = "was deleted" if art is not None else "is not on the server"
        raise InvalidRequestError(f"kernel {body.name} {body.version} {state}; upload it first", field="name")
    if art.sha256 != body.sha256:
        raise InvalidRequestError(
            f"sha256 {body.sha256} does not match the server's kernel {body.name} {body.version} "
            f"(sha256 {art.sha256})",
            field="sha256",
        )
    if art.stage != body.stage.value:
        raise InvalidRequestError(
            f"kernel {body.name} {body.version} is a {art.stage} kernel, not {body.stage.value}",
            field="stage",
        )


def _robot_ids(s: Session, body: RolloutIn) -> list[int]:
    known = set(s.scalars(select(Robot.id)))
    if body.robots is None:
        ids = sorted(known)
        if not ids:
            raise InvalidRequestError("no robots are registered: register robots first", field="robots")
    else:
        ids = list(body.robots)
        dupes = sorted({i for i in ids if ids.count(i) > 1})
        if dupes:
            raise InvalidRequestError(f"robots {dupes} are listed more than once", field="robots")
        unknown = [i for i in ids if i not in known]
        if unknown:
            raise InvalidRequestError(f"no robots with ids {unknown}", field="robots")
    if body.canaries > len(ids):
        robots = "1 robot" if len(ids) == 1 else f"{len(ids)} robots"
        raise InvalidRequestError(
            f"canaries {body.canaries} is more than the {robots} of the rollout", field="canaries"
        )
    busy = s.execute(
        select(RolloutRobot.robot_id, Rollout.id)
        .join(Rollout, Rollout.id == RolloutRobot.rollout_id)
        .where(Rollout.active.is_(True), Rollout.stage == body.stage.value, RolloutRobot.robot_id.in_(ids))
    ).all()
    if busy:
        taken = ", ".join(f"robot {rid} (rollout {roll})" for rid, roll in busy)
        raise ConflictError(f"already in an active {body.stage.value} rollout: {taken}; wait or abort it")
    return ids


def _create(state: AppState, body: RolloutIn, who: Principal) -> int:
    if body.watch_timeout_s < body.ack_timeout_s:
        raise InvalidRequestError(
            f"watch_timeout_s {body.watch_timeout_s:g} is shorter than ack_timeout_s {body.ack_timeout_s:g}: "
            "a robot is watched only after it timed out",
            field="watch_timeout_s",
        )
    with state.db.session() as s:
        _check_kernel(s, body)
        ids = _robot_ids(s, body)
        row = Rollout(
            stage=body.stage.value,
            name=body.name,
            version=body.version,
            sha256=body.sha256,
            state="running",
            active=True,
            canaries=body.canaries,
            wave_size=body.wave_size,
            max_failure_share=body.max_failure_share,
            commit_window_s=body.commit_window_s,
            ack_timeout_s=body.ack_timeout_s,
            watch_timeout_s=body.watch_timeout_s,
            max_step_ratio=body.max_step_ratio,
            fail_on_rollback_error=body.fail_on_rollback_error,
            wave=0,
            created_by=who.actor,
        )
        s.add(row)
        s.flush()
        for run in assign_waves(ids, body.canaries, body.wave_size):
            s.add(
                RolloutRobot(rollout_id=row.id, robot_id=run.robot_id, position=run.position, wave=run.wave)
            )
        record(
            s,
            who,
            "rollout.create",
            f"rollout:{row.id}",
            kernel=f"{body.stage.value}/{body.name}@{body.version}",
            robots=ids,
            canaries=body.canaries,
            wave_size=body.wave_size,
            max_failure_share=body.max_failure_share,
            commit_window_s=body.commit_window_s,
            ack_timeout_s=body.ack_timeout_s,
            watch_timeout_s=body.watch_timeout_s,
        )
        return row.id


def _driver(request: Request) -> RolloutDriver:
    driver: RolloutDriver = request.app.state.rollout_driver
    return driver


@router.post("", status_code=status.HTTP_201_CREATED, response_model=RolloutOut)
async def create_rollout(body: RolloutIn, request: Request, who: OperatorDep, state: StateDep) -> RolloutOut:
    """Start a rollout; its canaries are sent the update at once (the driver does the rest)."""
    rid = await run_in_threadpool(_create, state, body, who)
    queued: list[tuple[int, int]] | None = await run_in_threadpool(_driver(request).drive, rid)
    wake(state.hub, queued or [])
    return await run_in_threadpool(_read, state, rid)


def _read(state: AppState, rid: int) -> RolloutOut:
    with state.db.read() as s:
        row = s.get(Rollout, rid)
        if row is None:
            raise NotFoundError(f"no rollout with id {rid}")
        return _out(s, row, robots=True)


@router.get("", response_model=list[RolloutOut])
def list_rollouts(who: OperatorDep, state: StateDep) -> list[RolloutOut]:
    """Every rollout, newest first, with its robots counted by state."""
    with state.db.read() as s:
        rows = list(s.scalars(select(Rollout).order_by(Rollout.id.desc())))
        return [_out(s, r, robots=False) for r in rows]


@router.get("/{rollout_id}", response_model=RolloutOut)
def read_rollout(rollout_id: DbIdPath, who: OperatorDep, state: StateDep) -> RolloutOut:
    """The rollout with each robot's state and the reason."""
    return _read(state, rollout_id)


def _act(state: AppState, rid: int, action: str, who: Principal) -> list[tuple[int, int]]:
    with state.db.session() as s:
        row = s.scalars(select(Rollout).where(Rollout.id == rid).with_for_update()).first()
        if row is None:
            raise NotFoundError(f"no rollout with id {rid}")
        allowed = {"pause": ("running",), "resume": ("paused",), "abort": ("running", "paused")}[action]
        if row.state not in allowed:
            raise ConflictError(f"rollout {rid} is {row.state}; {action} needs it {' or '.join(allowed)}")
        record(s, who, f"rollout.{action}", f"rollout:{rid}")
        if action != "abort":
            row.state = "paused" if action == "pause" else "running"
            return []
        view, rows = load(s, row)
        now = utcnow()
        # first what the robots have answered since the last tick (as a paused tick judges it: no wave goes
        # out), so that a robot that has applied the update is rolled back now, not left to a later tick
        runs = tuple(run_of(r) for r in rows)
        judged = advance(replace(view, state="paused"), runs, observe(s, row.stage, rows), now)
        out = stop(judged, f"aborted by {who.actor}", now, state="aborted")
        return apply_outcome(s, state.hub, row, rows, out, now)


async def _action(rid: int, action: str, who: Principal, state: AppState) -> RolloutOut:
    wake(state.hub, await run_in_threadpool(_act, state, rid, action, who))
    return await run_in_threadpool(_read, state, rid)


@router.post("/{rollout_id}/pause", response_model=RolloutOut)
async def pause_rollout(rollout_id: DbIdPath, who: OperatorDep, state: StateDep) -> RolloutOut:
    """No further wave goes out; robots in flight are still judged (and a failure still stops it)."""
    return await _action(rollout_id, "pause", who, state)


@router.post("/{rollout_id}/resume", response_model=RolloutOut)
async def resume_rollout(rollout_id: DbIdPath, who: OperatorDep, state: StateDep) -> RolloutOut:
    """Go on with the waves of a paused rollout."""
    return await _action(rollout_id, "resume", who, state)


@router.post("/{rollout_id}/abort", response_model=RolloutOut)
async def abort_rollout(rollout_id: DbIdPath, who: OperatorDep, state: StateDep) -> RolloutOut:
    """Stop: robots not yet sent the update are skipped, every robot that got it is rolled back."""
    return await _action(rollout_id, "abort", who, state)
