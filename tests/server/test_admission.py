"""Long-polls' admission (server.admission): other requests go first, polls open a few at a time and at a
floor rate, a poll that gives up frees its place. Unit tests drive the middleware with a small ASGI app;
then a real server: a crowd of long-polls opened at once all open, and each gets its message."""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any
from urllib.parse import urlencode

import pytest
from hypothesis import given
from hypothesis import strategies as st
from starlette.requests import Request
from starlette.types import Message, Receive, Scope, Send

from server.admission import PollAdmission, is_long_poll, opened
from tests.server.live import BACKENDS, Live, start_live


def _scope(path: str, query: str = "", method: str = "GET") -> Scope:
    return {"type": "http", "method": method, "path": path, "query_string": query.encode(), "headers": []}


class _App:
    """Records which requests entered; each waits for its own event before it answers (a poll calls
    :func:`opened` first when told to, as the messages route does when it begins to wait)."""

    def __init__(self) -> None:
        self.entered: list[str] = []
        self.release: dict[str, asyncio.Event] = {}
        self.open_first: set[str] = set()

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        name = scope["path"]
        self.entered.append(name)
        if name in self.open_first:
            opened(Request(scope))
        await self.release.setdefault(name, asyncio.Event()).wait()
        await send({"type": "http.response.start", "status": 200, "headers": []})
        await send({"type": "http.response.body", "body": b""})


async def _receive() -> Message:
    return {"type": "http.request", "body": b"", "more_body": False}


async def _send(message: Message) -> None:
    return None


async def _settle() -> None:
    for _ in range(20):  # let every ready task run its next steps
        await asyncio.sleep(0)


def _request(gate: PollAdmission, scope: Scope) -> asyncio.Task[None]:
    return asyncio.ensure_future(gate(scope, _receive, _send))


def _poll(i: int) -> Scope:
    return _scope(f"/api/v1/robots/{i}/messages", "after=0&wait=20")


def test_a_long_poll_waits_while_another_request_is_in_progress() -> None:
    async def go() -> None:
        app = _App()
        gate = PollAdmission(app, slots=2, floor_hz=1e-6)  # no floor within the test
        upload = _request(gate, _scope("/api/v1/robots/1/maps", method="POST"))
        await _settle()
        poll = _request(gate, _poll(1))
        await _settle()
        assert app.entered == ["/api/v1/robots/1/maps"] and gate.door().waiting == 1
        app.release["/api/v1/robots/1/maps"].set()  # answered: nothing else in progress, the poll goes in
        await _settle()
        assert app.entered[-1] == "/api/v1/robots/1/messages" and gate.door().waiting == 0
        app.release["/api/v1/robots/1/messages"].set()
        await asyncio.gather(upload, poll)

    asyncio.run(go())


def test_polls_open_at_most_slots_at_a_time_and_the_next_goes_in_when_one_begins_to_wait() -> None:
    async def go() -> None:
        app = _App()
        gate = PollAdmission(app, slots=2, floor_hz=1e-6)
        polls = [_request(gate, _poll(i)) for i in range(5)]
        await _settle()
        assert len(app.entered) == 2 and gate.door().waiting == 3  # first come, first served
        assert app.entered == ["/api/v1/robots/0/messages", "/api/v1/robots/1/messages"]
        app.open_first.update(f"/api/v1/robots/{i}/messages" for i in range(2, 5))
        app.release["/api/v1/robots/0/messages"].set()  # poll 0 answers (its slot is free)
        await _settle()
        # poll 2 went in and began to wait at once (opened): poll 3 followed, and 4 after it
        assert app.entered[2:] == [f"/api/v1/robots/{i}/messages" for i in (2, 3, 4)]
        assert gate.door().waiting == 0
        for event in app.release.values():
            event.set()
        await asyncio.gather(*polls)
        assert gate.door().opening == 0 and gate.door().busy == 0

    asyncio.run(go())


