"""The Foxglove server's listener of the bridge: when a client subscribes to a topic it is sent the topic's
newest message at once, as a latched topic would (a map that changes rarely is seen without waiting for
the next version). Imports foxglove-sdk: load it after :func:`shared.foxbridge.bridge.require_foxglove`."""

from __future__ import annotations

from collections.abc import Callable

from foxglove.websocket import ChannelView, Client, ServerListener

__all__ = ["LatchingListener"]


class LatchingListener(ServerListener):
    """Calls ``republish(topic)`` on the server's thread for each new subscription (the SDK records the
    subscription before it calls, so the message reaches the new subscriber)."""

    def __init__(self, republish: Callable[[str], None]) -> None:
        self._republish = republish

    def on_subscribe(self, client: Client, channel: ChannelView) -> None:
        self._republish(channel.topic)
