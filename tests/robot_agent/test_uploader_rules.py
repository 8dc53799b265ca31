"""The uploader's conflict rules one by one (robot_agent/uploader.py, docs/reliability/identity.md), with an
in-process transport answering each upload as scripted: a version is marked delivered only on a 200 naming
it in this Robot DB's session, and every 409 leaves the outbox as it was. The same rules against a real
server: tests/robot_agent/test_uploader_identity.py."""

from __future__ import annotations

import json
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import httpx
import pytest

from robot_agent.errors import LinkError, SupersededError
from robot_agent.link import ServerLink
from robot_agent.store import RobotDB
from robot_agent.uploader import Uploader
from tests.robot_agent.records import step_record
from tests.robot_agent.uploaders import bare_uploader

Answer = Callable[[dict[str, Any]], httpx.Response]


def _setup(tmp_path: Path, answer: Answer) -> tuple[Uploader, RobotDB, list[dict[str, Any]]]:
    sent: list[dict[str, Any]] = []

    def handle(request: httpx.Request) -> httpx.Response:
        body = json.loads(request.content)
        sent.append(body)
        return answer(body)

    db = RobotDB(tmp_path / "robot.db")
    for v in range(1, 6):
        db.record_step(step_record(v))
    link = ServerLink("http://robot.test", 1, "lmr_x", transport=httpx.MockTransport(handle))
    return bare_uploader(link, db, 1), db, sent


def _conflict(error: str, version: int, session: str | None) -> httpx.Response:
    return httpx.Response(
        409,
        json={"error": error, "detail": "scripted", "current_version": version, "current_session": session},
    )


@pytest.mark.parametrize(
    "wrong", [{"version": 4}, {"version": 5, "map_session": "00000000-0000-4000-8000-000000000000"}]
)
def test_a_200_for_another_version_or_session_marks_nothing(tmp_path: Path, wrong: dict[str, Any]) -> None:
    def answer(_body: dict[str, Any]) -> httpx.Response:
        return httpx.Response(200, json={"duplicate": False, **wrong})

    up, db, _sent = _setup(tmp_path, answer)
    with pytest.raises(LinkError, match="not marked delivered"):
        up.send_maps()
    assert db.get("uploaded_version") is None and db.outbox_size() == 5


def test_a_snapshot_confirmed_in_this_session_is_marked_and_a_delta_follows(tmp_path: Path) -> None:
    up, db, sent = _setup(
        tmp_path,
        lambda b: httpx.Response(
            200, json={"version": b["version"], "duplicate": False, "map_session": b["map_session"]}
        ),
    )
    up.send_maps()
    db.record_step(step_record(6))
    up.send_maps()
    assert [(b.get("base_version"), b["version"], b["map_session"]) for b in sent] == [
        (None, 5, db.map_session()),
        (5, 6, db.map_session()),
    ]
    assert sent[0]["map_session_reason"] == "new Robot DB" and "map_session_reason" not in sent[1]
    assert db.get("uploaded_version") == 6 and db.outbox_size() == 0


@pytest.mark.parametrize(
    ("answer", "new_session"),
    [
        (_conflict("map_session_mismatch", 900, "00000000-0000-4000-8000-000000000000"), False),
        (_conflict("conflict", 2, None), False),  # the server is behind in this session: a snapshot
        (_conflict("conflict", 900, None), True),  # ahead in this session: a new session
        (_conflict("conflict", 5, None), True),  # holds this very version already, not from this upload
        (_conflict("map_session_ended", 3, "00000000-0000-4000-8000-000000000000"), True),
    ],
)
def test_a_409_never_marks_anything_delivered(
    tmp_path: Path, answer: httpx.Response, new_session: bool
) -> None:
    up, db, sent = _setup(tmp_path, lambda _b: answer)
    db.mark_uploaded(2)  # the server confirmed 1..2 earlier: the next upload is a delta 2 -> 5
    session = db.map_session()
    up.send_maps()
    assert sent[0]["base_version"] == 2 and sent[0]["map_session"] == session
    assert db.outbox_size() == 3, "nothing more marked delivered"
    assert up.need_snapshot
    if new_session:
        assert db.map_session() != session and db.get("uploaded_version") is None
    else:
        assert db.map_session() == session and db.get("uploaded_version") == 2
    then = db.map_session()
    up.send_maps()  # a snapshot, of the session in force (the scripted server refuses it again)
    assert sent[1]["base_version"] is None and sent[1]["map_session"] == then


def test_a_superseded_agent_stops_instead_of_retrying(tmp_path: Path) -> None:
    up, db, _sent = _setup(tmp_path, lambda _b: _conflict("agent_superseded", 0, None))
    with pytest.raises(SupersededError, match="scripted"):
        up.send_maps()
    assert db.outbox_size() == 5
    stop = threading.Event()
    with pytest.raises(SupersededError):
        up.run(stop)  # not swallowed by the round's retry


