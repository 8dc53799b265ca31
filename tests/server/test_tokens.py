"""Token lifecycle through the real server (each backend): robot token rotation, operator token expiry,
revocation cascading to the tokens a token created."""

from __future__ import annotations

import threading
from datetime import UTC, datetime, timedelta

import httpx
import pytest
from sqlalchemy import update

from robot_agent.errors import LinkError
from robot_agent.link import ServerLink
from server.deps import SESSION_COOKIE
from server.models import OperatorToken, utcnow
from tests.server.live import Live


def _mint(live: Live, token: str, name: str, **body: object) -> httpx.Response:
    with live.client(token) as c:
        return c.post("/tokens", json={"name": name, **body})


def _works(live: Live, token: str) -> bool:
    with live.client(token) as c:
        code = c.get("/whoami").status_code
    assert code in (200, 401)
    return code == 200


def test_rotating_a_robot_token_stops_the_old_one_at_once(live: Live) -> None:
    rid, old = live.new_robot()
    with live.operator() as op:
        r = op.post(f"/robots/{rid}/token")
        assert r.status_code == 201, r.text
        new = r.json()["token"]
        assert r.json()["id"] == rid and new != old and new.startswith("lmr_")
        assert op.post("/robots/999999/token").status_code == 404
        entry = op.get("/audit", params={"limit": 5}).json()
        assert any(e["action"] == "robot.token.rotate" and e["target"] == f"robot:{rid}" for e in entry)
        assert new not in str(entry) and old not in str(entry)  # the audit log never holds a secret
    assert not _works(live, old) and _works(live, new)
    # The agent's own link: the old token is refused, the new one polls (the robot keeps its history).
    stale, fresh = ServerLink(live.base_url, rid, old), ServerLink(live.base_url, rid, new)
    try:
        with pytest.raises(LinkError) as exc:
            stale.poll(0, 0)
        assert exc.value.status == 401
        assert fresh.poll(0, 0) == []
    finally:
        stale.close()
        fresh.close()
    with live.client(new) as robot:  # a robot cannot rotate tokens itself
        assert robot.post(f"/robots/{rid}/token").status_code == 403


def test_a_stream_opened_with_a_rotated_robot_token_ends(live: Live) -> None:
    rid, old = live.new_robot()
    ended, lines = threading.Event(), list[str]()

    def read() -> None:
        with live.client(old) as c, c.stream("GET", f"/robots/{rid}/maps/stream", timeout=30) as r:
            assert r.status_code == 200
            lines.extend(r.iter_lines())
        ended.set()

    reader = threading.Thread(target=read)
    reader.start()
    deadline = datetime.now(UTC) + timedelta(seconds=30)
    while not any(line.startswith("event: snapshot") for line in lines):
        assert datetime.now(UTC) < deadline
    with live.operator() as op:
        assert op.post(f"/robots/{rid}/token").status_code == 201
    assert ended.wait(10), "the stream outlived its rotated token"
    reader.join(5)


def test_operator_token_expiry(live: Live) -> None:
    r = _mint(live, live.admin_token, "temp", expires_in_s=3600)
    assert r.status_code == 201, r.text
    temp = r.json()
    assert temp["expires_at"] is not None and _works(live, temp["token"])
    at = datetime.fromisoformat(temp["expires_at"])
    assert timedelta(seconds=3590) < at - datetime.now(UTC) <= timedelta(seconds=3600)
    # A token cannot outlive its creator: inherited by default, refused when asked for later.
    child = _mint(live, temp["token"], "child").json()
    assert child["expires_at"] == temp["expires_at"]
    late = _mint(live, temp["token"], "late", expires_in_s=7200)
    assert late.status_code == 422 and "cannot outlive its creator" in late.json()["detail"]
    with live.client() as browser:  # a session of the token ends with it
        assert browser.post("/session", json={"token": temp["token"]}).status_code == 200
        sid = browser.cookies[SESSION_COOKIE]
    # Bad expiries: clear 422s naming the problem.
    past = (datetime.now(UTC) - timedelta(seconds=5)).isoformat()
    assert "not in the future" in _mint(live, live.admin_token, "x", expires_at=past).json()["detail"]
    both = _mint(live, live.admin_token, "x", expires_at=at.isoformat(), expires_in_s=5)
    assert both.status_code == 422 and "not both" in both.json()["detail"]
    naive = _mint(live, live.admin_token, "x", expires_at="2030-01-01T00:00:00")
    assert naive.status_code == 422 and "expires_at" in naive.json()["detail"]
    for bad in (0, -1, "inf", 1e12):
        assert _mint(live, live.admin_token, "x", expires_in_s=bad).status_code == 422
    # Expiry reached (white-box: moved into the past): the token, its child and its session are refused.
    with live.state.db.session() as s:
        s.execute(update(OperatorToken).where(OperatorToken.id == temp["id"]).values(expires_at=utcnow()))
    live.state.forget_credentials()
    assert not _works(live, temp["token"])
    assert _works(live, child["token"])  # its own expiry is still ahead (the same time, not moved)
    with live.client(cookies={SESSION_COOKIE: sid}) as browser:
        assert browser.get("/robots").status_code == 401
    assert _mint(live, temp["token"], "after").status_code == 401


