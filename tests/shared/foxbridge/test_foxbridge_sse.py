"""The bridge's reader of the live-map stream (shared/foxbridge/sse.py): the line parser against the
server's own event writer (server/mapstream.py), and the reader's reconnection (``Last-Event-ID``,
back-off) and refusals, through an in-process transport. (Through a real server:
test_foxglove_bridge_live.py.)"""

from __future__ import annotations

import json
import threading
from typing import Any

import httpx
import pytest
from hypothesis import given
from hypothesis import strategies as st

from server.mapstream import sse
from shared.foxbridge.errors import MapEventError, RobotUnknownError, StreamRefusedError
from shared.foxbridge.sse import Backoff, MapEvent, MapEventStream, SseParser

json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False, allow_infinity=False) | st.text(),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=5), inner, max_size=3),
    max_leaves=10,
)
events = st.lists(
    st.tuples(
        st.sampled_from(["snapshot", "delta"]),
        st.integers(0, 2**53),
        st.dictionaries(st.text(max_size=8), json_values, max_size=4),
    ),
    max_size=8,
)


def _parse(text: str) -> list[MapEvent]:
    parser = SseParser()
    out = []
    for line in text.split("\n"):
        event = parser.feed(line)
        if event is not None:
            out.append(event)
    return out


@given(events, st.lists(st.booleans(), max_size=8))
def test_the_parser_reads_back_what_the_server_writes(
    written: list[tuple[str, int, dict[str, Any]]], keepalives: list[bool]
) -> None:
    chunks = []
    for n, (kind, version, data) in enumerate(written):
        if n < len(keepalives) and keepalives[n]:
            chunks.append(b": keepalive\n\n")
        chunks.append(sse(kind, data, version))
    parsed = _parse(b"".join(chunks).decode())
    assert [(e.kind, e.id, e.data) for e in parsed] == written


def test_data_split_over_lines_is_joined_and_a_missing_id_is_none() -> None:
    assert _parse('event: delta\ndata: {"a":\ndata: 1}\n\n') == [MapEvent("delta", None, {"a": 1})]


@pytest.mark.parametrize(
    ("text", "named"),
    [
        ("event: delta\nid: 3\ndata: {oops\n\n", "'delta' event's data is not JSON"),
        ("event: delta\nid: 3\ndata: [1]\n\n", "'delta' event's data: expected a JSON object"),
        ("event: delta\nid: x3\ndata: {}\n\n", "'delta' event's id: expected a map version, got 'x3'"),
    ],
)
def test_a_malformed_event_names_what_is_wrong(text: str, named: str) -> None:
    with pytest.raises(MapEventError, match=named):
        _parse(text)


def test_backoff_doubles_up_to_its_cap_and_resets() -> None:
    b = Backoff(first_s=0.5, max_s=3.0)
    assert [b.next_delay() for _ in range(5)] == [0.5, 1.0, 2.0, 3.0, 3.0]
    b.reset()
    assert b.next_delay() == 0.5


def _events(*versions: int) -> bytes:
    return b"".join(sse("delta", {"version": v}, v) for v in versions)


def _stream(handler: Any, **kwargs: Any) -> MapEventStream:
    return MapEventStream(
        "http://linemap.test/",
        4,
        "tok",
        backoff=Backoff(first_s=0.0, max_s=0.0),
        transport=httpx.MockTransport(handler),
        **kwargs,
    )


def test_the_reader_reconnects_after_the_last_event_it_got() -> None:
    seen: list[httpx.Request] = []
    answers = [
        httpx.Response(200, content=_events(1, 2)),  # then the connection ends
        httpx.Response(503, json={"detail": "busy"}),  # retried
        httpx.Response(200, content=_events(3)),
        httpx.Response(401, json={"error": "unauthorized", "detail": "token revoked"}),
    ]

    def handler(request: httpx.Request) -> httpx.Response:
        seen.append(request)
        return answers[len(seen) - 1]

    stream = _stream(handler, trajectory=100)
    got: list[int | None] = []
    refused = r"refused the token for robot 4's map \(401: token revoked\)"
    with pytest.raises(StreamRefusedError, match=refused):
        got.extend(e.id for e in stream.events(threading.Event()))
    assert got == [1, 2, 3]
    assert [r.headers.get("Last-Event-ID") for r in seen] == [None, "2", "2", "3"]
    assert all(r.headers["Authorization"] == "Bearer tok" for r in seen)
    assert seen[0].url == "http://linemap.test/api/v1/robots/4/maps/stream?trajectory=100"
    assert stream.connections == 2


def test_resync_reopens_without_last_event_id() -> None:
    seen: list[httpx.Request] = []

    def handler(request: httpx.Request) -> httpx.Response:
        seen.append(request)
        return httpx.Response(200, content=_events(len(seen) + 4))

    stream = _stream(handler)
    stop = threading.Event()
    for event in stream.events(stop):
        if event.id == 5:
            stream.resync()
        if event.id == 6:
            stop.set()
    assert [r.headers.get("Last-Event-ID") for r in seen] == [None, None]


def test_an_unknown_robot_is_named() -> None:
    stream = _stream(lambda _r: httpx.Response(404, json={"detail": "robot 4 not found"}))
    with pytest.raises(RobotUnknownError, match=r"server at http://linemap.test has no robot 4"):
        next(iter(stream.events(threading.Event())))


def test_a_forbidden_robot_is_a_refusal() -> None:
    body = json.dumps({"detail": "this token is robot 5's"}).encode()
    stream = _stream(lambda _r: httpx.Response(403, content=body))
    with pytest.raises(StreamRefusedError, match=r"403: this token is robot 5's"):
        next(iter(stream.events(threading.Event())))
