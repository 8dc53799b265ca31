"""The notice listener's reconnect logic (server.pglisten) with in-process connections: backoff between
failed attempts, a catch-up for every subscriber each time it listens again, notices handed to the hub,
the idle check; and the backoff itself. (The real thing, a PostgreSQL connection terminated under two
server processes, is tests/server/test_fanout_processes.py.)"""

from __future__ import annotations

import asyncio
import random
from collections.abc import AsyncIterator
from typing import Any

import pytest

from server.hub import OVERFLOW, Hub
from server.notices import Notice, encode_notice
from server.pglisten import Backoff, ListenConnection, NoticeListener


class LostError(Exception):
    """The connection broke (what psycopg raises is an OperationalError; any exception counts)."""


class FakeConnection:
    """Delivers ``batches`` of payloads (one per ``notifies`` call, then it ends as on its timeout);
    ``then_fail``: the next call after them raises :class:`LostError`, else it waits for good."""

    def __init__(self, batches: list[list[str]], then_fail: bool = True, select_fails: bool = False) -> None:
        self.batches = batches
        self.then_fail = then_fail
        self.select_fails = select_fails
        self.queries: list[str] = []
        self.closed = False
        self.idle = asyncio.Event()  # it has delivered everything and waits

    async def execute(self, query: Any) -> Any:
        self.queries.append(str(query))
        if query == "SELECT 1" and self.select_fails:
            raise LostError("server closed the connection unexpectedly")

    async def notifies(self, *, timeout: float | None = None) -> AsyncIterator[Any]:
        if self.batches:
            for payload in self.batches.pop(0):
                yield type("Notify", (), {"payload": payload})()
            return
        if self.then_fail:
            raise LostError("terminating connection due to administrator command")
        self.idle.set()
        await asyncio.Event().wait()

    async def close(self) -> None:
        self.closed = True


class Script:
    """A connector that fails or hands out the given connections in turn, then blocks; ``sleeps``."""

    def __init__(self, steps: list[FakeConnection | Exception]) -> None:
        self.steps = steps
        self.sleeps: list[float] = []
        self.drained = asyncio.Event()

    async def connect(self) -> ListenConnection:
        if not self.steps:
            self.drained.set()
            await asyncio.Event().wait()
        step = self.steps.pop(0)
        if isinstance(step, Exception):
            raise step
        return step

    async def sleep(self, delay_s: float) -> None:
        self.sleeps.append(delay_s)


async def _run(hub: Hub, script: Script, **kwargs: Any) -> NoticeListener:
    listener = NoticeListener(
        hub, script.connect, backoff=Backoff(0.1, 1.0, jitter=0.0), sleep=script.sleep, **kwargs
    )
    waits = [script.drained.wait()] + [s.idle.wait() for s in script.steps if isinstance(s, FakeConnection)]
    tasks = [asyncio.ensure_future(w) for w in waits]
    listener.start()
    done, pending = await asyncio.wait(tasks, timeout=5, return_when=asyncio.FIRST_COMPLETED)
    for task in pending:
        task.cancel()
    assert done, "the listener did not settle"
    await listener.stop()
    return listener


def _drain(queue: asyncio.Queue[Any]) -> list[Any]:
    out = []
    while not queue.empty():
        out.append(queue.get_nowait())
    return out


def test_failed_attempts_back_off_and_listening_resyncs_every_subscriber() -> None:
    async def go() -> None:
        hub = Hub()
        conn = FakeConnection([], then_fail=False)
        script = Script([OSError("connection refused"), LostError("no route"), OSError("refused"), conn])
        with hub.subscribe("maps:1") as maps, hub.subscribe("messages:1") as messages:
            listener = await _run(hub, script)
            assert script.sleeps == [0.1, 0.2, 0.4]  # doubling between failed attempts
            assert (listener.listens, listener.failures) == (1, 3)
            assert conn.queries == ["LISTEN linemap"] and conn.closed
            assert _drain(maps) == [OVERFLOW] and _drain(messages) == [OVERFLOW]

    asyncio.run(go())


def test_notices_reach_subscribers_and_a_lost_connection_reconnects_and_resyncs() -> None:
    async def go() -> None:
        hub = Hub()
        other = encode_notice("0123abcd", "maps:1", 7)
        own = encode_notice(hub.origin, "maps:1", 8)
        first = FakeConnection([[other, own, "not a notice"]], then_fail=True)
        second = FakeConnection([[encode_notice("0123abcd", "maps:1", 9)]], then_fail=False)
        script = Script([first, OSError("refused"), second])
        with hub.subscribe("maps:1") as maps, hub.subscribe("maps:2") as unrelated:
            listener = await _run(hub, script)
            got = _drain(maps)
            assert _drain(unrelated) == [OVERFLOW]  # only the resync after the reconnection
        # first listen: resync, then the other process's notice 7 (not our own 8, not the junk); the
        # connection is lost, one attempt fails, the next listens: a resync (it replaces what the queue
        # held: the subscriber reads everything from the database anyway), then notice 9.
        assert got == [OVERFLOW, Notice("maps:1", 9)]
        assert (listener.listens, listener.failures) == (2, 2)
        assert script.sleeps == [0.1, 0.2]  # after a success the backoff starts over
        assert first.closed and second.closed

    asyncio.run(go())


def test_a_notice_is_delivered_before_the_connection_is_lost() -> None:
    async def go() -> None:
        hub = Hub()
        conn = FakeConnection([[encode_notice("0123abcd", "messages:3", 4)]], then_fail=True)
        script = Script([conn])
        with hub.subscribe("messages:3") as queue:
            await _run(hub, script)
            assert _drain(queue) == [OVERFLOW, Notice("messages:3", 4)]

    asyncio.run(go())


def test_a_quiet_connection_is_checked_and_replaced_when_dead() -> None:
    async def go() -> None:
        hub = Hub()
        dead = FakeConnection([[], []], then_fail=False, select_fails=True)  # quiet, then SELECT 1 fails
        fresh = FakeConnection([], then_fail=False)
        script = Script([dead, fresh])
        listener = await _run(hub, script, idle_check_s=0.01)
        assert dead.queries == ["LISTEN linemap", "SELECT 1"]
        assert (listener.listens, listener.failures) == (2, 1)

    asyncio.run(go())


def test_backoff_doubles_to_its_cap_and_starts_over() -> None:
    b = Backoff(0.1, 0.5, jitter=0.0)
    assert [b.next() for _ in range(5)] == [0.1, 0.2, 0.4, 0.5, 0.5]
    b.reset()
    assert b.next() == 0.1


def test_backoff_jitter_stays_within_its_band() -> None:
    b = Backoff(1.0, 1.0, jitter=0.2, rng=random.Random(1))
    delays = [b.next() for _ in range(200)]
    assert all(0.8 <= d <= 1.2 for d in delays) and len(set(delays)) > 1


@pytest.mark.parametrize(("args", "named"), [((0.0, 1.0), "initial_s"), ((2.0, 1.0), "max_s")])
def test_backoff_refuses_bad_bounds(args: tuple[float, float], named: str) -> None:
    with pytest.raises(ValueError, match=named):
        Backoff(*args)
