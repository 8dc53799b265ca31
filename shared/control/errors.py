"""The error of the control-message module (:mod:`shared.control`, docs/design.md §6).

A rejected message raises :class:`ControlMessageError`; its text names the element (with its 1-based line in
the document when known) and the reason, e.g. ``line 9 <minpts>: 'fifteen' is not an integer``. The robot
keeps running on the settings it had and reports ``reason`` in its acknowledgement (docs/design.md §9). A
reason longer than :data:`MAX_REASON_CHARS` (a value quoted from a 64 KiB message) is cut in the middle, so an
error never echoes a hostile document back into logs and acknowledgements.
"""

from __future__ import annotations

from shared.errors import LinemapError

__all__ = ["MAX_REASON_CHARS", "ControlMessageError"]

#: Longest ``reason`` kept (characters); longer ones keep their start and end.
MAX_REASON_CHARS = 300


class ControlMessageError(LinemapError, ValueError):
    """A control message is malformed, unsafe, outside the vocabulary, or sets an invalid configuration.

    ``element`` is the element's display name (``"<minpts>"``) or ``None``, ``line`` its 1-based line in the
    document or ``None`` (e.g. for a message built in code), ``reason`` the explanation alone.
    """

    def __init__(self, reason: str, *, element: str | None = None, line: int | None = None) -> None:
        reason = _clip(reason)
        self.reason = reason
        self.element = element
        self.line = line
        where = " ".join(part for part in (f"line {line}" if line else "", element or "") if part)
        super().__init__(f"{where}: {reason}" if where else f"control message: {reason}")

    def __reduce__(self) -> tuple[object, ...]:
        return (_rebuild, (self.reason, self.element, self.line))


def _clip(reason: str) -> str:
    """``reason`` cut to at most :data:`MAX_REASON_CHARS` characters, its start and end kept. O(len)."""
    if len(reason) <= MAX_REASON_CHARS:
        return reason
    head, tail = reason[:170], reason[-100:]
    return f"{head}...({len(reason) - 270} characters cut)...{tail}"


def _rebuild(reason: str, element: str | None, line: int | None) -> ControlMessageError:
    return ControlMessageError(reason, element=element, line=line)
