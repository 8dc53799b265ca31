"""Map identity in the uploader (robot_agent/uploader.py, docs/reliability/identity.md): every
upload carries the Robot DB's map session, a version is marked delivered only when the server confirms it
holds it in that session, a replaced Robot DB starts a new map on the server (the old one kept, never
mixed), and a server ahead of the robot in the same session makes the robot start a new session. The
uploader runs in-process against a real server (uvicorn on 127.0.0.1, SQLite on disk) through a real
:class:`ServerLink`."""

from __future__ import annotations

import queue
import shutil
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from robot_agent.errors import SupersededError
from robot_agent.health import ErrorReport
from robot_agent.link import PollAnswer, ServerLink
from robot_agent.poller import Poller
from robot_agent.store import RobotDB
from robot_agent.uploader import Uploader
from shared.protocol import MAP_SESSION_RE
from tests.robot_agent.records import step_record
from tests.robot_agent.uploaders import bare_uploader
from tests.server.live import Live, start_live


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    yield from start_live("sqlite", tmp_path_factory.mktemp("identity-server"))


def _uploader(live: Live, rid: int, token: str, db: RobotDB, instance: str | None = None) -> Uploader:
    return bare_uploader(ServerLink(live.base_url, rid, token, instance_id=instance), db, rid)


def _drain(up: Uploader, rounds: int = 10) -> None:
    """Upload rounds until the outbox is empty (at most ``rounds``)."""
    for _ in range(rounds):
        if not up.send_maps():
            return
    raise AssertionError(f"the outbox still holds {up.db.outbox_size()} versions after {rounds} rounds")


def _record(db: RobotDB, first: int, last: int) -> None:
    for v in range(first, last + 1):
        db.record_step(step_record(v))


def _wall_ids(live: Live, rid: int, session: str | None = None) -> list[int]:
    with live.operator() as op:
        r = op.get(f"/robots/{rid}/maps/latest", params={"session": session} if session else {})
        assert r.status_code == 200, r.text
        return [int(s[0]) for s in r.json()["segments"]]


def _sessions(live: Live, rid: int) -> list[dict[str, object]]:
    with live.operator() as op:
        r = op.get(f"/robots/{rid}/maps")
        assert r.status_code == 200, r.text
        out: list[dict[str, object]] = r.json()
        return out


def test_a_new_robot_db_has_a_session_and_every_upload_carries_it(live: Live, tmp_path: Path) -> None:
    rid, token = live.new_robot()
    db = RobotDB(tmp_path / "robot.db")
    session = db.map_session()
    assert MAP_SESSION_RE.fullmatch(session)
    assert RobotDB(tmp_path / "robot.db").map_session() == session  # kept across opening
    _record(db, 1, 3)
    up = _uploader(live, rid, token, db)
    _drain(up)  # a snapshot of 1..3
    _record(db, 4, 6)
    _drain(up)  # a delta 4..6
    assert db.get("uploaded_version") == 6
    listed = _sessions(live, rid)
    assert [(s["map_session"], s["current"], s["first_version"], s["last_version"]) for s in listed] == [
        (session, True, 3, 6)
    ]


def test_a_replaced_robot_db_starts_a_new_map_and_the_old_one_is_kept(live: Live, tmp_path: Path) -> None:
    rid, token = live.new_robot()
    old = RobotDB(tmp_path / "old.db")
    _record(old, 1, 40)
    _drain(_uploader(live, rid, token, old))
    old_walls = _wall_ids(live, rid)
    assert old_walls == [40]

    new = RobotDB(tmp_path / "new.db")  # the SD card was swapped: a fresh Robot DB, a new session
    assert new.map_session() != old.map_session()
    new.record_step(step_record(1))
    _record(new, 2, 5)
    up = _uploader(live, rid, token, new)
    _drain(up)
    assert new.get("uploaded_version") == 5
    assert _wall_ids(live, rid) == [5]  # only the new session's walls
    assert _wall_ids(live, rid, old.map_session()) == old_walls  # the old map, kept whole
    listed = _sessions(live, rid)
    assert [(s["map_session"], s["current"]) for s in listed] == [
        (new.map_session(), True),
        (old.map_session(), False),
    ]
    assert listed[1]["last_version"] == 40 and listed[1]["wall_count"] == 1
    with live.operator() as op:
        audit = op.get("/audit", params={"action": "map.session.start"}).json()
    assert any(e["target"] == f"robot:{rid}" and e["detail"]["session"] == new.map_session() for e in audit)


