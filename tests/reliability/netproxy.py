"""A fault-injecting HTTP/1.1 proxy on 127.0.0.1 for the reliability suite (docs/reliability.md).

It sits between the robot agent and the server and, per request, seeded, may:

- ``drop``: close the client's connection before the request is forwarded (the server never sees it);
- ``delay``: hold the request (or its response) back for a while, then forward it normally;
- ``duplicate``: send the request to the server twice (one after the other, or both at once) and answer the
  client with the second response;
- ``cut``: forward the request, then send only the first half of the response's bytes and close.

Requests are framed by ``Content-Length`` (the agent's httpx client sends no chunked bodies); responses by
``Content-Length``, ``chunked`` or connection close. Each forwarded request gets a fresh upstream
connection, so a fault never leaves a half-read upstream stream behind. Fault decisions come from one
``random.Random`` per request kind (``upload``, ``ack``, ``poll``, ``kernel``, ``other``), seeded from
``seed`` and the kind, so the n-th upload meets the same fault in every run whatever the other threads do;
``script`` can set the faults of a kind's first requests exactly (e.g. ``{"kernel": ["cut", "drop"]}``).

Bounded: the proxy serves at most ``max_connections`` client connections and stops by itself after
``max_s`` seconds; ``close()`` (or leaving the ``with`` block) stops it at once. :attr:`counters` counts
requests and faults per kind (``upload.received``, ``upload.cut``, ``upload.forwarded`` ...).
"""

from __future__ import annotations

import asyncio
import contextlib
import random
import re
import threading
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

__all__ = ["FAULTS", "FaultProxy", "ProxyError", "request_kind"]

FAULTS = ("drop", "delay", "duplicate", "cut")
_HEAD_LIMIT = 64 * 1024
_BODY_LIMIT = 16 * 1024 * 1024
_IDLE_S = 120.0  # a client connection with no request for this long is closed
_UPSTREAM_S = 90.0  # longest wait for the server's response (long-polls wait up to ~60 s)

_KINDS = (
    ("upload", re.compile(r"^POST /api/v1/robots/\d+/maps(\?|$)")),
    ("ack", re.compile(r"^POST /api/v1/robots/\d+/messages/\d+/ack(\?|$)")),
    ("poll", re.compile(r"^GET /api/v1/robots/\d+/messages(\?|$)")),
    ("kernel", re.compile(r"^GET /api/v1/kernels/")),
)


class ProxyError(Exception):
    """A malformed or unsupported HTTP message on either side (the connection is closed)."""


def request_kind(method: str, target: str) -> str:
    """``upload``, ``ack``, ``poll``, ``kernel`` or ``other`` for a request line's method and target."""
    line = f"{method} {target}"
    for kind, pattern in _KINDS:
        if pattern.match(line):
            return kind
    return "other"


@dataclass(frozen=True, slots=True)
class _Message:
    head: bytes  # start line and headers, up to and including the blank line
    body: bytes

    @property
    def raw(self) -> bytes:
        return self.head + self.body


def _headers(head: bytes) -> dict[str, str]:
    lines = head.decode("latin-1").split("\r\n")[1:]
    out: dict[str, str] = {}
    for line in lines:
        if not line:
            continue
        name, sep, value = line.partition(":")
        if not sep:
            raise ProxyError(f"header line without a colon: {line[:80]!r}")
        out[name.strip().lower()] = value.strip()
    return out


async def _read_head(reader: asyncio.StreamReader) -> bytes:
    try:
        return await reader.readuntil(b"\r\n\r\n")
    except asyncio.LimitOverrunError:
        raise ProxyError(f"message head longer than {_HEAD_LIMIT} bytes") from None


async def _read_chunked(reader: asyncio.StreamReader) -> bytes:
    parts = []
    while True:
        size_line = await reader.readuntil(b"\r\n")
        parts.append(size_line)
        size = int(size_line.split(b";")[0].strip() or b"0", 16)
        if size == 0:
            while True:  # trailers, up to the blank line
                line = await reader.readuntil(b"\r\n")
                parts.append(line)
                if line == b"\r\n":
                    return b"".join(parts)
        parts.append(await reader.readexactly(size + 2))


