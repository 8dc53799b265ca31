"""Operator credentials: browser sessions (cookie), operator tokens, who-am-I, and the audit log."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query, Request, Response, status
from pydantic import Field
from sqlalchemy import select

from server.audit import record
from server.csrf import CSRF_HEADER, csrf_token, require_csrf_token
from server.deps import SESSION_COOKIE, AppState, OperatorDep, PrincipalDep, StateDep
from server.errors import AuthError
from server.limiter import via_https
from server.models import AuditEntry, OperatorToken, Session, utcnow
from server.schemas import DB_INT_MAX, AuditOut, DbIdPath, LoginIn, TokenCreate, TokenCreated, WhoAmI
from server.security import OPERATOR_PREFIX, SESSION_PREFIX, hash_token, new_token
from server.tokens import create_operator_token, lock_live_issuer, resolve_expiry, revoke_operator_token

__all__ = ["SessionOut", "create_operator_token", "router"]

router = APIRouter(tags=["auth"])


class SessionOut(WhoAmI):
    """The logged-in operator and the CSRF token the dashboard sends with each state-changing request."""

    csrf_token: str | None = Field(
        description=f"Value of the header {CSRF_HEADER} for state-changing requests made with this session's "
        "cookie; null when the caller authenticated with a bearer token (which needs none)."
    )


def _secure(request: Request, state: AppState) -> bool:
    """Whether the session cookie is marked Secure: over HTTPS always (directly, or as a trusted proxy's
    ``X-Forwarded-Proto`` says), or when the operator says so."""
    return state.settings.secure_cookies or via_https(request.scope, state.settings.trusted_networks())


@router.post("/session", response_model=SessionOut)
def login(body: LoginIn, request: Request, response: Response, state: StateDep) -> SessionOut:
    """Exchange an operator token for a session cookie (HttpOnly, SameSite=Strict, Secure over HTTPS) for the
    dashboard; the answer holds the session's CSRF token."""
    who = state.lookup(body.token) if body.token.startswith(OPERATOR_PREFIX) else None
    if who is None or who.kind != "operator":
        raise AuthError("not a valid operator token")
    sid = new_token(SESSION_PREFIX)
    with state.db.session() as s:
        s.add(
            Session(
                token_hash=hash_token(sid), operator_id=who.id, expires_at=utcnow() + state.session_expiry()
            )
        )
        record(s, who, "session.login", f"operator:{who.id}")
    response.set_cookie(
        SESSION_COOKIE,
        sid,
        max_age=int(state.settings.session_ttl_s),
        httponly=True,
        samesite="strict",
        secure=_secure(request, state),
        path="/",
    )
    return SessionOut(kind=who.kind, id=who.id, name=who.name, csrf_token=csrf_token(sid))


@router.get("/session", response_model=SessionOut)
def current_session(request: Request, who: PrincipalDep) -> SessionOut:
    """Who is asking and, for a session cookie, its CSRF token (the dashboard reads it after a reload)."""
    sid = None if request.headers.get("authorization") else request.cookies.get(SESSION_COOKIE)
    return SessionOut(kind=who.kind, id=who.id, name=who.name, csrf_token=csrf_token(sid) if sid else None)


@router.delete("/session", status_code=status.HTTP_204_NO_CONTENT)
def logout(request: Request, response: Response, state: StateDep) -> None:
    """End the browser's session and clear its cookie (with the session's CSRF token, as every change)."""
    sid = request.cookies.get(SESSION_COOKIE)
    if sid:
        require_csrf_token(request.method, sid, request.headers.get(CSRF_HEADER))
        with state.db.session() as s:
            row = s.scalars(select(Session).where(Session.token_hash == hash_token(sid))).first()
            if row is not None:
                s.delete(row)
        state.forget_credentials()
    response.delete_cookie(
        SESSION_COOKIE, path="/", httponly=True, samesite="strict", secure=_secure(request, state)
    )


@router.get("/whoami", response_model=WhoAmI)
def whoami(who: PrincipalDep) -> WhoAmI:
    return WhoAmI(kind=who.kind, id=who.id, name=who.name)


@router.post("/tokens", status_code=status.HTTP_201_CREATED, response_model=TokenCreated)
def create_token(body: TokenCreate, who: OperatorDep, state: StateDep) -> TokenCreated:
    """A new operator token, shown once. It expires when asked (``expires_in_s`` or ``expires_at``), and
    never later than the token that creates it (which it inherits when none is asked); revoking the
    creating token revokes this one too."""
    with state.db.session() as s:
        tid, token = create_operator_token(s, body.name, created_by_id=who.id)
        expires_at = resolve_expiry(body.expires_in_s, body.expires_at, lock_live_issuer(s, who))
        if expires_at is not None:
            s.get_one(OperatorToken, tid).expires_at = expires_at
        record(
            s,
            who,
            "token.create",
            f"operator:{tid}",
            name=body.name,
            expires_at=None if expires_at is None else expires_at.isoformat(),
        )
    return TokenCreated(id=tid, name=body.name, token=token, expires_at=expires_at)


@router.delete("/tokens/{token_id}", status_code=status.HTTP_204_NO_CONTENT)
def revoke_token(
    token_id: DbIdPath,
    who: OperatorDep,
    state: StateDep,
    keep_robot_tokens: Annotated[
        bool,
        Query(
            description="Keep the robot tokens this token (or one it created) issued; by default they are "
            "revoked too (rotate them to bring the robots back)."
        ),
    ] = False,
) -> None:
    """Revoke an operator token, the sessions opened with it, every operator token it created
    (transitively) and the robot tokens those issued; the audit log has one entry per revoked token."""
    with state.db.session() as s:
        revoke_operator_token(s, who, token_id, keep_robot_tokens=keep_robot_tokens)
    state.forget_credentials()


@router.get("/audit", response_model=list[AuditOut])
def audit_log(
    who: OperatorDep,
    state: StateDep,
    limit: Annotated[int, Query(ge=1, le=1000)] = 100,
    before: Annotated[
        int | None, Query(ge=1, le=DB_INT_MAX, description="Only entries with id below this (paging).")
    ] = None,
    target: Annotated[
        str | None, Query(max_length=200, description="Only entries on this (robot:3).")
    ] = None,
    action: Annotated[
        str | None, Query(max_length=50, description="Only this action, or those starting with it and '.'.")
    ] = None,
) -> list[AuditOut]:
    """Operator actions and robot events (new map sessions, agent takeovers), newest first."""
    q = select(AuditEntry).order_by(AuditEntry.id.desc()).limit(limit)
    if before is not None:
        q = q.where(AuditEntry.id < before)
    if target is not None:
        q = q.where(AuditEntry.target == target)
    if action is not None:
        q = q.where(
            (AuditEntry.action == action) | AuditEntry.action.startswith(action + ".", autoescape=True)
        )
    with state.db.read() as s:
        return [
            AuditOut(id=e.id, at=e.at, actor=e.actor, action=e.action, target=e.target, detail=e.detail)
            for e in s.scalars(q)
        ]
