"""Typed dependencies: the application state, and who is asking (operator or robot) with what access.

Credentials: ``Authorization: Bearer <token>`` (operator token ``lmo_...`` or robot token ``lmr_...``), or
the browser's session cookie (operators only). Lookups go by the token's SHA-256; a small cache (a few
seconds) spares the database a read per request, so a revoked token stops working within that time.

:class:`AuthLimiter` counts failed authentications per client address (issue 9 item 5): after
``auth_fail_limit`` failures within ``auth_fail_window_s`` the address is refused with 429 for
``auth_block_s`` (enforced by :class:`server.app.AuthFailureLimit`).
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime, timedelta
from typing import Annotated, Literal

from fastapi import Depends, Request
from fastapi.concurrency import run_in_threadpool
from sqlalchemy import Connection, bindparam, select, update

from server.database import Database
from server.errors import AuthError, ForbiddenError
from server.hub import Hub
from server.models import OperatorToken, Robot, Session, utcnow
from server.security import OPERATOR_PREFIX, ROBOT_PREFIX, SESSION_PREFIX, hash_token
from server.settings import Settings
from server.writer import WriteBatcher

__all__ = [
    "SESSION_COOKIE",
    "AppState",
    "AuthLimiter",
    "OperatorDep",
    "Principal",
    "PrincipalDep",
    "RobotSelf",
    "StateDep",
    "presence",
    "require_operator",
    "retry_after_header",
    "robot_access",
    "robot_self",
]

SESSION_COOKIE = "linemap_session"
_CACHE_S = 5.0


@dataclass(frozen=True, slots=True)
class Principal:
    """Who is asking: an operator (token or session) or one robot."""

    kind: Literal["operator", "robot"]
    id: int
    name: str

    @property
    def actor(self) -> str:
        """How the audit log names this principal."""
        return f"{self.kind}:{self.name}"


class AuthLimiter:
    """Failed authentications per client address, in memory (one server process), with a sliding window.

    :meth:`failed` notes one failure of ``client``; when ``limit`` of them fall within ``window_s`` seconds,
    the client is blocked for ``block_s`` seconds and its count starts again afterwards. :meth:`retry_after`
    says how many seconds of a block are left (``None``: not blocked). Successful authentications neither
    count nor reset the count (a valid token cannot be used to keep guessing another). ``limit`` 0 disables
    it. Memory: at most ``max_clients`` addresses tracked (expired ones are pruned first, then the oldest
    dropped, then the blocks that end first); ``limit`` times per address. Each call is O(1) amortised
    (O(max_clients) when pruning), under a lock (thread-safe). ``clock`` (seconds, monotonic) can be
    replaced, e.g. by a test that steps time.
    """

    def __init__(
        self,
        limit: int,
        window_s: float,
        block_s: float,
        *,
        clock: Callable[[], float] = time.monotonic,
        max_clients: int = 10_000,
    ) -> None:
        self.limit, self.window_s, self.block_s = limit, window_s, block_s
        self.clock = clock
        self.max_clients = max_clients
        self._fails: dict[str, deque[float]] = {}
        self._blocked: dict[str, float] = {}
        self._lock = threading.Lock()

    @classmethod
    def from_settings(cls, settings: Settings) -> AuthLimiter:
        return cls(settings.auth_fail_limit, settings.auth_fail_window_s, settings.auth_block_s)

    @property
    def enabled(self) -> bool:
        return self.limit > 0

    def retry_after(self, client: str) -> float | None:
        """Seconds until ``client`` may try again, or ``None`` when it is not blocked."""
        if not self.enabled:
            return None
        with self._lock:
            until = self._blocked.get(client)
            if until is None:
                return None
            left = until - self.clock()
            if left <= 0:
                del self._blocked[client]
                return None
            return left

    def failed(self, client: str) -> None:
        """Note a failed authentication by ``client``; block it when that makes ``limit`` in the window."""
        if not self.enabled:
            return
        now = self.clock()
        with self._lock:
            times = self._fails.setdefault(client, deque())
            times.append(now)
            while times and times[0] <= now - self.window_s:
                times.popleft()
            if len(times) >= self.limit:
                del self._fails[client]
                self._blocked[client] = now + self.block_s
            if len(self._fails) + len(self._blocked) > self.max_clients:
                self._prune(now)

    def tracked(self) -> int:
        """How many client addresses are held in memory (counting or blocked)."""
        with self._lock:
            return len(self._fails) + len(self._blocked)

    def clear(self) -> None:
        """Forget every count and block."""
        with self._lock:
            self._fails.clear()
            self._blocked.clear()

    def _prune(self, now: float) -> None:
        for client in [c for c, t in self._fails.items() if not t or t[-1] <= now - self.window_s]:
            del self._fails[client]
        for client in [c for c, until in self._blocked.items() if until <= now]:
            del self._blocked[client]
        while self._fails and len(self._fails) + len(self._blocked) > self.max_clients:
            del self._fails[next(iter(self._fails))]  # the longest-tracked address goes first
        while len(self._blocked) > self.max_clients:
            del self._blocked[next(iter(self._blocked))]  # the block that ends first


def retry_after_header(seconds: float) -> str:
    """``Retry-After`` value: whole seconds, rounded up (at least 1)."""
    return str(max(1, math.ceil(seconds)))


@dataclass
class AppState:
    """Everything a request handler needs, created once per application."""

    settings: Settings
    db: Database
    writer: WriteBatcher
    hub: Hub = field(default_factory=Hub)
    limiter: AuthLimiter = field(init=False)
    _cache: dict[str, tuple[float, Principal | None]] = field(default_factory=dict)
    _seen: dict[int, datetime] = field(default_factory=dict)
    _seen_mono: dict[int, float] = field(default_factory=dict)  # time.monotonic() when last heard from
    mono_clock: Callable[[], float] = time.monotonic
    _unflushed: dict[int, datetime] = field(default_factory=dict)
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def __post_init__(self) -> None:
        self.limiter = AuthLimiter.from_settings(self.settings)

    def forget_credentials(self) -> None:
        """Drop cached lookups (after a token is revoked or a session closed)."""
        with self._lock:
            self._cache.clear()

    def cached(self, credential: str) -> tuple[str, Principal | None, bool]:
        """``(hash, principal, hit)`` from the cache alone (cheap enough for the event loop)."""
        key = hash_token(credential)
        with self._lock:
            hit = self._cache.get(key)
        if hit is not None and hit[0] > time.monotonic():
            return key, hit[1], True
        return key, None, False

    def lookup(self, credential: str) -> Principal | None:
        """The principal behind a bearer token or session id, or ``None`` (cache, then database)."""
        key, found, hit = self.cached(credential)
        if hit:
            return found
        found = self._lookup_db(credential, key)
        with self._lock:
            if len(self._cache) > 10_000:
                self._cache.clear()
            self._cache[key] = (time.monotonic() + _CACHE_S, found)
        return found

    def _lookup_db(self, credential: str, key: str) -> Principal | None:
        with self.db.read() as s:
            if credential.startswith(ROBOT_PREFIX):
                robot = s.scalars(select(Robot).where(Robot.token_hash == key)).first()
                return None if robot is None else Principal("robot", robot.id, robot.name)
            if credential.startswith(OPERATOR_PREFIX):
                op = s.scalars(
                    select(OperatorToken).where(
                        OperatorToken.token_hash == key, OperatorToken.revoked_at.is_(None)
                    )
                ).first()
                return None if op is None else Principal("operator", op.id, op.name)
            if credential.startswith(SESSION_PREFIX):
                row = s.execute(
                    select(OperatorToken, Session)
                    .join(Session, Session.operator_id == OperatorToken.id)
                    .where(Session.token_hash == key, OperatorToken.revoked_at.is_(None))
                ).first()
                if row is None or row[1].expires_at <= utcnow():
                    return None
                return Principal("operator", row[0].id, row[0].name)
        return None

    def mark_seen(self, robot_id: int) -> None:
        """Note that the robot was heard from now (in memory, on the wall clock for display and storage and
        on the monotonic clock for "online"; :meth:`flush_seen` writes the wall time down)."""
        now = utcnow()
        self._seen[robot_id] = now
        self._seen_mono[robot_id] = self.mono_clock()
        with self._lock:
            self._unflushed[robot_id] = now

    def last_seen(self, robot_id: int) -> datetime | None:
        """When the robot was last heard from, if later than what the database holds."""
        return self._seen.get(robot_id)

    def presence(self, robot_id: int, stored: datetime | None) -> tuple[datetime | None, bool]:
        """``(last_seen_at, online)`` of a robot whose stored ``last_seen_at`` is ``stored``: see
        :func:`presence`."""
        mono = self._seen_mono.get(robot_id)
        age_s = None if mono is None else self.mono_clock() - mono
        return presence(stored, self._seen.get(robot_id), age_s, utcnow(), self.settings.online_window_s)

    def flush_seen(self, conn: Connection | None = None) -> None:
        """Write the last-seen times noted since the previous flush (one executemany; in ``conn``'s
        transaction when given, e.g. a write batch). Reads merge in the newer in-memory times."""
        with self._lock:
            pending, self._unflushed = self._unflushed, {}
        if not pending:
            return
        rows = [{"rid": rid, "at": at} for rid, at in pending.items()]
        stmt = update(Robot).where(Robot.id == bindparam("rid")).values(last_seen_at=bindparam("at"))
        if conn is not None:
            conn.execute(stmt, rows)
            return
        with self.db.write_conn() as own:
            own.execute(stmt, rows)

    def session_expiry(self) -> timedelta:
        return timedelta(seconds=self.settings.session_ttl_s)


def presence(
    stored: datetime | None,
    memory: datetime | None,
    memory_age_s: float | None,
    now: datetime,
    window_s: float,
) -> tuple[datetime | None, bool]:
    """``(last_seen_at, online)`` from the stored last-seen time (any process may have written it, wall
    clock), this process' own (``memory``, with its age on the monotonic clock) and the wall clock ``now``.

    Online: heard from by this process within ``window_s`` on the monotonic clock, or a stored time newer
    than this process' own and at most ``window_s`` old on the wall clock (another process heard from it).
    A stored time more than ``window_s`` in the future means the clock stepped back since it was written: it
    proves nothing and is ignored (otherwise a silent robot would read online for as long as the step). So
    a robot this process has heard from reads offline ``window_s`` after it fell silent whatever the wall
    clock did; one known only from the database, within 2 x ``window_s`` of a step back (unless the step
    equals its silence to within ``window_s``: the wall clock is all there is then). O(1). See
    docs/reliability/agent.md."""
    window = timedelta(seconds=window_s)
    credible = stored if stored is not None and stored - now <= window else None
    if credible is not None and memory is not None and memory_age_s is not None and credible <= memory:
        credible = None  # what this process wrote itself: its monotonic age says more than the wall clock
    online = memory_age_s is not None and 0.0 <= memory_age_s <= window_s
    if credible is not None and now - credible <= window:
        online = True
    known = [t for t in (memory, credible) if t is not None]
    return (max(known) if known else stored), online


async def get_state(request: Request) -> AppState:
    state: AppState = request.app.state.linemap
    return state


StateDep = Annotated[AppState, Depends(get_state)]


async def get_principal(request: Request, state: StateDep) -> Principal:
    """The caller, from the bearer token or else the session cookie; 401 when neither is valid. Runs on
    the event loop; only a cache miss reads the database (in the thread pool)."""
    header = request.headers.get("authorization")
    if header:
        scheme, _, credential = header.partition(" ")
        credential = credential.strip()
        if scheme.lower() != "bearer" or not credential:
            raise AuthError("expected 'Authorization: Bearer <token>'")
    else:
        credential = request.cookies.get(SESSION_COOKIE) or ""
        if not credential:
            raise AuthError("no credential: send 'Authorization: Bearer <token>' or log in")
    _key, found, hit = state.cached(credential)
    if not hit:
        found = await run_in_threadpool(state.lookup, credential)
    if found is None:
        raise AuthError("unknown or revoked token" if header else "session expired or unknown: log in again")
    if not header and found.kind != "operator":
        raise AuthError("session expired or unknown: log in again")
    if found.kind == "robot":
        state.mark_seen(found.id)
    return found


PrincipalDep = Annotated[Principal, Depends(get_principal)]


async def require_operator(who: PrincipalDep) -> Principal:
    if who.kind != "operator":
        raise ForbiddenError("this route is for operators; robot tokens reach only their own robot's routes")
    return who


OperatorDep = Annotated[Principal, Depends(require_operator)]


async def robot_access(robot_id: int, who: PrincipalDep) -> Principal:
    """An operator, or the robot ``robot_id`` itself."""
    if who.kind == "robot" and who.id != robot_id:
        raise ForbiddenError(f"this robot token belongs to robot {who.id}, not robot {robot_id}")
    return who


async def robot_self(robot_id: int, who: PrincipalDep) -> Principal:
    """Only the robot ``robot_id`` itself (it uploads its maps and acknowledges its messages)."""
    if who.kind != "robot":
        raise ForbiddenError(f"only robot {robot_id}'s own token may do this")
    if who.id != robot_id:
        raise ForbiddenError(f"this robot token belongs to robot {who.id}, not robot {robot_id}")
    return who


RobotSelf = Annotated[Principal, Depends(robot_self)]