async def _read_request(reader: asyncio.StreamReader) -> _Message:
    head = await _read_head(reader)
    headers = _headers(head)
    if "chunked" in headers.get("transfer-encoding", "").lower():
        raise ProxyError("chunked request bodies are not supported")
    length = int(headers.get("content-length", "0") or "0")
    if not 0 <= length <= _BODY_LIMIT:
        raise ProxyError(f"request Content-Length {length}: expected 0..{_BODY_LIMIT}")
    body = await reader.readexactly(length) if length else b""
    return _Message(head, body)


async def _read_response(reader: asyncio.StreamReader, method: str) -> _Message:
    head = await _read_head(reader)
    status = int(head.split(b" ", 2)[1])
    headers = _headers(head)
    if method == "HEAD" or status in (204, 304) or 100 <= status < 200:
        return _Message(head, b"")
    if "chunked" in headers.get("transfer-encoding", "").lower():
        return _Message(head, await _read_chunked(reader))
    if "content-length" in headers:
        return _Message(head, await reader.readexactly(int(headers["content-length"])))
    return _Message(head, await reader.read(_BODY_LIMIT))  # framed by the connection's end


class FaultProxy:
    """The proxy, listening on ``127.0.0.1:port`` (``url``) and forwarding to ``upstream_host:upstream_port``.

    ``fault_rate`` (0..1, settable while running) is the share of requests that meet a fault, drawn evenly
    from ``faults``; ``delay_s`` bounds a delay fault (uniform). Runs its own event loop in a daemon thread.
    """

    def __init__(
        self,
        upstream_host: str,
        upstream_port: int,
        *,
        seed: int = 0,
        fault_rate: float = 0.3,
        faults: tuple[str, ...] = FAULTS,
        delay_s: tuple[float, float] = (0.01, 0.3),
        max_connections: int = 100_000,
        max_s: float = 1800.0,
        script: Mapping[str, Sequence[str | None]] | None = None,
    ) -> None:
        scripted = {f for seq in (script or {}).values() for f in seq if f is not None}
        unknown = (set(faults) | scripted) - set(FAULTS)
        if unknown:
            raise ValueError(f"unknown faults {sorted(unknown)}; expected some of {FAULTS}")
        self.upstream = (upstream_host, upstream_port)
        self.faults = faults
        self.delay_s = delay_s
        self.max_connections = max_connections
        self.max_s = max_s
        self.counters: Counter[str] = Counter()
        self._seed = seed
        self._rate = 0.0
        self.fault_rate = fault_rate
        self._rngs: dict[str, random.Random] = {}
        self._script = {kind: list(seq) for kind, seq in (script or {}).items()}
        self._lock = threading.Lock()
        self._loop = asyncio.new_event_loop()
        self._ready = threading.Event()
        self._thread = threading.Thread(target=self._run, name="fault-proxy", daemon=True)
        self._server: asyncio.Server | None = None
        self._stopped: asyncio.Event | None = None
        self._tasks: set[asyncio.Task[Any]] = set()
        self.port = 0
        self.error: BaseException | None = None

    # ------------------------------------------------------------------ control
    @property
    def fault_rate(self) -> float:
        return self._rate

    @fault_rate.setter
    def fault_rate(self, value: float) -> None:
        if not 0.0 <= value <= 1.0:
            raise ValueError(f"fault_rate = {value!r}: expected a share between 0 and 1")
        self._rate = value

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def count(self, key: str, n: int = 1) -> None:
        with self._lock:
            self.counters[key] += n

    def snapshot(self) -> dict[str, int]:
        """A copy of the counters."""
        with self._lock:
            return dict(self.counters)

    def __enter__(self) -> FaultProxy:
        self._thread.start()
        if not self._ready.wait(30) or self.port == 0:
            raise RuntimeError(f"the fault proxy did not start: {self.error!r}")
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        if self._thread.is_alive() and self._stopped is not None:
            self._loop.call_soon_threadsafe(self._stopped.set)
            self._thread.join(30)

    # ------------------------------------------------------------------ event loop
    def _run(self) -> None:
        try:
            self._loop.run_until_complete(self._main())
        except BaseException as exc:  # reported by __enter__ / kept for the test to see
            self.error = exc
        finally:
            self._ready.set()
            self._loop.close()

    async def _main(self) -> None:
        self._stopped = asyncio.Event()
        self._server = await asyncio.start_server(self._client, "127.0.0.1", 0, limit=_HEAD_LIMIT)
        self.port = self._server.sockets[0].getsockname()[1]
        self._ready.set()
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(self._stopped.wait(), timeout=self.max_s)
        self._server.close()
        for task in list(self._tasks):
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        await self._server.wait_closed()

    def _decide(self, kind: str) -> tuple[str | None, float]:
        """The fault for the next request of ``kind`` (or None) and a number in [0, 1) to size it."""
        with self._lock:
            rng = self._rngs.get(kind)
            if rng is None:
                rng = self._rngs[kind] = random.Random(f"{self._seed}-{kind}")
            if self._script.get(kind):
                return self._script[kind].pop(0), rng.random()
            hit = rng.random() < self._rate
            fault = rng.choice(self.faults) if hit else None
            return fault, rng.random()

    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._tasks.add(task)
        self.count("connections")
        try:
            if self.snapshot()["connections"] > self.max_connections:
                self.count("connections.refused")
                return
            while True:
                try:
                    request = await asyncio.wait_for(_read_request(reader), timeout=_IDLE_S)
                except (asyncio.IncompleteReadError, ConnectionError, TimeoutError):
                    return  # the client closed (or idled out): normal end of a keep-alive connection
                if not await self._serve(request, writer):
                    return
        except ProxyError:
            self.count("protocol_errors")
        except (OSError, asyncio.IncompleteReadError, TimeoutError):
            self.count("io_errors")
        except asyncio.CancelledError:  # the proxy stops: end the connection quietly
            self.count("connections.cancelled")
        finally:
            writer.close()
            with contextlib.suppress(Exception):
                await writer.wait_closed()
            self._tasks.discard(task)

    async def _forward(self, request: _Message, method: str) -> _Message:
        reader, writer = await asyncio.open_connection(*self.upstream, limit=_HEAD_LIMIT)
        try:
            writer.write(request.raw)
            await writer.drain()
            return await asyncio.wait_for(_read_response(reader, method), timeout=_UPSTREAM_S)
        finally:
            writer.close()
            with contextlib.suppress(Exception):
                await writer.wait_closed()

    async def _serve(self, request: _Message, writer: asyncio.StreamWriter) -> bool:
        """Handle one request; False when the client connection must be closed."""
        method, target = request.head.split(b"\r\n", 1)[0].decode("latin-1").split(" ")[:2]
        kind = request_kind(method, target)
        fault, size = self._decide(kind)
        self.count(f"{kind}.received")
        if fault is not None:
            self.count(f"{kind}.{fault}")
            self.count(f"faults.{fault}")
        if fault == "drop":
            return False
        lo, hi = self.delay_s
        if fault == "delay" and size < 0.5:  # half of the delays hold the request back ...
            await asyncio.sleep(lo + (hi - lo) * size * 2)
        if fault == "duplicate":
            self.count(f"{kind}.forwarded", 2)
            if size < 0.5:  # ... the original and its copy at once, or one after the other
                self.count(f"{kind}.duplicate.concurrent")
                _first, response = await asyncio.gather(
                    self._forward(request, method), self._forward(request, method)
                )
            else:
                self.count(f"{kind}.duplicate.sequential")
                await self._forward(request, method)
                response = await self._forward(request, method)
        else:
            self.count(f"{kind}.forwarded")
            response = await self._forward(request, method)
        status = response.head.split(b" ", 2)[1].decode("latin-1")
        self.count(f"{kind}.status.{status}")
        if fault == "delay" and size >= 0.5:  # ... and half the response
            await asyncio.sleep(lo + (hi - lo) * (size - 0.5) * 2)
        raw = response.raw
        if fault == "cut":
            writer.write(raw[: len(raw) // 2])
            await writer.drain()
            return False
        # counted before the bytes leave: a client that has read the response sees it counted
        self.count(f"{kind}.delivered")
        writer.write(raw)
        await writer.drain()
        return _headers(response.head).get("connection", "").lower() != "close"
