"""Every robot state of a rollout through the API, with a real uvicorn server and robots simulated over
HTTP (tests/server/rolloutsim.py): pending, canary in flight, installed, rolled back with its reason (by
its health, by its own guard, and after its commit while later waves run), failed (rejected, and refused
by the server's message checks), timed out and given up at the watch deadline; and the rollout's messages
queued through the operators' path (the same checks and ``message.post`` audit entries)."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest

from shared.control import OperationKind, parse_message
from shared.signing import KeyPair, generate_keypair
from tests.server.live import BACKENDS, Live, start_live
from tests.server.rolloutsim import OLD, SimRobot, healthy, upload_kernel

Handler = Callable[[SimRobot, int, str], None]


@pytest.fixture(scope="module", params=BACKENDS)
def live(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    yield from start_live(
        request.param, tmp_path_factory.mktemp(f"rollout-states-{request.param}"), rollout_tick_s=0.05
    )


@pytest.fixture(scope="module")
def key() -> KeyPair:
    return generate_keypair()


def read(live: Live, rid: int) -> dict[str, Any]:
    with live.operator() as op:
        r = op.get(f"/rollouts/{rid}")
    assert r.status_code == 200, r.text
    return dict(r.json())


def rows(got: dict[str, Any]) -> dict[int, dict[str, Any]]:
    return {r["robot_id"]: r for r in got["robots"]}


def until(
    live: Live, rid: int, what: str, check: Callable[[dict[str, Any]], bool], serve: Callable[[], None]
) -> dict[str, Any]:
    """Serve the robots until ``check`` holds for the rollout (a readiness wait, not a timing assertion)."""
    deadline = time.monotonic() + 60
    while True:
        serve()
        got = read(live, rid)
        if check(got):
            return got
        assert time.monotonic() < deadline, (
            f"waiting for {what}: {got['state']} {got['counts']} {got['stop_reason']}"
        )
        time.sleep(0.02)


def slow(robot: SimRobot, seq: int, xml: str) -> None:
    op = parse_message(xml).operations[0]
    robot.ack(seq, "applied")
    robot.report(active=f"{op.name}@{op.version}", step_ms=30.0)


def rejects(robot: SimRobot, seq: int, xml: str) -> None:
    robot.ack(seq, "rejected", "no space left for the kernel store")


def silent(robot: SimRobot, seq: int, xml: str) -> None:
    """Receives the update and never answers (offline, stuck)."""


def audit_of(live: Live, rid: int) -> list[dict[str, Any]]:
    with live.operator() as op:
        entries = op.get("/audit", params={"limit": 1000}).json()
    return [e for e in entries if e["detail"].get("rollout") == rid]


def test_every_robot_state_through_the_api(live: Live, key: KeyPair) -> None:
    kernel = upload_kernel(live, key)
    canary, good, rejecting, stuck, slow_one, late_a, late_b = robots = [SimRobot(live) for _ in range(7)]
    behaviour: dict[int, Handler] = {
        canary.id: healthy,
        good.id: healthy,
        rejecting.id: rejects,
        stuck.id: silent,
        slow_one.id: slow,
        late_a.id: healthy,
        late_b.id: healthy,
    }
    held: set[int] = {late_a.id, late_b.id}  # wave 2 answers only when the test lets it

    def serve() -> None:
        for robot in robots:
            if robot.id not in held:
                robot.serve(lambda r, seq, xml: behaviour[r.id](r, seq, xml))

    body = {
        **kernel,
        "robots": [r.id for r in robots],
        "canaries": 1,
        "wave_size": 4,
        "max_failure_share": 0.8,
        "commit_window_s": 0.5,
        "ack_timeout_s": 4.0,  # also how long wave 2 may be held below without timing out
        "watch_timeout_s": 6.0,
        "max_step_ratio": 2.0,
    }
    with live.operator() as op:
        r = op.post("/rollouts", json=body)
    assert r.status_code == 201, r.text
    got = r.json()
    rid = got["id"]
    assert got["watch_timeout_s"] == 6.0 and got["state"] == "running" and got["active"]
    first = rows(got)
    # the canary: wave 0, sent alone; the others pending
    assert (first[canary.id]["wave"], first[canary.id]["state"]) == (0, "sent")
    assert first[canary.id]["previous"] == OLD and first[canary.id]["seq"] is not None
    assert {first[x.id]["state"] for x in robots[1:]} == {"pending"}
    assert got["counts"] == {"sent": 1, "pending": 6}

    got = until(live, rid, "the canary in its window", lambda g: rows(g)[canary.id]["state"] != "sent", serve)
    assert rows(got)[canary.id]["state"] in ("applied", "installed")
    got = until(live, rid, "wave 1 decided", lambda g: g["wave"] == 2, serve)
    by = rows(got)
    assert by[canary.id]["state"] == "installed" and by[good.id]["state"] == "installed"
    assert by[rejecting.id]["state"] == "failed"
    assert by[rejecting.id]["reason"] == "rejected by the robot: no space left for the kernel store"
    assert (
        by[slow_one.id]["state"] == "rolled-back"
        and "step time 30.0 ms is 3.00 x" in by[slow_one.id]["reason"]
    )
    assert by[slow_one.id]["rollback_seq"] is not None
    assert by[stuck.id]["state"] == "timed-out" and by[stuck.id]["watched"]
    assert "no acknowledgement within 4 s (offline or stuck?)" in by[stuck.id]["reason"]
    assert {by[x.id]["state"] for x in (late_a, late_b)} == {"sent"}, "3 of 5 failed is within 80 %"

    # while wave 2 is in flight, a committed robot of wave 1 turns three times slower: it counts
    good.report(active=f"{kernel['name']}@{kernel['version']}", step_ms=31.0)
    got = until(
        live, rid, "the committed robot judged", lambda g: rows(g)[good.id]["state"] != "installed", serve
    )
    row = rows(got)[good.id]
    assert row["state"] == "rolled-back" and row["reason"].startswith(
        "after its commit, health: step time 31.0"
    )
    assert got["state"] == "running", "4 of 7 tried failed (57 %) is within 80 %"
    serve()
    assert parse_message(good.got[-1][1]).operations[0].kind is OperationKind.ROLLBACK

    held.clear()
    got = until(
        live,
        rid,
        "completed and done watching",
        lambda g: g["state"] == "completed" and not g["active"],
        serve,
    )
    by = rows(got)
    assert got["counts"] == {"installed": 3, "failed": 1, "rolled-back": 2, "timed-out": 1}
    assert by[stuck.id]["state"] == "timed-out" and not by[stuck.id]["watched"]
    assert "no answer within 6 s: no longer watched" in by[stuck.id]["reason"]
    assert f"a rollback to {OLD} is queued behind its update" in by[stuck.id]["reason"]
    stuck.poll()
    kinds = [parse_message(xml).operations[0].kind for _, xml in stuck.got]
    assert kinds == [OperationKind.UPDATE, OperationKind.ROLLBACK], "it goes back if it ever comes back"
    assert by[stuck.id]["rollback_seq"] == stuck.got[-1][0]

    entries = audit_of(live, rid)
    actions = {(e["action"], e["target"]) for e in entries}
    for action, robot in [
        ("rollout.robot.failed", rejecting),
        ("rollout.robot.rolled_back", slow_one),
        ("rollout.robot.rolled_back", good),
        ("rollout.robot.timed_out", stuck),
        ("rollout.robot.unwatched", stuck),
        ("kernel.below_floor", stuck),
    ]:
        assert (action, f"robot:{robot.id}") in actions, action
    # every message went through the operators' queueing path: one message.post each, by the rollout
    posts = [e for e in entries if e["action"] == "message.post"]
    assert all(e["actor"] == f"rollout:{rid}" for e in posts)
    assert len(posts) == sum(len(r.got) for r in robots) == 7 + 3  # 7 updates; rollbacks: slow, good, stuck
    with live.operator() as op:
        listed = op.get(f"/robots/{stuck.id}/messages").json()["messages"]
    assert [m["created_by"] for m in listed] == [f"rollout:{rid}"] * 2


def test_an_update_the_servers_checks_refuse_fails_that_robot(live: Live, key: KeyPair) -> None:
    """The kernel version is deleted after the rollout began: the next wave's update is refused by the
    same checks as an operator's message, and its robots fail with the server's reason."""
    kernel = upload_kernel(live, key)
    robots = [SimRobot(live) for _ in range(3)]
    body = {**kernel, "robots": [r.id for r in robots], "canaries": 1, "wave_size": 2, "commit_window_s": 0.3}
    with live.operator() as op:
        r = op.post("/rollouts", json={**body, "max_failure_share": 1.0})
        assert r.status_code == 201, r.text
        rid = r.json()["id"]
        assert op.post(f"/rollouts/{rid}/pause").status_code == 200  # the canary is judged, no wave goes out
        until(
            live,
            rid,
            "the canary committed",
            lambda g: g["counts"].get("installed") == 1,
            lambda: robots[0].serve(healthy),
        )
        gone = op.delete(f"/kernels/{kernel['name']}/{kernel['version']}")
        assert gone.status_code == 204, gone.text
        assert op.post(f"/rollouts/{rid}/resume").status_code == 200
    got = until(
        live, rid, "wave 1 refused", lambda g: g["state"] == "completed" and not g["active"], lambda: None
    )
    by = rows(got)
    for robot in robots[1:]:
        assert by[robot.id]["state"] == "failed"
        assert "the server refused the update: line 1 <update>: kernel dbscan" in by[robot.id]["reason"]
        assert "was deleted; upload it first" in by[robot.id]["reason"]
        assert robot.poll() == [], "nothing was queued for it"


def test_a_watch_shorter_than_the_acknowledgement_timeout_is_refused(live: Live, key: KeyPair) -> None:
    kernel = upload_kernel(live, key)
    robot = SimRobot(live)
    body = {**kernel, "robots": [robot.id], "ack_timeout_s": 600, "watch_timeout_s": 60}
    with live.operator() as op:
        r = op.post("/rollouts", json=body)
        assert r.status_code == 422
        assert "watch_timeout_s 60 is shorter than ack_timeout_s 600" in r.json()["detail"]
        r = op.post("/rollouts", json={**body, "watch_timeout_s": 10 * 86_400})
        assert r.status_code == 422 and "watch_timeout_s" in r.json()["detail"]
    assert robot.got == [] and robot.poll() == []
