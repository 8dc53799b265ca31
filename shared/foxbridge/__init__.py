"""A live bridge from a linemap server to Foxglove (the optional ``foxglove`` extra, foxglove-sdk): a
robot's map from the server's SSE stream (:mod:`.sse`), kept as frozen versions (:mod:`.mapstate`),
converted to Foxglove messages (:mod:`.convert`) and published on a Foxglove WebSocket server
(:mod:`.bridge`). Only :mod:`.convert`, :mod:`.listener` and the bridge's start import foxglove-sdk; without
it the bridge raises :class:`ExtraMissingError` naming the install command."""

from __future__ import annotations

from shared.foxbridge.errors import (
    BridgeError,
    ExtraMissingError,
    MapEventError,
    OutOfStepError,
    RobotUnknownError,
    StreamRefusedError,
)
from shared.foxbridge.mapstate import MapState, apply_delta, apply_event, from_snapshot
from shared.foxbridge.sse import Backoff, MapEvent, MapEventStream, SseParser

__all__ = [
    "Backoff",
    "BridgeError",
    "ExtraMissingError",
    "MapEvent",
    "MapEventError",
    "MapEventStream",
    "MapState",
    "OutOfStepError",
    "RobotUnknownError",
    "SseParser",
    "StreamRefusedError",
    "apply_delta",
    "apply_event",
    "from_snapshot",
]
