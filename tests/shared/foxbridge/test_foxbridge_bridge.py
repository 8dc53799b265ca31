"""The bridge object (shared/foxbridge/bridge.py) in-process: a delta out of step makes it ask the stream
for the whole map and go on from the snapshot that follows; a port in use is a clear error. (Through a
real server and a real Foxglove client: test_foxglove_bridge_live.py.)"""

from __future__ import annotations

import socket
import threading
from collections.abc import Iterator
from typing import Any

import pytest

from shared.foxbridge.bridge import FoxgloveBridge
from shared.foxbridge.errors import BridgeError
from shared.foxbridge.sse import MapEvent, MapEventStream


def _snapshot(version: int, walls: int) -> dict[str, Any]:
    segments = [[i, float(i), 0.0, float(i), 1.0] for i in range(walls)]
    return {"robot_id": 1, "version": version, "stamp_s": 0.0, "segments": segments, "pose": [1.0, 0.0, 0.0]}


class _Events(MapEventStream):
    """A stream that replays ``events`` and records the resynchronisations asked for."""

    def __init__(self, events: list[MapEvent]) -> None:
        super().__init__("http://unused", 1, None)
        self.replay = events
        self.resyncs: list[int | None] = []

    def events(self, stop: threading.Event) -> Iterator[MapEvent]:
        yield from self.replay

    def resync(self) -> None:
        self.resyncs.append(self.last_id)
        super().resync()


def test_an_out_of_step_delta_asks_for_the_whole_map_and_the_snapshot_is_published() -> None:
    stream = _Events(
        [
            MapEvent("snapshot", 1, _snapshot(1, 2)),
            MapEvent("delta", 6, {"version": 6, "base_version": 5, "segments": [[9, 0.0, 0.0, 1.0, 1.0]]}),
            MapEvent("snapshot", 7, _snapshot(7, 4)),
            MapEvent("delta", 8, {"version": 8, "base_version": 7, "removed": [0], "pose": [2.0, 1.0, 0.5]}),
        ]
    )
    with FoxgloveBridge(port=0) as bridge:
        bridge.follow(stream, threading.Event())
        assert len(stream.resyncs) == 1
        assert bridge.published == 3  # versions 1, 7 and 8; never the delta out of step
        assert bridge.state is not None and bridge.state.version == 8
        assert sorted(bridge.state.segments) == [1, 2, 3] and bridge.state.pose == (2.0, 1.0, 0.5)


def test_a_port_in_use_is_named() -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        named = f"cannot start the Foxglove WebSocket server on 127.0.0.1:{port}: .*in use"
        with pytest.raises(BridgeError, match=named):
            FoxgloveBridge(port=port)