def test_a_robot_db_restored_from_an_older_copy_starts_a_new_session(live: Live, tmp_path: Path) -> None:
    """The server holds versions 1..12 of the session; the robot's Robot DB comes back at version 5: its
    versions 6.. are other walls than the server's 6..12, so nothing may be marked delivered on the
    server's word: the robot starts a new session and the server keeps both maps apart."""
    rid, token = live.new_robot()
    path = tmp_path / "robot.db"
    db = RobotDB(path)
    session = db.map_session()
    _record(db, 1, 5)
    _drain(_uploader(live, rid, token, db))
    db.close()
    shutil.copy(path, tmp_path / "backup.db")
    db = RobotDB(path)
    _record(db, 6, 12)
    _drain(_uploader(live, rid, token, db))
    db.close()
    shutil.copy(tmp_path / "backup.db", path)  # the restore: WAL files were folded in at close

    db = RobotDB(path)
    assert db.map_session() == session and db.get("uploaded_version") == 5
    _record(db, 6, 8)
    up = _uploader(live, rid, token, db)
    up.send_maps()  # a delta 5 -> 8: refused (the server is at 12 of this session): a new session
    assert db.map_session() != session
    assert "restored from an older copy" in str(db.map_session_reason())
    assert db.get("uploaded_version") is None and db.outbox_size() == 3
    _drain(up)
    assert db.get("uploaded_version") == 8
    assert _wall_ids(live, rid) == [8]
    assert _wall_ids(live, rid, session) == [12]
    assert [(s["map_session"], s["last_version"]) for s in _sessions(live, rid)] == [
        (db.map_session(), 8),
        (session, 12),
    ]


def test_a_delta_of_another_session_is_answered_with_a_snapshot(live: Live, tmp_path: Path) -> None:
    rid, token = live.new_robot()
    a, b = RobotDB(tmp_path / "a.db"), RobotDB(tmp_path / "b.db")
    one = "00000000-0000-4000-8000-000000000001"  # one agent process (no takeover in this test)
    _record(a, 1, 3)
    up_a = _uploader(live, rid, token, a, one)
    _drain(up_a)
    _record(b, 1, 2)
    _drain(_uploader(live, rid, token, b, one))  # b's snapshot starts its session; a's session ends
    _record(a, 4, 4)
    up_a.send_maps()  # a delta of a's ended session: refused, a starts a new session
    assert a.get("uploaded_version") is None
    _drain(up_a)
    assert _wall_ids(live, rid) == [4]
    assert len(_sessions(live, rid)) == 3


def test_a_superseded_agent_is_refused_and_the_new_one_goes_on(live: Live, tmp_path: Path) -> None:
    rid, token = live.new_robot()
    a, b = RobotDB(tmp_path / "a.db"), RobotDB(tmp_path / "b.db")
    _record(a, 1, 2)
    up_a = _uploader(live, rid, token, a, "00000000-0000-4000-8000-00000000000a")
    _drain(up_a)
    _record(b, 1, 2)
    _drain(_uploader(live, rid, token, b, "00000000-0000-4000-8000-00000000000b"))  # b takes over
    _record(a, 3, 3)
    with pytest.raises(SupersededError, match="took over at"):
        up_a.send_maps()
    assert a.get("uploaded_version") == 2  # nothing more marked
    with live.operator() as op:
        robot = op.get(f"/robots/{rid}").json()
        actions = [e["action"] for e in op.get("/audit").json() if e["target"] == f"robot:{rid}"]
    assert robot["agent_instance"] == "00000000-0000-4000-8000-00000000000b"
    assert "agent.takeover" in actions and "agent.refused" in actions


