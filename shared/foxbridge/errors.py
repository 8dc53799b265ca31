"""The errors of the Foxglove bridge, under one root (:class:`BridgeError`, a :class:`LinemapError`), so
``linemap foxglove`` shows each as one line, never a traceback."""

from __future__ import annotations

from shared.errors import LinemapError

__all__ = [
    "BridgeError",
    "ExtraMissingError",
    "MapEventError",
    "OutOfStepError",
    "RobotUnknownError",
    "StreamRefusedError",
]


class BridgeError(LinemapError):
    """Root of the bridge's errors."""


class ExtraMissingError(BridgeError):
    """The optional ``foxglove-sdk`` package is not installed."""


class StreamRefusedError(BridgeError):
    """The linemap server refused the credential (401) or its access to the robot (403)."""


class RobotUnknownError(BridgeError):
    """The linemap server has no robot of that id (404)."""


class MapEventError(BridgeError, ValueError):
    """A map event of the stream is not what the server's stream sends (the field and what was expected)."""


class OutOfStepError(BridgeError):
    """A delta does not continue the version the bridge holds: the stream must resynchronise (snapshot)."""
