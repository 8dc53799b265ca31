"""Authentication across server processes and behind proxies, through real servers on 127.0.0.1.

- Two `linemap server` processes on one database (a fresh PostgreSQL database, and one SQLite file) share
  one failed-authentication budget, and a revocation on one reaches the other within 1 s: the revoked
  token, the tokens it created (transitively) and the robot tokens it issued are refused there, and a
  live-map stream opened there with it ends.
- Forwarded headers: from a client that is not a configured proxy, ``X-Forwarded-For`` / ``Forwarded``
  change nothing (neither evade the limit nor aim it at another address); from a configured proxy, the
  client it names is the source.

Distinct client addresses are real loopback source addresses (127.0.0.0/8 reaches the server on 127.0.0.1).
"""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from tests.server.live import Live, start_live
from tests.server.procs import ServerProc, fresh_database, server_procs

LIMIT = 6
WRONG = "lmo_not-a-real-token-0000000000000000000000"
#: The promise: a revocation takes effect on every process within this time (credential_cache_s <= 1 s).
REVOKE_DEADLINE_S = 1.0

_next_host = [100]


def _address() -> str:
    """A loopback source address no other test of this module uses."""
    _next_host[0] += 1
    host = f"127.0.1.{_next_host[0]}"
    with socket.socket() as probe:
        try:
            probe.bind((host, 0))
        except OSError:
            pytest.skip(f"cannot bind the loopback address {host} here")
    return host


def _from(host: str) -> httpx.HTTPTransport:
    return httpx.HTTPTransport(local_address=host)


def _status(srv: ServerProc | Live, token: str | None, host: str, **headers: str) -> int:
    with srv.client(token, transport=_from(host)) as c:
        return c.get("/whoami", headers=headers).status_code


def _poll_until(check: object, deadline_s: float) -> float:
    """Seconds until ``check()`` is true, polling without sleeping; fails after ``deadline_s``."""
    assert callable(check)
    start = time.monotonic()
    while not check():
        assert time.monotonic() - start < deadline_s, f"not within {deadline_s} s"
    return time.monotonic() - start


# --- two processes, one database -----------------------------------------------------------------------


@pytest.mark.parametrize("backend", ["postgresql", "sqlite"])
def test_two_processes_share_the_failure_budget(backend: str, tmp_path: Path) -> None:
    """Also: `linemap server` itself ignores forwarded headers from a local client (uvicorn's own proxy
    handling would believe them from 127.0.0.1), so a new forged address per guess evades nothing."""
    host, other = "127.0.0.1", _address()
    with (
        fresh_database(backend, tmp_path) as url,
        server_procs(url, 2, auth_fail_limit=LIMIT, auth_fail_delay_s=0) as (procs, admin),
    ):
        a, b = procs
        for i in range(LIMIT):  # alternate: each process sees only half of the failures
            forged = {"X-Forwarded-For": f"198.51.100.{i}"}
            assert _status(a if i % 2 else b, WRONG, host, **forged) == 401, i
        # Together they reached the limit: both refuse the next guess (N processes do not give N budgets).
        assert _status(a, WRONG, host) == 429
        assert _status(b, WRONG, host) == 429
        # A valid token from the same address still works on both; another address is not affected.
        assert _status(a, admin, host) == 200 and _status(b, admin, host) == 200
        assert _status(b, WRONG, other) == 401


@pytest.fixture(params=["postgresql", "sqlite"])
def two_servers(
    request: pytest.FixtureRequest, tmp_path: Path
) -> Iterator[tuple[ServerProc, ServerProc, str]]:
    # No limit on failed authentications: the revocation tests check dozens of revoked tokens from one
    # address, which the default limit (50) would answer 429 instead of 401.
    with (
        fresh_database(request.param, tmp_path) as url,
        server_procs(url, 2, auth_fail_limit=0) as (procs, admin),
    ):
        yield procs[0], procs[1], admin


def _stream_lines(
    srv: ServerProc, token: str, robot_id: int, ended: threading.Event, lines: list[str]
) -> None:
    try:
        with srv.client(token) as c, c.stream("GET", f"/robots/{robot_id}/maps/stream", timeout=30) as r:
            assert r.status_code == 200
            for line in r.iter_lines():
                lines.append(line)
    except httpx.HTTPError as exc:
        lines.append(f"error: {exc!r}")
    finally:
        ended.set()