def test_under_a_load_that_never_pauses_polls_still_open_at_the_floor_rate() -> None:
    async def go() -> None:
        app = _App()
        gate = PollAdmission(app, slots=2, floor_hz=200.0)
        busy = _request(gate, _scope("/api/v1/robots/9/maps", method="POST"))  # never answers in time
        await _settle()
        app.open_first.update(f"/api/v1/robots/{i}/messages" for i in range(3))
        polls = [_request(gate, _poll(i)) for i in range(3)]
        async with asyncio.timeout(30):  # readiness wait: the floor's timer lets them in one by one
            while len(app.entered) < 4:
                await asyncio.sleep(0.001)
        assert gate.door().busy == 1  # the upload was in progress all along
        for event in app.release.values():
            event.set()
        await asyncio.gather(busy, *polls)

    asyncio.run(go())


def test_a_poll_that_gives_up_at_the_door_frees_its_place() -> None:
    async def go() -> None:
        app = _App()
        gate = PollAdmission(app, slots=1, floor_hz=1e-6)
        first, gone, last = (_request(gate, _poll(i)) for i in range(3))
        await _settle()
        assert gate.door().waiting == 2
        gone.cancel()  # the client went away while waiting at the door
        await _settle()
        assert gate.door().waiting == 1
        app.open_first.add("/api/v1/robots/2/messages")
        app.release["/api/v1/robots/0/messages"].set()
        await _settle()
        assert app.entered == ["/api/v1/robots/0/messages", "/api/v1/robots/2/messages"]
        app.release["/api/v1/robots/2/messages"].set()
        await asyncio.gather(first, last)
        assert gone.cancelled() and gate.door().opening == 0

    asyncio.run(go())


def test_a_handler_that_raises_frees_its_slot() -> None:
    async def go() -> None:
        async def broken(scope: Scope, receive: Receive, send: Send) -> None:
            raise RuntimeError("boom")

        gate = PollAdmission(broken, slots=1)
        for i in range(3):
            with pytest.raises(RuntimeError, match="boom"):
                await gate(_poll(i), _receive, _send)
        assert gate.door().opening == 0 and gate.door().waiting == 0

    asyncio.run(go())


def test_polls_that_waited_are_screened_when_let_in_and_a_refused_one_gives_its_slot_on_at_once() -> None:
    """The failed-authentication limit blocked the flood's source while its polls waited at the door: each
    is refused when let in, without its route's work, and gives its slot on before its (held) refusal is
    sent, so the robot's own poll behind the flood goes in at once. A poll let in at once (it did not
    wait) is not screened again (the outer limit just did)."""

    async def go() -> None:
        app = _App()
        blocked: set[str] = set()
        held = asyncio.Event()  # the limiter's refusal delay: never over within the test
        refused: list[str] = []
        screened: list[str] = []

        async def screen(scope: Scope) -> Any:
            screened.append(scope["path"])
            if scope["path"] not in blocked:
                return None

            async def refusal(send: Send) -> None:
                refused.append(scope["path"])
                await held.wait()

            return refusal

        gate = PollAdmission(app, slots=1, floor_hz=1e-6, screen=screen)
        first = _request(gate, _poll(0))  # let in at once
        await _settle()
        flood = [_request(gate, _poll(i)) for i in range(1, 6)]
        robot = _request(gate, _poll(99))
        await _settle()
        assert gate.door().waiting == 6 and screened == []
        blocked.update(f"/api/v1/robots/{i}/messages" for i in range(1, 6))  # the source is blocked now
        app.open_first.add("/api/v1/robots/99/messages")
        app.release["/api/v1/robots/0/messages"].set()
        await _settle()
        assert refused == [f"/api/v1/robots/{i}/messages" for i in range(1, 6)]
        assert app.entered == ["/api/v1/robots/0/messages", "/api/v1/robots/99/messages"]
        assert screened == [f"/api/v1/robots/{i}/messages" for i in (1, 2, 3, 4, 5, 99)]
        assert gate.door().waiting == 0 and gate.door().opening == 0  # the robot's poll has opened
        assert not any(task.done() for task in flood)  # their refusals are still held
        held.set()
        app.release["/api/v1/robots/99/messages"].set()
        await asyncio.gather(first, robot, *flood)

    asyncio.run(go())


