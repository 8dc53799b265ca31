"""Credential lookups and their per-process cache, kept fresh by a bulk re-check, not a read per request.

A lookup goes by the credential's SHA-256 (:func:`find_principals`: one indexed query per kind of
credential, for one hash or many). :class:`CredentialCache` keeps each answer for at most ``ttl_s``
counted from the moment the query that produced it *began*, so an answer is never older than ``ttl_s``:
a revocation, rotation, expiry or logout committed by any process is seen by every process within
``ttl_s`` (<= 1 s, :mod:`server.settings`), as with a plain time-limited cache.

What changes is who pays for it: :meth:`CredentialCache.refresh` (every ``ttl_s / 2``) re-checks every
valid credential used recently in one query per kind and restarts their time, so a robot that sends a
request every 0.5 s no longer misses the cache (and costs a thread hop and a database read) on almost every
request. A credential the re-check no longer finds is
dropped at once. The cache of the process that revokes is cleared at once (:meth:`CredentialCache.clear`);
a refresh that was running meanwhile does not write its (older) answers back.

The re-check runs in its own thread (:meth:`CredentialCache.start`), not as an event-loop task: under load
the loop's timers fire late, and a re-check that comes later than ``ttl_s`` lets every entry expire at once
(each then costs a lookup in the thread pool, which loads the loop further).

Memory: at most ``max_entries`` credentials (then cleared). O(1) per cached request; O(used credentials)
per refresh.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterable
from contextlib import AbstractContextManager
from dataclasses import dataclass
from datetime import datetime
from typing import Literal

from sqlalchemy import or_, select
from sqlalchemy.orm import Session as DbSession

from server.models import OperatorToken, Robot, Session, utcnow
from server.security import OPERATOR_PREFIX, ROBOT_PREFIX, SESSION_PREFIX

__all__ = ["CredentialCache", "Kind", "Principal", "credential_kind", "find_principals"]

log = logging.getLogger(__name__)

Kind = Literal["robot", "operator", "session"]
#: Hashes per ``IN (...)`` list (well under SQLite's and PostgreSQL's parameter limits).
_CHUNK = 500
#: A cached credential unused for this long is not re-checked (it expires instead).
IDLE_S = 10.0


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


def credential_kind(credential: str) -> Kind | None:
    """Which table a credential lives in, by its prefix (``None``: no known prefix)."""
    if credential.startswith(ROBOT_PREFIX):
        return "robot"
    if credential.startswith(OPERATOR_PREFIX):
        return "operator"
    if credential.startswith(SESSION_PREFIX):
        return "session"
    return None


def find_principals(
    s: DbSession, kind: Kind, keys: Iterable[str], now: datetime | None = None
) -> dict[str, Principal]:
    """The principals behind the credential hashes ``keys`` of one ``kind`` that work now: a robot token
    not revoked; an operator token neither revoked nor expired; a session not expired whose operator
    token works. Hashes not found are left out. One query per ``_CHUNK`` hashes, on unique indexes."""
    now = now or utcnow()
    live = (
        OperatorToken.revoked_at.is_(None),
        or_(OperatorToken.expires_at.is_(None), OperatorToken.expires_at > now),
    )
    wanted = list(keys)
    out: dict[str, Principal] = {}
    for start in range(0, len(wanted), _CHUNK):
        chunk = wanted[start : start + _CHUNK]
        if kind == "robot":
            q = select(Robot.token_hash, Robot.id, Robot.name).where(
                Robot.token_hash.in_(chunk), Robot.token_revoked_at.is_(None)
            )
            out |= {key: Principal("robot", rid, name) for key, rid, name in s.execute(q)}
            continue
        if kind == "operator":
            q = select(OperatorToken.token_hash, OperatorToken.id, OperatorToken.name).where(
                OperatorToken.token_hash.in_(chunk), *live
            )
        else:
            q = (
                select(Session.token_hash, OperatorToken.id, OperatorToken.name)
                .join(OperatorToken, Session.operator_id == OperatorToken.id)
                .where(Session.token_hash.in_(chunk), Session.expires_at > now, *live)
            )
        out |= {key: Principal("operator", oid, name) for key, oid, name in s.execute(q)}
    return out


class _Entry:
    __slots__ = ("kind", "principal", "until", "used")

    def __init__(self, kind: Kind, principal: Principal | None, until: float, used: float) -> None:
        self.kind, self.principal, self.until, self.used = kind, principal, until, used


class CredentialCache:
    """Lookups by credential hash, each valid ``ttl_s`` from when its query began (module docstring).
    Thread-safe. ``clock``: monotonic seconds (a test may replace it)."""

    def __init__(
        self, ttl_s: float, *, clock: Callable[[], float] = time.monotonic, max_entries: int = 10_000
    ) -> None:
        self.ttl_s, self.clock, self.max_entries = ttl_s, clock, max_entries
        self._entries: dict[str, _Entry] = {}
        self._generation = 0  # bumped by clear(): a refresh begun before it writes nothing back
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._failing = False  # the last re-check failed (logged once per outage)

    def start(self, read: Callable[[], AbstractContextManager[DbSession]]) -> None:
        """Run :meth:`refresh` every ``ttl_s / 2`` in a daemon thread until :meth:`stop` (nothing when the
        cache is disabled). A failed re-check is logged; the entries then expire as without it."""
        if self.ttl_s <= 0 or self._thread is not None:
            return
        self._stop.clear()

        def run() -> None:
            while not self._stop.wait(self.ttl_s / 2):
                self.recheck(read)

        self._thread = threading.Thread(target=run, name="linemap-credentials", daemon=True)
        self._thread.start()

    def recheck(self, read: Callable[[], AbstractContextManager[DbSession]]) -> bool:
        """One :meth:`refresh` of the re-check thread; whether it worked. A failure (the database is away:
        lookups then go per request, as without the re-check) is logged once per outage, as a warning
        naming the error (the traceback at debug level), not every ``ttl_s / 2``; the recovery once."""
        try:
            self.refresh(read)
        except Exception as exc:
            if not self._failing:
                self._failing = True
                log.warning(
                    "could not re-check the cached credentials (%s: %s); retrying every %.2f s",
                    type(exc).__name__,
                    exc,
                    self.ttl_s / 2,
                )
            log.debug("credential re-check failed", exc_info=True)
            return False
        if self._failing:
            self._failing = False
            log.info("re-checking the cached credentials again")
        return True

    def stop(self) -> None:
        """End the re-check thread (waits for a re-check in progress)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10)
            self._thread = None

    def get(self, key: str, max_age_s: float | None = None) -> tuple[Principal | None, bool]:
        """``(principal, hit)`` from the cache alone (cheap enough for the event loop); ``max_age_s``: a
        miss unless the answer's query began at most that long ago (else up to ``ttl_s``)."""
        now = self.clock()
        with self._lock:
            entry = self._entries.get(key)
            if entry is None or entry.until <= now:
                return None, False
            if max_age_s is not None and now - (entry.until - self.ttl_s) > max_age_s:
                return None, False
            entry.used = now
            return entry.principal, True

    def started(self) -> tuple[float, int]:
        """Call just before a lookup's query: ``(time, generation)`` for :meth:`put`."""
        with self._lock:
            return self.clock(), self._generation

    def put(self, key: str, kind: Kind, principal: Principal | None, begun: tuple[float, int]) -> None:
        """Cache the answer of a query begun at ``begun`` (from :meth:`started`); nothing when the cache
        is disabled or was cleared since."""
        at, generation = begun
        if self.ttl_s <= 0:
            return
        with self._lock:
            if generation != self._generation:
                return
            if len(self._entries) >= self.max_entries and key not in self._entries:
                self._entries.clear()
            self._entries[key] = _Entry(kind, principal, at + self.ttl_s, self.clock())

    def clear(self) -> None:
        """Forget every answer (after this process revoked a credential or closed a session)."""
        with self._lock:
            self._entries.clear()
            self._generation += 1

    def __len__(self) -> int:
        with self._lock:
            return len(self._entries)

    def refresh(self, read: Callable[[], AbstractContextManager[DbSession]]) -> int:
        """Re-check every valid credential used within ``IDLE_S`` (one query per kind, in a session from
        ``read``) and restart its time; drop those no longer valid, and expired entries. Blocking (the
        thread of :meth:`start` calls it). Returns how many credentials were re-checked."""
        if self.ttl_s <= 0:
            return 0
        begun = self.started()
        at = begun[0]
        by_kind: dict[Kind, list[str]] = {}
        with self._lock:
            for key in [k for k, e in self._entries.items() if e.until <= at]:
                del self._entries[key]
            for key, entry in self._entries.items():
                if entry.principal is not None and at - entry.used <= IDLE_S:
                    by_kind.setdefault(entry.kind, []).append(key)
        if not by_kind:
            return 0
        found: dict[str, Principal] = {}
        with read() as s:
            now = utcnow()
            for kind, keys in by_kind.items():
                found |= find_principals(s, kind, keys, now)
        with self._lock:
            if begun[1] != self._generation:
                return 0  # cleared meanwhile: what we read may predate the revocation
            for keys in by_kind.values():
                for key in keys:
                    current = self._entries.get(key)
                    if current is None:
                        continue
                    if key in found:
                        current.principal, current.until = found[key], max(current.until, at + self.ttl_s)
                    else:
                        del self._entries[key]
        return sum(len(keys) for keys in by_kind.values())
