"""Each server process's one listener on PostgreSQL: ``LISTEN`` on a dedicated connection, and every
notice heard handed to the hub (:meth:`server.hub.Hub.receive`).

The connection is psycopg 3's own (``AsyncConnection``, autocommit), not one of SQLAlchemy's pool, which
would ``UNLISTEN`` it when it goes back to the pool. It is the only thing the listener does with it: it
waits in ``notifies()``; after ``IDLE_CHECK_S`` without a notice it runs ``SELECT 1`` so that a dead
peer is noticed (TCP keepalives cover a silent network too).

When the connection fails (the database restarted, ``pg_terminate_backend``, a network cut) the listener
reconnects with exponential backoff (:class:`Backoff`: 0.1 s doubling to 5 s, +-20 % jitter), and once
it listens again it calls :meth:`server.hub.Hub.resync`: every subscriber catches up from the database,
since notices sent meanwhile were lost. The safety net runs every ``poll_recheck_s`` (map streams re-read,
one read checks every waiting long-poll: :mod:`server.pollsweep`), so while no listener runs waiters are
late, never wrong.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import random
from collections.abc import AsyncIterator, Awaitable, Callable
from typing import Any, Protocol

from sqlalchemy.engine import make_url

from server.hub import Hub
from server.notices import CHANNEL

__all__ = ["IDLE_CHECK_S", "Backoff", "ListenConnection", "NoticeListener", "psycopg_connector"]

log = logging.getLogger(__name__)

#: Without a notice for this long (s), the listener checks its connection with ``SELECT 1``.
IDLE_CHECK_S = 15.0


class Backoff:
    """Delays between reconnection attempts: ``initial_s``, doubling up to ``max_s``, each scaled by a
    random factor in ``1 +- jitter`` (so that many processes do not reconnect in step). O(1)."""

    def __init__(
        self,
        initial_s: float = 0.1,
        max_s: float = 5.0,
        jitter: float = 0.2,
        rng: random.Random | None = None,
    ) -> None:
        if not 0 < initial_s <= max_s:
            raise ValueError(f"backoff needs 0 < initial_s <= max_s, got {initial_s} and {max_s}")
        if not 0 <= jitter < 1:
            raise ValueError(f"backoff jitter must be in [0, 1), got {jitter}")
        self.initial_s, self.max_s, self.jitter = initial_s, max_s, jitter
        self._rng = rng or random.Random()
        self._next_s = initial_s

    def next(self) -> float:
        """The delay before the next attempt (s); the one after it is twice as long, up to ``max_s``."""
        base = self._next_s
        self._next_s = min(self.max_s, base * 2)
        return base * (1 + self._rng.uniform(-self.jitter, self.jitter)) if self.jitter else base

    def reset(self) -> None:
        """After a success: the next failure waits ``initial_s`` again."""
        self._next_s = self.initial_s


class ListenConnection(Protocol):
    """What the listener needs of a connection (psycopg's ``AsyncConnection`` in autocommit)."""

    async def execute(self, query: Any) -> Any: ...

    def notifies(self, *, timeout: float | None = None) -> AsyncIterator[Any]: ...

    async def close(self) -> None: ...


Connector = Callable[[], Awaitable[ListenConnection]]


def psycopg_connector(database_url: str) -> Connector:
    """Opens a dedicated psycopg connection to the database of a SQLAlchemy ``postgresql`` URL, with TCP
    keepalives and ``application_name`` ``linemap-listener <pid>`` (to find it in ``pg_stat_activity``)."""
    conninfo = make_url(database_url).set(drivername="postgresql").render_as_string(hide_password=False)

    async def connect() -> ListenConnection:
        import psycopg

        conn = await psycopg.AsyncConnection.connect(
            conninfo,
            autocommit=True,
            connect_timeout=5,
            keepalives=1,
            keepalives_idle=10,
            keepalives_interval=5,
            keepalives_count=3,
            application_name=f"linemap-listener {os.getpid()}",
        )
        return conn

    return connect


class NoticeListener:
    """Listens on :data:`server.notices.CHANNEL` and feeds ``hub`` until :meth:`stop` (module docstring).
    ``connect`` opens a connection; ``sleep`` waits between attempts (both replaceable in tests)."""

    def __init__(
        self,
        hub: Hub,
        connect: Connector,
        *,
        backoff: Backoff | None = None,
        idle_check_s: float = IDLE_CHECK_S,
        sleep: Callable[[float], Awaitable[None]] = asyncio.sleep,
    ) -> None:
        self.hub = hub
        self._connect = connect
        self.backoff = backoff or Backoff()
        self.idle_check_s = idle_check_s
        self._sleep = sleep
        self._task: asyncio.Task[None] | None = None
        #: times the listener began listening (the first time and after each reconnection)
        self.listens = 0
        #: failed connections or lost ones, in all
        self.failures = 0
        #: the listener is listening now
        self.listening = asyncio.Event()

    def start(self) -> None:
        """Run in the background on the running event loop."""
        if self._task is None:
            self._task = asyncio.get_running_loop().create_task(self.run(), name="linemap-listener")

    async def stop(self) -> None:
        """End the background task and close its connection."""
        task, self._task = self._task, None
        if task is not None:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task

    async def run(self) -> None:
        """Listen, reconnecting after each failure, until cancelled."""
        failed_in_a_row = 0
        while True:
            listened = self.listens
            try:
                await self._listen_once()
            except asyncio.CancelledError:
                raise
            except Exception as exc:  # any failure of the connection: try again later, never give up
                self.failures += 1
                failed_in_a_row = 1 if self.listens > listened else failed_in_a_row + 1
                delay_s = self.backoff.next()
                (log.warning if failed_in_a_row == 1 else log.debug)(
                    "notice listener lost its database connection (%s: %s); attempt %d in %.2f s",
                    type(exc).__name__,
                    str(exc).strip()[:200],
                    failed_in_a_row + 1,
                    delay_s,
                )
                self.listening.clear()
                await self._sleep(delay_s)

    async def _listen_once(self) -> None:
        conn = await self._connect()
        try:
            await conn.execute(f"LISTEN {CHANNEL}")
            self.listens += 1
            self.backoff.reset()
            told = self.hub.resync()  # notices may have been sent while no one listened
            if self.listens > 1:
                log.info("notice listener listening again (%d subscribers catch up)", told)
            self.listening.set()
            while True:
                async for notify in conn.notifies(timeout=self.idle_check_s):
                    self.hub.receive(notify.payload)
                await conn.execute("SELECT 1")  # quiet for a while: is the peer still there?
        finally:
            self.listening.clear()
            with contextlib.suppress(Exception):
                await conn.close()
