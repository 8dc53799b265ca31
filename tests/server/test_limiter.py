"""The limiter's source of a request (peer, trusted proxies, forwarded headers), its settings and its
bounded memory and table, in process; the limiter through real servers is in
tests/reliability/test_rel_auth_limits.py and tests/reliability/test_rel_auth_processes.py."""

from __future__ import annotations

import ipaddress
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st
from pydantic import ValidationError
from sqlalchemy import func, select

from server.database import Database
from server.limiter import AuthLimiter, IPNetwork, client_source, source_key, via_https
from server.migrate import upgrade
from server.models import AuthFailure
from server.settings import Settings
from tests.server.authlimits import SteppedClock

PROXY = [ipaddress.ip_network("10.0.0.0/8")]
EVERYTHING: list[IPNetwork] = [ipaddress.ip_network("0.0.0.0/0"), ipaddress.ip_network("::/0")]


def _scope(peer: str, *headers: tuple[str, str]) -> dict[str, object]:
    return {"client": (peer, 5555), "headers": [(k.encode(), v.encode()) for k, v in headers]}


def test_untrusted_peer_is_the_source_whatever_it_sends() -> None:
    scope = _scope("192.0.2.7", ("x-forwarded-for", "198.51.100.1"), ("forwarded", "for=198.51.100.2"))
    assert client_source(scope) == "192.0.2.7"
    assert client_source(scope, PROXY) == "192.0.2.7"
    assert client_source(scope, PROXY, "forwarded") == "192.0.2.7"


def test_trusted_proxy_chain_gives_the_rightmost_untrusted_address() -> None:
    xff = ("x-forwarded-for", "6.6.6.6, 203.0.113.5, 10.1.1.1")  # spoof, client, inner proxy
    assert client_source(_scope("10.0.0.2", xff), PROXY) == "203.0.113.5"
    split = _scope("10.0.0.2", ("x-forwarded-for", "6.6.6.6"), ("x-forwarded-for", "203.0.113.6"))
    assert client_source(split, PROXY) == "203.0.113.6"  # several header lines are one list
    garbage = _scope("10.0.0.2", ("x-forwarded-for", "203.0.113.5, not-an-address"))
    assert client_source(garbage, PROXY) == "10.0.0.2"  # what the proxy appended is unreadable: the proxy
    only_proxies = _scope("10.0.0.2", ("x-forwarded-for", "10.3.3.3, 10.4.4.4"))
    assert client_source(only_proxies, PROXY) == "10.3.3.3"
    assert client_source(_scope("10.0.0.2"), PROXY) == "10.0.0.2"  # no header: the proxy itself


def test_forwarded_header_is_read_only_when_configured() -> None:
    both = _scope(
        "10.0.0.2",
        ("forwarded", 'for="[2001:db8:cafe::17]:4711";proto=https, for=203.0.113.9;by=10.0.0.2'),
        ("x-forwarded-for", "198.51.100.4"),
    )
    assert client_source(both, PROXY, "forwarded") == "203.0.113.9"
    assert client_source(both, PROXY, "x-forwarded-for") == "198.51.100.4"
    v6 = _scope("10.0.0.2", ("forwarded", 'for="[2001:db8:cafe::17]:4711"'))
    assert client_source(v6, PROXY, "forwarded") == "2001:db8:cafe::/64"
    hidden = _scope("10.0.0.2", ("forwarded", "for=_hidden, for=unknown"))
    assert client_source(hidden, PROXY, "forwarded") == "10.0.0.2"


def test_source_keys() -> None:
    assert source_key(ipaddress.ip_address("192.0.2.1")) == "192.0.2.1"
    assert source_key(ipaddress.ip_address("::ffff:192.0.2.1")) == "192.0.2.1"
    assert source_key(ipaddress.ip_address("2001:db8:1:2:3:4:5:6")) == "2001:db8:1:2::/64"
    assert client_source({"client": None, "headers": []}) == "unknown"


