"""A clean, prompt shutdown: long-polls and event streams end when the server is told to stop.

uvicorn stops on SIGINT/SIGTERM by waiting for open requests to finish, then cancelling them after its
graceful timeout; a robot's long-poll (up to ``long_poll_max_s``) or a dashboard's map stream (endless)
was cancelled mid-await and logged a traceback per request. Here :class:`ShutdownSignal` is set when the
server begins to stop (``linemap server`` sets it from uvicorn's exit handler), and
:class:`DisconnectOnShutdown` then tells every waiting handler its client has gone: a handler's
``request.is_disconnected()`` becomes true (both the long-poll and the stream check it every
``poll_recheck_s``), so the long-poll answers its (empty) result and the stream ends (its body closed
properly), within about ``poll_recheck_s`` (1 s by default). A request whose body is still arriving is not
cut short.
"""

from __future__ import annotations

import asyncio
import contextlib

from starlette.types import ASGIApp, Message, Receive, Scope, Send

__all__ = ["DisconnectOnShutdown", "ShutdownSignal"]

_DISCONNECT: Message = {"type": "http.disconnect"}


class ShutdownSignal:
    """Set once when the server begins to stop; safe to set from a signal handler or another thread."""

    def __init__(self) -> None:
        self._set = False
        self._loop: asyncio.AbstractEventLoop | None = None
        self._event: asyncio.Event | None = None

    @property
    def is_set(self) -> bool:
        return self._set

    def event(self) -> asyncio.Event:
        """The asyncio event of the running loop (made on first use, in that loop)."""
        if self._event is None:
            self._loop = asyncio.get_running_loop()
            self._event = asyncio.Event()
            if self._set:
                self._event.set()
        return self._event

    def set(self) -> None:
        """Begin the shutdown: every waiting long-poll and stream is told its client left."""
        self._set = True
        if self._loop is not None and self._event is not None:
            with contextlib.suppress(RuntimeError):  # the loop is closed already: nothing is waiting
                self._loop.call_soon_threadsafe(self._event.set)


class DisconnectOnShutdown:
    """ASGI middleware: once ``signal`` is set, ``receive`` answers ``http.disconnect`` to a request whose
    body has been read (at once if asked then, or when it is set while a handler waits on ``receive``)."""

    def __init__(self, app: ASGIApp, signal: ShutdownSignal) -> None:
        self.app = app
        self.signal = signal

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        stop = self.signal.event()
        body_done = False

        async def guarded_receive() -> Message:
            nonlocal body_done
            if not body_done:
                message = await receive()
                if message["type"] != "http.request" or not message.get("more_body", False):
                    body_done = True
                return message
            if stop.is_set():
                return _DISCONNECT
            inner = asyncio.ensure_future(receive())
            stopped = asyncio.ensure_future(stop.wait())
            try:
                await asyncio.wait({inner, stopped}, return_when=asyncio.FIRST_COMPLETED)
            finally:
                stopped.cancel()
                if not inner.done():
                    inner.cancel()
            return inner.result() if inner.done() and not inner.cancelled() else _DISCONNECT

        started = finished = False

        async def tracking_send(message: Message) -> None:
            nonlocal started, finished
            if message["type"] == "http.response.start":
                started = True
            elif message["type"] == "http.response.body" and not message.get("more_body", False):
                finished = True
            await send(message)

        await self.app(scope, guarded_receive, tracking_send)
        if started and not finished and stop.is_set():
            # A stream that stopped on the (shutdown) disconnect: end its body properly, so the client sees
            # a complete response rather than a cut connection.
            await send({"type": "http.response.body", "body": b"", "more_body": False})
