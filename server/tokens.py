"""Operator and robot token lifecycle in the database: create (with an optional expiry, never outliving the
creator), check that the issuing token is still live in the same transaction, revoke with the cascade.

Rule (docs/reliability/auth-processes.md): revoking an operator token revokes every operator token it
created, transitively, and every robot token any of them issued (registration or rotation), each with its
own audit entry. A token cannot be created by a token being revoked at the same moment on another
process: the new row is written first, then the issuer's row is read under a shared row lock
(PostgreSQL ``FOR SHARE``, which waits for a concurrent revocation's ``FOR UPDATE``; SQLite serialises
writers), so either the creation sees the revocation and is refused, or the revocation's cascade sees the
new token.
"""

from __future__ import annotations

from datetime import datetime, timedelta

from sqlalchemy import select, update
from sqlalchemy.orm import Session as DbSession

from server.audit import record
from server.deps import Principal
from server.errors import AuthError, InvalidRequestError, NotFoundError
from server.models import OperatorToken, Robot, utcnow
from server.security import OPERATOR_PREFIX, hash_token, new_token

__all__ = ["create_operator_token", "lock_live_issuer", "resolve_expiry", "revoke_operator_token"]


def create_operator_token(
    db_session: DbSession,
    name: str,
    *,
    created_by_id: int | None = None,
    expires_at: datetime | None = None,
) -> tuple[int, str]:
    """Add an operator token in the caller's transaction; returns (id, token)."""
    token = new_token(OPERATOR_PREFIX)
    row = OperatorToken(
        name=name, token_hash=hash_token(token), created_by_id=created_by_id, expires_at=expires_at
    )
    db_session.add(row)
    db_session.flush()
    return row.id, token


def lock_live_issuer(s: DbSession, who: Principal) -> datetime | None:
    """Check, under a shared row lock held to the end of the transaction, that the operator token behind
    ``who`` is neither revoked nor expired; returns its expiry (None: none). Call it after writing what it
    issues. Raises :class:`AuthError` (the transaction rolls back) when the token is no longer live."""
    row = s.execute(
        select(OperatorToken.revoked_at, OperatorToken.expires_at)
        .where(OperatorToken.id == who.id)
        .with_for_update(read=True)
    ).first()
    if row is None or row[0] is not None or (row[1] is not None and row[1] <= utcnow()):
        raise AuthError("unknown or revoked token")
    return row[1]


def resolve_expiry(
    expires_in_s: float | None, expires_at: datetime | None, issuer_expires_at: datetime | None
) -> datetime | None:
    """The new token's expiry: the one asked for (``expires_in_s`` from now, or ``expires_at``), else the
    issuer's; never later than the issuer's. Raises :class:`InvalidRequestError` naming the problem."""
    now = utcnow()
    if expires_in_s is not None and expires_at is not None:
        raise InvalidRequestError("give expires_in_s or expires_at, not both")
    wanted = now + timedelta(seconds=expires_in_s) if expires_in_s is not None else expires_at
    if wanted is not None and wanted <= now:
        raise InvalidRequestError(f"expires_at {wanted.isoformat()} is not in the future")
    if issuer_expires_at is None:
        return wanted
    if wanted is None:
        return issuer_expires_at
    if wanted > issuer_expires_at:
        raise InvalidRequestError(
            f"expiry {wanted.isoformat()} is later than the creating token's own expiry "
            f"{issuer_expires_at.isoformat()}: a token cannot outlive its creator"
        )
    return wanted


def revoke_operator_token(
    s: DbSession, who: Principal, token_id: int, *, keep_robot_tokens: bool = False
) -> list[int]:
    """Revoke operator token ``token_id`` and, transitively, every operator token it created and (unless
    ``keep_robot_tokens``) every robot token those issued; one audit entry each. The root row is written
    first (PostgreSQL: its row lock waits for a creation holding ``FOR SHARE`` on it, which then commits
    before the cascade reads the children). Returns the ids of the operator tokens newly revoked.
    Raises :class:`NotFoundError`. O(descendants) statements' rows, one query per generation."""
    now = utcnow()
    hit = s.execute(
        update(OperatorToken)
        .where(OperatorToken.id == token_id, OperatorToken.revoked_at.is_(None))
        .values(revoked_at=now)
        .returning(OperatorToken.id)
    ).first()
    name = s.scalar(select(OperatorToken.name).where(OperatorToken.id == token_id))
    if name is None:
        raise NotFoundError(f"no operator token {token_id}")
    revoked: list[int] = []
    if hit is not None:
        revoked.append(token_id)
        record(s, who, "token.revoke", f"operator:{token_id}", name=name)
    seen, frontier = {token_id}, [token_id]
    while frontier:
        children = s.execute(
            select(
                OperatorToken.id, OperatorToken.name, OperatorToken.created_by_id, OperatorToken.revoked_at
            )
            .where(OperatorToken.created_by_id.in_(frontier))
            .order_by(OperatorToken.id)
        ).all()
        live = [c for c in children if c[3] is None and c[0] not in seen]
        if live:
            s.execute(
                update(OperatorToken)
                .where(OperatorToken.id.in_([c[0] for c in live]), OperatorToken.revoked_at.is_(None))
                .values(revoked_at=now)
            )
        for cid, cname, parent, _ in live:
            revoked.append(cid)
            record(s, who, "token.revoke", f"operator:{cid}", name=cname, cascade_from=parent, root=token_id)
        frontier = [c[0] for c in children if c[0] not in seen]
        seen.update(frontier)
    if not keep_robot_tokens:
        robots = s.execute(
            select(Robot.id, Robot.name, Robot.token_issued_by_id)
            .where(Robot.token_issued_by_id.in_(seen), Robot.token_revoked_at.is_(None))
            .order_by(Robot.id)
        ).all()
        if robots:
            s.execute(update(Robot).where(Robot.id.in_([r[0] for r in robots])).values(token_revoked_at=now))
        for rid, rname, issuer in robots:
            record(
                s, who, "robot.token.revoke", f"robot:{rid}", name=rname, cascade_from=issuer, root=token_id
            )
    return revoked
