"""Live fan-out across real `linemap server` processes on one PostgreSQL database: a control message queued
on A wakes a robot long-polling B, every map upload to A reaches a live-map viewer on B as a delta, in
order (also across a killed listener connection, and for a browser resuming with Last-Event-ID), and
``--workers`` (PostgreSQL only).

The servers re-read the database only every 60 s here (``poll_recheck_s``), so what arrives promptly
arrived through the notices, not the fallback re-read."""

from __future__ import annotations

import json
import os
import subprocess
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import httpx
from sqlalchemy import create_engine, text

from server.database import normalize_url
from tests.server.procs import LINEMAP, ServerProc, fresh_database, server_procs

SLOW_RECHECK_S = 60  # longer than every wait below: only a notice can wake a waiter in time
WAIT_S = 30.0


def _snapshot(version: int) -> dict[str, Any]:
    return {
        "version": version,
        "base_version": None,
        "stamp_s": 1.0,
        "segments": [[1, 0.0, 0.0, 1.0, 0.0]],
        "centroids": [],
        "pose": [0.0, 0.0, 0.0],
        "trajectory": [],
    }


def _delta(version: int) -> dict[str, Any]:
    return {
        "version": version,
        "base_version": version - 1,
        "stamp_s": float(version),
        "segments": [[version, float(version), 0.0, float(version), 1.0]],
        "removed": [],
        "centroids": [],
        "pose": [float(version), 0.0, 0.0],
        "trajectory": [[float(version), float(version), 0.0, 0.0]],
    }


class Viewer:
    """A live-map stream read in a thread: ``events`` collects (kind, id, data) as they arrive."""

    def __init__(self, srv: ServerProc, token: str, rid: int, last_event_id: int | None = None) -> None:
        self.events: list[tuple[str, int, dict[str, Any]]] = []
        self._client = httpx.Client(
            base_url=srv.base_url + "/api/v1",
            headers={"Authorization": f"Bearer {token}"},
            timeout=httpx.Timeout(10.0, read=None),
        )
        headers = {} if last_event_id is None else {"Last-Event-ID": str(last_event_id)}
        self._cm = self._client.stream("GET", f"/robots/{rid}/maps/stream", headers=headers)
        self._thread = threading.Thread(target=self._read, daemon=True)

    def _read(self) -> None:
        resp = self._cm.__enter__()
        assert resp.status_code == 200
        kind, ident = "", -1
        try:
            for line in resp.iter_lines():
                if line.startswith("event: "):
                    kind = line[7:]
                elif line.startswith("id: "):
                    ident = int(line[4:])
                elif line.startswith("data: "):
                    self.events.append((kind, ident, json.loads(line[6:])))
        except httpx.HTTPError:
            pass  # closed by the test

    def wait_for(self, version: int) -> list[tuple[str, int, dict[str, Any]]]:
        """The events once one has ``version`` (or what came by the deadline: readiness, not timing)."""
        deadline = time.monotonic() + WAIT_S
        while not any(v >= version for _, v, _ in self.events) and time.monotonic() < deadline:
            time.sleep(0.02)
        return list(self.events)

    def __enter__(self) -> Viewer:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._client.close()
        self._thread.join(10)


@contextmanager
def _two(tmp_path: Path) -> Iterator[tuple[ServerProc, ServerProc, str, int, str]]:
    """Servers A and B on a fresh PostgreSQL database, and a robot (id, token) registered on A."""
    with (
        fresh_database("postgresql", tmp_path) as url,
        server_procs(url, 2, poll_recheck_s=SLOW_RECHECK_S) as (procs, admin),
    ):
        a, b = procs
        with a.client(admin) as op:
            made = op.post("/robots", json={"name": "fanout-bot"}).json()
        yield a, b, admin, int(made["id"]), str(made["token"])


def _upload(srv: ServerProc, token: str, rid: int, body: dict[str, Any]) -> None:
    with srv.client(token) as robot:
        r = robot.post(f"/robots/{rid}/maps", json=body)
        assert r.status_code == 200, r.text


def test_message_queued_on_a_wakes_a_long_poll_on_b(tmp_path: Path) -> None:
    with _two(tmp_path) as (a, b, admin, rid, token):
        answer: list[httpx.Response] = []

        def poll() -> None:
            with b.client(token) as robot:
                answer.append(robot.get(f"/robots/{rid}/messages", params={"after": 0, "wait": WAIT_S}))

        poller = threading.Thread(target=poll)
        poller.start()
        with a.client(admin) as op:
            time.sleep(0.2)  # let the poll reach B and wait (were it late, it would find the message at once)
            r = op.post(
                f"/robots/{rid}/messages",
                content=b"<xml><message><mode>online</mode></message></xml>",
                headers={"Content-Type": "application/xml"},
            )
            assert r.status_code == 201, r.text
        poller.join(WAIT_S + 5)
        assert answer, "the long-poll on B did not return"
        assert [m["seq"] for m in answer[0].json()["messages"]] == [1]


def test_twenty_uploads_on_a_reach_viewers_on_b_as_twenty_deltas_in_order(tmp_path: Path) -> None:
    """Three viewers on B (they share B's reads of the log), uploads as fast as A takes them."""
    with _two(tmp_path) as (a, b, admin, rid, token):
        _upload(a, token, rid, _snapshot(1))
        with Viewer(b, admin, rid) as v1, Viewer(b, admin, rid) as v2, Viewer(b, admin, rid) as v3:
            for viewer in (v1, v2, v3):
                assert viewer.wait_for(1)[0][:2] == ("snapshot", 1)
            for v in range(2, 22):
                _upload(a, token, rid, _delta(v))
            seen = [viewer.wait_for(21) for viewer in (v1, v2, v3)]
    for events in seen:
        expected = [("snapshot", 1)] + [("delta", v) for v in range(2, 22)]
        assert [(kind, v) for kind, v, _ in events] == expected
        assert all(data["base_version"] == v - 1 for _, v, data in events[1:])
        assert events[-1][2]["segments"] == [[21, 21.0, 0.0, 21.0, 1.0]]


