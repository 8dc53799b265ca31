"""Credential cache misses that arrive together are answered by one database read (:class:`LookupBatcher`).

When many clients come at once to a process whose cache is cold (a server restart with a fleet connected,
many robots switched on together), every first request missed the cache and paid its own lookup in the
thread pool: a pool connection (opened then, at start), a query and a commit each, while the event loop sat
idle waiting for them (``benchmarks/server_load.py`` on PostgreSQL: the first second's uploads took
0.6 s at the median, with the process's interpreter lock held 12 % of the time). :func:`find_principals
<server.credcache.find_principals>` takes many hashes in one query, so the misses that arrive while a read
is running wait for the next one, which answers all of them; the same credential asked twice waits for one
answer. A read's error reaches every request that waited for it.

Runs on the event loop (one read at a time, in the thread pool). O(1) per request; one read per batch.
"""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable

from server.credcache import Kind, Principal

__all__ = ["LookupBatcher"]

#: answers a batch ``{kind: [hash, ...]}`` with ``{hash: principal or None}`` for every hash asked
Resolve = Callable[[dict[Kind, list[str]]], Awaitable[dict[str, Principal | None]]]


class LookupBatcher:
    """Joins concurrent lookups into batches for ``resolve`` (module docstring). Event-loop thread only."""

    def __init__(self, resolve: Resolve) -> None:
        self._resolve = resolve
        self._next: dict[Kind, list[str]] = {}
        self._waiting: dict[str, asyncio.Future[Principal | None]] = {}
        self._task: asyncio.Task[None] | None = None
        self.batches = 0  # reads made (for tests and diagnostics)

    async def get(self, key: str, kind: Kind) -> Principal | None:
        """The principal behind credential hash ``key`` of ``kind`` (None: no such valid credential), from
        the read that answers the batch it joins."""
        fut = self._waiting.get(key)
        if fut is None:
            fut = asyncio.get_running_loop().create_future()
            self._waiting[key] = fut
            self._next.setdefault(kind, []).append(key)
            if self._task is None or self._task.done():
                self._task = asyncio.get_running_loop().create_task(self._drain())
        return await asyncio.shield(fut)

    async def _drain(self) -> None:
        while self._next:
            batch, self._next = self._next, {}
            futures = {key: self._waiting[key] for keys in batch.values() for key in keys}
            try:
                found = await self._resolve(batch)
            except Exception as exc:  # every request of the batch gets the read's error
                for key, fut in futures.items():
                    self._waiting.pop(key, None)
                    if not fut.done():
                        fut.set_exception(exc)
                        fut.exception()  # retrieved here: a request that went away leaves no warning
                continue
            finally:
                self.batches += 1
            for key, fut in futures.items():
                self._waiting.pop(key, None)
                if not fut.done():
                    fut.set_result(found.get(key))
