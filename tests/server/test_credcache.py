"""The credential cache (server.credcache) on a real, migrated SQLite database: an answer is never served
longer than ``ttl_s`` after the query that produced it began; the bulk re-check keeps valid credentials
cached and drops revoked, rotated, expired and logged-out ones; a re-check that raced a local revocation
writes nothing back. The clock is a stepped fake (no sleeping)."""

from __future__ import annotations

import logging
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import timedelta
from pathlib import Path

import pytest
from sqlalchemy import update
from sqlalchemy.orm import Session as DbSession

from server.credcache import IDLE_S, CredentialCache, Principal, credential_kind, find_principals
from server.database import Database
from server.migrate import upgrade
from server.models import OperatorToken, Robot, Session, utcnow
from server.security import OPERATOR_PREFIX, ROBOT_PREFIX, SESSION_PREFIX, hash_token, new_token

TTL_S = 0.5


class Clock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture
def db(tmp_path: Path) -> Iterator[Database]:
    database = Database(f"sqlite:///{tmp_path / 'server.db'}")
    upgrade(database.engine)
    yield database
    database.dispose()


def _robot(db: Database, name: str) -> tuple[int, str]:
    token = new_token(ROBOT_PREFIX)
    with db.session() as s:
        robot = Robot(name=name, token_hash=hash_token(token))
        s.add(robot)
        s.flush()
        return robot.id, token


def _operator(db: Database, name: str) -> tuple[int, str]:
    token = new_token(OPERATOR_PREFIX)
    with db.session() as s:
        op = OperatorToken(name=name, token_hash=hash_token(token))
        s.add(op)
        s.flush()
        return op.id, token


def _session(db: Database, operator_id: int) -> str:
    sid = new_token(SESSION_PREFIX)
    with db.session() as s:
        s.add(
            Session(
                token_hash=hash_token(sid), operator_id=operator_id, expires_at=utcnow() + timedelta(hours=1)
            )
        )
    return sid


def _lookup(cache: CredentialCache, db: Database, credential: str) -> Principal | None:
    """What AppState.lookup does on a miss: the query, then the answer cached from when it began."""
    key, kind = hash_token(credential), credential_kind(credential)
    assert kind is not None
    begun = cache.started()
    with db.read() as s:
        found = find_principals(s, kind, [key]).get(key)
    cache.put(key, kind, found, begun)
    return found


def test_find_principals_answers_only_for_working_credentials(db: Database) -> None:
    rid, robot = _robot(db, "r1")
    oid, op = _operator(db, "op")
    sid = _session(db, oid)
    _rid2, revoked = _robot(db, "r2")
    oid2, expired = _operator(db, "old")
    sid_of_expired = _session(db, oid2)
    with db.session() as s:
        s.execute(
            update(Robot).where(Robot.token_hash == hash_token(revoked)).values(token_revoked_at=utcnow())
        )
        s.execute(update(OperatorToken).where(OperatorToken.id == oid2).values(expires_at=utcnow()))
    with db.read() as s:
        robots = find_principals(s, "robot", [hash_token(robot), hash_token(revoked), "0" * 64])
        ops = find_principals(s, "operator", [hash_token(op), hash_token(expired)])
        sessions = find_principals(s, "session", [hash_token(sid), hash_token(sid_of_expired)])
    assert robots == {hash_token(robot): Principal("robot", rid, "r1")}
    assert ops == {hash_token(op): Principal("operator", oid, "op")}
    assert sessions == {hash_token(sid): Principal("operator", oid, "op")}  # its token's expiry ends it
    assert credential_kind("lmx_nope") is None


def test_an_answer_is_never_served_past_its_time_without_a_recheck(db: Database) -> None:
    clock = Clock()
    cache = CredentialCache(TTL_S, clock=clock)
    _rid, token = _robot(db, "r1")
    assert _lookup(cache, db, token) is not None
    clock.now += TTL_S - 0.01
    assert cache.get(hash_token(token))[1] is True
    clock.now += 0.02
    assert cache.get(hash_token(token)) == (None, False)  # a miss: the caller looks it up again


