"""The bridge itself: a Foxglove WebSocket server (foxglove-sdk) whose channels carry a robot's map as
the linemap server streams it. Topics (frame ``map``, metres):

- ``/linemap/walls``: ``foxglove.SceneUpdate``, the walls as one LINE_LIST;
- ``/linemap/trajectory``: ``foxglove.SceneUpdate``, the kept trajectory as a LINE_STRIP;
- ``/linemap/centroids``: ``foxglove.SceneUpdate``, a sphere per cluster centroid (``centroids=True``);
- ``/linemap/pose``: ``foxglove.PoseInFrame``, the robot's pose;
- ``/linemap/tf``: ``foxglove.FrameTransform``, ``map`` -> ``base_link``.

Every version publishes all of them (each replaces the last: the entities keep their ids). A Foxglove
client that subscribes later gets the newest message of the topic at once, as a latched topic would.
"""

from __future__ import annotations

import importlib
import logging
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from shared.foxbridge.errors import BridgeError, ExtraMissingError, OutOfStepError
from shared.foxbridge.mapstate import TRAJECTORY_KEEP, MapState, apply_event
from shared.foxbridge.sse import MapEventStream

if TYPE_CHECKING:
    from foxglove.websocket import WebSocketServer

__all__ = ["TOPICS", "FoxgloveBridge", "require_foxglove"]

logger = logging.getLogger(__name__)

#: Topic of each published message (MapMessages field -> topic).
TOPICS: dict[str, str] = {
    "walls": "/linemap/walls",
    "trajectory": "/linemap/trajectory",
    "centroids": "/linemap/centroids",
    "pose": "/linemap/pose",
    "transform": "/linemap/tf",
}

INSTALL_HINT = "pip install 'linemap[foxglove]'"


def require_foxglove() -> None:
    """Raise :class:`ExtraMissingError` (with the command that installs it) when foxglove-sdk is absent."""
    try:
        importlib.import_module("foxglove")
    except ImportError:
        raise ExtraMissingError(
            f"the Foxglove bridge needs the optional foxglove-sdk package: {INSTALL_HINT}"
        ) from None


class FoxgloveBridge:
    """A Foxglove WebSocket server on ``host:port`` (port 0: any free one) publishing a map's messages.

    Thread-safe: the stream's thread publishes; the server's thread republishes the newest message of a
    topic when a client subscribes to it (:class:`~shared.foxbridge.listener.LatchingListener`). Use as a
    context manager (the server stops on exit).
    """

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 8765,
        *,
        centroids: bool = True,
        name: str = "linemap",
        clock: Callable[[], float] = time.time,
    ) -> None:
        require_foxglove()
        import foxglove
        from foxglove.channels import FrameTransformChannel, PoseInFrameChannel, SceneUpdateChannel

        from shared.foxbridge.listener import LatchingListener

        self._clock = clock
        self._lock = threading.Lock()
        self._latest: dict[str, Any] = {}  # topic -> newest message
        self.state: MapState | None = None
        self.published = 0  # versions published
        self._context = foxglove.Context()
        ctx = self._context
        self._channels: dict[str, Any] = {
            TOPICS["walls"]: SceneUpdateChannel(TOPICS["walls"], context=ctx),
            TOPICS["trajectory"]: SceneUpdateChannel(TOPICS["trajectory"], context=ctx),
            TOPICS["pose"]: PoseInFrameChannel(TOPICS["pose"], context=ctx),
            TOPICS["transform"]: FrameTransformChannel(TOPICS["transform"], context=ctx),
        }
        if centroids:
            self._channels[TOPICS["centroids"]] = SceneUpdateChannel(TOPICS["centroids"], context=ctx)
        try:
            listener = LatchingListener(self._republish)
            self.server: WebSocketServer = foxglove.start_server(
                name=name, host=host, port=port, context=ctx, server_listener=listener
            )
        except Exception as exc:  # the SDK raises its own types for a busy port or a bad address
            raise BridgeError(f"cannot start the Foxglove WebSocket server on {host}:{port}: {exc}") from None

    @property
    def port(self) -> int:
        """The port the Foxglove server listens on."""
        return self.server.port

    def __enter__(self) -> FoxgloveBridge:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self.server.stop()

    def publish(self, state: MapState) -> None:
        """Publish every message of ``state`` (:func:`shared.foxbridge.convert.map_messages`)."""
        from shared.foxbridge.convert import map_messages

        messages = map_messages(state, self._clock())
        out: list[tuple[Any, Any]] = []
        with self._lock:
            self.state = state
            for key, topic in TOPICS.items():
                message, channel = getattr(messages, key), self._channels.get(topic)
                if message is not None and channel is not None:
                    self._latest[topic] = message
                    out.append((channel, message))
            self.published += 1
        for channel, message in out:  # logged outside the lock: the SDK's own locks are never held with it
            channel.log(message)

    def _republish(self, topic: str) -> None:
        """Send ``topic``'s newest message again (a client just subscribed to it)."""
        with self._lock:
            message, channel = self._latest.get(topic), self._channels.get(topic)
        if message is not None and channel is not None:
            channel.log(message)

    def follow(self, stream: MapEventStream, stop: threading.Event, keep: int = TRAJECTORY_KEEP) -> None:
        """Keep the map from ``stream``'s events and publish each version, until ``stop`` is set (or the
        stream raises: a refused token, an unknown robot). A delta that does not continue the held
        version makes the stream resynchronise (a snapshot follows)."""
        state = self.state
        for event in stream.events(stop):
            try:
                state = apply_event(state, event.kind, event.data, keep)
            except OutOfStepError as exc:
                logger.info("%s; asking for the whole map", exc)
                stream.resync()
                continue
            self.publish(state)
            logger.debug("published map version %d (%d walls)", state.version, len(state.segments))