def test_a_loop_that_ended_with_polls_at_the_door_leaves_nothing_to_the_next() -> None:
    """The state is the event loop's own: an app run again in a new loop (as tests and restarts do)
    starts with nobody in progress and nobody at the door."""
    app = _App()
    gate = PollAdmission(app, slots=1, floor_hz=1e-6)

    async def first() -> None:
        _request(gate, _scope("/api/v1/robots/1/maps", method="POST"))  # never answers
        _request(gate, _poll(1))
        await _settle()
        assert gate.door().waiting == 1 and gate.door().busy == 1
        # asyncio.run cancels both when this returns

    asyncio.run(first())

    async def second() -> None:
        app.open_first.add("/api/v1/robots/2/messages")
        poll = _request(gate, _poll(2))
        await _settle()
        assert app.entered[-1] == "/api/v1/robots/2/messages"  # let in at once: nothing in progress here
        assert gate.door().busy == 0 and gate.door().opening == 0
        app.release["/api/v1/robots/2/messages"].set()
        await poll

    asyncio.run(second())


def test_settings_out_of_range_name_the_setting() -> None:
    with pytest.raises(ValueError, match="poll_open_slots=0"):
        PollAdmission(_App(), slots=0)
    with pytest.raises(ValueError, match="poll_open_floor_hz=0"):
        PollAdmission(_App(), floor_hz=0.0)


@given(wait=st.floats(allow_nan=True, allow_infinity=True), other=st.text(max_size=20))
def test_only_a_get_of_messages_asking_to_wait_is_a_long_poll(wait: float, other: str) -> None:
    query = urlencode({"after": 3, "wait": repr(wait), "x": other})  # as a client sends it
    assert is_long_poll(_scope("/api/v1/robots/4/messages", query)) == (wait > 0)
    assert not is_long_poll(_scope("/api/v1/robots/4/messages", query, method="POST"))
    assert not is_long_poll(_scope("/api/v1/robots/4/maps", query))
    assert not is_long_poll(_scope("/api/v1/robots/4/messages", "after=3"))
    assert not is_long_poll(_scope("/api/v1/robots/4/messages", "wait=soon"))  # left to the route's 422


