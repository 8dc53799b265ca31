"""The Foxglove bridge's cost (`linemap foxglove`, docs/foxglove.md): figures, not pass/fail.

- conversion: per map version, building and encoding every message (walls, trajectory, centroids, pose,
  transform) for maps of ``--walls`` walls (median of ``--runs``), and the walls message's size;
- latency: a real `linemap server` (uvicorn in this process, SQLite in a temporary directory), a robot
  uploading a snapshot then ``--versions`` deltas, one new wall each; per version, the time from sending
  the upload to (a) the ``delta`` event reaching a bare SSE client (the baseline, measured in the same run)
  and (b) the walls message with that many walls reaching a Foxglove WebSocket client through the bridge
  (the bridge in this process: its stream reader in a thread).

Exit 0 when it ran, 2 when the setup failed.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import socket
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path
from types import MappingProxyType
from typing import Any

import httpx
import uvicorn
from websockets.asyncio.client import connect

from server.app import create_app
from server.bootstrap import ensure_admin_token
from server.settings import Settings
from shared.foxbridge.bridge import FoxgloveBridge
from shared.foxbridge.convert import map_messages, stamp_of, walls_update
from shared.foxbridge.mapstate import MapState
from shared.foxbridge.sse import MapEventStream, SseParser

__all__ = ["main"]


def _state(n_walls: int) -> MapState:
    segments = {i: (float(i), 0.0, float(i), 1.0) for i in range(n_walls)}
    return MapState(
        robot_id=1,
        version=1,
        map_session=None,
        stamp_s=1.0,
        segments=MappingProxyType(segments),
        centroids=tuple((float(i), 0.5) for i in range(n_walls)),
        pose=(1.0, 2.0, 0.3),
        trajectory=tuple((float(i), float(i), 0.0, 0.0) for i in range(1000)),
        wall_time_s=None,
    )


def conversion(walls: list[int], runs: int) -> None:
    print("conversion (build + encode all messages of a version; trajectory 1000 poses):")
    for n in walls:
        state = _state(n)
        times = []
        size = 0
        for _ in range(runs):
            t0 = time.perf_counter()
            m = map_messages(state, 1.7e9)
            size = len(m.walls.encode())
            m.trajectory.encode()
            m.centroids.encode()
            times.append((time.perf_counter() - t0) * 1e3)
        median = statistics.median(times)
        print(f"  {n:>6} walls: median {median:7.2f} ms, walls message {size / 1024:7.1f} KiB")


class _Server:
    def __init__(self, app: Any) -> None:
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.port = self.sock.getsockname()[1]
        self.server = uvicorn.Server(uvicorn.Config(app, log_level="warning"))
        self.thread = threading.Thread(target=self.server.run, kwargs={"sockets": [self.sock]}, daemon=True)

    def __enter__(self) -> _Server:
        self.thread.start()
        deadline = time.monotonic() + 30
        while not self.server.started:
            if time.monotonic() > deadline:
                raise RuntimeError("the server did not start")
            time.sleep(0.01)
        return self

    def __exit__(self, *exc: object) -> None:
        self.server.should_exit = True
        self.thread.join(10)
        self.sock.close()


def _sse_baseline(url: str, token: str, arrived: dict[int, float], stop: threading.Event) -> None:
    headers = {"Authorization": f"Bearer {token}"}
    with httpx.Client(timeout=60) as c, c.stream("GET", url, headers=headers) as r:
        parser = SseParser()
        for line in r.iter_lines():
            event = parser.feed(line)
            if event is not None and event.id is not None:
                arrived.setdefault(event.id, time.perf_counter())
            if stop.is_set():
                return


def _wall(k: int) -> list[float]:
    return [float(k), float(k), 0.0, float(k), 1.0]


def _expected_walls(k: int) -> bytes:
    """The walls message of version k as the bridge encodes it (walls 1..k, stamped wall_time_s)."""
    segments = {i: (float(i), 0.0, float(i), 1.0) for i in range(1, k + 1)}
    state = MapState(1, k, None, float(k), MappingProxyType(segments), wall_time_s=_wall_time(k))
    return walls_update(state, stamp_of(state, 0.0)).encode()


def _wall_time(k: int) -> float:
    return 1.7e9 + k


async def _foxglove_walls(port: int, expected: dict[bytes, int], arrived: dict[int, float]) -> None:
    """Record when each version's walls message (known bytes) reaches a Foxglove client."""
    async with connect(f"ws://127.0.0.1:{port}", subprotocols=["foxglove.sdk.v1"]) as ws:  # type: ignore[list-item]
        walls_id = None
        while walls_id is None:
            frame = await ws.recv()
            if isinstance(frame, str):
                channels = json.loads(frame).get("channels", [])
                ids = [c["id"] for c in channels if c["topic"] == "/linemap/walls"]
                walls_id = ids[0] if ids else None
        await ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": walls_id}]}))
        while len(arrived) < len(expected):
            frame = await ws.recv()
            if isinstance(frame, bytes) and frame[0] == 1:
                version = expected.get(frame[13:])
                if version is not None:
                    arrived.setdefault(version, time.perf_counter())


