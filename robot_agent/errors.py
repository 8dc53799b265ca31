"""The robot agent's errors: everything it raises on purpose derives from :class:`AgentError`.

:class:`AgentError` is a :class:`~shared.errors.LinemapError`, so the CLI shows the message, never a
traceback. Messages say what was refused and why, in words an operator can act on.
"""

from __future__ import annotations

from typing import Any

from shared.errors import LinemapError

__all__ = ["AgentError", "KernelRejected", "LinkError", "SourceError", "UnexpectedAnswerError"]


class AgentError(LinemapError):
    """Root of the robot agent's errors."""


class KernelRejected(AgentError):  # noqa: N818  (named for the outcome it reports)
    """A downloaded kernel failed a check (sha256, signature, import, conformance, dry run).

    ``reason`` is the human-readable why, also the exception's message; it is what the server is told.
    """

    def __init__(self, reason: str) -> None:
        self.reason = reason
        super().__init__(reason)


class LinkError(AgentError):
    """The server could not be reached or answered in a way the agent cannot use: ``status`` is the HTTP
    status if there was one, ``retry_after_s`` the server's ``Retry-After``."""

    def __init__(
        self, message: str, *, status: int | None = None, retry_after_s: float | None = None
    ) -> None:
        super().__init__(message)
        self.status = status
        self.retry_after_s = retry_after_s


class UnexpectedAnswerError(LinkError):
    """Something answered that is not the server's API: a redirect, a wrong content type (a login
    portal's HTML page), a body that is not JSON or JSON of the wrong shape. A link fault like no answer at
    all: retried after a backoff, never taken as the server's word (a kernel download is fetched again, not
    rejected)."""

    def __init__(self, where: str, resp: Any, expected: str, *, retry_after_s: float | None = None) -> None:
        ctype = resp.headers.get("content-type", "") or "no content type"
        text = resp.content[:80].decode("utf-8", "replace").replace("\n", " ")
        super().__init__(
            f"{where}: unexpected answer (HTTP {resp.status_code}, {ctype}: {text!r}); expected {expected}",
            status=None,
            retry_after_s=retry_after_s,
        )
        self.http_status = resp.status_code


class SupersededError(AgentError):
    """Another agent with this robot's token took over (the server answered 409 ``agent_superseded``), or
    another agent holds this Robot DB: this agent must stop, not retry (docs/reliability/identity.md)."""


class SourceError(AgentError):
    """The scan source (simulator, log file, serial scanner) cannot be opened or read."""
