"""The failed-authentication limit: shared by every server process, never in the way of a valid credential.

Rules (docs/reliability/auth-processes.md):

- Only *failures* count and cost anything: an API request that carries a credential and is answered 401 is
  one failure of its *source*. Successes are never counted, never written, never delayed.
- Counts live in the database (table ``auth_failures``, one row per source and window, written by one
  atomic upsert per failure), so N server processes on one database give a source one budget, not N.
  A process remembers the blocks it learnt of, so a blocked source's further failures cost no write.
- Over the budget (``limit`` failures within ``window_s``), the source's *failed* attempts are answered 429
  with ``Retry-After`` (after ``delay_s``) for ``block_s``. A valid token or session from that same
  source is served as usual: while a source is blocked, the middleware decides validity first by the
  credential's hash lookup (the same indexed lookup every request does, so the answer's timing says
  nothing about how close a guess was), and only an invalid credential is refused.
- The source is the TCP peer address. ``X-Forwarded-For`` / ``Forwarded`` are read only when the peer is
  one of the operator's ``trusted_proxies``; then the client is the right-most address in the header that
  is not itself a trusted proxy. IPv6 sources count per /64 (one host usually holds a whole /64).
"""

from __future__ import annotations

import asyncio
import ipaddress
import logging
import math
import threading
import time
from collections.abc import Callable, Sequence
from typing import Literal, cast

from sqlalchemy import Table, and_, case, delete, null, or_
from sqlalchemy.dialects.postgresql import insert as pg_insert
from sqlalchemy.dialects.sqlite import insert as sqlite_insert
from sqlalchemy.sql.dml import ReturningInsert
from starlette.responses import JSONResponse
from starlette.types import Scope, Send

from server.database import Database
from server.models import AuthFailure
from server.settings import Settings

__all__ = [
    "AuthLimiter",
    "IPNetwork",
    "client_source",
    "retry_after_header",
    "source_key",
    "via_https",
]

log = logging.getLogger(__name__)

IPNetwork = ipaddress.IPv4Network | ipaddress.IPv6Network
_IP = ipaddress.IPv4Address | ipaddress.IPv6Address
#: At most this many refusals are held back by ``delay_s`` at once per process (beyond, answered at once),
#: so the delay cannot be turned into a way of holding the server's sockets.
MAX_HELD = 256


def retry_after_header(seconds: float) -> str:
    """``Retry-After`` value: whole seconds, rounded up (at least 1)."""
    return str(max(1, math.ceil(seconds)))


def _parse_ip(text: str) -> _IP | None:
    """An address from a peer or forwarded value (``1.2.3.4``, ``1.2.3.4:80``, ``[::1]:80``, ``::1``)."""
    text = text.strip().strip('"')
    if text.startswith("["):
        text = text[1 : text.find("]")] if "]" in text else ""
    elif text.count(":") == 1:
        text = text.split(":", 1)[0]
    try:
        return ipaddress.ip_address(text)
    except ValueError:
        return None


def source_key(ip: _IP) -> str:
    """What the limit counts by: an IPv4 address, or the /64 of an IPv6 one (IPv4-mapped: the IPv4)."""
    if isinstance(ip, ipaddress.IPv6Address):
        if ip.ipv4_mapped is not None:
            return str(ip.ipv4_mapped)
        return str(ipaddress.ip_network(f"{ip}/64", strict=False))
    return str(ip)


def _forwarded_hops(headers: Sequence[tuple[bytes, bytes]], header: str) -> list[str]:
    """The addresses a proxy chain names, left (first client) to right (nearest proxy)."""
    values = [v.decode("latin-1") for k, v in headers if k == header.encode()]
    hops: list[str] = []
    for element in ",".join(values).split(","):
        if header == "x-forwarded-for":
            hops.append(element.strip())
            continue
        found = ""
        for pair in element.split(";"):
            name, _, value = pair.strip().partition("=")
            if name.lower() == "for":
                found = value
        hops.append(found)
    return hops


def _trusted(ip: _IP, networks: Sequence[IPNetwork]) -> bool:
    if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
        ip = ip.ipv4_mapped
    return any(ip.version == n.version and ip in n for n in networks)


def client_source(
    scope: Scope,
    networks: Sequence[IPNetwork] = (),
    header: Literal["x-forwarded-for", "forwarded"] = "x-forwarded-for",
) -> str:
    """The source a request is counted against (see the module docstring). O(header length)."""
    client = scope.get("client")
    peer = str(client[0]) if client else ""
    ip = _parse_ip(peer)
    if ip is None:
        return peer or "unknown"
    if networks and _trusted(ip, networks):
        for hop in reversed(_forwarded_hops(scope.get("headers", ()), header)):
            named = _parse_ip(hop)
            if named is None:  # garbage or "unknown": the nearest trusted proxy is all we know
                break
            ip = named
            if not _trusted(named, networks):
                break
    return source_key(ip)


def via_https(scope: Scope, networks: Sequence[IPNetwork] = ()) -> bool:
    """Whether the client reached us over HTTPS: the connection's own scheme, or ``X-Forwarded-Proto:
    https`` (or ``Forwarded: proto=https``) set by a trusted proxy (``networks``) that is the TCP peer.
    The header is ignored from any other peer."""
    if scope.get("scheme") == "https":
        return True
    client = scope.get("client")
    ip = _parse_ip(str(client[0])) if client else None
    if ip is None or not networks or not _trusted(ip, networks):
        return False
    for name, value in scope.get("headers", ()):
        text = value.decode("latin-1").lower()
        if name == b"x-forwarded-proto" and text.split(",")[-1].strip() == "https":
            return True
        if name == b"forwarded" and "proto=https" in text.split(",")[-1].replace(" ", ""):
            return True
    return False


