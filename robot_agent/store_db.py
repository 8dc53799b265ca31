"""The Robot DB's SQLite file: opened (created and migrated to the newest schema with Alembic), one
transaction at a time, and its key-value ``meta`` table.

SQLite in WAL mode with ``synchronous=FULL``: a committed transaction survives kill -9 and power loss.
Writers of this process queue on one lock (SQLite has one writer). :class:`RobotDBFile` is the base of
:class:`robot_agent.store.RobotDB`; the tables' own methods are in :mod:`robot_agent.store_map` and
:mod:`robot_agent.store_control`.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, cast

from alembic import command
from alembic.config import Config
from sqlalchemy import Engine, Table, create_engine, event
from sqlalchemy.dialects.sqlite import insert as sqlite_insert
from sqlalchemy.exc import SQLAlchemyError
from sqlalchemy.orm import Session, sessionmaker

from robot_agent.errors import AgentError
from robot_agent.models import Meta

__all__ = ["MIGRATIONS_DIR", "RobotDBFile", "put_meta", "put_metas", "table_of"]

log = logging.getLogger(__name__)

_PACKAGED = Path(__file__).resolve().parent / "migrations"
MIGRATIONS_DIR = (
    _PACKAGED
    if (_PACKAGED / "env.py").is_file()
    else Path(__file__).resolve().parent.parent / "migrations" / "robot"
)


class RobotDBFile:
    """The Robot DB at ``path`` (created and migrated to the newest schema on open)."""

    def __init__(self, path: Path | str) -> None:
        self.path = Path(path)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self.engine: Engine = create_engine(
                f"sqlite:///{self.path}", connect_args={"check_same_thread": False, "timeout": 30}
            )
            event.listen(self.engine, "connect", _pragmas)
            self._migrate()
        except (OSError, SQLAlchemyError) as exc:
            raise AgentError(f"cannot open the Robot DB {self.path}: {exc}") from None
        self._factory = sessionmaker(self.engine, expire_on_commit=False)
        self._lock = threading.Lock()

    def _migrate(self) -> None:
        cfg = Config()
        cfg.set_main_option("script_location", str(MIGRATIONS_DIR))
        with self.engine.begin() as conn:
            cfg.attributes["connection"] = conn
            command.upgrade(cfg, "head")

    @contextmanager
    def tx(self) -> Iterator[Session]:
        """One transaction (writers of this process queue on a lock: SQLite has one writer)."""
        with self._lock, self._factory() as s, s.begin():
            yield s

    def close(self) -> None:
        self.engine.dispose()

    def integrity_ok(self) -> bool:
        with self.engine.connect() as conn:
            return conn.exec_driver_sql("PRAGMA integrity_check").scalar() == "ok"

    # ------------------------------------------------------------------ meta
    def get(self, key: str, default: Any = None) -> Any:
        with self._factory() as s:
            row = s.get(Meta, key)
            return default if row is None else row.value.get("v", default)

    def put(self, key: str, value: Any) -> None:
        with self.tx() as s:
            put_meta(s, key, value)


def put_meta(s: Session, key: str, value: Any) -> None:
    """Set ``meta[key]`` to ``value`` (JSON) within the transaction ``s``."""
    row = s.get(Meta, key)
    if row is None:
        s.add(Meta(key=key, value={"v": value}))
    else:
        row.value = {"v": value}


def table_of(model: type[Any]) -> Table:
    """The Core table of an ORM ``model`` (for statements built once and run with parameters)."""
    return cast(Table, model.__table__)


def put_metas(s: Session, values: dict[str, Any]) -> None:
    """Set each ``meta[key]`` of ``values`` (JSON) within the transaction ``s``, in one upsert statement
    (the step's path: no ORM load of the rows). A ``Meta`` row this session had loaded is not refreshed:
    use it on keys the transaction does not read through the ORM."""
    s.execute(_UPSERT_META, [{"key": k, "value": {"v": v}} for k, v in values.items()])


_meta_upsert = sqlite_insert(table_of(Meta))
_UPSERT_META = _meta_upsert.on_conflict_do_update(
    index_elements=["key"], set_={"value": _meta_upsert.excluded.value}
)


def _pragmas(dbapi_connection: Any, _record: Any) -> None:
    cur = dbapi_connection.cursor()
    cur.execute("PRAGMA journal_mode=WAL")
    cur.execute("PRAGMA synchronous=FULL")
    cur.execute("PRAGMA foreign_keys=ON")
    cur.execute("PRAGMA busy_timeout=30000")
    cur.close()
