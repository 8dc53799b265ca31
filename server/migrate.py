"""Run the Alembic migrations of ``migrations/server`` from code (the server does this on every start).

Any number of server processes may start at once on one database: the migration environment
(``migrations/server/env.py``) runs every upgrade and downgrade in one transaction that first takes
:func:`hold_schema_lock`, so one process migrates while the others wait, then find the schema at head and
change nothing (before, two processes on a fresh PostgreSQL database both created ``alembic_version`` and
one died). First-start set-up (the admin token) takes the same lock.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from alembic import command
from alembic.config import Config
from alembic.runtime.migration import MigrationContext
from alembic.script import ScriptDirectory
from sqlalchemy import Connection, Engine
from sqlalchemy.exc import SQLAlchemyError

from server.errors import ServerError

__all__ = [
    "MIGRATIONS_DIR",
    "SCHEMA_LOCK_KEY",
    "current_revision",
    "downgrade",
    "head_revision",
    "hold_schema_lock",
    "upgrade",
]

log = logging.getLogger(__name__)

_PACKAGED = Path(__file__).resolve().parent / "migrations"  # inside an installed wheel
MIGRATIONS_DIR = (
    _PACKAGED
    if (_PACKAGED / "env.py").is_file()
    else Path(__file__).resolve().parent.parent / "migrations" / "server"
)


#: The PostgreSQL advisory-lock key of schema changes (any fixed 64-bit number; "linemap" in ASCII).
SCHEMA_LOCK_KEY = 0x6C696E656D6170


def hold_schema_lock(conn: Connection) -> None:
    """Take this database's schema lock for the rest of ``conn``'s transaction (waiting for another
    process that holds it). PostgreSQL: ``pg_advisory_xact_lock`` (released at commit or rollback).
    SQLite: ``BEGIN IMMEDIATE``, the file's write lock, held to the end of the transaction (the driver
    would otherwise run DDL outside any transaction); waits up to the connection's busy timeout. Other
    databases: no lock (a warning)."""
    dialect = conn.dialect.name
    if dialect == "postgresql":
        conn.exec_driver_sql(f"SELECT pg_advisory_xact_lock({SCHEMA_LOCK_KEY})")
    elif dialect == "sqlite":
        raw: Any = conn.connection.driver_connection
        if not raw.in_transaction:  # else the driver's transaction already holds the write lock
            conn.exec_driver_sql("BEGIN IMMEDIATE")
    else:
        log.warning("no schema lock on %s databases: start one server process at a time", dialect)


def _config(engine: Engine) -> Config:
    if not (MIGRATIONS_DIR / "env.py").is_file():
        raise ServerError(f"migrations not found at {MIGRATIONS_DIR} (expected an Alembic env.py there)")
    cfg = Config()
    cfg.set_main_option("script_location", str(MIGRATIONS_DIR))
    cfg.attributes["url"] = engine.url.render_as_string(hide_password=False)
    return cfg


def upgrade(engine: Engine, revision: str = "head") -> None:
    """Bring the database to ``revision``; a database error becomes a :class:`ServerError` naming the URL."""
    cfg = _config(engine)
    try:
        with engine.begin() as conn:
            cfg.attributes["connection"] = conn
            command.upgrade(cfg, revision)
    except SQLAlchemyError as exc:
        where = engine.url.render_as_string(hide_password=True)
        raise ServerError(f"could not migrate database {where}: {getattr(exc, 'orig', None) or exc}") from exc


def downgrade(engine: Engine, revision: str = "base") -> None:
    cfg = _config(engine)
    with engine.begin() as conn:
        cfg.attributes["connection"] = conn
        command.downgrade(cfg, revision)


def current_revision(engine: Engine) -> str | None:
    with engine.connect() as conn:
        return MigrationContext.configure(conn).get_current_revision()


def head_revision() -> str | None:
    cfg = Config()
    cfg.set_main_option("script_location", str(MIGRATIONS_DIR))
    return ScriptDirectory.from_config(cfg).get_current_head()