def test_revoking_a_token_revokes_what_it_created(live: Live) -> None:
    t1 = _mint(live, live.admin_token, "t1").json()
    t2 = _mint(live, t1["token"], "t2").json()
    t3 = _mint(live, t2["token"], "t3").json()
    sibling = _mint(live, live.admin_token, "sibling").json()
    with live.client(t2["token"]) as c:
        bot = c.post("/robots", json={"name": f"bot-{t2['id']}"}).json()
        kept = c.post("/robots", json={"name": f"kept-{t2['id']}"}).json()
    with live.operator() as op:  # the robot token 'kept' is re-issued by the admin: not T2's any more
        kept = {**kept, "token": op.post(f"/robots/{kept['id']}/token").json()["token"]}
        assert op.delete(f"/tokens/{t1['id']}").status_code == 204
        assert op.delete(f"/tokens/{t1['id']}").status_code == 204  # again: nothing new, no error
        assert op.delete("/tokens/999999").status_code == 404
        log = op.get("/audit", params={"limit": 10}).json()
    assert [_works(live, t["token"]) for t in (t1, t2, t3, bot)] == [False] * 4
    assert _works(live, sibling["token"]) and _works(live, kept["token"]) and _works(live, live.admin_token)
    with live.operator() as op:  # the operator sees which robot needs a new token
        assert op.get(f"/robots/{bot['id']}").json()["token_revoked_at"] is not None
        assert op.get(f"/robots/{kept['id']}").json()["token_revoked_at"] is None
    cascade = {e["target"]: e["detail"] for e in log if e["action"] in ("token.revoke", "robot.token.revoke")}
    assert cascade[f"operator:{t2['id']}"] == {"name": "t2", "cascade_from": t1["id"], "root": t1["id"]}
    assert cascade[f"operator:{t3['id']}"]["cascade_from"] == t2["id"]
    assert cascade[f"robot:{bot['id']}"]["cascade_from"] == t2["id"]
    assert len([e for e in log if e["target"] == f"operator:{t1['id']}"]) == 1
    # Rotation brings a cascaded robot back; keep_robot_tokens leaves robot tokens alone.
    with live.operator() as op:
        bot = {**bot, "token": op.post(f"/robots/{bot['id']}/token").json()["token"]}
        assert op.get(f"/robots/{bot['id']}").json()["token_revoked_at"] is None
        t4 = _mint(live, live.admin_token, "t4").json()
        with live.client(t4["token"]) as c:
            mine = c.post(f"/robots/{bot['id']}/token").json()["token"]
        assert op.delete(f"/tokens/{t4['id']}", params={"keep_robot_tokens": True}).status_code == 204
    assert _works(live, mine) and not _works(live, t4["token"])


def test_a_long_poll_begun_before_a_rotation_does_not_hand_out_messages(live: Live) -> None:
    """The robot's token is rotated while it long-polls; a message queued then is not given to the old
    token (401), and the new token gets it."""
    rid, old = live.new_robot()
    answer: list[httpx.Response] = []

    def poll() -> None:
        with live.client(old) as c:
            answer.append(c.get(f"/robots/{rid}/messages", params={"after": 0, "wait": 30}))

    poller = threading.Thread(target=poll)
    poller.start()
    deadline = datetime.now(UTC) + timedelta(seconds=30)
    while live.state.hub.subscribers(f"messages:{rid}") == 0:  # the poll is waiting (white-box)
        assert datetime.now(UTC) < deadline
    with live.operator() as op:
        new = op.post(f"/robots/{rid}/token").json()["token"]
        xml = "<xml><message><mode>online</mode></message></xml>"
        r = op.post(f"/robots/{rid}/messages", content=xml, headers={"Content-Type": "application/xml"})
        assert r.status_code == 201, r.text
    poller.join(40)
    assert answer and answer[0].status_code == 401, answer and answer[0].text
    with live.client(new) as robot:
        assert [m["seq"] for m in robot.get(f"/robots/{rid}/messages").json()["messages"]] == [1]
