"""Run the Alembic migrations of ``migrations/server`` from code (the server does this on every start)."""

from __future__ import annotations

import logging
from pathlib import Path

from alembic import command
from alembic.config import Config
from alembic.runtime.migration import MigrationContext
from alembic.script import ScriptDirectory
from sqlalchemy import Engine
from sqlalchemy.exc import SQLAlchemyError

from server.errors import ServerError

__all__ = ["MIGRATIONS_DIR", "current_revision", "downgrade", "head_revision", "upgrade"]

log = logging.getLogger(__name__)

_PACKAGED = Path(__file__).resolve().parent / "migrations"  # inside an installed wheel
MIGRATIONS_DIR = (
    _PACKAGED
    if (_PACKAGED / "env.py").is_file()
    else Path(__file__).resolve().parent.parent / "migrations" / "server"
)


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
