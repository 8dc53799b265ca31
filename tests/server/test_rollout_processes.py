"""A rollout across two real `linemap server` processes on one PostgreSQL database: created on A (whose
driver then holds its lease and drives it), with robots that long-poll, acknowledge and report on B.

The servers re-read the database only every 60 s (``poll_recheck_s``), longer than any wait here, so a
long-poll on B that returns with the rollout's message was woken by A's ``NOTIFY``: the rollout's messages
take the operators' queueing path (server.msgqueue), notices included. The robots' acknowledgements on B
advance the rollout in A's view."""

from __future__ import annotations

import threading
import time
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from shared.control import OperationKind, parse_message
from shared.signing import generate_keypair, load_private_key, sha256_hex, sign_digest
from tests.server.procs import ServerProc, fresh_database, server_procs

SLOW_RECHECK_S = 60  # longer than every wait below: only a notice can wake a waiter in time
WAIT_S = 30.0
OLD = "dbscan@1.0.0"


def _kernel(a: ServerProc, admin: str) -> dict[str, str]:
    key = generate_keypair()
    source = f'"""two-process rollout kernel {uuid.uuid4().hex}"""\n'.encode()
    sig = sign_digest(load_private_key(key.private_pem), sha256_hex(source))
    with a.client(admin) as op:
        assert op.post("/keys", json={"name": "ci", "public_key": key.public_b64}).status_code == 201
        data = {"name": "dbscan", "stage": "noise-removal", "version": "1.1.0", "signature": sig}
        r = op.post("/kernels", data=data, files={"file": ("dbscan.py", source, "text/x-python")})
        assert r.status_code == 201, r.text
    return {"stage": "noise-removal", "name": "dbscan", "version": "1.1.0", "sha256": sha256_hex(source)}


class Robot:
    """A robot registered on A that talks to B only."""

    def __init__(self, a: ServerProc, b: ServerProc, admin: str, name: str) -> None:
        with a.client(admin) as op:
            made = op.post("/robots", json={"name": name}).json()
        self.id = int(made["id"])
        self.http = b.client(str(made["token"]))
        self.version = 0
        self.after = 0
        self.got: list[dict[str, Any]] = []
        self.report(OLD)

    def report(self, active: str, step_ms: float = 10.0) -> None:
        self.version += 1
        status = {"active_kernels": {"noise-removal": active}, "step_ms": step_ms, "last_error": None}
        r = self.http.post(
            f"/robots/{self.id}/maps", json={"version": self.version, "base_version": None, "status": status}
        )
        assert r.status_code == 200, r.text

    def ack(self, seq: int, outcome: str = "applied") -> None:
        r = self.http.post(f"/robots/{self.id}/messages/{seq}/ack", json={"outcome": outcome, "reason": None})
        assert r.status_code == 200, r.text


class LongPoll:
    """One long-poll of a robot's messages on B, in a thread: ``started`` (UTC) before the request,
    ``answer`` and ``returned`` (UTC) after."""

    def __init__(self, robot: Robot) -> None:
        self.robot = robot
        self.answer: list[dict[str, Any]] | None = None
        self.started = datetime.now(UTC)
        self.returned: datetime | None = None
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        r = self.robot.http.get(
            f"/robots/{self.robot.id}/messages", params={"after": self.robot.after, "wait": WAIT_S}
        )
        self.returned = datetime.now(UTC)
        assert r.status_code == 200, r.text
        self.answer = r.json()["messages"]

    def result(self) -> list[dict[str, Any]]:
        self._thread.join(WAIT_S + 10)
        assert self.answer is not None, "the long-poll on B did not return"
        self.robot.got += self.answer
        if self.answer:
            self.robot.after = self.answer[-1]["seq"]
        return self.answer


@contextmanager
def _two(tmp_path: Path) -> Iterator[tuple[ServerProc, ServerProc, str]]:
    with (
        fresh_database("postgresql", tmp_path) as url,
        server_procs(url, 2, poll_recheck_s=SLOW_RECHECK_S, rollout_tick_s=0.1) as (procs, admin),
    ):
        yield procs[0], procs[1], admin


def _read(srv: ServerProc, admin: str, rid: int) -> dict[str, Any]:
    with srv.client(admin) as op:
        r = op.get(f"/rollouts/{rid}")
    assert r.status_code == 200, r.text
    return dict(r.json())


