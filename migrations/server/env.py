"""Alembic environment of the server database (run by ``server.migrate`` on start, or by ``alembic``)."""

from __future__ import annotations

import os

from alembic import context
from sqlalchemy import Connection, create_engine, pool

from server.database import normalize_url
from server.migrate import hold_schema_lock
from server.models import Base
from server.settings import DEFAULT_DATABASE_URL

config = context.config
target_metadata = Base.metadata


def _url() -> str:
    given = config.attributes.get("url") or context.get_x_argument(as_dictionary=True).get("db")
    return normalize_url(given or os.environ.get("LINEMAP_DATABASE_URL") or DEFAULT_DATABASE_URL)


def run_offline() -> None:
    context.configure(url=_url(), target_metadata=target_metadata, literal_binds=True, render_as_batch=True)
    with context.begin_transaction():
        context.run_migrations()


def _migrate(connection: Connection) -> None:
    """The migrations in ``connection``'s transaction, under the schema lock: processes starting together
    on one database migrate one after the other (server.migrate.hold_schema_lock)."""
    hold_schema_lock(connection)
    context.configure(connection=connection, target_metadata=target_metadata, render_as_batch=True)
    with context.begin_transaction():
        context.run_migrations()


def run_online() -> None:
    connection = config.attributes.get("connection")
    if connection is not None:
        if connection.in_transaction():
            _migrate(connection)
        else:
            with connection.begin():
                _migrate(connection)
        return
    engine = create_engine(_url(), poolclass=pool.NullPool)
    try:
        with engine.begin() as conn:
            _migrate(conn)
    finally:
        engine.dispose()


if context.is_offline_mode():
    run_offline()
else:
    run_online()
