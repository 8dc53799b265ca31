"""Typed dependencies: the application state, and who is asking (operator or robot) with what access.

Credentials: ``Authorization: Bearer <token>`` (operator token ``lmo_...`` or robot token ``lmr_...``), or
the browser's session cookie (operators only). Lookups go by the token's SHA-256 (an indexed read); a
cache of at most ``credential_cache_s`` (<= 1 s), re-checked in bulk in the background
(:mod:`server.credcache`), spares the database a read per request, so a token revoked or expired on any
server process stops working everywhere within that time (in the revoking process at once). Streams
re-check their credential often, against answers at most 0.5 s old (:func:`still_valid`).

The failed-authentication limit lives in :mod:`server.limiter`.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime, timedelta
from typing import Annotated

from fastapi import Depends, Header, Request
from fastapi.concurrency import run_in_threadpool
from sqlalchemy import Connection, bindparam, select, update

from server.agents import InstanceCheck
from server.credbatch import LookupBatcher
from server.credcache import CredentialCache, Kind, Principal, credential_kind, find_principals
from server.csrf import CSRF_HEADER, require_csrf_token
from server.database import Database
from server.errors import AuthError, ForbiddenError
from server.hub import Hub
from server.limiter import AuthLimiter, retry_after_header
from server.models import Robot, utcnow
from server.pollsweep import PollSweep
from server.recentmaps import RecentMaps
from server.security import SESSION_PREFIX, hash_token
from server.settings import Settings
from server.writer import WriteBatcher
from shared.protocol import AGENT_INSTANCE_HEADER, MAP_SESSION_PATTERN, anchored

__all__ = [
    "SESSION_COOKIE",
    "AgentChecked",
    "AppState",
    "AuthLimiter",
    "OperatorDep",
    "Principal",
    "PrincipalDep",
    "RobotSelf",
    "StateDep",
    "check_instance",
    "presence",
    "require_operator",
    "retry_after_header",
    "robot_access",
    "robot_self",
    "still_valid",
]

SESSION_COOKIE = "linemap_session"
#: :func:`still_valid` takes a cached answer only if its database read began at most this long ago (s).
STILL_VALID_MAX_AGE_S = 0.5


@dataclass
class AppState:
    """Everything a request handler needs, created once per application."""

    settings: Settings
    db: Database
    writer: WriteBatcher
    hub: Hub = field(default_factory=Hub)
    recent_maps: RecentMaps = field(default_factory=RecentMaps)
    limiter: AuthLimiter = field(init=False)
    instances: InstanceCheck = field(init=False)  # the agent process speaking for each robot
    credentials: CredentialCache = field(init=False)
    polls: PollSweep = field(init=False)  # the long-polls' safety net (server.pollsweep)
    lookups: LookupBatcher = field(init=False)  # cache misses answered together (server.credbatch)
    _seen: dict[int, datetime] = field(default_factory=dict)
    _seen_mono: dict[int, float] = field(default_factory=dict)  # time.monotonic() when last heard from
    mono_clock: Callable[[], float] = time.monotonic
    _unflushed: dict[int, datetime] = field(default_factory=dict)
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def __post_init__(self) -> None:
        self.instances = InstanceCheck(self.db)
        self.limiter = AuthLimiter.from_settings(self.settings, self.db)
        self.credentials = CredentialCache(self.settings.credential_cache_s)
        self.polls = PollSweep(self.hub, self.read_seqs)
        self.lookups = LookupBatcher(lambda batch: run_in_threadpool(self.lookup_many, batch))

    def read_seqs(self, ids: list[int]) -> dict[int, int]:
        """``{robot_id: last_seq}`` of the robots among ``ids`` that exist (blocking; a worker thread).
        One statement per 1,000 ids."""
        out: dict[int, int] = {}
        with self.db.read() as s:
            for start in range(0, len(ids), 1000):
                q = select(Robot.id, Robot.last_seq).where(Robot.id.in_(ids[start : start + 1000]))
                out.update((int(rid), int(seq)) for rid, seq in s.execute(q))
        return out

    def forget_credentials(self) -> None:
        """Drop cached lookups (after a token is revoked or a session closed)."""
        self.credentials.clear()

    def cached(self, credential: str, max_age_s: float | None = None) -> tuple[str, Principal | None, bool]:
        """``(hash, principal, hit)`` from the cache alone (cheap enough for the event loop); ``max_age_s``:
        see :meth:`CredentialCache.get`."""
        key = hash_token(credential)
        if credential_kind(credential) is None:
            return key, None, True  # no known prefix: no table holds it, no read needed
        found, hit = self.credentials.get(key, max_age_s)
        return key, found, hit

    async def principal(self, credential: str) -> Principal | None:
        """The principal behind a bearer token or session id, or ``None``: from the cache, else from the
        next read of the misses that arrived together (:mod:`server.credbatch`). On the event loop."""
        key, found, hit = self.cached(credential)
        if hit:
            return found
        kind = credential_kind(credential)
        return None if kind is None else await self.lookups.get(key, kind)

    def lookup_many(self, batch: dict[Kind, list[str]]) -> dict[str, Principal | None]:
        """The principals behind the credential hashes of ``batch`` (``{kind: [hash, ...]}``, None for those
        not valid), in one read, each answer cached. Blocking: call it from a worker thread."""
        begun = self.credentials.started()
        out: dict[str, Principal | None] = {}
        with self.db.read() as s:
            for kind, keys in batch.items():
                found = find_principals(s, kind, keys)
                for key in keys:
                    out[key] = found.get(key)
                    self.credentials.put(key, kind, out[key], begun)
        return out

    def lookup(self, credential: str, *, fresh: bool = False) -> Principal | None:
        """The principal behind a bearer token or session id, or ``None`` (cache, then database; only the
        database when ``fresh``). Blocking: call it from a worker thread."""
        key, found, hit = self.cached(credential)
        if hit and not fresh:
            return found
        kind = credential_kind(credential)
        if kind is None:
            return None
        begun = self.credentials.started()
        with self.db.read() as s:
            found = find_principals(s, kind, [key]).get(key)
        self.credentials.put(key, kind, found, begun)
        return found

    async def authenticate(self, credential: str) -> bool:
        """Whether ``credential`` is a valid token or session now (cache first; on the event loop)."""
        return await self.principal(credential) is not None

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

    def flush_seen(self, conn: Connection | None = None, *, shard: tuple[int, int] | None = None) -> None:
        """Write the last-seen times noted since the previous flush (one executemany; in ``conn``'s
        transaction when given, e.g. a write batch). Reads merge in the newer in-memory times.
        ``shard=(k, n)``: only the robots whose id is ``k`` modulo ``n`` (the robots of one writer thread,
        :meth:`server.writer.WriteBatcher.shard`: their rows are written by that thread alone)."""
        with self._lock:
            if shard is None:
                pending, self._unflushed = self._unflushed, {}
            else:
                k, n = shard
                pending = {rid: at for rid, at in self._unflushed.items() if rid % n == k}
                for rid in pending:
                    del self._unflushed[rid]
        if not pending:
            return
        rows = [{"rid": rid, "at": at} for rid, at in sorted(pending.items())]
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
    the event loop; only a cache miss reads the database (in the thread pool). The cookie holds session
    ids only, and a state-changing request authenticated by it needs its CSRF token (:mod:`server.csrf`,
    403 otherwise)."""
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
        if not credential.startswith(SESSION_PREFIX):  # a token belongs in Authorization, never a cookie
            raise AuthError(
                f"the session cookie holds a session id ({SESSION_PREFIX}...), not a token: log in again"
            )
    request.state.credential = credential  # for streams that re-check it (still_valid)
    found = await state.principal(credential)
    if found is None:
        raise AuthError("unknown or revoked token" if header else "session expired or unknown: log in again")
    if not header and found.kind != "operator":
        raise AuthError("session expired or unknown: log in again")
    if not header:  # the cookie authenticates: a state-changing request must prove it is the dashboard's
        require_csrf_token(request.method, credential, request.headers.get(CSRF_HEADER))
    if found.kind == "robot":
        state.mark_seen(found.id)
    return found