def _listener_pid(url: str, server_pid: int, other_than: int | None = None) -> int | None:
    engine = create_engine(normalize_url(url))
    try:
        with engine.connect() as conn:
            pid = conn.execute(
                text(
                    "SELECT pid FROM pg_stat_activity WHERE application_name = :name "
                    "AND datname = current_database() AND query = 'LISTEN linemap'"
                ),
                {"name": f"linemap-listener {server_pid}"},
            ).scalar()
    finally:
        engine.dispose()
    return None if pid is None or pid == other_than else int(pid)


def test_killed_listener_connection_reconnects_and_no_viewer_misses_a_delta(tmp_path: Path) -> None:
    with (
        fresh_database("postgresql", tmp_path) as url,
        server_procs(url, 2, poll_recheck_s=SLOW_RECHECK_S) as (procs, admin),
    ):
        a, b = procs
        with a.client(admin) as op:
            made = op.post("/robots", json={"name": "fanout-bot"}).json()
        rid, token = int(made["id"]), str(made["token"])
        _upload(a, token, rid, _snapshot(1))
        with Viewer(b, admin, rid) as viewer:
            viewer.wait_for(1)
            for v in range(2, 6):
                _upload(a, token, rid, _delta(v))
            viewer.wait_for(5)
            old = _listener_pid(url, b.proc.pid)
            assert old is not None, "B has no listener connection"
            engine = create_engine(normalize_url(url))
            with engine.connect() as conn:
                assert conn.execute(text("SELECT pg_terminate_backend(:p)"), {"p": old}).scalar()
            engine.dispose()
            for v in range(6, 11):  # while B's listener is away (or back already: either way)
                _upload(a, token, rid, _delta(v))
            deadline = time.monotonic() + WAIT_S
            new = None
            while new is None and time.monotonic() < deadline:  # readiness: B listens again
                new = _listener_pid(url, b.proc.pid, other_than=old)
                time.sleep(0.05)
            assert new is not None, "B's listener did not reconnect"
            for v in range(11, 16):
                _upload(a, token, rid, _delta(v))
            events = viewer.wait_for(15)
    assert [(kind, v) for kind, v, _ in events] == [("snapshot", 1)] + [("delta", v) for v in range(2, 16)]


def test_browser_resumes_after_last_event_id_on_another_process(tmp_path: Path) -> None:
    with _two(tmp_path) as (a, b, admin, rid, token):
        _upload(a, token, rid, _snapshot(1))
        with Viewer(a, admin, rid) as first:
            assert first.wait_for(1)[0][:2] == ("snapshot", 1)
        for v in range(2, 5):  # while the browser is away
            _upload(a, token, rid, _delta(v))
        with Viewer(b, admin, rid, last_event_id=1) as resumed:
            events = resumed.wait_for(4)
        assert [(kind, v) for kind, v, _ in events] == [("delta", 2), ("delta", 3), ("delta", 4)]
        _upload(a, token, rid, _snapshot(5))  # a snapshot upload: no delta leads past it
        _upload(a, token, rid, _delta(6))
        with Viewer(b, admin, rid, last_event_id=4) as behind:
            events = behind.wait_for(6)
        assert [(kind, v) for kind, v, _ in events] == [("snapshot", 6)]
        with b.client(admin) as op:
            bad = op.get(f"/robots/{rid}/maps/stream", headers={"Last-Event-ID": "x"})
        assert bad.status_code == 422 and "last-event-id" in bad.text.lower()


def test_two_workers_serve_one_port(tmp_path: Path) -> None:
    with (
        fresh_database("postgresql", tmp_path) as url,
        server_procs(url, 1, args=("--workers", "2"), poll_recheck_s=SLOW_RECHECK_S) as (procs, admin),
    ):
        (srv,) = procs
        with srv.client(admin) as op:
            made = op.post("/robots", json={"name": "workers-bot"}).json()
            rid, token = int(made["id"]), str(made["token"])
        _upload(srv, token, rid, _snapshot(1))
        with Viewer(srv, admin, rid) as viewer:
            viewer.wait_for(1)
            for v in range(2, 12):  # each on a new connection: the kernel spreads them over the workers
                _upload(srv, token, rid, _delta(v))
            events = viewer.wait_for(11)
        assert [(kind, v) for kind, v, _ in events] == [("snapshot", 1)] + [
            ("delta", v) for v in range(2, 12)
        ]
        assert len(_listener_pids(url)) == 2, "each worker has its own listener connection"


def _listener_pids(url: str) -> list[int]:
    engine = create_engine(normalize_url(url))
    try:
        with engine.connect() as conn:
            rows = conn.execute(
                text(
                    "SELECT pid FROM pg_stat_activity WHERE application_name LIKE 'linemap-listener %' "
                    "AND datname = current_database()"
                )
            )
            return [int(r[0]) for r in rows]
    finally:
        engine.dispose()


def test_sqlite_refuses_two_workers_naming_the_setting(tmp_path: Path) -> None:
    db = tmp_path / "one.db"
    out = subprocess.run(
        [LINEMAP, "server", "--db", str(db), "--workers", "2"],
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, "COLUMNS": "200"},
    )
    assert out.returncode == 2
    assert "--workers" in out.stderr and "PostgreSQL" in out.stderr and "one writer" in out.stderr
    assert "Traceback" not in out.stderr
    assert not db.exists(), "nothing was created"
