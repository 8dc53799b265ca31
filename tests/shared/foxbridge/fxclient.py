"""A Foxglove WebSocket client for the bridge's tests, speaking the protocol as Foxglove does
(subprotocol ``foxglove.sdk.v1``, which foxglove-sdk's server requires; the operations are those of
the Foxglove WebSocket protocol): it reads the server's
``serverInfo`` and ``advertise`` operations, subscribes to every advertised channel, and decodes each
binary message-data frame (opcode 1, subscription id uint32, receive time uint64, payload) with the
channel's advertised protobuf schema."""

from __future__ import annotations

import asyncio
import base64
import json
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from websockets.asyncio.client import ClientConnection, connect

from tests.shared.foxbridge.fxwire import decode_with

__all__ = ["SUBPROTOCOL", "Channel", "FoxClient"]

SUBPROTOCOL = "foxglove.sdk.v1"
MESSAGE_DATA = 0x01
_HEADER = struct.Struct("<BIQ")


@dataclass(frozen=True)
class Channel:
    id: int
    topic: str
    encoding: str
    schema_name: str
    schema: bytes


class FoxClient:
    """One connection; :meth:`wait_for` returns the first decoded message of a topic that passes a check."""

    def __init__(self, ws: ClientConnection) -> None:
        self.ws = ws
        self.channels: dict[int, Channel] = {}
        self.subscriptions: dict[int, Channel] = {}
        self.server_info: dict[str, Any] = {}
        self.latest: dict[str, Any] = {}  # topic -> the newest decoded message

    @classmethod
    async def open(cls, url: str) -> FoxClient:
        ws = await connect(url, subprotocols=[SUBPROTOCOL])  # type: ignore[list-item]
        assert ws.subprotocol == SUBPROTOCOL
        return cls(ws)

    async def close(self) -> None:
        await self.ws.close()

    def _control(self, text: str) -> None:
        op = json.loads(text)
        if op["op"] == "serverInfo":
            self.server_info = op
        elif op["op"] == "advertise":
            for c in op["channels"]:
                assert c["schemaEncoding"] == "protobuf", c
                raw = base64.b64decode(c["schema"])
                self.channels[c["id"]] = Channel(c["id"], c["topic"], c["encoding"], c["schemaName"], raw)

    async def subscribe_all(self, topics: set[str], timeout_s: float = 30.0) -> None:
        """Wait until ``topics`` are advertised, then subscribe to them."""
        deadline = time.monotonic() + timeout_s
        while not topics <= {c.topic for c in self.channels.values()}:
            left = deadline - time.monotonic()
            assert left > 0, f"advertised only {sorted(c.topic for c in self.channels.values())}"
            frame = await asyncio.wait_for(self.ws.recv(), left)
            if isinstance(frame, str):
                self._control(frame)
        subs = []
        for n, channel in enumerate(c for c in self.channels.values() if c.topic in topics):
            self.subscriptions[100 + n] = channel
            subs.append({"id": 100 + n, "channelId": channel.id})
        await self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    async def wait_for(self, topic: str, check: Callable[[Any], bool], timeout_s: float = 30.0) -> Any:
        """The newest message on ``topic`` once ``check`` holds for it (each topic's messages arrive in
        order; those of every topic are kept as they come); fails at the deadline naming the last one."""
        deadline = time.monotonic() + timeout_s
        while not (topic in self.latest and check(self.latest[topic])):
            left = deadline - time.monotonic()
            assert left > 0, f"no message on {topic} passed the check; the last was {self.latest.get(topic)}"
            frame = await asyncio.wait_for(self.ws.recv(), left)
            if isinstance(frame, str):
                self._control(frame)
                continue
            opcode, sub_id, _recv_ns = _HEADER.unpack_from(frame)
            if opcode != MESSAGE_DATA:
                continue
            channel = self.subscriptions[sub_id]
            payload = frame[_HEADER.size :]
            self.latest[channel.topic] = decode_with(channel.schema_name, channel.schema, payload)
        return self.latest[topic]