def _both(first: Callable[[str], None], second: Callable[[str], None], reason: str) -> None:
    first(reason)
    second(reason)


def test_an_idle_robot_sends_its_map_again_to_a_server_that_lost_it(live: Live, tmp_path: Path) -> None:
    """A server restored from an older copy holds less than it confirmed; a robot with nothing new to
    send learns it from its next poll's answer and sends a snapshot. Here the "restored" server is a
    second robot record that holds no map, talked to with a copy of a Robot DB whose 6 versions robot
    ``first`` confirmed."""
    first, first_token = live.new_robot()
    path = tmp_path / "robot.db"
    db = RobotDB(path)
    _record(db, 1, 6)
    _drain(_uploader(live, first, first_token, db))
    session = db.map_session()
    assert db.delivered_map() == (session, 6)
    db.close()
    rid, token = live.new_robot()  # the server's record of this robot knows no map
    db = RobotDB(path)
    up = _uploader(live, rid, token, db)
    assert up.send_maps() is False  # the outbox is empty: nothing to send on its own
    told: list[str] = []
    link = up.link  # one agent: the poller and the uploader share its link
    poller = Poller(
        link,
        lambda: 0,
        lambda raw: pytest.fail(f"no message was queued: {raw}"),
        queue.Queue(),
        ErrorReport(60.0),
        poll_wait_s=0.0,
        delivered_map=db.delivered_map,
        map_lost=lambda reason: _both(told.append, up.resend_map, reason),
    )
    stop = threading.Event()
    thread = threading.Thread(target=poller.run, args=(stop,))
    thread.start()
    try:
        assert up._wake.wait(30.0), "the poll's answer did not make the uploader send the map"
    finally:
        stop.set()
        thread.join(30.0)
    assert (
        told
        and f"not version 6 of session {session}" in told[0]
        and "version 0 of map session None" in told[0]
    )
    assert up.send_maps() is True  # the snapshot
    assert up.need_snapshot is False
    assert _wall_ids(live, rid) == _wall_ids(live, first)
    with live.operator() as op:
        latest = op.get(f"/robots/{rid}/maps/latest").json()
    assert (latest["version"], latest["map_session"]) == (6, session)
    answer = link.poll_answer(0, 0.0)
    assert (answer.map_version, answer.map_session) == (6, session)
    assert up.send_maps() is False  # and nothing more once the server holds it


S, T = "00000000-0000-4000-8000-000000000001", "00000000-0000-4000-8000-000000000002"


@pytest.mark.parametrize(
    ("held", "now", "answer", "lost"),
    [
        ((S, 6), S, PollAnswer([], 6, S), False),  # the server holds what it confirmed
        ((S, 6), S, PollAnswer([], 9, S), False),  # and more (uploads during the poll)
        ((S, None), S, PollAnswer([], 0, None), False),  # nothing confirmed in this session yet
        ((S, 6), S, PollAnswer([], None, None), False),  # a server that does not say
        ((S, 6), T, PollAnswer([], 0, None), False),  # the robot began a new session during the poll
        ((S, 6), S, PollAnswer([], 5, S), True),  # restored: fewer versions of the session
        ((S, 6), S, PollAnswer([], 0, None), True),  # restored: no map at all
        ((S, 6), S, PollAnswer([], 40, T), True),  # restored to another session's map
    ],
)
def test_the_poller_tells_a_lost_map_only_when_the_server_holds_less(
    held: tuple[str, int | None], now: str, answer: PollAnswer, lost: bool
) -> None:
    told: list[str] = []
    poller = Poller(
        ServerLink("http://127.0.0.1:9", 1, "t"),  # never called here
        lambda: 0,
        lambda raw: pytest.fail("no message"),
        queue.Queue(),
        ErrorReport(60.0),
        delivered_map=lambda: (now, held[1]),
        map_lost=told.append,
    )
    poller._check_map(held, answer)
    assert bool(told) is lost, told
