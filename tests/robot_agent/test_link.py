"""The link (robot_agent/link.py) takes nothing the network says on trust (docs/reliability/agent.md):
``Retry-After`` is non-negative, finite and capped (seconds or an HTTP-date; garbage ignored); an answer
that is not the API's (a portal's HTML page, a redirect, JSON of the wrong shape, a body that is not JSON)
is a link fault (:class:`UnexpectedAnswerError`, retried), never a crash. Against a real HTTP server on
127.0.0.1."""

from __future__ import annotations

import math
import random
from collections.abc import Callable, Iterator
from datetime import UTC, datetime, timedelta
from email.utils import format_datetime
from pathlib import Path

import httpx
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from robot_agent.errors import LinkError, UnexpectedAnswerError
from robot_agent.link import DEFAULT_MAX_RETRY_AFTER_S, Backoff, ServerLink, is_transient, parse_retry_after
from tests.robot_agent.answerproxy import AnswerProxy
from tests.server.authlimits import BLOCK_S, LIMIT, SteppedClock, start_limited
from tests.server.live import Live, start_live

NOW = datetime(2026, 12, 2, 10, 0, tzinfo=UTC)


@pytest.mark.parametrize(
    ("value", "expected"),
    [
        ("inf", None),
        ("-inf", None),
        ("nan", None),
        ("-5", None),
        ("soon", None),
        ("", None),
        ("1e400", None),
        ("86400", 60.0),
        ("3", 3.0),
        ("0", 0.0),
        ("  2.5 ", 2.5),
        (format_datetime(NOW + timedelta(seconds=30), usegmt=True), 30.0),
        (format_datetime(NOW + timedelta(days=1), usegmt=True), 60.0),
        (format_datetime(NOW - timedelta(days=1), usegmt=True), 0.0),
        ("Wed, 99 Foo 2026 25:61:00 GMT", None),
    ],
)
def test_retry_after_is_clamped_and_validated(value: str, expected: float | None) -> None:
    assert parse_retry_after(value, DEFAULT_MAX_RETRY_AFTER_S, NOW.timestamp()) == expected


@given(st.text(max_size=60))
def test_any_retry_after_gives_a_usable_delay(value: str) -> None:
    got = parse_retry_after(value, 60.0, NOW.timestamp())
    assert got is None or (math.isfinite(got) and 0.0 <= got <= 60.0)
    delay = Backoff(0.5, rng=random.Random(0)).next_delay(got)
    assert math.isfinite(delay) and 0.0 <= delay <= 60.0


@given(st.floats(allow_nan=True, allow_infinity=True))
def test_backoff_ignores_an_unusable_retry_after(value: float) -> None:
    delay = Backoff(0.5, rng=random.Random(0)).next_delay(value)
    assert math.isfinite(delay) and delay >= 0.0


@pytest.fixture
def proxy() -> Iterator[AnswerProxy]:
    with AnswerProxy("http://127.0.0.1:9") as p:  # nothing behind it: every answer is the proxy's own
        yield p


@pytest.mark.parametrize("mode", ["portal", "redirect", "shape", "notjson"])
def test_an_answer_that_is_not_the_apis_is_a_transient_link_fault(proxy: AnswerProxy, mode: str) -> None:
    proxy.mode = mode
    link = ServerLink(proxy.url, 1, "lmr_x")
    try:
        calls: list[Callable[[], object]] = [
            lambda: link.poll(0, 1.0),
            lambda: link.upload({"version": 1}, "k"),
            lambda: link.fetch_kernel("dbscan", "1.1.0"),
        ]
        for call in calls:
            with pytest.raises(UnexpectedAnswerError, match="unexpected answer") as info:
                call()
            assert is_transient(info.value), "retried, never taken as the server's word"
            assert "expected" in str(info.value)
    finally:
        link.close()


@pytest.mark.parametrize(("mode", "after"), [("503-inf", None), ("503-day", 5.0), ("503-garbage", None)])
def test_a_503_carries_only_a_usable_retry_after(proxy: AnswerProxy, mode: str, after: float | None) -> None:
    proxy.mode = mode
    link = ServerLink(proxy.url, 1, "lmr_x", max_retry_after_s=5.0)
    try:
        with pytest.raises(LinkError) as info:
            link.poll(0, 1.0)
        assert info.value.status == 503 and info.value.retry_after_s == after
        assert math.isfinite(Backoff().next_delay(info.value.retry_after_s))
    finally:
        link.close()


