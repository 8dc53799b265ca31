"""Long-polls open when the server has a moment, so that map uploads are not queued behind a crowd of them.

A robot's long-poll for control messages costs the server about as much to open as a map upload (HTTP,
authentication, dependencies, one read: ~2-3 ms of CPU on the 2-core reference machine), and then
nothing while it waits. Uploads are what the fleet's operators watch (the live map) and their latency is
the server's figure of merit; a poll's opening is not: the robot has asked to wait anyway. When many
polls open at once (every robot starting together, or coming back after a server restart) they used to
take the event loop for their whole batch, and the uploads arriving meanwhile waited behind them: with
100 robots starting in the same moment, every upload of the first half second took ~0.5 s (issue 22,
``benchmarks/server_load.py``).

:class:`PollAdmission` (ASGI middleware) gives the other requests priority over long-polls' openings
(``GET .../messages`` with ``wait`` > 0). A poll waits at the door, before any of its work is done, and
is let in, first come first served, when fewer than ``slots`` polls are opening and either

- no other request is in progress (arrived, its response not started yet), or
- no poll was let in for ``1 / floor_hz`` seconds: under a load that never pauses, polls still open at
  ``floor_hz`` a second (the priority cannot starve them; ~15 % of a core at the default 50/s).

A poll that waited at the door is screened again when it is let in (``screen``, the failed-authentication
limit's :class:`server.authguard.AuthScreen`): if its source was blocked meanwhile and its credential is
invalid, it gets the limit's 429 there, its slot given on at once, without its route's work. So a flood
of long-polls with a bad token, admitted past the limit before the limit had counted enough of them,
drains from the door at the cost of a cache lookup each, instead of keeping real robots' polls waiting
behind it.

A poll has opened when its handler begins to wait (it calls :func:`opened`), or when its response starts
or its handler ends (an immediate answer, an error). Nothing else is held back; a poll that waited at the
door loses nothing (its read happens when it is let in, and the messages it asks for are in the database);
a control message reaches a poll that is already waiting as before. Under steady load polls re-open a few
a second and are let in at the next pause. O(1) a request.
"""

from __future__ import annotations

import asyncio
import collections
import weakref
from collections.abc import Awaitable, Callable
from urllib.parse import parse_qsl

from starlette.requests import Request
from starlette.types import ASGIApp, Message, Receive, Scope, Send

__all__ = ["POLL_OPEN_FLOOR_HZ", "POLL_OPEN_SLOTS", "PollAdmission", "Screen", "is_long_poll", "opened"]

#: Long-polls opening at a time (the server's setting ``poll_open_slots``).
POLL_OPEN_SLOTS = 2
#: Long-polls let in a second while other requests never pause (the setting ``poll_open_floor_hz``).
POLL_OPEN_FLOOR_HZ = 50.0
_KEY = "linemap.poll_admission"

#: Screens a request's scope: a coroutine that sends its refusal, or None to serve it.
Screen = Callable[[Scope], Awaitable[Callable[[Send], Awaitable[None]] | None]]


def is_long_poll(scope: Scope) -> bool:
    """Whether ``scope`` is a robot's long-poll for messages: ``GET .../robots/{id}/messages`` whose query
    asks to wait (``wait`` a number above 0; one that is not a number is left to the route's validation,
    which answers 422). O(length of the query)."""
    if scope["type"] != "http" or scope["method"] != "GET" or not scope["path"].endswith("/messages"):
        return False
    for name, value in parse_qsl(scope.get("query_string", b"").decode("latin-1")):
        if name == "wait":
            try:
                return float(value) > 0
            except ValueError:
                return False
    return False


class _Slot:
    """One admitted poll's hold on a slot; released once (by :func:`opened` or by the middleware)."""

    __slots__ = ("_door", "_held")

    def __init__(self, door: _Door) -> None:
        self._door, self._held = door, True

    def release(self) -> None:
        if self._held:
            self._held = False
            self._door.opening -= 1
            self._door.wake()


def opened(request: Request) -> None:
    """The long-poll of ``request`` has opened (it begins to wait): the next one may open. A no-op for a
    request that was not let in as a long-poll (a test calling the route directly, another route)."""
    slot = request.scope.get(_KEY)
    if isinstance(slot, _Slot):
        slot.release()