def test_the_recheck_keeps_valid_credentials_and_drops_revoked_ones(db: Database) -> None:
    clock = Clock()
    cache = CredentialCache(TTL_S, clock=clock)
    rid, keep = _robot(db, "keep")
    _rid2, revoke = _robot(db, "revoke")
    oid, op = _operator(db, "op")
    sid = _session(db, oid)
    for credential in (keep, revoke, op, sid):
        assert _lookup(cache, db, credential) is not None
    with db.session() as s:  # as another process would: this process's cache is not told
        s.execute(
            update(Robot).where(Robot.token_hash == hash_token(revoke)).values(token_revoked_at=utcnow())
        )
        s.query(Session).delete()  # a logout
    for _ in range(10):  # far past the first answers' time, re-checked every half ttl
        clock.now += TTL_S / 2
        assert cache.refresh(db.read) >= 2
    assert cache.get(hash_token(keep)) == (Principal("robot", rid, "keep"), True)
    assert cache.get(hash_token(op)) == (Principal("operator", oid, "op"), True)
    assert cache.get(hash_token(revoke)) == (None, False)
    assert cache.get(hash_token(sid)) == (None, False)
    assert _lookup(cache, db, revoke) is None and _lookup(cache, db, sid) is None


def test_a_recheck_that_raced_a_local_revocation_writes_nothing_back(db: Database) -> None:
    clock = Clock()
    cache = CredentialCache(TTL_S, clock=clock)
    _rid, token = _robot(db, "r1")
    assert _lookup(cache, db, token) is not None

    @contextmanager
    def read_then_revoked() -> Iterator[DbSession]:
        with db.read() as s:
            yield s  # the re-check reads the token as valid ...
        cache.clear()  # ... and this process revokes it before the re-check writes its answers

    clock.now += TTL_S / 2
    assert cache.refresh(read_then_revoked) == 0
    assert cache.get(hash_token(token)) == (None, False)
    # Likewise a single lookup whose query began before the clear.
    begun = cache.started()
    cache.clear()
    cache.put(hash_token(token), "robot", Principal("robot", 1, "r1"), begun)
    assert len(cache) == 0


def test_idle_and_invalid_entries_are_not_rechecked(db: Database) -> None:
    clock = Clock()
    cache = CredentialCache(TTL_S, clock=clock)
    _rid, token = _robot(db, "r1")
    assert _lookup(cache, db, token) is not None
    assert _lookup(cache, db, ROBOT_PREFIX + "not-a-token") is None  # cached as invalid, for ttl at most
    clock.now += TTL_S / 2
    assert cache.refresh(db.read) == 1  # the valid one only
    rechecks = 0
    for _ in range(int(2 * (IDLE_S + 2) / TTL_S)):  # unused from now on: kept for IDLE_S, then let expire
        clock.now += TTL_S / 2
        rechecks += cache.refresh(db.read)
    assert 0 < rechecks <= 2 * IDLE_S / TTL_S
    assert len(cache) == 0


def test_a_zero_ttl_caches_nothing(db: Database) -> None:
    cache = CredentialCache(0.0)
    _rid, token = _robot(db, "r1")
    assert _lookup(cache, db, token) is not None
    assert len(cache) == 0 and cache.refresh(db.read) == 0


def test_a_stream_check_takes_only_a_recent_answer(db: Database) -> None:
    """server.deps.still_valid asks for answers at most 0.5 s old, whatever ``ttl_s`` allows."""
    clock = Clock()
    cache = CredentialCache(1.0, clock=clock)
    _rid, token = _robot(db, "r1")
    assert _lookup(cache, db, token) is not None
    clock.now += 0.4
    assert cache.get(hash_token(token), max_age_s=0.5)[1] is True
    clock.now += 0.2  # 0.6 s after its query began: still cached for requests, not for a stream
    assert cache.get(hash_token(token), max_age_s=0.5) == (None, False)
    assert cache.get(hash_token(token))[1] is True
    assert cache.refresh(db.read) == 1  # re-checked now: recent again
    assert cache.get(hash_token(token), max_age_s=0.5)[1] is True


def test_a_database_outage_is_logged_once_and_the_recovery_once(
    db: Database, caplog: pytest.LogCaptureFixture
) -> None:
    clock = Clock()
    cache = CredentialCache(TTL_S, clock=clock)
    _rid, token = _robot(db, "r")
    assert _lookup(cache, db, token) is not None  # an entry to re-check

    @contextmanager
    def away() -> Iterator[DbSession]:
        raise ConnectionError("database unreachable")
        yield  # pragma: no cover

    with caplog.at_level(logging.DEBUG, logger="server.credcache"):
        assert [cache.recheck(away) for _ in range(5)] == [False] * 5
        assert cache.recheck(db.read) is True
        assert cache.recheck(db.read) is True
    warnings = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1
    assert "ConnectionError: database unreachable" in warnings[0].getMessage()
    assert not any(r.exc_info for r in caplog.records if r.levelno > logging.DEBUG)  # traceback: debug only
    assert [r.getMessage() for r in caplog.records if r.levelno == logging.INFO] == [
        "re-checking the cached credentials again"
    ]