def _until(a: ServerProc, admin: str, rid: int, what: str, check: Any) -> dict[str, Any]:
    deadline = time.monotonic() + WAIT_S
    while True:  # readiness wait on A's view, not a timing assertion
        got = _read(a, admin, rid)
        if check(got):
            return got
        assert time.monotonic() < deadline, f"waiting for {what}: {got['state']} {got['counts']}"
        time.sleep(0.05)


def _at(text: str) -> datetime:
    t = datetime.fromisoformat(text)
    return t if t.tzinfo else t.replace(tzinfo=UTC)


def test_rollout_on_a_reaches_robots_long_polling_b_and_their_acks_on_b_advance_it(tmp_path: Path) -> None:
    with _two(tmp_path) as (a, b, admin):
        kernel = _kernel(a, admin)
        target = f"{kernel['name']}@{kernel['version']}"
        canary, *wave = robots = [Robot(a, b, admin, f"bot-{i}") for i in range(3)]
        poll = LongPoll(canary)
        with a.client(admin) as op:
            body = {**kernel, "robots": [r.id for r in robots], "canaries": 1, "wave_size": 2}
            r = op.post("/rollouts", json={**body, "commit_window_s": 1.5})
            assert r.status_code == 201, r.text
        rid = r.json()["id"]
        [update] = poll.result()
        assert parse_message(update["xml"]).operations[0].kind is OperationKind.UPDATE
        assert update["created_by"] == f"rollout:{rid}"

        # the wave robots wait on B before A queues their updates (after the canary's 1.5 s window)
        polls = [LongPoll(r) for r in wave]
        canary.ack(update["seq"])
        canary.report(target)
        got = _until(a, admin, rid, "the canary committed", lambda g: g["counts"].get("installed") == 1)
        assert got["wave"] >= 1
        latency_s = []
        for p in polls:
            [msg] = p.result()
            assert parse_message(msg["xml"]).operations[0].kind is OperationKind.UPDATE
            row = next(x for x in _read(a, admin, rid)["robots"] if x["robot_id"] == p.robot.id)
            sent = _at(row["sent_at"])
            assert sent > p.started, "queued while the long-poll on B was waiting"
            assert p.returned is not None
            latency_s.append((p.returned - sent).total_seconds())
            p.robot.ack(msg["seq"])
            p.robot.report(target)
        print(f"A queued -> B's long-poll returned: {', '.join(f'{s:.3f} s' for s in latency_s)}")

        got = _until(a, admin, rid, "completed", lambda g: g["state"] == "completed" and not g["active"])
        assert got["counts"] == {"installed": 3}
        assert _read(b, admin, rid)["counts"] == {"installed": 3}, "B reads the same rollout"
        with a.client(admin) as op:
            entries = op.get("/audit", params={"limit": 1000}).json()
        posts = [e for e in entries if e["action"] == "message.post" and e["actor"] == f"rollout:{rid}"]
        assert sorted(e["target"] for e in posts) == sorted(f"robot:{r.id}" for r in robots)
        for robot in robots:
            robot.http.close()


def test_a_rollback_queued_on_a_wakes_the_canary_long_polling_b(tmp_path: Path) -> None:
    """The canary's step time triples: A stops the rollout and queues its rollback, which wakes the
    canary's long-poll on B; the other robot hears nothing."""
    with _two(tmp_path) as (a, b, admin):
        kernel = _kernel(a, admin)
        canary, other = [Robot(a, b, admin, f"bot-{i}") for i in range(2)]
        poll = LongPoll(canary)
        with a.client(admin) as op:
            body = {**kernel, "robots": [canary.id, other.id], "canaries": 1, "commit_window_s": 60}
            rid = op.post("/rollouts", json=body).json()["id"]
        [update] = poll.result()
        poll = LongPoll(canary)
        canary.ack(update["seq"])
        canary.report(f"{kernel['name']}@{kernel['version']}", step_ms=30.0)
        [rollback] = poll.result()
        op_ = parse_message(rollback["xml"]).operations[0]
        assert op_.kind is OperationKind.ROLLBACK and f"{op_.name}@{op_.version}" == OLD and op_.below_floor
        got = _read(a, admin, rid)
        assert got["state"] == "stopped" and "3.00 x" in got["stop_reason"]
        assert {r["robot_id"]: r["state"] for r in got["robots"]} == {
            canary.id: "rolled-back",
            other.id: "skipped",
        }
        r = other.http.get(f"/robots/{other.id}/messages", params={"after": 0})
        assert r.json()["messages"] == []
        for robot in (canary, other):
            robot.http.close()
