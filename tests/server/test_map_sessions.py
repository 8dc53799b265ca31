"""Map identity on the server through a real server (server/mapsessions.py, server/agents.py, the messages
route's resynchronisation): one map per (robot, session), the refusals' machine-readable codes, the
listing, reading a replaced map, the SSE stream starting over on a new session, one agent per robot token,
and message numbering that continues after the robot's."""

from __future__ import annotations

import threading
from typing import Any

import httpx

from tests.server.live import Live
from tests.server.test_maps import _events

S1, S2 = "11111111-1111-4111-8111-111111111111", "22222222-2222-4222-8222-222222222222"


def _snap(session: str | None, version: int, ids: list[int]) -> dict[str, Any]:
    body: dict[str, Any] = {
        "version": version,
        "segments": [[i, float(i), 0.0, float(i), 1.0] for i in ids],
        "trajectory": [[0.1 * version, 0.0, 0.0, 0.0]],
    }
    if session is not None:
        body["map_session"] = session
    return body


def _delta(session: str, base: int, version: int, ids: list[int]) -> dict[str, Any]:
    return {**_snap(session, version, ids), "base_version": base}


def _robot(live: Live, token: str, instance: str | None = None) -> httpx.Client:
    headers = {"Authorization": f"Bearer {token}"}
    if instance is not None:
        headers["X-Linemap-Agent-Instance"] = instance
    return httpx.Client(base_url=live.base_url + "/api/v1", headers=headers, timeout=30.0)


def test_a_new_session_keeps_the_old_map_and_refusals_name_the_mismatch(live: Live) -> None:
    rid, token = live.new_robot()
    with _robot(live, token) as robot, live.operator() as op:
        assert robot.post(f"/robots/{rid}/maps", json=_snap(S1, 5, [1, 2])).json()["map_session"] == S1
        r = robot.post(f"/robots/{rid}/maps", json=_delta(S2, 5, 6, [3]))
        assert r.status_code == 409
        assert r.json()["error"] == "map_session_mismatch"
        assert r.json()["current_session"] == S1 and r.json()["current_version"] == 5
        r = robot.post(f"/robots/{rid}/maps", json=_snap(S2, 2, [7]))  # a lower version: a new map
        assert r.status_code == 200 and r.json() == {"version": 2, "duplicate": False, "map_session": S2}
        latest = op.get(f"/robots/{rid}/maps/latest").json()
        assert latest["map_session"] == S2 and [s[0] for s in latest["segments"]] == [7]
        old = op.get(f"/robots/{rid}/maps/latest", params={"session": S1}).json()
        assert old["version"] == 5 and [s[0] for s in old["segments"]] == [1, 2]
        assert len(old["trajectory"]) == 1
        for body in (_delta(S1, 5, 6, [3]), _snap(S1, 9, [3])):  # the ended session never comes back
            r = robot.post(f"/robots/{rid}/maps", json=body)
            assert r.status_code == 409 and r.json()["error"] == "map_session_ended", r.text
            assert r.json()["current_session"] == S2
        listed = op.get(f"/robots/{rid}/maps").json()
        assert [
            (m["map_session"], m["current"], m["first_version"], m["last_version"], m["wall_count"])
            for m in listed
        ] == [
            (S2, True, 2, 2, 1),
            (S1, False, 5, 5, 2),
        ]
        svg = op.get(f"/robots/{rid}/maps/export", params={"format": "svg", "session": S1})
        assert svg.status_code == 200 and svg.headers["X-Map-Version"] == "5"


def test_a_robot_from_before_sessions_keeps_its_map_when_sessions_begin(live: Live) -> None:
    rid, token = live.new_robot()
    with _robot(live, token) as robot, live.operator() as op:
        assert robot.post(f"/robots/{rid}/maps", json=_snap(None, 3, [1])).status_code == 200
        assert (
            robot.post(f"/robots/{rid}/maps", json={**_snap(None, 4, [2]), "base_version": 3}).status_code
            == 200
        )
        assert op.get(f"/robots/{rid}/maps").json()[0]["map_session"] is None
        assert robot.post(f"/robots/{rid}/maps", json=_snap(S1, 1, [9])).status_code == 200
        listed = op.get(f"/robots/{rid}/maps").json()
        assert [(m["map_session"], m["last_version"], m["wall_count"]) for m in listed] == [
            (S1, 1, 1),
            (None, 4, 2),
        ]
        r = robot.post(f"/robots/{rid}/maps", json=_snap(None, 9, [1]))  # the old agent again
        assert r.status_code == 409 and r.json()["error"] == "map_session_ended"


def test_bad_session_ids_are_refused_with_their_name(live: Live) -> None:
    rid, token = live.new_robot()
    with _robot(live, token) as robot, live.operator() as op:
        r = robot.post(f"/robots/{rid}/maps", json=_snap("AAAAAAAA-AAAA-4AAA-8AAA-AAAAAAAAAAAA", 1, [1]))
        assert r.status_code == 422 and "map_session" in r.text
        assert op.get(f"/robots/{rid}/maps/latest", params={"session": "nope"}).status_code == 422
        r = op.get(f"/robots/{rid}/maps/latest", params={"session": S2})
        assert r.status_code == 404 and S2 in r.json()["detail"]
        r = robot.get(f"/robots/{rid}/messages", headers={"X-Linemap-Agent-Instance": "not-a-uuid"})
        assert r.status_code == 422


