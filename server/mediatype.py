"""415 for a request body whose ``Content-Type`` its route does not take (docs/reliability/csrf.md).

Which media types a route takes is read from the route itself, so every route present and future is
covered: the request-body content types it declares for OpenAPI (``openapi_extra``, e.g. the XML control
message), else ``multipart/form-data`` for routes with form or file parameters (plus
``application/x-www-form-urlencoded`` when there is no file), else ``application/json`` for routes with a
body model, else none (any body is refused). ``text/xml`` is taken wherever ``application/xml`` is (the
two are the same type, RFC 7303). A request without a body (no ``Content-Length`` above 0 and no
``Transfer-Encoding``) is never refused here; a body without ``Content-Type`` is.

Without this, a route that reads its body whatever the type (the XML route did) can be reached by a
cross-origin "simple" request (``text/plain``, no CORS preflight) riding on the operator's cookie.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

from fastapi import params
from fastapi.responses import JSONResponse
from fastapi.routing import APIRoute
from starlette.routing import BaseRoute, Match, Route
from starlette.types import ASGIApp, Receive, Scope, Send

__all__ = ["MediaTypeGuard", "accepted_media_types", "media_type"]

log = logging.getLogger(__name__)

JSON = "application/json"
FORM = "multipart/form-data"
URLENCODED = "application/x-www-form-urlencoded"
_ALIASES = {"application/xml": ("text/xml",)}


def media_type(content_type: str) -> str:
    """The media type of a ``Content-Type`` value: ``type/subtype`` in lower case, parameters dropped."""
    return content_type.split(";", 1)[0].strip().lower()


def accepted_media_types(route: BaseRoute) -> tuple[str, ...]:
    """The request-body media types ``route`` takes (empty: it takes no body). O(parameters)."""
    if not isinstance(route, APIRoute):
        return ()
    declared = ((route.openapi_extra or {}).get("requestBody") or {}).get("content") or {}
    if declared:
        types = [media_type(t) for t in declared]
    elif route.body_field is None:
        return ()
    else:
        infos = [f.field_info for f in route.dependant.body_params]
        if any(isinstance(i, params.File) for i in infos):
            types = [FORM]
        elif any(isinstance(i, params.Form) for i in infos):
            types = [FORM, URLENCODED]
        else:
            types = [JSON]
    out: list[str] = []
    for t in types:
        out += [t, *_ALIASES.get(t, ())]
    return tuple(dict.fromkeys(out))


def _has_body(headers: dict[bytes, bytes]) -> bool:
    if b"transfer-encoding" in headers:
        return True
    length = headers.get(b"content-length", b"").strip()
    return bool(length) and length != b"0"


class MediaTypeGuard:
    """ASGI middleware: 415 naming the expected types when a body's ``Content-Type`` is not one its route
    takes. ``routes`` is the application's route list (read at each request, so routes added later are
    covered); the route is found as the router finds it (first full match), which costs O(routes) per
    request with a body; a request no route matches is left to the router (404 or 405)."""

    def __init__(self, app: ASGIApp, routes: Sequence[BaseRoute]) -> None:
        self.app = app
        self.routes = routes
        self._accepted: dict[int, tuple[str, ...]] = {}

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http":
            headers: dict[bytes, bytes] = {}
            for name, value in scope["headers"]:
                headers.setdefault(name.lower(), value)
            if _has_body(headers):
                problem = self.problem(scope, headers)
                if problem is not None:
                    detail, expected = problem
                    body = JSONResponse(
                        {"error": "unsupported_media_type", "detail": detail, "expected": list(expected)},
                        status_code=415,
                    )
                    await send({"type": "http.response.start", "status": 415, "headers": body.raw_headers})
                    await send({"type": "http.response.body", "body": body.body})
                    return
        await self.app(scope, receive, send)

    def problem(self, scope: Scope, headers: dict[bytes, bytes]) -> tuple[str, tuple[str, ...]] | None:
        route = next((r for r in self.routes if r.matches(scope)[0] == Match.FULL), None)
        if route is None or not isinstance(route, Route):
            return None  # unknown path or wrong method (the router answers), or a mount (static files)
        key = id(route)
        if key not in self._accepted:
            self._accepted[key] = accepted_media_types(route)
        expected = self._accepted[key]
        raw = headers.get(b"content-type")
        given = media_type(raw.decode("latin-1")) if raw is not None else None
        if given is not None and given in expected:
            return None
        what = f"{scope.get('method')} {getattr(route, 'path', scope.get('path'))}"
        sent = f"Content-Type {raw.decode('latin-1')[:80]!r}" if raw is not None else "no Content-Type"
        if not expected:
            return f"{what} takes no request body (got one with {sent})", expected
        return f"{sent}: {what} takes {' or '.join(expected)}", expected
