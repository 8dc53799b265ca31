"""Typed dependencies: the application state, and who is asking (operator or robot) with what access.

Credentials: ``Authorization: Bearer <token>`` (operator token ``lmo_...`` or robot token ``lmr_...``), or
the browser's session cookie (operators only). Lookups go by the token's SHA-256; a small cache (a few
seconds) spares the database a read per request, so a revoked token stops working within that time.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from datetime import timedelta
from typing import Annotated, Literal

from fastapi import Depends, Request
from sqlalchemy import select, update

from server.database import Database
from server.errors import AuthError, ForbiddenError
from server.hub import Hub
from server.models import OperatorToken, Robot, Session, utcnow
from server.security import OPERATOR_PREFIX, ROBOT_PREFIX, SESSION_PREFIX, hash_token
from server.settings import Settings

__all__ = [
    "SESSION_COOKIE",
    "AppState",
    "OperatorDep",
    "Principal",
    "PrincipalDep",
    "RobotSelf",
    "StateDep",
    "require_operator",
    "robot_access",
    "robot_self",
]

SESSION_COOKIE = "linemap_session"
_CACHE_S = 5.0
_SEEN_EVERY_S = 2.0


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


@dataclass
class AppState:
    """Everything a request handler needs, created once per application."""

    settings: Settings
    db: Database
    hub: Hub = field(default_factory=Hub)
    _cache: dict[str, tuple[float, Principal | None]] = field(default_factory=dict)
    _seen: dict[int, float] = field(default_factory=dict)
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def forget_credentials(self) -> None:
        """Drop cached lookups (after a token is revoked or a session closed)."""
        with self._lock:
            self._cache.clear()

    def lookup(self, credential: str) -> Principal | None:
        """The principal behind a bearer token or session id, or ``None``."""
        key = hash_token(credential)
        now = time.monotonic()
        with self._lock:
            hit = self._cache.get(key)
        if hit is not None and hit[0] > now:
            return hit[1]
        found = self._lookup_db(credential, key)
        with self._lock:
            if len(self._cache) > 10_000:
                self._cache.clear()
            self._cache[key] = (now + _CACHE_S, found)
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
        """Record that the robot was heard from (at most one write every couple of seconds per robot)."""
        now = time.monotonic()
        with self._lock:
            if now - self._seen.get(robot_id, -1e9) < _SEEN_EVERY_S:
                return
            self._seen[robot_id] = now
        with self.db.session() as s:
            s.execute(update(Robot).where(Robot.id == robot_id).values(last_seen_at=utcnow()))

    def session_expiry(self) -> timedelta:
        return timedelta(seconds=self.settings.session_ttl_s)


def get_state(request: Request) -> AppState:
    state: AppState = request.app.state.linemap
    return state


StateDep = Annotated[AppState, Depends(get_state)]


def get_principal(request: Request, state: StateDep) -> Principal:
    """The caller, from the bearer token or else the session cookie; 401 when neither is valid."""
    header = request.headers.get("authorization")
    if header:
        scheme, _, credential = header.partition(" ")
        if scheme.lower() != "bearer" or not credential.strip():
            raise AuthError("expected 'Authorization: Bearer <token>'")
        found = state.lookup(credential.strip())
        if found is None:
            raise AuthError("unknown or revoked token")
    else:
        cookie = request.cookies.get(SESSION_COOKIE)
        if not cookie:
            raise AuthError("no credential: send 'Authorization: Bearer <token>' or log in")
        found = state.lookup(cookie)
        if found is None or found.kind != "operator":
            raise AuthError("session expired or unknown: log in again")
    if found.kind == "robot":
        state.mark_seen(found.id)
    return found


PrincipalDep = Annotated[Principal, Depends(get_principal)]


def require_operator(who: PrincipalDep) -> Principal:
    if who.kind != "operator":
        raise ForbiddenError("this route is for operators; robot tokens reach only their own robot's routes")
    return who


OperatorDep = Annotated[Principal, Depends(require_operator)]


def robot_access(robot_id: int, who: PrincipalDep) -> Principal:
    """An operator, or the robot ``robot_id`` itself."""
    if who.kind == "robot" and who.id != robot_id:
        raise ForbiddenError(f"this robot token belongs to robot {who.id}, not robot {robot_id}")
    return who


def robot_self(robot_id: int, who: PrincipalDep) -> Principal:
    """Only the robot ``robot_id`` itself (it uploads its maps and acknowledges its messages)."""
    if who.kind != "robot":
        raise ForbiddenError(f"only robot {robot_id}'s own token may do this")
    if who.id != robot_id:
        raise ForbiddenError(f"this robot token belongs to robot {who.id}, not robot {robot_id}")
    return who


RobotSelf = Annotated[Principal, Depends(robot_self)]