def test_the_stream_starts_over_on_a_new_session(live: Live) -> None:
    """A new session's first version may be below the old one's: the subscriber gets a snapshot of the
    new map, not silence."""
    rid, token = live.new_robot()
    with _robot(live, token) as robot:
        robot.post(f"/robots/{rid}/maps", json=_snap(S1, 50, [1, 2, 3]))
    ready = threading.Event()

    def new_session() -> None:
        ready.wait(20)
        with _robot(live, token) as robot:
            robot.post(f"/robots/{rid}/maps", json=_snap(S2, 3, [8]))

    thread = threading.Thread(target=new_session)
    thread.start()
    got = []
    with live.operator() as op, op.stream("GET", f"/robots/{rid}/maps/stream", timeout=20) as resp:
        for event in _events(resp):
            got.append(event)
            ready.set()
            if len(got) == 2:
                break
    thread.join(20)
    (k0, first), (k1, second) = got
    assert k0 == "snapshot" and first["map_session"] == S1 and first["version"] == 50
    assert k1 == "snapshot" and second["map_session"] == S2 and second["version"] == 3
    assert [s[0] for s in second["segments"]] == [8]


def test_a_new_agent_takes_over_and_the_old_one_is_refused_everywhere(live: Live) -> None:
    rid, token = live.new_robot()
    a_id, b_id = "aaaaaaaa-aaaa-4aaa-8aaa-aaaaaaaaaaaa", "bbbbbbbb-bbbb-4bbb-8bbb-bbbbbbbbbbbb"
    with _robot(live, token, a_id) as a, _robot(live, token, b_id) as b, _robot(live, token) as legacy:
        assert a.post(f"/robots/{rid}/maps", json=_snap(S1, 1, [1])).status_code == 200
        assert b.get(f"/robots/{rid}/messages").status_code == 200  # b takes over
        for r in (
            a.post(f"/robots/{rid}/maps", json=_delta(S1, 1, 2, [2])),
            a.get(f"/robots/{rid}/messages"),
            a.post(f"/robots/{rid}/messages/1/ack", json={"outcome": "applied"}),
        ):
            assert r.status_code == 409 and r.json()["error"] == "agent_superseded", r.text
            assert "took over at" in r.json()["detail"]
        assert b.post(f"/robots/{rid}/maps", json=_delta(S1, 1, 2, [2])).status_code == 200
        assert legacy.get(f"/robots/{rid}/messages").status_code == 200  # no header: not checked
    with live.operator() as op:
        assert op.get(f"/robots/{rid}").json()["agent_instance"] == b_id
        audit = op.get("/audit", params={"target": f"robot:{rid}", "action": "agent"}).json()
    assert {e["action"] for e in audit} == {"agent.takeover", "agent.refused"}
    takeover = next(e for e in audit if e["action"] == "agent.takeover")
    assert takeover["detail"]["previous_instance"] == a_id and takeover["detail"]["instance"] == b_id


def test_numbering_continues_after_the_robots_when_the_server_is_behind(live: Live) -> None:
    """As after a restore from an older backup: the server's last message is 1, the robot has applied up
    to 4. A message queued before the robot's poll is renumbered after 4; later ones follow."""
    rid, token = live.new_robot()
    with live.operator() as op, _robot(live, token) as robot:
        xml = {"content": "<xml><message><mode>offline</mode></message></xml>"}
        headers = {"Content-Type": "application/xml"}
        assert op.post(f"/robots/{rid}/messages", headers=headers, **xml).json()["seq"] == 1  # type: ignore[arg-type]
        got = robot.get(f"/robots/{rid}/messages", params={"after": 4}).json()
        assert [m["seq"] for m in got["messages"]] == [5] and got["last_seq"] == 5
        assert op.post(f"/robots/{rid}/messages", headers=headers, **xml).json()["seq"] == 6  # type: ignore[arg-type]
        audit = op.get("/audit", params={"target": f"robot:{rid}", "action": "messages.resync"}).json()
        assert [e["detail"] for e in audit] == [
            {"robot_applied": 4, "server_last_seq": 1, "renumbered": [[1, 5]]}
        ]
        assert (
            op.get(f"/robots/{rid}/messages", params={"after": 4}).json()["last_seq"] == 6
        )  # operators: no resync


def test_a_version_number_of_a_replaced_map_names_the_new_maps_version(live: Live) -> None:
    """Versions count anew in each session: ``?version=5`` after a new session's version 5 is the new map,
    never the replaced one the server read before."""
    rid, token = live.new_robot()
    with _robot(live, token) as robot, live.operator() as op:
        robot.post(f"/robots/{rid}/maps", json=_snap(S1, 5, [1, 2]))
        assert op.get(f"/robots/{rid}/maps/latest").json()["map_session"] == S1  # read whole: kept
        r = robot.post(f"/robots/{rid}/maps", json=_snap(S2, 5, [9]))
        assert r.status_code == 200, r.text
        got = op.get(f"/robots/{rid}/maps/latest", params={"version": 5}).json()
        assert got["map_session"] == S2 and [s[0] for s in got["segments"]] == [9]