def test_trusted_proxies_setting_is_validated() -> None:
    assert Settings(trusted_proxies=" 10.0.0.5 , 192.168.1.0/24,").trusted_networks() == [
        ipaddress.ip_network("10.0.0.5/32"),
        ipaddress.ip_network("192.168.1.0/24"),
    ]
    with pytest.raises(ValidationError, match="'nonsense' is not an IP address or CIDR network"):
        Settings(trusted_proxies="10.0.0.5,nonsense")
    with pytest.raises(ValidationError):
        Settings(credential_cache_s=5.0)  # a revocation must reach every process within 1 s


@given(
    peer=st.sampled_from(["127.0.0.1", "10.0.0.5", "::1", "2001:db8::7", "", "not-an-ip"]),
    values=st.lists(st.text(max_size=60), max_size=4),
    header=st.sampled_from(["x-forwarded-for", "forwarded"]),
)
def test_client_source_never_fails_and_ignores_headers_of_untrusted_peers(
    peer: str, values: list[str], header: str
) -> None:
    headers = [(header.encode(), v.encode("utf-8", "surrogateescape")) for v in values]
    scope = {"client": (peer, 1234) if peer else None, "headers": headers}
    assert client_source(scope) == client_source({"client": scope["client"], "headers": []})
    trusted = client_source(scope, EVERYTHING, header)  # type: ignore[arg-type]
    assert isinstance(trusted, str) and trusted


@pytest.mark.parametrize(
    ("peer", "headers", "scheme", "trusted", "expected"),
    [
        ("10.0.0.5", [], "https", "", True),
        ("10.0.0.5", [(b"x-forwarded-proto", b"https")], "http", "", False),  # no proxy is trusted
        ("10.0.0.5", [(b"x-forwarded-proto", b"https")], "http", "10.0.0.0/8", True),
        ("10.0.0.5", [(b"forwarded", b"for=1.2.3.4;proto=https")], "http", "10.0.0.0/8", True),
        ("192.168.1.9", [(b"x-forwarded-proto", b"https")], "http", "10.0.0.0/8", False),  # forged
        ("10.0.0.5", [(b"x-forwarded-proto", b"http")], "http", "10.0.0.0/8", False),
    ],
)
def test_https_is_believed_from_the_connection_or_a_trusted_proxy_only(
    peer: str, headers: list[tuple[bytes, bytes]], scheme: str, trusted: str, expected: bool
) -> None:
    networks = Settings(trusted_proxies=trusted).trusted_networks()
    scope = {"type": "http", "scheme": scheme, "client": (peer, 1234), "headers": headers}
    assert via_https(scope, networks) is expected


def test_memory_and_table_are_bounded(tmp_path: Path) -> None:
    """In memory: at most ``max_cached`` remembered blocks; in the table: only the last window's sources."""
    db = Database(f"sqlite:///{tmp_path / 'limits.db'}")
    upgrade(db.engine)
    t = SteppedClock()
    limiter = AuthLimiter(db, 1, 60.0, 30.0, clock=t, max_cached=100)
    try:
        for i in range(1000):
            limiter.failed(f"10.0.{i // 256}.{i % 256}")
            assert limiter.cached_blocks() <= 100
        assert limiter.failed("192.0.2.1") is None  # the limit-th failure starts the block...
        assert limiter.failed("192.0.2.1") == 30.0  # ...the next is refused, newest address remembered
        t.now_s += 61.0 + 30.0
        limiter.failed("192.0.2.2")  # prunes the rows of sources whose window and block are over
        with db.read() as s:
            assert s.scalar(select(func.count()).select_from(AuthFailure)) == 1
    finally:
        db.dispose()


def test_default_settings_limit_brute_force(tmp_path: Path) -> None:
    s = Settings()
    assert (s.auth_fail_limit, s.auth_fail_window_s, s.auth_block_s) == (50, 60.0, 60.0)
    assert s.auth_fail_delay_s == 1.0 and 0 < s.credential_cache_s <= 1.0
    assert s.trusted_proxies == "" and s.trusted_networks() == []
    db = Database(f"sqlite:///{tmp_path / 'd.db'}")
    assert AuthLimiter.from_settings(s, db).enabled
    db.dispose()
