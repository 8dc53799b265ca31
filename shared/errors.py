"""The error hierarchy of the ``shared`` package.

Every error raised on purpose by ``shared`` derives from :class:`LinemapError`, so a caller (the CLI, the
robot agent, the server) can catch one type at its boundary and show the message, never a traceback.
Messages name the bad value and what was expected.
"""

from __future__ import annotations

__all__ = [
    "DuplicateKernelError",
    "InvalidInputError",
    "KernelParameterError",
    "KernelSourceError",
    "LinemapError",
    "StateError",
    "UnknownKernelError",
]


class LinemapError(Exception):
    """Root of every error that linemap raises on purpose."""


class InvalidInputError(LinemapError, ValueError):
    """An array or record handed to a type or kernel has the wrong shape, dtype or values."""


class KernelParameterError(LinemapError, ValueError):
    """A kernel parameter is unknown, of the wrong type, or out of its allowed range.

    ``problems`` lists one ``(parameter, message)`` pair per bad parameter.
    """

    def __init__(self, kernel: str, problems: list[tuple[str, str]]) -> None:
        self.kernel = kernel
        self.problems = problems
        text = "; ".join(f"{kernel}.{name}: {msg}" for name, msg in problems)
        super().__init__(f"invalid parameters for kernel '{kernel}': {text}")


class UnknownKernelError(LinemapError, LookupError):
    """No kernel is registered under the requested stage, name or version."""


class DuplicateKernelError(LinemapError):
    """A kernel with the same stage, name and version is already registered."""


class KernelSourceError(LinemapError, ValueError):
    """A kernel module's source is refused before any of it runs (not UTF-8, not Python, nested too
    deeply, too complex to parse within the limits). ``reason`` says what and what is expected; ``line``
    is the source line when known."""

    def __init__(self, reason: str, line: int | None = None) -> None:
        self.reason = reason
        self.line = line
        super().__init__(reason)


class StateError(LinemapError, ValueError):
    """A stored mapper state is refused: not the stored form, another format version, or a description of
    something other than the mapper restoring it (shared.pipeline.state)."""
