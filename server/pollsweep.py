"""The long-polls' safety net, one database read for all of them.

A robot's long-poll (``GET /robots/{id}/messages?wait=...``) is woken by the hub the moment a message is
queued for it (:mod:`server.hub`: in this process directly, from other processes through PostgreSQL's
``LISTEN/NOTIFY``, and every waiter after the listener reconnects). As a safety net against a wake-up that
never came, each waiting poll used to re-read its robot's messages every ``poll_recheck_s``: with 100
robots waiting, 100 reads a second, each a pool checkout and two statements (on PostgreSQL, round trips
and a thread each), measured as the largest CPU share of a PostgreSQL server under
``benchmarks/server_load.py`` and a 25 % loss of uploads/s. :class:`PollSweep` keeps the same guarantee
with **one** statement per period for every waiting poll of the process: it reads the message numbering
(``robots.last_seq``) of the robots whose polls wait, and wakes (through the hub's topic) only the polls
whose robot has a message above the number they wait after, or no longer exists.

Cost per period: one read of O(robots waited on) rows; a waiter costs O(1) to register.
"""

from __future__ import annotations

import asyncio
import logging
from collections import defaultdict
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from fastapi.concurrency import run_in_threadpool

from server.hub import Hub

__all__ = ["PollSweep", "message_topic"]

log = logging.getLogger(__name__)


def message_topic(robot_id: int) -> str:
    """The hub topic that wakes the robot's long-polls."""
    return f"messages:{robot_id}"


class PollSweep:
    """Which robots' long-polls wait, for which numbers; :meth:`sweep` wakes those that missed a message.

    ``read_seqs(ids)`` returns ``{robot_id: last_seq}`` for the robots among ``ids`` that exist (blocking:
    it runs in a worker thread). All methods run on the event loop's thread."""

    def __init__(self, hub: Hub, read_seqs: Callable[[list[int]], dict[int, int]]) -> None:
        self._hub = hub
        self._read = read_seqs
        #: robot id -> the ``after`` numbers its waiting polls asked for -> how many polls
        self._waiting: defaultdict[int, defaultdict[int, int]] = defaultdict(lambda: defaultdict(int))
        self.sweeps = 0
        self.woken = 0

    @contextmanager
    def watch(self, robot_id: int, after: int) -> Iterator[None]:
        """Count a poll of ``robot_id`` waiting for a message numbered above ``after`` while the block
        runs."""
        afters = self._waiting[robot_id]
        afters[after] += 1
        try:
            yield
        finally:
            afters[after] -= 1
            if afters[after] <= 0:
                del afters[after]
            if not afters:
                self._waiting.pop(robot_id, None)

    def waiting(self) -> dict[int, int]:
        """``{robot_id: the lowest number its waiting polls wait after}``."""
        return {rid: min(afters) for rid, afters in self._waiting.items() if afters}

    async def sweep(self) -> int:
        """One safety-net pass: read the numbering of every robot waited on (one statement) and wake the
        polls of each robot with a message above what its earliest poll waits after, or with no row
        (deleted: the poll then answers 404). Returns how many robots' polls it woke."""
        waiting = self.waiting()
        if not waiting:
            return 0
        seqs = await run_in_threadpool(self._read, sorted(waiting))
        woken = 0
        for rid, after in waiting.items():
            last = seqs.get(rid)
            if last is None or last > after:
                self._hub.publish(message_topic(rid), last)
                woken += 1
        self.sweeps += 1
        self.woken += woken
        if woken:
            log.debug("poll sweep woke the polls of %d robots (a wake-up was missed)", woken)
        return woken

    async def run(self, period_s: float) -> None:
        """Sweep every ``period_s`` until cancelled; a failed read is logged and retried next period."""
        while True:
            await asyncio.sleep(period_s)
            try:
                await self.sweep()
            except Exception:  # never end the safety net; the next period reads again
                log.exception("the long-polls' safety-net read failed; retrying in %.1f s", period_s)
