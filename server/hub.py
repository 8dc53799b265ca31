"""In-process notifications: wake long-polling robots and feed SSE subscribers the moment something lands.

Topics are strings (``messages:7``, ``maps:7``). Publishing never blocks: each subscriber has a bounded
queue, and a subscriber that falls behind gets :data:`OVERFLOW` and must resynchronise from the database
(the map stream then sends a fresh snapshot). Waiters also re-read the database every few seconds, so
writes made by another server process sharing a PostgreSQL database are seen too, only later.

All methods must be called from the event loop's thread.
"""

from __future__ import annotations

import asyncio
from collections import defaultdict
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any, Final

__all__ = ["OVERFLOW", "Hub"]

OVERFLOW: Final = object()


class Hub:
    """Topic -> set of subscriber queues."""

    def __init__(self, queue_size: int = 64) -> None:
        self._queue_size = queue_size
        self._subscribers: defaultdict[str, set[asyncio.Queue[Any]]] = defaultdict(set)

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
        """Hand ``item`` to every subscriber of ``topic``; returns how many received it."""
        subs = self._subscribers.get(topic, ())
        for queue in subs:
            try:
                queue.put_nowait(item)
            except asyncio.QueueFull:
                # Make room for the marker: the subscriber rereads the state instead of the lost items.
                while not queue.empty():
                    queue.get_nowait()
                queue.put_nowait(OVERFLOW)
        return len(subs)

    def subscribers(self, topic: str) -> int:
        return len(self._subscribers.get(topic, ()))