def _upload(robot: httpx.Client, rid: int, k: int) -> float:
    body: dict[str, Any] = {
        "version": k,
        "base_version": None if k == 1 else k - 1,
        "stamp_s": float(k),
        "wall_time_s": _wall_time(k),
        "segments": [_wall(k)],
        "pose": [float(k), 0.5, 0.0],
        "trajectory": [[float(k), float(k), 0.5, 0.0]],
    }
    t0 = time.perf_counter()
    r = robot.post(f"/robots/{rid}/maps", json=body)
    if r.status_code != 200:
        raise RuntimeError(f"upload {k}: {r.status_code} {r.text}")
    return t0


def latency(versions: int, interval_s: float) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        app = create_app(Settings(database_url=f"sqlite:///{Path(tmp) / 's.db'}"))
        admin = ensure_admin_token(app.state.linemap.db)
        assert admin is not None
        with _Server(app) as srv:
            base = f"http://127.0.0.1:{srv.port}"
            with httpx.Client(base_url=base + "/api/v1", headers={"Authorization": f"Bearer {admin}"}) as op:
                created = op.post("/robots", json={"name": "bench"}).json()
            rid, robot_token = int(created["id"]), str(created["token"])
            auth = {"Authorization": f"Bearer {robot_token}"}
            with httpx.Client(base_url=base + "/api/v1", headers=auth, timeout=30) as robot:
                _upload(robot, rid, 1)
                expected = {_expected_walls(k): k for k in range(2, versions + 2)}
                stop = threading.Event()
                sse_at: dict[int, float] = {}
                url = f"{base}/api/v1/robots/{rid}/maps/stream"
                threading.Thread(target=_sse_baseline, args=(url, admin, sse_at, stop), daemon=True).start()
                with FoxgloveBridge(port=0, name="bench") as bridge:
                    stream = MapEventStream(base, rid, admin)
                    threading.Thread(target=bridge.follow, args=(stream, stop), daemon=True).start()
                    fox_at: dict[int, float] = {}
                    sent: dict[int, float] = {}

                    async def run() -> None:
                        listener = asyncio.create_task(_foxglove_walls(bridge.port, expected, fox_at))
                        while bridge.published == 0 or 1 not in sse_at:  # both followed version 1
                            await asyncio.sleep(0.01)
                        for k in range(2, versions + 2):
                            sent[k] = await asyncio.to_thread(_upload, robot, rid, k)
                            await asyncio.sleep(interval_s)
                        await asyncio.wait_for(listener, 60)

                    asyncio.run(run())
                    stop.set()
    sse = [(sse_at[k] - sent[k]) * 1e3 for k in sent]
    fox = [(fox_at[k] - sent[k]) * 1e3 for k in sent]
    print(f"latency, upload sent -> arrival ({versions} versions, one every {interval_s * 1e3:.0f} ms):")
    for name, xs in (("SSE client (baseline)", sse), ("Foxglove client via bridge", fox)):
        xs.sort()
        p99 = xs[min(len(xs) - 1, round(0.99 * (len(xs) - 1)))]
        print(f"  {name:<28} median {statistics.median(xs):6.1f} ms  p99 {p99:6.1f} ms  max {xs[-1]:6.1f} ms")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--walls", type=int, nargs="+", default=[100, 1000, 5000])
    parser.add_argument("--runs", type=int, default=20)
    parser.add_argument("--versions", type=int, default=100)
    parser.add_argument("--interval-ms", type=float, default=50.0)
    args = parser.parse_args()
    try:
        conversion(args.walls, args.runs)
        latency(args.versions, args.interval_ms / 1e3)
    except (RuntimeError, OSError, httpx.HTTPError) as exc:
        print(f"setup failed: {exc}", file=sys.stderr)
        raise SystemExit(2) from None


if __name__ == "__main__":
    main()
