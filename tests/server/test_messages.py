"""Control messages through a real server: validation, ordering, long-poll wake-up, acknowledgements."""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from server.routers.messages import WAIT_JITTER, poll_wait_s
from shared.control import parse_message
from tests.server.live import Live

LISTING1 = (Path(__file__).parents[1] / "shared" / "control" / "fixtures" / "listing1.xml").read_bytes()
XML = {"Content-Type": "application/xml"}


def _post(live: Live, robot_id: int, xml: bytes | str) -> Any:
    with live.operator() as op:
        return op.post(f"/robots/{robot_id}/messages", content=xml, headers=XML)


def test_listing1_end_to_end(live: Live) -> None:
    """The paper's Listing 1 as printed: queued, delivered to the robot byte for byte, acknowledged."""
    rid, token = live.new_robot()
    r = _post(live, rid, LISTING1)
    assert r.status_code == 201, r.text
    assert r.json()["seq"] == 1 and r.json()["status"] == "queued"
    with live.client(token) as robot:
        got = robot.get(f"/robots/{rid}/messages", params={"after": 0}).json()
        assert [m["seq"] for m in got["messages"]] == [1]
        assert got["messages"][0]["xml"].encode() == LISTING1
        assert parse_message(got["messages"][0]["xml"]).mode is not None
        ack = robot.post(f"/robots/{rid}/messages/1/ack", json={"outcome": "applied"})
        assert ack.status_code == 200, ack.text
    with live.operator() as op:
        seen = op.get(f"/robots/{rid}/messages/1").json()
        assert seen["status"] == "applied" and seen["acked_at"] is not None
        robot_row = op.get(f"/robots/{rid}").json()
        assert robot_row["pending_messages"] == 0 and robot_row["last_seq"] == 1


@pytest.mark.parametrize(
    ("xml", "needle"),
    [
        (b"<xml><message><mode>online</mode>", "line"),
        (b"<xml><message><mode>sideways</mode></message></xml>", "<mode>"),
        (
            b"<xml><message><noise-removal><dbscan><minpts>fifteen</minpts></dbscan></noise-removal></message></xml>",
            "minpts",
        ),
        (b'<?xml version="1.0"?><!DOCTYPE x [<!ENTITY e SYSTEM "file:///etc/passwd">]><xml>&e;</xml>', "DTD"),
    ],
)
def test_invalid_message_is_refused_with_the_parser_reason(live: Live, xml: bytes, needle: str) -> None:
    rid, _ = live.new_robot()
    r = _post(live, rid, xml)
    assert r.status_code == 422, r.text
    body = r.json()
    assert body["error"] == "invalid"
    assert needle.lower() in body["detail"].lower()
    with live.operator() as op:
        assert op.get(f"/robots/{rid}").json()["last_seq"] == 0, "nothing was queued"


def test_messages_come_in_order_after_seq(live: Live) -> None:
    rid, token = live.new_robot()
    for mode in ("online", "offline", "mixed"):
        assert _post(live, rid, f"<xml><message><mode>{mode}</mode></message></xml>").status_code == 201
    with live.client(token) as robot:
        got = robot.get(f"/robots/{rid}/messages", params={"after": 1}).json()
    assert [m["seq"] for m in got["messages"]] == [2, 3]
    assert "offline" in got["messages"][0]["xml"] and got["last_seq"] == 3


def test_long_poll_wakes_up_when_a_message_is_posted(live: Live) -> None:
    """The robot waits (up to 20 s; the server re-reads its database only every 30 s); a post wakes it."""
    rid, token = live.new_robot()
    result: dict[str, Any] = {}
    started = threading.Event()

    def poll() -> None:
        with live.client(token) as robot:
            started.set()
            result["body"] = robot.get(f"/robots/{rid}/messages", params={"after": 0, "wait": 20}).json()

    t = threading.Thread(target=poll)
    t.start()
    started.wait(10)
    # Post until the waiting poll has subscribed: the server counts subscribers on the robot's topic.
    _wait_for_subscriber(live, f"messages:{rid}")
    assert _post(live, rid, b"<xml><message><mode>offline</mode></message></xml>").status_code == 201
    t.join(30)
    assert [m["seq"] for m in result["body"]["messages"]] == [1]


def _wait_for_subscriber(live: Live, topic: str) -> None:
    import time

    deadline = time.monotonic() + 10
    while live.state.hub.subscribers(topic) == 0:  # readiness wait, not a timing assertion
        assert time.monotonic() < deadline, f"no subscriber on {topic}"
        time.sleep(0.01)


def test_long_poll_with_nothing_returns_empty(live: Live) -> None:
    rid, token = live.new_robot()
    with live.client(token) as robot:
        got = robot.get(f"/robots/{rid}/messages", params={"after": 0, "wait": 0.2}).json()
    assert got == {"messages": [], "last_seq": 0, "map_version": 0, "map_session": None}


