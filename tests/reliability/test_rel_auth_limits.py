"""Brute-force limit on failed authentication, through the real server on 127.0.0.1.

The server counts failed authentications per source (:class:`server.limiter.AuthLimiter`, shared in the
database): after ``auth_fail_limit`` within ``auth_fail_window_s`` the source's *failed* attempts get 429
with ``Retry-After`` for ``auth_block_s``, while valid credentials from the same source are still served.
Distinct client addresses are real: each test's clients bind their own loopback source address
(127.0.0.0/8 all reaches the server on 127.0.0.1). Time is a stepped clock put into the running server's
limiter, so "for a bounded time" is checked without sleeping. Forwarded headers, trusted proxies and
several server processes: tests/reliability/test_rel_auth_processes.py. The oversize-body limit (413) is
tested in tests/server/test_auth.py::test_oversize_body_is_413; the limiter's memory and table bounds and its
default settings in tests/server/test_limiter.py; the robot agent's link seeing this 429 in
tests/robot_agent/test_link.py.
"""

from __future__ import annotations

import socket
from collections.abc import Iterator

import httpx
import pytest

from server.deps import SESSION_COOKIE
from tests.server.authlimits import BLOCK_S, LIMIT, WINDOW_S, WRONG, SteppedClock, start_limited
from tests.server.live import Live


@pytest.fixture(scope="module")
def clock() -> SteppedClock:
    return SteppedClock()


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory, clock: SteppedClock) -> Iterator[Live]:
    yield from start_limited(tmp_path_factory.mktemp("auth-limit-server"), clock)


_next_host = [10]


def _address() -> str:
    """A loopback source address no other test of this module uses."""
    _next_host[0] += 1
    host = f"127.0.0.{_next_host[0]}"
    with socket.socket() as probe:
        try:
            probe.bind((host, 0))
        except OSError:
            pytest.skip(f"cannot bind the loopback address {host} here")
    return host


def _client(live: Live, host: str, token: str | None = None, **kw: object) -> httpx.Client:
    return live.client(token, transport=httpx.HTTPTransport(local_address=host), **kw)


def _whoami(live: Live, host: str, token: str | None) -> httpx.Response:
    with _client(live, host, token) as c:
        return c.get("/whoami")


def _fail(live: Live, host: str, times: int) -> None:
    for i in range(times):
        r = _whoami(live, host, WRONG)
        assert r.status_code == 401, (i, r.status_code, r.text)


def test_failures_beyond_the_limit_get_429_for_a_bounded_time(live: Live, clock: SteppedClock) -> None:
    host, other = _address(), _address()
    _fail(live, host, LIMIT)  # the LIMIT-th failure is still answered 401, and starts the block
    r = _whoami(live, host, WRONG)
    assert r.status_code == 429 and r.headers["retry-after"] == str(int(BLOCK_S))
    assert r.json() == {
        "error": "too_many_requests",
        "detail": f"too many failed authentications from {host}: try again in {int(BLOCK_S)} s "
        "(valid credentials are still accepted)",
    }
    # Blocked: every failed attempt of this address, whatever the guess (token, cookie, malformed header)...
    with _client(live, host, cookies={SESSION_COOKIE: "lms_guess"}) as c:
        assert c.get("/robots").status_code == 429
    with _client(live, host) as c:
        assert c.get("/robots", headers={"Authorization": "Basic Z3Vlc3M="}).status_code == 429
    # ...but never a valid credential from that same address.
    assert _whoami(live, host, live.admin_token).status_code == 200
    # Not affected: requests without a credential (nothing to guess), public pages, other addresses.
    assert _whoami(live, host, None).status_code == 401
    with _client(live, host, WRONG) as c:
        assert c.get(live.base_url + "/healthz").status_code == 200
    assert _whoami(live, other, live.admin_token).status_code == 200
    assert _whoami(live, other, WRONG).status_code == 401
    # Bounded: Retry-After counts down; when the block ends, the address is served again from a clean count.
    clock.now_s += BLOCK_S - 0.5
    r = _whoami(live, host, WRONG)
    assert r.status_code == 429 and r.headers["retry-after"] == "1"
    clock.now_s += 0.5
    _fail(live, host, LIMIT)
    assert _whoami(live, host, WRONG).status_code == 429


def test_successes_neither_count_nor_reset_and_the_window_slides(live: Live, clock: SteppedClock) -> None:
    host = _address()
    _fail(live, host, LIMIT - 1)
    for _ in range(3 * LIMIT):
        assert _whoami(live, host, live.admin_token).status_code == 200
    _fail(live, host, 1)  # LIMIT failures in the window, successes in between: blocked
    assert _whoami(live, host, WRONG).status_code == 429
    assert _whoami(live, host, live.admin_token).status_code == 200
    late = _address()
    _fail(live, late, LIMIT - 1)
    clock.now_s += WINDOW_S + 1  # those failures leave the window
    _fail(live, late, LIMIT - 1)
    assert _whoami(live, late, WRONG).status_code == 401


def test_failed_logins_and_expired_sessions_count(live: Live) -> None:
    host = _address()
    with _client(live, host) as browser:
        for _ in range(LIMIT - 1):
            assert browser.post("/session", json={"token": WRONG}).status_code == 401
        browser.cookies.set(SESSION_COOKIE, "lms_expired-or-guessed")
        assert browser.get("/robots").status_code == 401
        browser.cookies.clear()
        r = browser.post("/session", json={"token": WRONG})
        assert r.status_code == 429 and "Set-Cookie" not in r.headers
        assert int(r.headers["retry-after"]) == int(BLOCK_S)
        # The operator behind the same address still logs in, and the session works.
        r = browser.post("/session", json={"token": live.admin_token})
        assert r.status_code == 200 and SESSION_COOKIE in r.cookies
        assert browser.get("/robots").status_code == 200


def test_fifty_bad_tokens_leave_valid_robot_and_operator_tokens_working(live: Live) -> None:
    """A guesser behind the same address (NAT) as a robot and an operator: 60 bad tokens, then the robot
    polls and uploads, the operator reads and logs in; the guesser is still refused."""
    host = _address()
    rid, robot_token = live.new_robot()
    _fail(live, host, LIMIT)
    for _ in range(60 - LIMIT):
        assert _whoami(live, host, WRONG).status_code == 429
    with _client(live, host, robot_token) as robot:
        assert robot.get(f"/robots/{rid}/messages", params={"after": 0, "wait": 0}).status_code == 200
        up = {"version": 1, "base_version": None, "stamp_s": 1.0, "segments": [[1, 0, 0, 1, 0]]}
        assert robot.post(f"/robots/{rid}/maps", json=up).status_code == 200, "robot upload refused"
    with _client(live, host, live.admin_token) as op:
        assert op.get(f"/robots/{rid}").status_code == 200
        assert op.post("/robots", json={"name": f"nat-{host}"}).status_code == 201
    assert _whoami(live, host, WRONG).status_code == 429
    assert _whoami(live, host, "lmr_" + WRONG[4:]).status_code == 429


def test_limit_zero_switches_it_off(live: Live) -> None:
    host = _address()
    limiter = live.state.limiter
    saved = limiter.limit
    limiter.limit = 0
    try:
        _fail(live, host, 4 * LIMIT)
    finally:
        limiter.limit = saved
