"""The psycopg connection under a SQLAlchemy connection, and psycopg's errors as SQLAlchemy's: for the
statements the upload path sends to psycopg itself (:mod:`server.pgrows`, :mod:`server.pgwrite`,
:mod:`server.maplog`) inside its pipelines, outside SQLAlchemy's execution. Imports nothing of the server,
so any module of it may use it."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import psycopg
from sqlalchemy import Connection
from sqlalchemy.exc import DBAPIError

__all__ = ["driver", "driver_errors"]


def driver(conn: Connection) -> psycopg.Connection[Any]:
    """The psycopg connection under ``conn``."""
    pg = conn.connection.driver_connection
    if not isinstance(pg, psycopg.Connection):
        raise TypeError(f"expected a psycopg connection, got {type(pg).__name__}")
    return pg


@contextmanager
def driver_errors() -> Iterator[None]:
    """psycopg's errors, raised outside SQLAlchemy's execution (a pipeline's sync), as SQLAlchemy's."""
    try:
        yield
    except psycopg.Error as exc:
        raise DBAPIError.instance(None, None, exc, psycopg.Error) from exc