PrincipalDep = Annotated[Principal, Depends(get_principal)]


async def still_valid(request: Request, state: AppState) -> bool:
    """Whether the credential this request was authenticated with still works: a stream calls it every
    fraction of a second and ends when it says no (revoked token, revoked parent token, closed or expired
    session, rotated robot token), whichever process revoked it. Answered from the cache only when that
    answer's database read began at most ``STILL_VALID_MAX_AGE_S`` ago (the cache re-checks the
    credentials in use every ``credential_cache_s / 2``: :mod:`server.credcache`), else read from the
    database. A thread-pool read per stream and check was slow under load (1.8 s median measured under
    server_load: the stream fell seconds behind its map)."""
    credential = getattr(request.state, "credential", None)
    if not credential:
        return False
    _key, found, hit = state.cached(credential, STILL_VALID_MAX_AGE_S)
    if hit:
        return found is not None
    return await run_in_threadpool(lambda: state.lookup(credential, fresh=True) is not None)


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


async def check_instance(
    robot_id: int,
    who: PrincipalDep,
    state: StateDep,
    instance: Annotated[
        str | None,
        Header(
            alias=AGENT_INSTANCE_HEADER,
            pattern=anchored(MAP_SESSION_PATTERN),
            description="The agent process's instance id (a lower-case UUID).",
        ),
    ] = None,
) -> None:
    """Dependency of the robot's own routes (uploads, polls, acknowledgements): refuse a superseded agent."""
    if instance is None or who.kind != "robot" or who.id != robot_id:
        return
    if state.instances.fresh(robot_id, instance):
        return
    await run_in_threadpool(state.instances.check, robot_id, instance, who.actor)


AgentChecked = Depends(check_instance)