def test_acknowledgement_rules(live: Live) -> None:
    rid, token = live.new_robot()
    _post(live, rid, b"<xml><message><mode>offline</mode></message></xml>")
    with live.client(token) as robot:
        no_reason = robot.post(f"/robots/{rid}/messages/1/ack", json={"outcome": "rejected"})
        assert no_reason.status_code == 422 and "reason" in no_reason.json()["detail"]
        r = robot.post(
            f"/robots/{rid}/messages/1/ack", json={"outcome": "rejected", "reason": "n_smax 0 < 1"}
        )
        assert r.status_code == 200 and r.json()["reason"] == "n_smax 0 < 1"
        again = robot.post(
            f"/robots/{rid}/messages/1/ack", json={"outcome": "rejected", "reason": "n_smax 0 < 1"}
        )
        assert again.status_code == 200, "a retried acknowledgement is accepted"
        flip = robot.post(f"/robots/{rid}/messages/1/ack", json={"outcome": "applied"})
        assert flip.status_code == 409
        missing = robot.post(f"/robots/{rid}/messages/9/ack", json={"outcome": "applied"})
        assert missing.status_code == 404
    with live.operator() as op:
        assert op.get(f"/robots/{rid}/messages/1").json()["status"] == "rejected"


def test_kernel_operation_must_name_a_stored_kernel(live: Live) -> None:
    rid, _ = live.new_robot()
    xml = (
        '<xml><message><kernel-install stage="noise-removal" name="no-such-kernel" version="1.0.0"'
        f' sha256="{"a" * 64}"/></message></xml>'
    )
    parse_message(xml)  # valid as a message: the server refuses it for what it names
    r = _post(live, rid, xml)
    assert r.status_code == 422
    assert "no-such-kernel" in r.json()["detail"] and "upload it first" in r.json()["detail"]


def test_message_size_limit(live: Live) -> None:
    rid, _ = live.new_robot()
    big = b"<xml><message>" + b" " * (300 * 1024) + b"</message></xml>"
    r = _post(live, rid, big)
    assert r.status_code == 413
    assert "limit" in r.json()["detail"]


def test_concurrent_posts_get_distinct_consecutive_numbers(live: Live) -> None:
    from concurrent.futures import ThreadPoolExecutor

    rid, _ = live.new_robot()
    with ThreadPoolExecutor(8) as pool:
        codes = list(
            pool.map(
                lambda _: _post(live, rid, b"<xml><message><mode>online</mode></message></xml>"), range(16)
            )
        )
    assert all(r.status_code == 201 for r in codes)
    assert sorted(r.json()["seq"] for r in codes) == list(range(1, 17))


def test_non_utf8_message_is_refused(live: Live) -> None:
    rid, _ = live.new_robot()
    body = (
        '<?xml version="1.0" encoding="ISO-8859-1"?>'
        "<xml><message><mode>online</mode></message><!-- é --></xml>"
    )
    r = _post(live, rid, body.encode("latin-1"))
    assert r.status_code == 422 and "UTF-8" in r.json()["detail"]


def test_ids_and_numbers_beyond_the_columns_range_are_refused_not_a_server_error(live: Live) -> None:
    """Ids and message numbers are 32-bit columns: a larger one is a 422 naming the parameter, on both
    backends (PostgreSQL overflowed in the driver: a 500)."""
    rid, token = live.new_robot()
    big = 2**40
    with live.operator() as op:
        for path in [f"/robots/{big}", f"/robots/{big}/messages", f"/robots/{big}/maps/latest"]:
            r = op.get(path)
            assert r.status_code == 422, (path, r.text)
            assert "robot_id" in r.text
    with live.client(token) as robot:
        r = robot.get(f"/robots/{rid}/messages", params={"after": big, "wait": 0.2})
        assert r.status_code == 422 and "after" in r.text, r.text
        r = robot.get(f"/robots/{rid}/messages/{big}")
        assert r.status_code == 422 and "seq" in r.text, r.text
        r = robot.get(f"/robots/{rid}/messages", params={"after": 2**31 - 1, "wait": 0.2})
        assert r.status_code == 200, r.text  # the largest number the column holds is fine


@given(
    wait=st.floats(0, 1e6, allow_nan=False),
    cap=st.floats(0.001, 3600, allow_nan=False),
    u=st.floats(0, 1, exclude_max=True),
)
def test_a_long_polls_wait_is_the_asked_one_capped_and_at_most_a_tenth_shorter(
    wait: float, cap: float, u: float
) -> None:
    """Polls begun together end apart (server/routers/messages.py WAIT_JITTER): never longer than asked or
    than the server's cap, never more than 10 % shorter."""
    got = poll_wait_s(wait, cap, u)
    asked = min(wait, cap)
    assert asked * (1 - WAIT_JITTER) <= got <= asked
    assert poll_wait_s(wait, cap, 0.0) == asked
