"""Brute-force limit on failed authentication (issue 9 item 5), through the real server on 127.0.0.1.

The server counts failed authentications per client address (:class:`server.deps.AuthLimiter`): after
``auth_fail_limit`` within ``auth_fail_window_s`` the address's credentialed API requests get 429 with
``Retry-After`` for ``auth_block_s``. Distinct client addresses are real: each test's clients bind their own
loopback source address (127.0.0.0/8 all reaches the server on 127.0.0.1). Time is a stepped clock put into
the running server's limiter, so "for a bounded time" is checked without sleeping. The oversize-body limit
(413) is tested in tests/server/test_auth.py::test_oversize_body_is_413.
"""

from __future__ import annotations

import socket
from collections.abc import Iterator

import httpx
import pytest

from robot_agent.errors import LinkError
from robot_agent.link import Backoff, ServerLink
from server.deps import SESSION_COOKIE, AuthLimiter
from server.settings import Settings
from tests.server.live import Live, start_live

LIMIT, WINDOW_S, BLOCK_S = 5, 60.0, 30.0
WRONG = "lmo_not-a-real-token-0000000000000000000000"


class SteppedClock:
    """A monotonic clock the test moves by hand (seconds)."""

    def __init__(self) -> None:
        self.now_s = 1000.0

    def __call__(self) -> float:
        return self.now_s


@pytest.fixture(scope="module")
def clock() -> SteppedClock:
    return SteppedClock()


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory, clock: SteppedClock) -> Iterator[Live]:
    for server in start_live(
        "sqlite",
        tmp_path_factory.mktemp("auth-limit-server"),
        auth_fail_limit=LIMIT,
        auth_fail_window_s=WINDOW_S,
        auth_block_s=BLOCK_S,
    ):
        server.state.limiter.clock = clock
        yield server


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
        "detail": f"too many failed authentications from {host}: try again in {int(BLOCK_S)} s",
    }
    # Blocked: every credentialed API request of this address, whatever the guess (a valid token too).
    assert _whoami(live, host, live.admin_token).status_code == 429
    with _client(live, host, cookies={SESSION_COOKIE: "lms_guess"}) as c:
        assert c.get("/robots").status_code == 429
    # Not affected: requests without a credential (nothing to guess), public pages, other addresses.
    assert _whoami(live, host, None).status_code == 401
    with _client(live, host, WRONG) as c:
        assert c.get(live.base_url + "/healthz").status_code == 200
    assert _whoami(live, other, live.admin_token).status_code == 200
    assert _whoami(live, other, WRONG).status_code == 401
    # Bounded: Retry-After counts down; when the block ends, the address is served again from a clean count.
    clock.now_s += BLOCK_S - 0.5
    r = _whoami(live, host, live.admin_token)
    assert r.status_code == 429 and r.headers["retry-after"] == "1"
    clock.now_s += 0.5
    assert _whoami(live, host, live.admin_token).status_code == 200
    _fail(live, host, LIMIT)
    assert _whoami(live, host, WRONG).status_code == 429


def test_successes_neither_count_nor_reset_and_the_window_slides(live: Live, clock: SteppedClock) -> None:
    host = _address()
    _fail(live, host, LIMIT - 1)
    for _ in range(3 * LIMIT):
        assert _whoami(live, host, live.admin_token).status_code == 200
    _fail(live, host, 1)  # LIMIT failures in the window, successes in between: blocked
    assert _whoami(live, host, live.admin_token).status_code == 429
    late = _address()
    _fail(live, late, LIMIT - 1)
    clock.now_s += WINDOW_S + 1  # those failures leave the window
    _fail(live, late, LIMIT - 1)
    assert _whoami(live, late, live.admin_token).status_code == 200


def test_failed_logins_and_expired_sessions_count(live: Live) -> None:
    host = _address()
    with _client(live, host) as browser:
        for _ in range(LIMIT - 1):
            assert browser.post("/session", json={"token": WRONG}).status_code == 401
        browser.cookies.set(SESSION_COOKIE, "lms_expired-or-guessed")
        assert browser.get("/robots").status_code == 401
        browser.cookies.clear()
        r = browser.post("/session", json={"token": live.admin_token})
        assert r.status_code == 429 and "Set-Cookie" not in r.headers
        assert int(r.headers["retry-after"]) == int(BLOCK_S)


def test_the_robot_agent_link_sees_retry_after(live: Live) -> None:
    """The robot's own HTTP client (from 127.0.0.1) reports 429 with the server's Retry-After, which its
    back-off never undercuts."""
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
        live.state.limiter.clear()
    good = ServerLink(live.base_url, rid, token)
    try:
        assert good.poll(0, 0) == []
    finally:
        good.close()


def test_limit_zero_switches_it_off(live: Live) -> None:
    host = _address()
    limiter = live.state.limiter
    saved = limiter.limit
    limiter.limit = 0
    try:
        _fail(live, host, 4 * LIMIT)
    finally:
        limiter.limit = saved


def test_memory_is_bounded_by_max_clients() -> None:
    t = SteppedClock()
    limiter = AuthLimiter(3, 60.0, 30.0, clock=t, max_clients=100)
    for i in range(10_000):
        limiter.failed(f"10.0.{i // 256}.{i % 256}")
        assert limiter.tracked() <= 100
    for _ in range(3):
        limiter.failed("192.0.2.1")
    assert limiter.retry_after("192.0.2.1") == 30.0  # the newest address is still counted and blocked


def test_default_settings_limit_brute_force() -> None:
    s = Settings()
    assert (s.auth_fail_limit, s.auth_fail_window_s, s.auth_block_s) == (50, 60.0, 60.0)
    limiter = AuthLimiter.from_settings(s)
    assert limiter.enabled