class AuthLimiter:
    """Failed authentications per source in the database, shared by every process on it.

    :meth:`failed` (blocking: call it from a worker thread) notes one failure with a single atomic upsert
    and says whether the source was already over the limit (then answer 429). :meth:`blocked_for` answers
    from this process's memory alone (O(1), fine on the event loop). ``limit`` 0 disables the limiter.
    ``clock`` gives Unix seconds (shared by processes); a test may replace it. Memory: at most
    ``max_cached`` remembered blocks. Old rows are pruned at most once per window by the failure path.
    """

    def __init__(
        self,
        db: Database,
        limit: int,
        window_s: float,
        block_s: float,
        delay_s: float = 0.0,
        *,
        clock: Callable[[], float] = time.time,
        max_cached: int = 10_000,
    ) -> None:
        self.db = db
        self.limit, self.window_s, self.block_s, self.delay_s = limit, window_s, block_s, delay_s
        self.clock = clock
        self.max_cached = max_cached
        self._blocks: dict[str, float] = {}
        self._lock = threading.Lock()
        self._pruned_at = -math.inf
        self._held = 0

    @classmethod
    def from_settings(cls, settings: Settings, db: Database) -> AuthLimiter:
        return cls(
            db,
            settings.auth_fail_limit,
            settings.auth_fail_window_s,
            settings.auth_block_s,
            settings.auth_fail_delay_s,
        )

    @property
    def enabled(self) -> bool:
        return self.limit > 0

    def blocked_for(self, source: str) -> float | None:
        """Seconds left of a block of ``source`` this process knows of, or ``None``."""
        if not self.enabled:
            return None
        with self._lock:
            until = self._blocks.get(source)
            if until is None:
                return None
            left = until - self.clock()
            if left <= 0:
                del self._blocks[source]
                return None
            return left

    def failed(self, source: str) -> float | None:
        """Count one failure of ``source``; the seconds left of its block when it was over the limit
        before this failure (answer 429), else ``None`` (answer 401; the failure that reaches the limit
        starts the block). One upsert in its own transaction."""
        if not self.enabled:
            return None
        known = self.blocked_for(source)
        if known is not None:
            return known  # already refused here: no write for the rest of the block
        now = self.clock()
        with self.db.write_conn() as conn:
            failures, until = conn.execute(self._upsert(source, now)).one()
            if now - self._pruned_at >= self.window_s:
                self._pruned_at = now
                conn.execute(
                    delete(AuthFailure).where(
                        AuthFailure.window_start_s <= now - self.window_s,
                        or_(AuthFailure.blocked_until_s.is_(None), AuthFailure.blocked_until_s <= now),
                    )
                )
        if until is None or until <= now:
            return None
        self._remember(source, until, now)
        return until - now if failures > self.limit else None

    def _upsert(self, source: str, now: float) -> ReturningInsert[int, float | None]:
        table = cast(Table, AuthFailure.__table__)
        c = table.c
        first_block = now + self.block_s if self.limit <= 1 else None
        insert = pg_insert if self.db.engine.dialect.name == "postgresql" else sqlite_insert
        stmt = insert(table).values(
            source=source, window_start_s=now, failures=1, blocked_until_s=first_block
        )
        blocked = and_(c.blocked_until_s.is_not(None), c.blocked_until_s > now)
        fresh = or_(c.blocked_until_s.is_not(None), c.window_start_s <= now - self.window_s)
        return stmt.on_conflict_do_update(
            index_elements=[c.source],
            set_={
                "window_start_s": case((blocked, c.window_start_s), (fresh, now), else_=c.window_start_s),
                "failures": case((blocked, c.failures + 1), (fresh, 1), else_=c.failures + 1),
                "blocked_until_s": case(
                    (blocked, c.blocked_until_s),
                    (fresh, first_block if first_block is not None else null()),
                    (c.failures + 1 >= self.limit, now + self.block_s),
                    else_=null(),
                ),
            },
        ).returning(c.failures, c.blocked_until_s)

    def _remember(self, source: str, until: float, now: float) -> None:
        with self._lock:
            self._blocks[source] = until
            if len(self._blocks) > self.max_cached:
                for key in [k for k, t in self._blocks.items() if t <= now]:
                    del self._blocks[key]
                while len(self._blocks) > self.max_cached:
                    del self._blocks[next(iter(self._blocks))]  # the longest-remembered first

    def cached_blocks(self) -> int:
        """How many blocks this process remembers."""
        with self._lock:
            return len(self._blocks)

    def clear(self) -> None:
        """Forget every count and block (the shared table too)."""
        with self._lock:
            self._blocks.clear()
        with self.db.write_conn() as conn:
            conn.execute(delete(AuthFailure))

    async def refuse(self, send: Send, source: str, left_s: float) -> None:
        """Answer a failed attempt of a blocked source: 429 with ``Retry-After``, after ``delay_s``."""
        if self.delay_s > 0 and self._held < MAX_HELD:
            self._held += 1
            try:
                await asyncio.sleep(self.delay_s)
            finally:
                self._held -= 1
            left_s = self.blocked_for(source) or 1.0
        seconds = retry_after_header(left_s)
        body = JSONResponse(
            {
                "error": "too_many_requests",
                "detail": f"too many failed authentications from {source}: try again in {seconds} s "
                "(valid credentials are still accepted)",
            },
            status_code=429,
            headers={"Retry-After": seconds},
        )
        await send({"type": "http.response.start", "status": 429, "headers": body.raw_headers})
        await send({"type": "http.response.body", "body": body.body})

