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

from fastapi import Request, params
from fastapi.routing import APIRoute
from starlette.routing import BaseRoute

from server.errors import UnsupportedMediaTypeError

__all__ = ["accepted_media_types", "media_type", "require_media_type"]

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


def _has_body(request: Request) -> bool:
    if "transfer-encoding" in request.headers:
        return True
    length = request.headers.get("content-length", "").strip()
    return bool(length) and length != "0"


async def require_media_type(request: Request) -> None:
    """Dependency of every route (set on the application): :class:`UnsupportedMediaTypeError` (415) naming
    the expected types when the request has a body whose ``Content-Type`` the route does not take. Runs
    before the route's own dependencies (authentication) and its handler; O(1) after the route's first
    request (its accepted types are cached)."""
    if not _has_body(request):
        return
    route = request.scope.get("route")
    if route is None:
        return
    key = id(route)
    expected = _ACCEPTED.get(key)
    if expected is None:
        expected = _ACCEPTED[key] = accepted_media_types(route)
    raw = request.headers.get("content-type")
    if raw is not None and media_type(raw) in expected:
        return
    what = f"{request.method} {getattr(route, 'path', request.url.path)}"
    sent = f"Content-Type {raw[:80]!r}" if raw is not None else "no Content-Type"
    if not expected:
        raise UnsupportedMediaTypeError(f"{what} takes no request body (got one with {sent})", expected=[])
    raise UnsupportedMediaTypeError(f"{sent}: {what} takes {' or '.join(expected)}", expected=list(expected))


#: Accepted media types by ``id(route)`` (routes live as long as the application).
_ACCEPTED: dict[int, tuple[str, ...]] = {}
