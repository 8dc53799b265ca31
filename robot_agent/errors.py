"""The robot agent's errors: everything it raises on purpose derives from :class:`AgentError`.

:class:`AgentError` is a :class:`~shared.errors.LinemapError`, so the CLI shows the message, never a
traceback. Messages say what was refused and why, in words an operator can act on.
"""

from __future__ import annotations

from shared.errors import LinemapError

__all__ = ["AgentError", "KernelRejected", "LinkError", "SourceError"]


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


class SourceError(AgentError):
    """The scan source (simulator, log file, serial scanner) cannot be opened or read."""
