"""The failed-authentication limit at the HTTP boundary: which requests it refuses, and when.

:class:`server.limiter.AuthLimiter` keeps the rules and the counts; this module applies them to requests.
:class:`AuthScreen` decides, from a request's scope alone, whether it is an invalid credential from a
source that is blocked now (such a request is refused with 429 before any of its work is done).
:class:`AuthFailureLimit` (ASGI middleware, outermost) screens every API request as it arrives and counts
each 401 the application answers. The long-polls' door (:mod:`server.admission`) screens a poll again
when the poll is let in: polls that arrived before their source was blocked, and waited at the door
meanwhile, are refused there instead of each doing its route's work (a flood of long-polls with a bad
token from one address no longer keeps the robots' own polls waiting behind it).
"""

from __future__ import annotations

import asyncio
import functools
import logging
from collections.abc import Awaitable, Callable, Sequence
from typing import Literal

from starlette.requests import cookie_parser
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from server.limiter import AuthLimiter, IPNetwork, client_source

__all__ = ["AuthFailureLimit", "AuthScreen", "Refusal"]

log = logging.getLogger(__name__)

#: Sends a refusal (429 with ``Retry-After``, after the limiter's delay) to one request.
Refusal = Callable[[Send], Awaitable[None]]


class AuthScreen:
    """Which API requests (``api_prefix``) carry a credential, where from, and whether the limit refuses
    them now: a bearer token (``Authorization``), the ``cookie`` session cookie, or a login (``POST
    <api_prefix>/session``) from a source (:func:`server.limiter.client_source` with the trusted
    ``networks`` and ``header``) that this process knows is blocked, whose credential ``authenticate``
    finds invalid. A valid credential is never refused. O(headers) and one credential lookup (cached) when
    the source is blocked."""

    def __init__(
        self,
        limiter: AuthLimiter,
        authenticate: Callable[[str], Awaitable[bool]],
        cookie: str,
        api_prefix: str,
        networks: Sequence[IPNetwork] = (),
        header: Literal["x-forwarded-for", "forwarded"] = "x-forwarded-for",
    ) -> None:
        self.limiter = limiter
        self.authenticate = authenticate
        self.cookie, self.api_prefix = cookie, api_prefix
        self.networks, self.header = list(networks), header

    def credential(self, scope: Scope) -> tuple[bool, str | None]:
        """(does the request carry a credential, the bearer token or session id when readable here)."""
        if scope["type"] != "http":
            return False, None
        path: str = scope.get("path", "")
        if not path.startswith(self.api_prefix + "/"):
            return False, None
        presented = scope.get("method") == "POST" and path == self.api_prefix + "/session"
        credential: str | None = None
        for name, value in scope["headers"]:
            if name == b"authorization":
                scheme, _, token = value.decode("latin-1").partition(" ")
                return True, token.strip() if scheme.lower() == "bearer" else ""
            if name == b"cookie":
                sid = cookie_parser(value.decode("latin-1")).get(self.cookie)
                if sid is not None:
                    presented, credential = True, sid
        return presented, credential

    def source(self, scope: Scope) -> str:
        """The source the request counts against."""
        return client_source(scope, self.networks, self.header)

    async def refusal(self, scope: Scope) -> Refusal | None:
        """The refusal to send instead of serving the request, or ``None`` to serve it."""
        presented, credential = self.credential(scope)
        if not presented:
            return None
        return await self.refusal_of(self.source(scope), credential)

    async def refusal_of(self, source: str, credential: str | None) -> Refusal | None:
        """:meth:`refusal` for a request from ``source`` presenting ``credential`` (None: one not readable
        here, such as a login's password, which only the route can judge)."""
        if credential is None or not self.limiter.enabled:
            return None
        left = self.limiter.blocked_for(source)
        if left is None or await self.authenticate(credential):
            return None
        return functools.partial(self.limiter.refuse, source=source, left_s=left)


class AuthFailureLimit:
    """ASGI middleware applying the limit to every API request that carries a credential.

    A request :class:`AuthScreen` refuses gets its 429 before the application runs (no body read, no route
    work). Otherwise a 401 from the application counts one failure of the request's source; when the
    source was already over the limit, that 401 is replaced by the 429.
    """

    def __init__(self, app: ASGIApp, screen: AuthScreen) -> None:
        self.app, self.screen, self.limiter = app, screen, screen.limiter

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        presented, credential = self.screen.credential(scope)
        if not presented or not self.limiter.enabled:
            await self.app(scope, receive, send)
            return
        source = self.screen.source(scope)
        refusal = await self.screen.refusal_of(source, credential)
        if refusal is not None:
            await refusal(send)
            return
        replaced = False

        async def watching_send(message: Message) -> None:
            nonlocal replaced
            if replaced:
                return  # the 401's body: a 429 went out instead
            if message["type"] == "http.response.start" and message["status"] == 401:
                try:
                    wait = await asyncio.to_thread(self.limiter.failed, source)
                except Exception:  # the count is lost, the 401 still goes out (never a 500 for it)
                    log.exception("could not count a failed authentication of %s", source)
                    wait = None
                if wait is not None:
                    replaced = True
                    await self.limiter.refuse(send, source, wait)
                    return
            await send(message)

        await self.app(scope, receive, watching_send)
