"""The client side of a robot's live-map stream (``GET /api/v1/robots/{id}/maps/stream``, server-sent
events): a line parser (pure) and a reader that keeps the stream open, reconnecting with
``Last-Event-ID`` and a growing back-off when the connection drops, so the deltas missed meanwhile come
from the server's delta log (or a snapshot when the log cannot continue).

A refused credential (401, 403) or an unknown robot (404) ends the reader with its error at once: waiting
would not change them.
"""

from __future__ import annotations

import json
import logging
import threading
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import httpx

from shared.foxbridge.errors import BridgeError, MapEventError, RobotUnknownError, StreamRefusedError

__all__ = ["Backoff", "MapEvent", "MapEventStream", "SseParser"]

logger = logging.getLogger(__name__)

#: No byte for this long (s) means a dead connection: the server sends a comment every 15 s of silence.
READ_TIMEOUT_S = 45.0


@dataclass(frozen=True)
class MapEvent:
    """One event of the stream: its type (``snapshot``, ``delta``), ``id`` (the map version; None when
    the event carried none) and its data parsed from JSON."""

    kind: str
    id: int | None
    data: dict[str, Any]


@dataclass
class SseParser:
    """Server-sent events from text lines (the WHATWG rules this stream uses: ``event``, ``id``, ``data``
    fields, comment lines starting with ``:``, a blank line ends an event). O(1) per line plus the data."""

    _kind: str = ""
    _id: str | None = None
    _data: list[str] = field(default_factory=list)

    def feed(self, line: str) -> MapEvent | None:
        """Take one line (without its line break); returns the event a blank line completes, else None.
        Raises :class:`MapEventError` for an event whose data is not a JSON object or whose id is not a
        whole number."""
        if line == "":
            return self._dispatch()
        if line.startswith(":"):
            return None  # a comment (the server's keep-alive)
        name, _, value = line.partition(":")
        value = value.removeprefix(" ")
        if name == "event":
            self._kind = value
        elif name == "data":
            self._data.append(value)
        elif name == "id":
            self._id = value
        return None  # `retry` and unknown fields are ignored, as browsers do

    def _dispatch(self) -> MapEvent | None:
        kind, ident, data = self._kind or "message", self._id, self._data
        self._kind, self._id, self._data = "", None, []
        if not data:
            return None
        text = "\n".join(data)
        try:
            parsed = json.loads(text)
        except ValueError:
            raise MapEventError(f"a {kind!r} event's data is not JSON: {text[:80]!r}") from None
        if not isinstance(parsed, dict):
            raise MapEventError(f"a {kind!r} event's data: expected a JSON object, got {text[:80]!r}")
        version: int | None = None
        if ident is not None:
            if not ident.isdigit():
                raise MapEventError(f"a {kind!r} event's id: expected a map version, got {ident!r}")
            version = int(ident)
        return MapEvent(kind, version, parsed)


@dataclass
class Backoff:
    """Waits between reconnections: ``first_s``, doubling up to ``max_s``; :meth:`reset` after an event."""

    first_s: float = 0.5
    max_s: float = 30.0
    _next: float = 0.0

    def next_delay(self) -> float:
        delay = self._next or self.first_s
        self._next = min(delay * 2.0, self.max_s)
        return delay

    def reset(self) -> None:
        self._next = 0.0


def _detail(response: httpx.Response) -> str:
    """The server's ``detail`` of an error answer (its JSON), or the status line."""
    try:
        body = json.loads(response.read())
        if isinstance(body, dict) and isinstance(body.get("detail"), str):
            return str(body["detail"])
    except (ValueError, httpx.HTTPError):
        pass
    return f"HTTP {response.status_code}"


class MapEventStream:
    """A robot's live-map events, kept flowing across dropped connections.

    ``server``: the linemap server's base URL (``http://host:8000``); ``token``: an operator token or the
    robot's own. :meth:`events` yields until ``stop`` is set (checked between events and while waiting).
    """

    def __init__(
        self,
        server: str,
        robot_id: int,
        token: str | None,
        *,
        trajectory: int | None = None,
        backoff: Backoff | None = None,
        transport: httpx.BaseTransport | None = None,
    ) -> None:
        self.url = f"{server.rstrip('/')}/api/v1/robots/{robot_id}/maps/stream"
        self.robot_id = robot_id
        self.params = {} if trajectory is None else {"trajectory": str(trajectory)}
        self.headers = {"Accept": "text/event-stream"}
        if token:
            self.headers["Authorization"] = f"Bearer {token}"
        self.backoff = backoff or Backoff()
        self.transport = transport
        self.last_id: int | None = None
        self.connections = 0  # how many times the stream was opened (for logs and tests)
        self._resync = False

    def resync(self) -> None:
        """Ask for the whole map: the stream is reopened without ``Last-Event-ID`` (the server then starts
        with a snapshot). Called when a delta does not continue what the caller holds."""
        self._resync = True
        self.last_id = None

    def _check(self, response: httpx.Response) -> None:
        code = response.status_code
        if code == 200:
            return
        if code in (401, 403):
            raise StreamRefusedError(
                f"the linemap server refused the token for robot {self.robot_id}'s map "
                f"({code}: {_detail(response)}); pass an operator token or the robot's own with --token "
                "or LINEMAP_TOKEN"
            )
        if code == 404:
            raise RobotUnknownError(
                f"the linemap server at {self.url.split('/api/')[0]} has no robot {self.robot_id} "
                f"({_detail(response)})"
            )
        if 400 <= code < 500 and code not in (408, 429):
            raise BridgeError(f"the linemap server refused the map stream ({code}: {_detail(response)})")
        raise httpx.TransportError(f"HTTP {code}: {_detail(response)}")  # retried

    def events(self, stop: threading.Event) -> Iterator[MapEvent]:
        """The events, in order, across reconnections (each resuming after :attr:`last_id`)."""
        timeout = httpx.Timeout(10.0, read=READ_TIMEOUT_S)
        with httpx.Client(timeout=timeout, transport=self.transport) as client:
            while not stop.is_set():
                headers = dict(self.headers)
                if self.last_id is not None:
                    headers["Last-Event-ID"] = str(self.last_id)
                self._resync = False
                try:
                    with client.stream("GET", self.url, headers=headers, params=self.params) as response:
                        self._check(response)
                        self.connections += 1
                        logger.info("map stream open (%s, after version %s)", self.url, self.last_id)
                        parser = SseParser()
                        for line in response.iter_lines():
                            event = parser.feed(line)
                            if event is None:
                                continue
                            self.backoff.reset()
                            if event.id is not None:
                                self.last_id = event.id
                            yield event
                            if stop.is_set() or self._resync:
                                break
                    if self._resync or stop.is_set():
                        continue
                    logger.warning("the map stream ended; reconnecting")
                except httpx.TransportError as exc:  # refused, dropped, timed out, a 5xx
                    logger.warning("map stream: %s; reconnecting", exc or type(exc).__name__)
                stop.wait(self.backoff.next_delay())