@pytest.mark.parametrize(
    ("held", "stamp_s", "outcome"),
    [
        (4, 0.4, "lost answer"),  # the server holds version 4 with the stamp this robot recorded it with
        (5, 0.5, "lost answer"),
        (4, 0.41, "snapshot"),  # behind this upload, with a map this robot did not make: replaced whole
        (5, 0.51, "new session"),  # at this upload's version, a map this robot did not make
        (9, 0.9, "new session"),  # a version this robot never recorded
    ],
)
def test_a_server_ahead_with_this_robots_own_version_is_a_lost_answer(
    tmp_path: Path, held: int, stamp_s: float, outcome: str
) -> None:
    """Killed after the server applied an upload but before the answer was recorded, the robot finds the
    server ahead in its own session: the server names the version's scan stamp, and a version this robot
    recorded with that stamp is its own upload, taken as delivered; anything else is not."""

    def answer(_body: dict[str, Any]) -> httpx.Response:
        return httpx.Response(
            409,
            json={
                "error": "conflict",
                "detail": "scripted",
                "current_version": held,
                "current_session": None,
                "current_stamp_s": stamp_s,
            },
        )

    up, db, _sent = _setup(tmp_path, answer)
    db.mark_uploaded(2)
    session = db.map_session()
    assert db.stamp_of(4) == pytest.approx(0.4) and db.stamp_of(9) is None
    up.send_maps()  # a delta 2 -> 5: the server says it is at `held` already
    if outcome == "lost answer":
        assert db.map_session() == session and db.get("uploaded_version") == held
        assert db.outbox_size() == 5 - held and not up.need_snapshot
    elif outcome == "snapshot":
        assert db.map_session() == session and db.get("uploaded_version") == 2 and up.need_snapshot
    else:
        assert db.map_session() != session and db.get("uploaded_version") is None


def test_a_full_disk_reaches_the_server_although_the_repeated_upload_carried_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The Robot DB's disk fills once the server took an upload: noting the delivery fails and the round
    is retried with the same upload (same key), which the server answers from its first answer without
    applying the status it carries now ("recording paused"). That error must still reach the server, sent
    alone. Before, the uploader took the repeated upload's status as heard and the server never learnt
    that recording had paused (CI's test_agent_disk_full timed out on it)."""
    import sqlite3

    from robot_agent.health import ErrorReport
    from shared.protocol import RobotStatus
    from tests.robot_agent.agentproc import wait_for

    heard: list[str | None] = []  # the last_error values the server applied, in order
    keys: set[str] = set()

    def handle(request: httpx.Request) -> httpx.Response:
        body = json.loads(request.content)
        if request.method == "PUT":
            heard.append(body.get("last_error"))
            return httpx.Response(204)
        key = request.headers["Idempotency-Key"]
        if key not in keys:  # a repeated key is answered as first, its status not applied
            keys.add(key)
            heard.append((body.get("status") or {}).get("last_error"))
        return httpx.Response(200, json={"version": body["version"], "map_session": body["map_session"]})

    db = RobotDB(tmp_path / "robot.db")
    for v in range(1, 6):
        db.record_step(step_record(v))
    error: dict[str, str | None] = {"now": None}
    rounds = {"n": 0}
    pending = db.pending_upload

    def pending_upload(limit: int) -> Any:
        rounds["n"] += 1
        if rounds["n"] == 2:  # recording paused after the first round: the retried upload carries it
            error["now"] = "the Robot DB's disk is full: recording paused at map version 5"
        return pending(limit)

    def full(_version: int) -> None:
        raise sqlite3.OperationalError("database or disk is full")

    monkeypatch.setattr(db, "pending_upload", pending_upload)
    monkeypatch.setattr(db, "mark_uploaded", full)
    link = ServerLink("http://robot.test", 1, "lmr_x", transport=httpx.MockTransport(handle))
    stop = threading.Event()
    up = Uploader(
        link,
        db,
        lambda: RobotStatus(last_error=error["now"]),
        lambda _v: None,
        threading.Event(),
        threading.Event(),
        ErrorReport(60.0),
        robot_id=1,
        retry_base_s=0.001,
        retry_cap_s=0.01,
    )
    worker = threading.Thread(target=up.run, args=(stop,), daemon=True)
    worker.start()
    try:
        wait_for(
            "the server to hear that recording paused", lambda: any("paused" in (e or "") for e in heard), 30
        )
    finally:
        stop.set()
        worker.join(10)
    assert rounds["n"] >= 2 and len(keys) == 1
