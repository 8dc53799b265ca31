"""The server's error hierarchy: every error raised on purpose derives from :class:`ServerError`.

Each carries the HTTP status and a short machine-readable ``code``; :mod:`server.app` turns them into JSON
``{"error": code, "detail": message, ...extra}`` responses, so a client never sees a traceback.
"""

from __future__ import annotations

from typing import Any

from shared.errors import LinemapError

__all__ = [
    "AgentSupersededError",
    "AuthError",
    "ConflictError",
    "ForbiddenError",
    "GoneError",
    "InvalidRequestError",
    "MapSessionEndedError",
    "MapSessionMismatchError",
    "NotFoundError",
    "RateLimitedError",
    "ServerError",
    "TooLargeError",
    "UnavailableError",
    "UnsupportedMediaTypeError",
]


class ServerError(LinemapError):
    """Root of the server's errors: ``status`` is the HTTP status, ``extra`` goes into the JSON body."""

    status = 500
    code = "server_error"

    def __init__(self, detail: str, **extra: Any) -> None:
        super().__init__(detail)
        self.detail = detail
        self.extra = extra


class InvalidRequestError(ServerError):
    """The request is well-formed HTTP but its content is wrong (bad XML, bad signature, bad field)."""

    status = 422
    code = "invalid"


class AuthError(ServerError):
    """No credential, or one the server does not know (401)."""

    status = 401
    code = "unauthenticated"


class ForbiddenError(ServerError):
    """A valid credential that does not reach this resource (403)."""

    status = 403
    code = "forbidden"


class NotFoundError(ServerError):
    status = 404
    code = "not_found"


class ConflictError(ServerError):
    """The request contradicts stored state (immutable kernel version, stale map base version)."""

    status = 409
    code = "conflict"


class MapSessionMismatchError(ConflictError):
    """A delta of a mapping session that is not the server's current one for the robot: send a snapshot."""

    code = "map_session_mismatch"


class MapSessionEndedError(ConflictError):
    """An upload of a mapping session the server ended (another session replaced it): the robot must start
    a new session, never add to the ended map or bring it back."""

    code = "map_session_ended"


class AgentSupersededError(ConflictError):
    """A request from an agent process after another agent with the robot's token took over."""

    code = "agent_superseded"


class GoneError(ServerError):
    """The resource existed and is no longer kept (a deleted kernel version, a map version older than the
    map history holds)."""

    status = 410
    code = "gone"


class TooLargeError(ServerError):
    status = 413
    code = "too_large"


class UnsupportedMediaTypeError(ServerError):
    """A request body of a type the route does not take (415; ``expected`` lists the types it takes)."""

    status = 415
    code = "unsupported_media_type"


class UnavailableError(ServerError):
    """A dependency of the server (its database) does not answer (503)."""

    status = 503
    code = "unavailable"


class StorageFullError(ServerError):
    """The database has no space left for the write (507); nothing of the request was stored."""

    status = 507
    code = "storage_full"


class RateLimitedError(ServerError):
    """Over a quota (429); ``retry_after_s`` becomes ``Retry-After`` (whole seconds, rounded up)."""

    status = 429
    code = "too_many_requests"

    def __init__(self, detail: str, retry_after_s: float, **extra: Any) -> None:
        super().__init__(detail, **extra)
        self.retry_after_s = retry_after_s