class _Door:
    """The admission's state in one event loop: requests in progress (``busy``), polls opening
    (``opening``), the polls at the door in arrival order, the loop time the last one was let in, and the
    timer that lets one in at the floor rate when the others never pause."""

    def __init__(self, loop: asyncio.AbstractEventLoop, slots: int, gap_s: float) -> None:
        self.loop, self.slots, self.gap_s = loop, slots, gap_s
        self.busy = self.opening = 0
        self.queue: collections.deque[asyncio.Future[None]] = collections.deque()
        self.last_in: float | None = None  # set when the first poll comes: the floor counts from there
        self.timer: asyncio.TimerHandle | None = None

    @property
    def waiting(self) -> int:
        """Long-polls waiting at the door now. O(waiting)."""
        return sum(not f.done() for f in self.queue)

    def may_enter(self) -> bool:
        if self.opening >= self.slots:
            return False
        now = self.loop.time()
        last = now if self.last_in is None else self.last_in
        return self.busy == 0 or now - last >= self.gap_s

    def enter(self) -> None:
        self.opening += 1
        self.last_in = self.loop.time()

    def wake(self) -> None:
        """Let in the polls at the door that may enter now; if some wait only for the others to pause, a
        timer lets the first in when the floor rate allows."""
        while self.queue and self.queue[0].done():  # cancelled while waiting (the client went away)
            self.queue.popleft()
        while self.queue and self.may_enter():
            entry = self.queue.popleft()
            if not entry.done():
                self.enter()
                entry.set_result(None)
            while self.queue and self.queue[0].done():
                self.queue.popleft()
        if self.queue and self.opening < self.slots and self.timer is None:
            now = self.loop.time()
            last = now if self.last_in is None else self.last_in
            self.timer = self.loop.call_later(max(0.0, last + self.gap_s - now), self._on_timer)

    def _on_timer(self) -> None:
        self.timer = None
        self.wake()


class PollAdmission:
    """ASGI middleware: other requests before long-polls' openings (see the module's docstring). Its
    state is kept per event loop (one in a server process; tests may run an app in several, one after the
    other), so nothing of a loop that has ended reaches the next."""

    def __init__(
        self,
        app: ASGIApp,
        slots: int = POLL_OPEN_SLOTS,
        floor_hz: float = POLL_OPEN_FLOOR_HZ,
        screen: Screen | None = None,
    ) -> None:
        if slots < 1:
            raise ValueError(f"poll_open_slots={slots}: expected at least 1")
        if not floor_hz > 0:
            raise ValueError(f"poll_open_floor_hz={floor_hz}: expected a rate above 0")
        self.app, self.slots, self.gap_s, self.screen = app, slots, 1.0 / floor_hz, screen
        self._doors: weakref.WeakKeyDictionary[asyncio.AbstractEventLoop, _Door] = weakref.WeakKeyDictionary()

    def door(self) -> _Door:
        """The state of the running event loop (made on first use)."""
        loop = asyncio.get_running_loop()
        door = self._doors.get(loop)
        if door is None:
            door = self._doors[loop] = _Door(loop, self.slots, self.gap_s)
        return door

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
        elif is_long_poll(scope):
            await self._poll(self.door(), scope, receive, send)
        else:
            await self._other(self.door(), scope, receive, send)

    async def _other(self, door: _Door, scope: Scope, receive: Receive, send: Send) -> None:
        """A request that goes first: counted in progress until its response starts (a stream then no
        longer counts) or its handler ends."""
        door.busy += 1
        counted = True

        def done() -> None:
            nonlocal counted
            if counted:
                counted = False
                door.busy -= 1
                door.wake()

        async def started_send(message: Message) -> None:
            if message["type"] == "http.response.start":
                done()
            await send(message)

        try:
            await self.app(scope, receive, started_send)
        finally:
            done()

    async def _poll(self, door: _Door, scope: Scope, receive: Receive, send: Send) -> None:
        if door.last_in is None:
            door.last_in = door.loop.time()
        waited = bool(door.queue) or not door.may_enter()
        if waited:
            entry = door.loop.create_future()
            door.queue.append(entry)
            door.wake()
            try:
                await entry
            except asyncio.CancelledError:
                if entry.done() and not entry.cancelled():  # let in as it was cancelled: give the slot on
                    door.opening -= 1
                    door.wake()
                raise
        else:
            door.enter()
        slot = _Slot(door)
        scope[_KEY] = slot

        async def releasing_send(message: Message) -> None:
            if message["type"] == "http.response.start":
                slot.release()
            await send(message)

        try:
            if waited and self.screen is not None:
                refusal = await self.screen(scope)
                if refusal is not None:
                    slot.release()  # before the refusal's delay: the door does not wait for it
                    await refusal(send)
                    return
            await self.app(scope, receive, releasing_send)
        finally:
            slot.release()
