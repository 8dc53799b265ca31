"""Errors of the sensor drivers (:mod:`robot_agent.sensors`): all derive from :class:`SensorError`.

:class:`SensorError` is an :class:`~robot_agent.errors.AgentError` (so a
:class:`~shared.errors.LinemapError`): the CLI shows the message, never a traceback. Messages name the
device or the command, the bad value and what was expected.
"""

from __future__ import annotations

from robot_agent.errors import AgentError

__all__ = [
    "ScipChecksumError",
    "ScipError",
    "ScipStatusError",
    "SensorDisconnectedError",
    "SensorError",
    "SensorTimeoutError",
]


class SensorError(AgentError):
    """Root of the sensor drivers' errors (laser scanner, wheel encoders)."""


class ScipError(SensorError, ValueError):
    """A reply breaks the SCIP 2.0 format: framing, encoding, length or an unexpected echo."""


class ScipChecksumError(ScipError):
    """A line of a SCIP 2.0 reply does not match its checksum character."""


class ScipStatusError(SensorError):
    """The scanner answered a command with a status other than the expected one.

    ``command`` is the command line sent (e.g. ``'MD0044072501000'``), ``status`` the two-character code,
    ``meaning`` the protocol's explanation of it.
    """

    def __init__(self, command: str, status: str, meaning: str) -> None:
        self.command = command
        self.status = status
        self.meaning = meaning
        super().__init__(f"URG-04LX refused {command!r}: status {status!r} ({meaning})")

    def __reduce__(self) -> tuple[type[ScipStatusError], tuple[str, str, str]]:
        return (type(self), (self.command, self.status, self.meaning))


class SensorTimeoutError(SensorError):
    """No complete reply or scan frame arrived within the read timeout."""


class SensorDisconnectedError(SensorError):
    """The serial device cannot be opened, vanished (unplugged), or did not come back in time."""
