"""Cross-site request forgery: state-changing requests made with the session cookie must come from the
dashboard itself (docs/reliability/csrf.md).

Two independent checks; a forged request fails both.

1. :class:`OriginGuard` (ASGI middleware, every route): a request with a method other than GET, HEAD or
   OPTIONS that does not carry ``Authorization`` (so it may be riding on the browser's cookie) is refused
   with 403 when the browser says it comes from elsewhere: ``Sec-Fetch-Site`` other than ``same-origin``
   (``same-site`` is what a page on another port of the same host gets, so it is refused too), or an
   ``Origin`` that is neither the server's own origin (the request's scheme, host and port) nor one of the
   ``csrf_trusted_origins`` setting (e.g. the public origin of a reverse proxy). A request with neither
   header (curl, httpx, an old browser) passes this check; the next one still holds for it.
2. :func:`require_csrf_token` (called where the session cookie authenticates, in
   :func:`server.deps.get_principal`, so on every authenticated route present and future, and at logout):
   such a state-changing request must carry the header ``X-Linemap-CSRF`` with the token bound to its
   session, :func:`csrf_token` of the session id. A "simple" cross-origin request (form, ``text/plain``
   fetch, image) cannot carry a custom header, and a page that cannot read the HttpOnly cookie or this
   server's responses cannot know the value. The dashboard gets it at login and from
   ``GET /api/v1/session``.

Bearer-token clients (robots, scripts) are not affected: a browser never adds ``Authorization`` by itself.
"""

from __future__ import annotations

import base64
import functools
import hashlib
import hmac
import logging
from collections.abc import Iterable
from urllib.parse import urlsplit

from fastapi.responses import JSONResponse
from starlette.types import ASGIApp, Receive, Scope, Send

from server.errors import ForbiddenError

__all__ = [
    "CSRF_HEADER",
    "SAFE_METHODS",
    "OriginGuard",
    "csrf_token",
    "normalize_origin",
    "require_csrf_token",
]

log = logging.getLogger(__name__)

#: The header the dashboard sends on every state-changing request (its value: :func:`csrf_token`).
CSRF_HEADER = "X-Linemap-CSRF"
#: Methods that change nothing (never checked).
SAFE_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})
_DEFAULT_PORTS = {"http": 80, "https": 443}


def csrf_token(session_id: str) -> str:
    """The CSRF token bound to a session: a keyed-by-purpose SHA-256 of the session id (43 characters).

    Stateless, so every server process sharing the database agrees; knowing it does not reveal the session
    id (a pre-image), and it is neither the session id nor the hash the database stores. O(len(id))."""
    digest = hashlib.sha256(b"linemap-csrf-token\x00" + session_id.encode("utf-8", "surrogatepass")).digest()
    return base64.urlsafe_b64encode(digest).rstrip(b"=").decode("ascii")


def require_csrf_token(method: str, session_id: str, presented: str | None) -> None:
    """Raise :class:`ForbiddenError` unless a state-changing ``method`` authenticated by the session cookie
    ``session_id`` presents its :func:`csrf_token` in ``X-Linemap-CSRF``. Safe methods pass."""
    if method.upper() in SAFE_METHODS:
        return
    if not presented:
        raise ForbiddenError(
            f"a {method.upper()} with the session cookie needs the header {CSRF_HEADER} "
            "(the dashboard sends it; get its value from GET /api/v1/session), or use "
            "'Authorization: Bearer <token>'",
            reason="csrf",
        )
    if not hmac.compare_digest(presented.strip().encode("utf-8", "replace"), csrf_token(session_id).encode()):
        raise ForbiddenError(
            f"{CSRF_HEADER} does not belong to this session: reload the dashboard "
            "(GET /api/v1/session gives the current value)",
            reason="csrf",
        )


@functools.lru_cache(maxsize=1024)  # a server sees few distinct origins; bounded whatever it is sent
def normalize_origin(origin: str) -> str | None:
    """``scheme://host[:port]`` in lower case with the scheme's default port left out, or ``None`` when
    ``origin`` is not a web origin (``null``, a path, user info, an unknown scheme, a bad port)."""
    try:
        parts = urlsplit(origin.strip())
        port = parts.port
    except ValueError:
        return None
    scheme = parts.scheme.lower()
    host = (parts.hostname or "").lower()
    if scheme not in _DEFAULT_PORTS or not host or parts.username or parts.password:
        return None
    if parts.path not in ("", "/") or parts.query or parts.fragment:
        return None
    if ":" in host:  # an IPv6 literal
        host = f"[{host}]"
    return f"{scheme}://{host}" if port in (None, _DEFAULT_PORTS[scheme]) else f"{scheme}://{host}:{port}"


def _own_origin(scope: Scope, headers: dict[bytes, bytes]) -> str | None:
    """The origin this request was sent to: its scheme (as uvicorn saw it) and its ``Host`` header."""
    scheme = str(scope.get("scheme", "http"))
    host = headers.get(b"host", b"").decode("latin-1").strip()
    if not host and scope.get("server"):
        name, port = scope["server"]
        host = f"[{name}]:{port}" if ":" in str(name) else f"{name}:{port}"
    return normalize_origin(f"{scheme}://{host}") if host else None


class OriginGuard:
    """Refuse (403) state-changing requests without ``Authorization`` that a browser marks as coming from
    another origin (module docstring, check 1). O(headers) per request; no body is read."""

    def __init__(self, app: ASGIApp, trusted_origins: Iterable[str] = ()) -> None:
        self.app = app
        self.trusted = frozenset(o for o in (normalize_origin(t) for t in trusted_origins) if o)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http" and str(scope.get("method", "GET")).upper() not in SAFE_METHODS:
            problem = self.problem(scope)
            if problem is not None:
                log.warning("refused %s %s: %s", scope.get("method"), scope.get("path"), problem)
                body = JSONResponse(
                    {"error": "forbidden", "detail": problem, "reason": "cross-origin"}, status_code=403
                )
                await send({"type": "http.response.start", "status": 403, "headers": body.raw_headers})
                await send({"type": "http.response.body", "body": body.body})
                return
        await self.app(scope, receive, send)

    def problem(self, scope: Scope) -> str | None:
        """Why this request is refused, or ``None`` when it may go on."""
        headers: dict[bytes, bytes] = {}
        for name, value in scope["headers"]:
            headers.setdefault(name.lower(), value)  # the first of repeated headers, as Starlette reads them
        if headers.get(b"authorization", b"").strip():
            return None  # a bearer credential: the browser never adds one by itself
        site = headers.get(b"sec-fetch-site")
        if site is not None and site.decode("latin-1").strip().lower() != "same-origin":
            return (
                f"cross-origin request refused: Sec-Fetch-Site is {site.decode('latin-1')[:40]!r}; "
                "state-changing requests with the session cookie must come from the dashboard's own page "
                "(same-origin), other clients send 'Authorization: Bearer <token>'"
            )
        raw = headers.get(b"origin")
        if raw is None:
            return None
        origin = normalize_origin(raw.decode("latin-1"))
        own = _own_origin(scope, headers)
        if origin is not None and (origin == own or origin in self.trusted):
            return None
        allowed = ", ".join(sorted({o for o in (own, *self.trusted) if o})) or "none"
        return (
            f"cross-origin request refused: Origin {raw.decode('latin-1')[:100]!r} is not this server's "
            f"origin ({allowed}); behind a reverse proxy add its public origin to the setting "
            "csrf_trusted_origins (LINEMAP_CSRF_TRUSTED_ORIGINS)"
        )
