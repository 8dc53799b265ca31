"""The error of the control-message module (:mod:`shared.control`, SPEC §6).

A rejected message raises :class:`ControlMessageError`; its text names the element (with its 1-based line in
the document when known) and the reason, e.g. ``line 9 <minpts>: 'fifteen' is not an integer``. The robot
keeps running on the settings it had and reports ``reason`` in its acknowledgement (SPEC §9).
"""

from __future__ import annotations

from shared.errors import LinemapError

__all__ = ["ControlMessageError"]


class ControlMessageError(LinemapError, ValueError):
    """A control message is malformed, unsafe, outside the vocabulary, or sets an invalid configuration.

    ``element`` is the element's display name (``"<minpts>"``) or ``None``, ``line`` its 1-based line in the
    document or ``None`` (e.g. for a message built in code), ``reason`` the explanation alone.
    """

    def __init__(self, reason: str, *, element: str | None = None, line: int | None = None) -> None:
        self.reason = reason
        self.element = element
        self.line = line
        where = " ".join(part for part in (f"line {line}" if line else "", element or "") if part)
        super().__init__(f"{where}: {reason}" if where else f"control message: {reason}")

    def __reduce__(self) -> tuple[object, ...]:
        return (_rebuild, (self.reason, self.element, self.line))


def _rebuild(reason: str, element: str | None, line: int | None) -> ControlMessageError:
    return ControlMessageError(reason, element=element, line=line)
