"""Notifications: wake long-polling robots and feed SSE subscribers the moment something lands, in this
server process and in every other one on the same PostgreSQL database.

Topics are strings (``messages:7``, ``maps:7``). Publishing never blocks: each subscriber has a bounded
queue, and a subscriber that falls behind gets :data:`OVERFLOW` and must resynchronise from the database
(the map stream then catches up from the stored deltas, or sends a fresh snapshot).

Across processes (PostgreSQL only): a writer calls :meth:`Hub.announce` inside its write transaction, which
queues a ``NOTIFY`` (:mod:`server.notices`: topic and version only) that PostgreSQL delivers at commit,
so no listener hears of data before it can read it. Each process's listener (:mod:`server.pglisten`)
hands the payloads to :meth:`Hub.receive`, which publishes a :class:`~server.notices.Notice` to the local
subscribers ("read the topic from the database up to this version"); a process skips its own notices,
whose full items it has published in-process already. After the listener reconnects it calls
:meth:`Hub.resync`: every subscriber gets :data:`OVERFLOW` and catches up from the database, covering
whatever was written while no one listened. A safety net runs every ``poll_recheck_s``: map streams
re-read, and one read checks every waiting long-poll of the process (:mod:`server.pollsweep`). On
SQLite (one process) :meth:`announce` does nothing.

All methods but :meth:`Hub.announce` must be called from the event loop's thread.
"""

from __future__ import annotations

import asyncio
import logging
import secrets
from collections import defaultdict
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any, Final

from sqlalchemy import Connection

from server.notices import CHANNEL, NoticeError, decode_notice, encode_notice

__all__ = ["OVERFLOW", "Hub"]

log = logging.getLogger(__name__)

OVERFLOW: Final = object()


class Hub:
    """Topic -> set of subscriber queues. ``cross_process``: announce writes to other server processes
    (PostgreSQL ``NOTIFY``)."""

    def __init__(self, queue_size: int = 64, *, cross_process: bool = False) -> None:
        self._queue_size = queue_size
        self._subscribers: defaultdict[str, set[asyncio.Queue[Any]]] = defaultdict(set)
        self.cross_process = cross_process
        #: names this process in its notices (random: worker processes share everything else)
        self.origin = secrets.token_hex(8)

    @contextmanager
    def subscribe(self, topic: str) -> Iterator[asyncio.Queue[Any]]:
        """A queue that receives every item published on ``topic`` while the context is open."""
        queue: asyncio.Queue[Any] = asyncio.Queue(self._queue_size)
        self._subscribers[topic].add(queue)
        try:
            yield queue
        finally:
            subs = self._subscribers.get(topic)
            if subs is not None:
                subs.discard(queue)
                if not subs:
                    del self._subscribers[topic]

    def publish(self, topic: str, item: Any) -> int:
        """Hand ``item`` to every subscriber of ``topic`` in this process; returns how many received it."""
        subs = self._subscribers.get(topic, ())
        for queue in subs:
            try:
                queue.put_nowait(item)
            except asyncio.QueueFull:
                _overflow(queue)
        return len(subs)

    def announce(self, conn: Connection, topic: str, version: int) -> None:
        """Tell the other server processes that ``topic`` reached ``version``, in ``conn``'s transaction:
        PostgreSQL delivers the notice at commit, or never if the transaction rolls back. A no-op unless
        ``cross_process``. Any thread (it only uses ``conn``). One statement, O(1)."""
        payload = self.notice(topic, version)
        if payload is not None:
            conn.exec_driver_sql("SELECT pg_notify(%s, %s)", (CHANNEL, payload))

    def notice(self, topic: str, version: int) -> str | None:
        """The payload :meth:`announce` would send on :data:`server.notices.CHANNEL` (None unless
        ``cross_process``), for a writer that sends it in a statement of its own
        (:func:`server.maplog.append`). O(1)."""
        return encode_notice(self.origin, topic, version) if self.cross_process else None

    def receive(self, payload: str) -> bool:
        """Publish a notice heard from the database to this process's subscribers of its topic; False
        (logged) for a payload that is not a notice, and for this process's own notices."""
        try:
            origin, notice = decode_notice(payload)
        except NoticeError as exc:
            log.warning("ignored a payload on channel %r: %s", CHANNEL, exc)
            return False
        if origin == self.origin:
            return False
        self.publish(notice.topic, notice)
        return True

    def resync(self) -> int:
        """Tell every subscriber to catch up from the database (:data:`OVERFLOW`), e.g. after notices may
        have been missed; returns how many were told. O(subscribers)."""
        n = 0
        for subs in self._subscribers.values():
            for queue in subs:
                _overflow(queue)
                n += 1
        return n

    def subscribers(self, topic: str) -> int:
        return len(self._subscribers.get(topic, ()))


def _overflow(queue: asyncio.Queue[Any]) -> None:
    """Replace what ``queue`` holds by :data:`OVERFLOW`: the subscriber rereads the state instead."""
    while not queue.empty():
        queue.get_nowait()
    queue.put_nowait(OVERFLOW)
