"""Rollouts through a real uvicorn server, with robots simulated by HTTP clients that poll their messages,
acknowledge them and report their status with map uploads, as the agent does."""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from server.rolloutdriver import RolloutDriver
from shared.control import OperationKind, parse_message
from shared.signing import KeyPair, generate_keypair
from tests.server.live import BACKENDS, Live, start_live
from tests.server.rolloutsim import OLD, SimRobot, healthy, upload_kernel


@pytest.fixture(scope="module", params=BACKENDS)
def fast(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    """A server whose rollout driver ticks every 50 ms."""
    yield from start_live(
        request.param, tmp_path_factory.mktemp(f"rollouts-{request.param}"), rollout_tick_s=0.05
    )


@pytest.fixture(scope="module")
def key() -> KeyPair:
    return generate_keypair()


def start(live: Live, kernel: dict[str, str], robots: list[SimRobot], **kw: Any) -> dict[str, Any]:
    body = {**kernel, "robots": [r.id for r in robots], "commit_window_s": 0.3, **kw}
    with live.operator() as op:
        r = op.post("/rollouts", json=body)
    assert r.status_code == 201, r.text
    return dict(r.json())


def read(live: Live, rid: int) -> dict[str, Any]:
    with live.operator() as op:
        r = op.get(f"/rollouts/{rid}")
    assert r.status_code == 200, r.text
    return dict(r.json())


def run_until(
    live: Live, rid: int, robots: list[SimRobot], on_update: Callable[[SimRobot, int, str], None], done: str
) -> dict[str, Any]:
    """Serve the robots until the rollout is ``done`` (a state) and has nothing left in flight."""
    deadline = time.monotonic() + 60
    while True:  # readiness wait on the rollout's state, not a timing assertion
        for robot in robots:
            robot.serve(on_update)
        got = read(live, rid)
        if got["state"] == done and not got["active"]:
            for robot in robots:  # the messages of the last tick (rollbacks)
                robot.serve(on_update)
            return got
        assert time.monotonic() < deadline, f"rollout still {got['state']}: {got['counts']}"
        time.sleep(0.02)


def op_audit(live: Live) -> list[dict[str, Any]]:
    with live.operator() as op:
        return list(op.get("/audit", params={"limit": 1000}).json())


def by_robot(got: dict[str, Any]) -> dict[int, dict[str, Any]]:
    return {r["robot_id"]: r for r in got["robots"]}


def test_healthy_rollout_completes_wave_after_wave(fast: Live, key: KeyPair) -> None:
    kernel = upload_kernel(fast, key)
    robots = [SimRobot(fast) for _ in range(7)]
    rollout = start(fast, kernel, robots, canaries=1, wave_size=3)
    got = run_until(fast, rollout["id"], robots, healthy, "completed")
    assert got["counts"] == {"installed": 7}
    rows = got["robots"]
    assert [r["wave"] for r in rows] == [0, 1, 1, 1, 2, 2, 2]
    for wave in (1, 2):  # a wave goes out only after the one before is committed
        before = max(r["finished_at"] for r in rows if r["wave"] == wave - 1)
        assert all(r["sent_at"] >= before for r in rows if r["wave"] == wave)
    assert all(r["previous"] == OLD for r in rows)
    with fast.operator() as op:
        audit = [
            e
            for e in op.get("/audit", params={"limit": 1000}).json()
            if e["detail"].get("rollout") == got["id"]
        ]
    actions = Counter(e["action"] for e in audit)
    assert actions["rollout.wave"] == 3 and actions["rollout.robot.committed"] == 7
    assert actions["rollout.completed"] == 1
    created = [
        e for e in op_audit(fast) if e["action"] == "rollout.create" and e["target"] == f"rollout:{got['id']}"
    ]
    assert created and created[0]["actor"] == "operator:admin"


def test_failing_canary_of_ten_stops_rolls_it_back_and_leaves_nine_untouched(
    fast: Live, key: KeyPair
) -> None:
    """The canary's step time triples under the new kernel: the rollout stops after it, sends it
    ``<kernel-rollback below-floor="allow">`` to the version it ran before, and no other robot hears of
    it."""
    kernel = upload_kernel(fast, key)
    robots = [SimRobot(fast) for _ in range(10)]

    def slow(robot: SimRobot, seq: int, xml: str) -> None:
        op = parse_message(xml).operations[0]
        robot.ack(seq, "applied")
        robot.report(active=f"{op.name}@{op.version}", step_ms=30.0)

    rollout = start(fast, kernel, robots, canaries=1, wave_size=3, max_step_ratio=2.0, commit_window_s=30.0)
    got = run_until(fast, rollout["id"], robots, slow, "stopped")
    assert "canary robot" in got["stop_reason"] and "3.00 x" in got["stop_reason"]
    assert got["counts"] == {"rolled-back": 1, "skipped": 9}
    canary = robots[0]
    row = by_robot(got)[canary.id]
    assert row["state"] == "rolled-back" and "step time 30.0 ms" in row["reason"]
    rollback = parse_message(canary.got[-1][1]).operations[0]
    assert rollback.kind is OperationKind.ROLLBACK and rollback.below_floor
    assert f"{rollback.name}@{rollback.version}" == OLD and row["rollback_seq"] == canary.got[-1][0]
    for other in robots[1:]:
        assert other.got == [], "no message reached the other nine"
        assert by_robot(got)[other.id]["state"] == "skipped"
    with fast.operator() as op:
        audit = op.get("/audit", params={"limit": 1000}).json()
    mine = {(e["action"], e["target"]) for e in audit if e["detail"].get("rollout") == got["id"]}
    assert ("rollout.stopped", f"rollout:{got['id']}") in mine
    assert ("rollout.robot.rolled_back", f"robot:{canary.id}") in mine
    assert ("kernel.below_floor", f"robot:{canary.id}") in mine


def test_robot_that_rolls_back_itself_fails_with_its_reason(fast: Live, key: KeyPair) -> None:
    kernel = upload_kernel(fast, key)
    robots = [SimRobot(fast) for _ in range(3)]

    def raises(robot: SimRobot, seq: int, xml: str) -> None:
        robot.ack(seq, "applied")
        robot.ack(seq, "rolled-back", "kernel raised in service: ZeroDivisionError: division by zero")
        robot.report(active=OLD, last_error="rolled back: kernel raised in service")

    rollout = start(fast, kernel, robots, canaries=1, wave_size=2)
    got = run_until(fast, rollout["id"], robots, raises, "stopped")
    row = by_robot(got)[robots[0].id]
    assert row["state"] == "rolled-back" and "ZeroDivisionError" in row["reason"]
    assert row["rollback_seq"] is None, "the robot put its previous kernel back itself"
    assert got["counts"] == {"rolled-back": 1, "skipped": 2}


def test_stuck_robot_times_out_and_the_others_go_on(fast: Live, key: KeyPair) -> None:
    kernel = upload_kernel(fast, key)
    robots = [SimRobot(fast) for _ in range(4)]
    stuck = robots[2]

    def maybe(robot: SimRobot, seq: int, xml: str) -> None:
        if robot is not stuck:
            healthy(robot, seq, xml)

    # 3 s: the healthy robots, served in the loop below, answer well within it even on a loaded machine
    rollout = start(fast, kernel, robots, canaries=1, wave_size=3, max_failure_share=0.5, ack_timeout_s=3.0)
    deadline = time.monotonic() + 60
    while True:  # the stuck robot is watched after the rollout completes: wait for the states only
        for robot in robots:
            robot.serve(maybe)
        got = read(fast, rollout["id"])
        if got["state"] == "completed":
            break
        assert time.monotonic() < deadline, got
        time.sleep(0.02)
    states = {rid: (r["state"], r["reason"]) for rid, r in by_robot(got).items()}
    assert states[stuck.id][0] == "timed-out" and "no acknowledgement within 3 s" in states[stuck.id][1]
    assert [states[r.id][0] for r in robots if r is not stuck] == ["installed"] * 3
    assert got["active"], "the stuck robot's update may still be applied: watched"
    healthy(stuck, stuck.got[0][0], stuck.got[0][1])  # it comes back and applies it late
    got = run_until(fast, rollout["id"], robots, maybe, "completed")
    row = by_robot(got)[stuck.id]
    assert row["state"] == "rolled-back" and "applied later" in row["reason"]
    assert parse_message(stuck.got[-1][1]).operations[0].kind is OperationKind.ROLLBACK


def test_pause_resume_abort(fast: Live, key: KeyPair) -> None:
    kernel = upload_kernel(fast, key)
    robots = [SimRobot(fast) for _ in range(4)]
    rollout = start(fast, kernel, robots, canaries=1, wave_size=2, commit_window_s=0.2)
    rid = rollout["id"]
    with fast.operator() as op:
        assert op.post(f"/rollouts/{rid}/pause").json()["state"] == "paused"
        again = op.post(f"/rollouts/{rid}/pause")
        assert again.status_code == 409 and "paused" in again.json()["detail"]
    # the canary is judged while paused, but no wave goes out
    deadline = time.monotonic() + 60
    while by_robot(read(fast, rid))[robots[0].id]["state"] != "installed":
        robots[0].serve(healthy)
        assert time.monotonic() < deadline
        time.sleep(0.02)
    got = read(fast, rid)
    assert got["counts"] == {"installed": 1, "pending": 3}
    with fast.operator() as op:
        assert op.post(f"/rollouts/{rid}/resume").json()["state"] == "running"
    deadline = time.monotonic() + 60
    while read(fast, rid)["counts"].get("sent", 0) + read(fast, rid)["counts"].get("applied", 0) < 2:
        assert time.monotonic() < deadline
        time.sleep(0.02)
    robots[1].serve(healthy)  # one of wave 1 applies; the other has not answered yet
    with fast.operator() as op:
        r = op.post(f"/rollouts/{rid}/abort")
        assert r.status_code == 200, r.text
        got = r.json()
    assert got["state"] == "aborted" and got["stop_reason"] == "aborted by operator:admin"
    states = {rid_: r["state"] for rid_, r in by_robot(got).items()}
    assert states[robots[0].id] == "rolled-back" and states[robots[1].id] == "rolled-back"
    assert states[robots[2].id] == "sent" and states[robots[3].id] == "skipped"
    got = run_until(fast, rid, robots, healthy, "aborted")  # robot 3 applies late: rolled back too
    assert by_robot(got)[robots[2].id]["state"] == "rolled-back"
    assert robots[3].got == []
    with fast.operator() as op:
        assert op.post(f"/rollouts/{rid}/resume").status_code == 409
        assert op.get("/rollouts").json()[0]["id"] >= rid


def test_bad_requests_name_what_is_wrong(fast: Live, key: KeyPair) -> None:
    kernel = upload_kernel(fast, key)
    robot = SimRobot(fast)
    with fast.operator() as op:
        cases = [
            ({**kernel, "robots": [robot.id, 999999]}, 422, "no robots with ids [999999]"),
            ({**kernel, "robots": [robot.id, robot.id]}, 422, "more than once"),
            ({**kernel, "robots": [robot.id], "sha256": "0" * 64}, 422, "does not match"),
            ({**kernel, "robots": [robot.id], "version": "9.9.9"}, 422, "upload it first"),
            ({**kernel, "robots": [robot.id], "stage": "clustering"}, 422, "not clustering"),
            ({**kernel, "robots": [robot.id], "canaries": 2}, 422, "canaries 2 is more than the 1"),
            ({**kernel, "robots": [robot.id], "max_failure_share": 1.5}, 422, "max_failure_share"),
            ({**kernel, "robots": [2**63]}, 422, "robots.0"),
        ]
        for body, code, needle in cases:
            r = op.post("/rollouts", json=body)
            assert r.status_code == code and needle in r.json()["detail"], (body, r.text)
        assert op.get("/rollouts/999999").status_code == 404
        assert op.post("/rollouts/999999/abort").status_code == 404
        first = op.post("/rollouts", json={**kernel, "robots": [robot.id], "commit_window_s": 3600})
        assert first.status_code == 201
        busy = op.post("/rollouts", json={**kernel, "robots": [robot.id]})
        assert busy.status_code == 409 and f"robot {robot.id}" in busy.json()["detail"]
        assert op.post(f"/rollouts/{first.json()['id']}/abort").status_code == 200
    assert robot.http.get("/rollouts").status_code == 403, "operators only"
    assert robot.http.post("/rollouts", json={**kernel, "robots": [robot.id]}).status_code == 403


def test_one_process_drives_a_rollout_at_a_time(fast: Live, key: KeyPair) -> None:
    """A second driver (another server process) skips a rollout whose lease the first holds."""
    kernel = upload_kernel(fast, key)
    robot = SimRobot(fast)
    rollout = start(fast, kernel, [robot], commit_window_s=3600)
    mine = fast.app.state.rollout_driver
    other = RolloutDriver(fast.state, owner="other-process")
    assert other.drive(rollout["id"]) is None, "the serving process holds the lease"
    assert mine.drive(rollout["id"]) is not None
    with fast.operator() as op:
        assert op.post(f"/rollouts/{rollout['id']}/abort").status_code == 200


def test_restarted_server_resumes_its_rollouts(tmp_path: Path, key: KeyPair) -> None:
    """The rollout survives a server restart on the same database: the new process drives it on."""
    servers = start_live("sqlite", tmp_path, rollout_tick_s=0.05)
    first = next(servers)
    kernel = upload_kernel(first, key)
    robots = [SimRobot(first) for _ in range(3)]
    rollout = start(first, kernel, robots, canaries=1, wave_size=2, commit_window_s=0.2)
    deadline = time.monotonic() + 60
    # the canary applied (its 0.2 s window may end between two reads: installed is as good; the wave's
    # robots are not served, so the rollout is still running at the restart)
    while by_robot(read(first, rollout["id"]))[robots[0].id]["state"] not in ("applied", "installed"):
        robots[0].serve(healthy)
        assert time.monotonic() < deadline
        time.sleep(0.02)
    for robot in robots:
        robot.http.close()
    for _ in servers:  # runs start_live to its end: uvicorn stops, the lifespan releases the leases
        pass
    from server.app import create_app
    from server.settings import Settings
    from tests.server.live import ServerThread

    app = create_app(Settings(database_url=f"sqlite:///{tmp_path / 'server.db'}", rollout_tick_s=0.05))
    with ServerThread(app) as srv:
        second = Live(f"http://127.0.0.1:{srv.port}", first.admin_token, app.state.linemap, "sqlite", app)
        for robot in robots:
            robot.http = second.client(robot.http.headers["Authorization"].split()[1])
        got = run_until(second, rollout["id"], robots, healthy, "completed")
    assert got["counts"] == {"installed": 3}
