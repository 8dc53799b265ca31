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

A poll has opened when its handler begins to wait (it calls :func:`opened`), or when its response starts
or its handler ends (an immediate answer, an error). Nothing else is held back; a poll that waited at the
door loses nothing (its read happens when it is let in, and the messages it asks for are in the database);
a control message reaches a poll that is already waiting as before. Under steady load polls re-open a few
a second and are let in at the next pause. O(1) a request.
"""

from __future__ import annotations

import asyncio
import collections
from urllib.parse import parse_qsl

from starlette.requests import Request
from starlette.types import ASGIApp, Message, Receive, Scope, Send

__all__ = ["POLL_OPEN_FLOOR_HZ", "POLL_OPEN_SLOTS", "PollAdmission", "is_long_poll", "opened"]

#: Long-polls opening at a time (the server's setting ``poll_open_slots``).
POLL_OPEN_SLOTS = 2
#: Long-polls let in a second while other requests never pause (the setting ``poll_open_floor_hz``).
POLL_OPEN_FLOOR_HZ = 50.0
_KEY = "linemap.poll_admission"


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

    def __init__(self, door: PollAdmission) -> None:
        self._door, self._held = door, True

    def release(self) -> None:
        if self._held:
            self._held = False
            self._door._opening -= 1
            self._door._wake()


def opened(request: Request) -> None:
    """The long-poll of ``request`` has opened (it begins to wait): the next one may open. A no-op for a
    request that was not let in as a long-poll (a test calling the route directly, another route)."""
    slot = request.scope.get(_KEY)
    if isinstance(slot, _Slot):
        slot.release()


class PollAdmission:
    """ASGI middleware: other requests before long-polls' openings (see the module's docstring).

    State (one event loop's): requests in progress (``_busy``), polls opening (``_opening``), the polls at
    the door in arrival order, the loop time the last one was let in, and the timer that lets one in at
    the floor rate when the others never pause."""

    def __init__(
        self, app: ASGIApp, slots: int = POLL_OPEN_SLOTS, floor_hz: float = POLL_OPEN_FLOOR_HZ
    ) -> None:
        if slots < 1:
            raise ValueError(f"poll_open_slots={slots}: expected at least 1")
        if not floor_hz > 0:
            raise ValueError(f"poll_open_floor_hz={floor_hz}: expected a rate above 0")
        self.app, self.slots, self.gap_s = app, slots, 1.0 / floor_hz
        self._busy = self._opening = 0
        self._door: collections.deque[asyncio.Future[None]] = collections.deque()
        self._last_in: float | None = None  # set when the first poll comes: the floor counts from there
        self._timer: asyncio.TimerHandle | None = None

    @property
    def waiting(self) -> int:
        """Long-polls waiting at the door now."""
        return sum(not f.done() for f in self._door)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
        elif is_long_poll(scope):
            await self._poll(scope, receive, send)
        else:
            await self._other(scope, receive, send)

    async def _other(self, scope: Scope, receive: Receive, send: Send) -> None:
        """A request that goes first: counted in progress until its response starts (a stream then no
        longer counts) or its handler ends."""
        self._busy += 1
        counted = True

        def done() -> None:
            nonlocal counted
            if counted:
                counted = False
                self._busy -= 1
                self._wake()

        async def started_send(message: Message) -> None:
            if message["type"] == "http.response.start":
                done()
            await send(message)

        try:
            await self.app(scope, receive, started_send)
        finally:
            done()

    async def _poll(self, scope: Scope, receive: Receive, send: Send) -> None:
        if self._last_in is None:
            self._last_in = self._loop_time()
        if self._door or not self._may_enter():
            entry = asyncio.get_running_loop().create_future()
            self._door.append(entry)
            self._wake()
            try:
                await entry
            except asyncio.CancelledError:
                if entry.done() and not entry.cancelled():  # let in as it was cancelled: give the slot on
                    self._opening -= 1
                    self._wake()
                raise
        else:
            self._enter()
        slot = _Slot(self)
        scope[_KEY] = slot

        async def releasing_send(message: Message) -> None:
            if message["type"] == "http.response.start":
                slot.release()
            await send(message)

        try:
            await self.app(scope, receive, releasing_send)
        finally:
            slot.release()

    def _may_enter(self) -> bool:
        if self._opening >= self.slots:
            return False
        last = self._loop_time() if self._last_in is None else self._last_in
        return self._busy == 0 or self._loop_time() - last >= self.gap_s

    def _enter(self) -> None:
        self._opening += 1
        self._last_in = self._loop_time()

    @staticmethod
    def _loop_time() -> float:
        return asyncio.get_running_loop().time()

    def _wake(self) -> None:
        """Let in the polls at the door that may enter now; if some wait only for the others to pause, a
        timer lets the first in when the floor rate allows."""
        while self._door and self._door[0].done():  # cancelled while waiting (the client went away)
            self._door.popleft()
        while self._door and self._may_enter():
            entry = self._door.popleft()
            if not entry.done():
                self._enter()
                entry.set_result(None)
            while self._door and self._door[0].done():
                self._door.popleft()
        if self._door and self._opening < self.slots and self._timer is None:
            last = self._loop_time() if self._last_in is None else self._last_in
            due_s = max(0.0, last + self.gap_s - self._loop_time())
            self._timer = asyncio.get_running_loop().call_later(due_s, self._on_timer)

    def _on_timer(self) -> None:
        self._timer = None
        self._wake()
