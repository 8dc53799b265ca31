"""A reverse proxy on 127.0.0.1 that forwards the agent's requests to a real server, or answers them itself
the way a broken network does (for the agent's link tests, docs/reliability/agent.md):

- ``pass``: forward (long-polls included; one thread per connection);
- ``503-inf`` / ``503-day`` / ``503-garbage``: ``503`` with ``Retry-After: inf`` / ``86400`` / ``soon``;
- ``portal``: ``200 text/html``, a Wi-Fi login page, to everything;
- ``redirect``: ``302`` to a login page;
- ``shape``: ``200 application/json`` of the wrong shape (``{"messages": "none"}`` and the like);
- ``notjson``: ``200 application/json`` whose body is not JSON.

:attr:`AnswerProxy.mode` switches at once (:attr:`AnswerProxy.only` limits it to some request kinds);
:attr:`counters` counts ``<mode>.<kind>`` answers
(``kind``: poll, upload, ack, kernel, other).
"""

from __future__ import annotations

import re
import threading
from collections import Counter
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

import httpx

__all__ = ["MODES", "AnswerProxy"]

MODES = ("pass", "503-inf", "503-day", "503-garbage", "portal", "redirect", "shape", "notjson")
_PORTAL = b"<!doctype html><html><body><h1>Welcome to HotelWiFi</h1><form>Log in</form></body></html>"
_KINDS = (
    ("upload", re.compile(r"^POST /api/v1/robots/\d+/maps")),
    ("ack", re.compile(r"^POST /api/v1/robots/\d+/messages/\d+/ack")),
    ("poll", re.compile(r"^GET /api/v1/robots/\d+/messages")),
    ("kernel", re.compile(r"^GET /api/v1/kernels/")),
)


def _kind(method: str, path: str) -> str:
    line = f"{method} {path}"
    return next((k for k, p in _KINDS if p.match(line)), "other")


class AnswerProxy:
    """Listens on a free port of 127.0.0.1 (:attr:`url`); ``close()`` stops it."""

    def __init__(self, upstream: str) -> None:
        self.mode = "pass"
        self.only: frozenset[str] | None = None  # the request kinds ``mode`` applies to (None: all)
        self.counters: Counter[str] = Counter()
        self._lock = threading.Lock()
        self._client = httpx.Client(base_url=upstream, timeout=httpx.Timeout(120.0))
        proxy = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"

            def log_message(self, *_args: Any) -> None:
                pass

            def _serve(self) -> None:
                length = int(self.headers.get("content-length") or 0)
                body = self.rfile.read(length) if length else b""
                mode, kind = proxy.mode, _kind(self.command, self.path)
                if proxy.only is not None and kind not in proxy.only:
                    mode = "pass"
                with proxy._lock:
                    proxy.counters[f"{mode}.{kind}"] += 1
                if mode == "pass":
                    headers = {
                        k: v for k, v in self.headers.items() if k.lower() not in ("host", "content-length")
                    }
                    try:
                        resp = proxy._client.request(self.command, self.path, content=body, headers=headers)
                    except httpx.HTTPError:
                        self._answer(502, "text/plain", b"bad gateway")
                        return
                    drop = ("content-length", "transfer-encoding", "connection", "content-encoding")
                    extra = {k: v for k, v in resp.headers.items() if k.lower() not in drop}
                    self._answer(resp.status_code, None, resp.content, extra)
                    return
                if mode.startswith("503-"):
                    after = {"503-inf": "inf", "503-day": "86400", "503-garbage": "soon"}[mode]
                    self._answer(503, "text/plain", b"busy", {"Retry-After": after})
                elif mode == "portal":
                    self._answer(200, "text/html; charset=utf-8", _PORTAL)
                elif mode == "redirect":
                    self._answer(302, "text/html", _PORTAL, {"Location": "http://login.portal/"})
                elif mode == "shape":
                    wrong = b'{"messages": "none", "version": "x", "current_version": null}'
                    self._answer(200, "application/json", wrong)
                else:
                    self._answer(200, "application/json", b"{not json")

            def _answer(
                self, status: int, ctype: str | None, body: bytes, headers: dict[str, str] | None = None
            ) -> None:
                self.send_response(status)
                for k, v in (headers or {}).items():
                    self.send_header(k, v)
                if ctype is not None:
                    self.send_header("Content-Type", ctype)
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)

            def handle(self) -> None:
                try:
                    super().handle()
                except OSError:  # the agent hung up, or the proxy closed under a request in flight
                    self.close_connection = True

            do_GET = do_POST = do_PUT = do_DELETE = _serve  # noqa: N815

        self._server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self._server.daemon_threads = True
        self.url = f"http://127.0.0.1:{self._server.server_address[1]}"
        self._thread = threading.Thread(target=self._server.serve_forever, daemon=True)
        self._thread.start()

    def count(self, mode: str, kind: str) -> int:
        with self._lock:
            return self.counters[f"{mode}.{kind}"]

    def close(self) -> None:
        self._server.shutdown()
        self._server.server_close()
        self._client.close()

    def __enter__(self) -> AnswerProxy:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