_CTYPES = st.sampled_from(
    ["application/json", "application/json; charset=utf-8", "text/html", "text/x-python", "", "text/plain"]
)
_BODIES = st.one_of(
    st.binary(max_size=200),
    st.sampled_from(
        [
            b'{"messages": []}',
            b'{"messages": [{"seq": 0, "xml": "x"}]}',
            b'{"messages": [{"seq": 1}]}',
            b'{"messages": null}',
            b"[]",
            b"null",
            b'{"version": -1}',
            b'{"current_version": "x"}',
            b'{"detail": 5}',
            b"1e999",
        ]
    ),
)


@settings(max_examples=300, suppress_health_check=[HealthCheck.too_slow])
@given(
    status=st.sampled_from([200, 201, 204, 301, 302, 304, 400, 401, 404, 409, 413, 429, 500, 503]),
    ctype=_CTYPES,
    body=_BODIES,
    retry_after=st.one_of(st.none(), st.text(max_size=30)),
)
def test_whatever_comes_back_the_link_returns_a_valid_answer_or_raises_a_link_error(
    status: int, ctype: str, body: bytes, retry_after: str | None
) -> None:
    headers = {"content-type": ctype} if ctype else {}
    if retry_after is not None and retry_after.isprintable() and retry_after.isascii():
        headers["retry-after"] = retry_after

    def answer(_request: httpx.Request) -> httpx.Response:
        return httpx.Response(status, headers=headers, content=body)

    link = ServerLink("http://server.invalid", 1, "lmr_x", transport=httpx.MockTransport(answer))
    try:
        for call in (
            lambda: link.poll(0, 1.0),
            lambda: link.upload({"version": 1}, "k"),
            lambda: link.ack(1, "applied", None),
            lambda: link.fetch_kernel("dbscan", "1.1.0"),
        ):
            hint: float | None = None
            try:
                call()
            except LinkError as exc:  # the only way a call may fail, whatever came back
                hint = exc.retry_after_s
            assert hint is None or 0.0 <= hint <= DEFAULT_MAX_RETRY_AFTER_S
    finally:
        link.close()


@pytest.fixture
def live(tmp_path: Path) -> Iterator[Live]:
    """A real server on 127.0.0.1 that blocks a source after ``LIMIT`` failed authentications."""
    yield from start_limited(tmp_path, SteppedClock())


def test_the_robot_agent_link_sees_retry_after(live: Live) -> None:
    """The robot's own HTTP client (from 127.0.0.1) reports 429 with the server's Retry-After, which its
    back-off never undercuts; the robot's real token from the same address works during the block."""
    live.state.limiter.clear()
    rid, token = live.new_robot()
    link = ServerLink(live.base_url, rid, "lmr_stolen-or-mistyped")
    try:
        for _ in range(LIMIT):
            with pytest.raises(LinkError) as exc:
                link.poll(0, 0)
            assert exc.value.status == 401
        with pytest.raises(LinkError) as exc:
            link.poll(0, 0)
        assert exc.value.status == 429 and exc.value.retry_after_s == BLOCK_S
        assert "too many failed authentications" in str(exc.value)
        assert Backoff().next_delay(exc.value.retry_after_s) >= BLOCK_S
    finally:
        link.close()
    good = ServerLink(live.base_url, rid, token)
    try:
        assert good.poll(0, 0) == []
    finally:
        good.close()
        live.state.limiter.clear()


def test_a_status_alone_reaches_the_real_server(tmp_path: Path) -> None:
    """``ServerLink.report_status`` through a real server: its 204 (no body) is the answer it expects, and
    the server shows the robot's ``last_error`` (found when every status-only report failed with
    "unexpected answer (HTTP 204, application/json)", overwriting the error it was to report)."""
    for live in start_live("sqlite", tmp_path):
        rid, token = live.new_robot()
        link = ServerLink(live.base_url, rid, token)
        try:
            link.report_status({"mode": "online", "last_error": "message 3 rejected: bad signature"})
            with live.operator() as op:
                assert op.get(f"/robots/{rid}").json()["last_error"] == "message 3 rejected: bad signature"
            link.report_status({"mode": "online", "last_error": None})
            with live.operator() as op:
                assert op.get(f"/robots/{rid}").json()["last_error"] is None
        finally:
            link.close()