@pytest.fixture(scope="module", params=BACKENDS)
def one_slot(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    """A server letting one long-poll open at a time."""
    tmp: Path = tmp_path_factory.mktemp(f"admission-{request.param}")
    yield from start_live(request.param, tmp, poll_open_slots=1)


def test_a_crowd_of_long_polls_opened_at_once_all_open_and_get_their_messages(one_slot: Live) -> None:
    robots = [one_slot.new_robot() for _ in range(12)]
    results: dict[int, Any] = {}

    def poll(rid: int, token: str) -> None:
        with one_slot.client(token) as robot:
            results[rid] = robot.get(f"/robots/{rid}/messages", params={"after": 0, "wait": 30})

    threads = [threading.Thread(target=poll, args=r) for r in robots]
    for t in threads:
        t.start()
    _wait_until(lambda: len(one_slot.state.polls.waiting()) == len(robots))  # every one opened
    with one_slot.operator() as op:
        for rid, _ in robots:
            r = op.post(
                f"/robots/{rid}/messages",
                content=b"<xml><message><mode>offline</mode></message></xml>",
                headers={"Content-Type": "application/xml"},
            )
            assert r.status_code in (200, 201), r.text
    for t in threads:
        t.join(60)
    assert all(not t.is_alive() for t in threads)
    for rid, _ in robots:
        assert results[rid].status_code == 200, results[rid].text
        assert [m["seq"] for m in results[rid].json()["messages"]] == [1]


def _wait_until(cond: Any) -> None:
    import time

    deadline = time.monotonic() + 30
    while not cond():  # readiness wait, not a timing assertion
        assert time.monotonic() < deadline, "the long-polls never all opened"
        time.sleep(0.01)


def _gate(app: Any) -> PollAdmission:
    """The app's PollAdmission (white-box: built with the middleware stack on the first request)."""
    layer = app.middleware_stack
    while not isinstance(layer, PollAdmission):
        layer = layer.app
    return layer


def _waiting(gate: PollAdmission) -> int:
    """Polls waiting at the door of the server's event loop (read from the test's thread)."""
    return sum(door.waiting for door in list(gate._doors.values()))


@pytest.fixture(scope="module", params=BACKENDS)
def strict(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    """One poll opening at a time, no floor within a test, a source blocked after 3 failures, no delay."""
    tmp: Path = tmp_path_factory.mktemp(f"admission-strict-{request.param}")
    settings = {"poll_open_slots": 1, "poll_open_floor_hz": 0.001}
    settings |= {"auth_fail_limit": 3, "auth_fail_delay_s": 0}
    yield from start_live(request.param, tmp, **settings)


def test_bad_token_polls_at_the_door_when_their_source_is_blocked_are_refused_without_route_work(
    strict: Live,
) -> None:
    """A real server: an upload whose body is still arriving holds the door; 8 long-polls with a bad token
    wait there; the same source then fails 3 times and is blocked; when the upload ends, the 8 polls get
    the limit's 429 at the door: none reaches its route (none is counted as a new failure), and the
    robot's own poll, queued behind them, opens and gets its message."""
    import socket

    rid, token = strict.new_robot()
    with strict.client() as anyone:
        assert anyone.get("/healthz").status_code in (200, 404)  # the middleware stack is built
    gate = _gate(strict.app)
    limiter = strict.state.limiter
    failures: list[str] = []
    counted = limiter.failed

    def counting(source: str) -> Any:
        failures.append(source)
        return counted(source)

    limiter.failed = counting  # type: ignore[method-assign]
    host, port = strict.base_url.rsplit("//", 1)[1].split(":")
    slow = socket.create_connection((host, int(port)))
    results: dict[str, Any] = {}
    try:
        head = (
            f"POST /api/v1/robots/{rid}/maps HTTP/1.1\r\nHost: {host}\r\nAuthorization: Bearer {token}\r\n"
            "Content-Type: application/json\r\nContent-Length: 40\r\n\r\n{"
        )
        slow.sendall(head.encode())

        def poll(name: str, auth: str) -> None:
            with strict.client(auth) as c:
                results[name] = c.get(f"/robots/{rid}/messages", params={"after": 0, "wait": 30})

        threads = [threading.Thread(target=poll, args=(f"bad{i}", "lmr_not_a_token")) for i in range(8)]
        for t in threads:
            t.start()
        _wait_until(lambda: _waiting(gate) == 8)
        robot = threading.Thread(target=poll, args=("robot", token))
        robot.start()
        _wait_until(lambda: _waiting(gate) == 9)
        with strict.client("lmr_not_a_token") as bad:
            codes = [bad.get("/whoami").status_code for _ in range(4)]
        assert codes[:3] == [401, 401, 401] and codes[3] == 429, codes  # blocked after 3 failures
        before = len(failures)
        slow.sendall(b" " * 39)  # the upload's body ends (not a valid map: its answer is an error)
        _wait_until(lambda: not any(t.is_alive() for t in threads))
        assert all(results[f"bad{i}"].status_code == 429 for i in range(8))
        assert len(failures) == before, "a refused poll reached its route and failed there"
        _wait_until(lambda: len(strict.state.polls.waiting()) >= 1)  # the robot's poll has opened
        with strict.operator() as op:
            r = op.post(
                f"/robots/{rid}/messages",
                content=b"<xml><message><mode>offline</mode></message></xml>",
                headers={"Content-Type": "application/xml"},
            )
            assert r.status_code in (200, 201), r.text
        robot.join(60)
        assert results["robot"].status_code == 200, results["robot"].text
        assert [m["seq"] for m in results["robot"].json()["messages"]] == [1]
    finally:
        slow.close()
        limiter.failed = counted  # type: ignore[method-assign]