def test_revocation_reaches_the_other_process_within_a_second(
    two_servers: tuple[ServerProc, ServerProc, str],
) -> None:
    a, b, admin = two_servers
    with a.client(admin) as op:
        parent = op.post("/tokens", json={"name": "leaked"}).json()
    with b.client(parent["token"]) as leaked:  # the leaked token works on B and mints there
        child = leaked.post("/tokens", json={"name": "minted"}).json()
        with b.client(child["token"]) as minted:
            grandchild = minted.post("/tokens", json={"name": "minted-2"}).json()
        robot = leaked.post("/robots", json={"name": "minted-robot"}).json()
        assert leaked.get("/whoami").status_code == 200
    ended, lines = threading.Event(), list[str]()
    reader = threading.Thread(target=_stream_lines, args=(b, parent["token"], robot["id"], ended, lines))
    reader.start()
    _poll_until(lambda: any(line.startswith("event: snapshot") for line in lines), 30)  # stream is open
    with a.client(admin) as op:
        assert op.delete(f"/tokens/{parent['id']}").status_code == 204
    revoked_at = time.monotonic()
    _poll_until(lambda: _status(b, parent["token"], "127.0.0.1") == 401, REVOKE_DEADLINE_S)
    # Cascaded, refused everywhere within the promise, counted from the revocation. Each token has its
    # own cache entry on B: the parent can be refused there at once (its open stream re-checks it past
    # the cache) while a child's entry is still live for up to credential_cache_s, so each is polled.
    for token in (child["token"], grandchild["token"], robot["token"]):
        assert _status(a, token, "127.0.0.1") == 401  # the revoking process forgets at once
        left_s = REVOKE_DEADLINE_S - (time.monotonic() - revoked_at)
        _poll_until(lambda t=token: _status(b, t, "127.0.0.1") == 401, max(left_s, 0.0))
    _poll_until(ended.is_set, REVOKE_DEADLINE_S)
    reader.join(5)
    assert not any(line.startswith("error") for line in lines), lines
    assert _status(b, admin, "127.0.0.1") == 200
    with b.client(admin) as op:
        log = op.get("/audit", params={"limit": 20}).json()
    revoked = {(e["action"], e["target"]): e["detail"] for e in log if e["action"].endswith("revoke")}
    assert revoked[("token.revoke", f"operator:{parent['id']}")] == {"name": "leaked"}
    assert revoked[("token.revoke", f"operator:{child['id']}")]["cascade_from"] == parent["id"]
    assert revoked[("token.revoke", f"operator:{grandchild['id']}")]["cascade_from"] == child["id"]
    assert revoked[("robot.token.revoke", f"robot:{robot['id']}")]["root"] == parent["id"]


def test_a_revoked_token_cannot_mint_a_surviving_token_on_another_process(
    two_servers: tuple[ServerProc, ServerProc, str],
) -> None:
    """The leaked token creates tokens on B as fast as it can while A revokes it: every token B handed
    out is refused afterwards (none outlives the revocation)."""
    a, b, admin = two_servers
    with a.client(admin) as op:
        leaked = op.post("/tokens", json={"name": "leaked"}).json()
    minted: list[str] = []
    refused = threading.Event()

    def mint() -> None:
        with b.client(leaked["token"]) as c:
            while True:
                r = c.post("/tokens", json={"name": "persist"})
                if r.status_code != 201:
                    assert r.status_code == 401, r.text
                    refused.set()
                    return
                minted.append(r.json()["token"])

    worker = threading.Thread(target=mint)
    worker.start()
    _poll_until(lambda: len(minted) >= 5, 30)
    with a.client(admin) as op:
        assert op.delete(f"/tokens/{leaked['id']}").status_code == 204
    _poll_until(refused.is_set, REVOKE_DEADLINE_S + 5)
    worker.join(10)
    assert minted
    survivors = [t for t in minted if _status(b, t, "127.0.0.1") != 401 or _status(a, t, "127.0.0.1") != 401]
    assert survivors == [], f"{len(survivors)} of {len(minted)} minted tokens outlived the revocation"


# --- forwarded headers -----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def proxied(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Live, str]]:
    """One server that trusts a single proxy address (and nothing else)."""
    proxy = _address()
    for server in start_live(
        "sqlite",
        tmp_path_factory.mktemp("auth-proxy"),
        auth_fail_limit=LIMIT,
        auth_fail_delay_s=0,
        trusted_proxies=proxy,
    ):
        yield server, proxy


def test_forged_forwarded_headers_from_an_untrusted_client_change_nothing(proxied: tuple[Live, str]) -> None:
    live, _proxy = proxied
    attacker, victim = _address(), _address()
    # Evade: a new forged address with every guess; still one source, blocked after LIMIT.
    for i in range(LIMIT):
        forged = {"X-Forwarded-For": f"198.51.100.{i}", "Forwarded": f"for=198.51.100.{i}"}
        assert _status(live, WRONG, attacker, **forged) == 401
    assert _status(live, WRONG, attacker, **{"X-Forwarded-For": "198.51.100.77"}) == 429
    # Aim: the attacker names the victim's address; the victim is not blocked, the attacker is.
    for _ in range(2 * LIMIT):
        _status(live, WRONG, attacker, **{"X-Forwarded-For": victim, "Forwarded": f"for={victim}"})
    assert _status(live, WRONG, victim) == 401
    assert _status(live, live.admin_token, attacker, **{"X-Forwarded-For": victim}) == 200


def test_a_trusted_proxy_names_the_client(proxied: tuple[Live, str]) -> None:
    live, proxy = proxied
    client_a, client_b = "203.0.113.10", "203.0.113.11"
    for _ in range(LIMIT):
        # A spoofed left part is ignored: the proxy appends the real client on the right.
        assert _status(live, WRONG, proxy, **{"X-Forwarded-For": f"10.9.9.9, {client_a}"}) == 401
    assert _status(live, WRONG, proxy, **{"X-Forwarded-For": client_a}) == 429
    assert _status(live, WRONG, proxy, **{"X-Forwarded-For": client_b}) == 401  # another client behind it
    assert _status(live, live.admin_token, proxy, **{"X-Forwarded-For": client_a}) == 200
    # IPv6 clients count per /64: the neighbours of one host share its budget.
    for i in range(LIMIT):
        assert _status(live, WRONG, proxy, **{"X-Forwarded-For": f"2001:db8:1:2::{i + 1}"}) == 401
    assert _status(live, WRONG, proxy, **{"X-Forwarded-For": "2001:db8:1:2::ffff"}) == 429
    assert _status(live, WRONG, proxy, **{"X-Forwarded-For": "2001:db8:1:3::1"}) == 401
