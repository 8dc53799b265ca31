"""`linemap foxglove` through the real thing: a real uvicorn linemap server (each database backend), the
bridge as its own process, and a Foxglove WebSocket client (fxclient.py) that subscribes to the bridge's
topics and decodes what arrives with the advertised schemas. The walls, pose, transform and trajectory
that arrive are the server's map, before and after a robot's delta, and after the server restarts; a
refused token, an unknown robot and a missing extra end the bridge with one line, never a traceback."""

from __future__ import annotations

import asyncio
import math
import os
import queue
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from server.app import create_app
from server.bootstrap import ensure_admin_token
from server.settings import Settings
from tests.server.live import BACKENDS, Live, ServerThread, start_live
from tests.shared.foxbridge.fxclient import FoxClient
from tests.shared.foxbridge.fxwire import yaw_of

ROOT = Path(__file__).resolve().parents[3]
TOPICS = {"/linemap/walls", "/linemap/pose", "/linemap/tf", "/linemap/trajectory", "/linemap/centroids"}
LINE_STRIP, LINE_LIST = 0, 2


@pytest.fixture(scope="module", params=BACKENDS)
def fox_live(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    tmp = tmp_path_factory.mktemp(f"fox-{request.param}")
    yield from start_live(request.param, tmp, poll_recheck_s=30.0)


SNAPSHOT: dict[str, Any] = {
    "version": 1,
    "base_version": None,
    "stamp_s": 1.0,
    "segments": [[1, 0.0, 0.0, 4.0, 0.0], [2, 4.0, 0.0, 4.0, 3.0], [3, 4.0, 3.0, 0.0, 3.0]],
    "centroids": [[2.0, 0.1]],
    "pose": [1.0, 1.5, 0.25],
    "trajectory": [[0.5, 0.5, 1.0, 0.0], [1.0, 1.0, 1.5, 0.25]],
}
DELTA: dict[str, Any] = {
    "version": 2,
    "base_version": 1,
    "stamp_s": 2.0,
    "segments": [[9, 0.0, 3.0, 0.0, 0.0], [2, 4.0, 0.0, 4.5, 3.0]],
    "removed": [1],
    "centroids": [[3.0, 1.0], [1.0, 2.0]],
    "pose": [2.0, 2.5, -1.2],
    "trajectory": [[2.0, 2.0, 2.5, -1.2]],
}


@dataclass
class Bridge:
    proc: subprocess.Popen[str]
    port: int
    stderr: list[str]


def _bridge_cmd(server: str, robot: int, port: int = 0) -> list[str]:
    return [sys.executable, "-m", "shared.cli.main", "foxglove", "--server", server, "--robot", str(robot),
            "--port", str(port)]  # fmt: skip


@contextmanager
def bridge(server: str, robot: int, token: str) -> Iterator[Bridge]:
    """`linemap foxglove` on any free port; yields once it printed its WebSocket address."""
    env = {**os.environ, "LINEMAP_TOKEN": token}
    pipe = subprocess.PIPE
    cmd = _bridge_cmd(server, robot)
    proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=pipe, stderr=pipe, text=True)
    lines: queue.Queue[str] = queue.Queue()
    stderr: list[str] = []
    assert proc.stdout is not None and proc.stderr is not None
    out, err = proc.stdout, proc.stderr

    def pump() -> None:
        for line in out:
            lines.put(line)

    threading.Thread(target=pump, daemon=True).start()
    threading.Thread(target=lambda: stderr.extend(err), daemon=True).start()
    try:
        first = lines.get(timeout=60)  # the readiness line (a deadline, not a timing assertion)
        assert first.startswith("Foxglove WebSocket server on ws://127.0.0.1:"), (first, stderr)
        port = int(first.split("ws://127.0.0.1:")[1].split()[0])
        yield Bridge(proc, port, stderr)
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def _points(scene: Any) -> list[tuple[float, float]]:
    return [(p.x, p.y) for p in scene.entities[0].lines[0].points]


def _walls_of(map_json: dict[str, Any]) -> list[tuple[float, float]]:
    out: list[tuple[float, float]] = []
    for _id, x0, y0, x1, y1 in sorted(map_json["segments"]):
        out += [(x0, y0), (x1, y1)]
    return out


async def _check_map(client: FoxClient, server_map: dict[str, Any]) -> None:
    """The bridge's messages carry ``server_map`` (the server's ``GET /robots/{id}/maps``)."""
    walls = _walls_of(server_map)
    scene = await client.wait_for("/linemap/walls", lambda m: _points(m) == walls)
    entity = scene.entities[0]
    assert (entity.id, entity.frame_id, entity.lines[0].type) == ("walls", "map", LINE_LIST)
    x, y, theta = server_map["pose"]

    def at_pose(m: Any) -> bool:
        return (m.pose.position.x, m.pose.position.y) == (x, y)

    pose = await client.wait_for("/linemap/pose", at_pose)
    assert pose.frame_id == "map"
    assert math.isclose(yaw_of(pose.pose.orientation), theta, abs_tol=1e-9)
    tf = await client.wait_for("/linemap/tf", lambda m: (m.translation.x, m.translation.y) == (x, y))
    assert (tf.parent_frame_id, tf.child_frame_id) == ("map", "base_link")
    assert math.isclose(yaw_of(tf.rotation), theta, abs_tol=1e-9)
    path = [(r[1], r[2]) for r in server_map["trajectory"]]
    traj = await client.wait_for("/linemap/trajectory", lambda m: _points(m) == path)
    assert traj.entities[0].lines[0].type == LINE_STRIP
    centroids = [tuple(c) for c in server_map["centroids"]]

    def at_centroids(m: Any) -> bool:
        return [(s.pose.position.x, s.pose.position.y) for s in m.entities[0].spheres] == centroids

    await client.wait_for("/linemap/centroids", at_centroids)


def _server_map(live: Live, rid: int) -> dict[str, Any]:
    with live.operator() as op:
        r = op.get(f"/robots/{rid}/maps/latest", params={"trajectory": 5000})
        assert r.status_code == 200, r.text
        body: dict[str, Any] = r.json()
        return body


def _upload(live: Live, token: str, rid: int, body: dict[str, Any]) -> None:
    with live.client(token) as robot:
        r = robot.post(f"/robots/{rid}/maps", json=body)
        assert r.status_code == 200, r.text


def test_foxglove_sees_the_servers_map_and_its_changes(fox_live: Live) -> None:
    rid, robot_token = fox_live.new_robot()
    _upload(fox_live, robot_token, rid, SNAPSHOT)

    async def scenario(port: int) -> None:
        client = await FoxClient.open(f"ws://127.0.0.1:{port}")
        try:
            await client.subscribe_all(TOPICS)
            assert client.server_info["name"] == "linemap"
            await _check_map(client, _server_map(fox_live, rid))  # sent on subscribing (latched)
            _upload(fox_live, robot_token, rid, DELTA)
            after = _server_map(fox_live, rid)
            assert after["version"] == 2 and len(after["segments"]) == 3
            await _check_map(client, after)
        finally:
            await client.close()

    with bridge(fox_live.base_url, rid, fox_live.admin_token) as b:
        asyncio.run(scenario(b.port))
        b.proc.send_signal(signal.SIGINT)
        assert b.proc.wait(30) == 0
    assert not any("Traceback" in line for line in b.stderr), b.stderr


def _run_bridge(cmd: list[str], env: dict[str, str]) -> str:
    """Run the bridge to its end; its error message (stderr, as one line: rich wraps it on a pipe), after
    checking that it exited with 2 and printed one error and no traceback."""
    done = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 2, done
    assert done.stderr.startswith("error: ") and done.stderr.count("error:") == 1, done.stderr
    assert "Traceback" not in done.stderr
    return " ".join(done.stderr.split())


def test_a_refused_token_and_an_unknown_robot_end_the_bridge_with_one_line(fox_live: Live) -> None:
    rid, _ = fox_live.new_robot()
    env = {**os.environ, "LINEMAP_TOKEN": "not-a-token"}
    refused = _run_bridge(_bridge_cmd(fox_live.base_url, rid), env)
    assert f"refused the token for robot {rid}'s map (401: unknown or revoked token)" in refused

    env["LINEMAP_TOKEN"] = fox_live.admin_token
    unknown = _run_bridge(_bridge_cmd(fox_live.base_url, 999_999), env)
    assert f"the linemap server at {fox_live.base_url} has no robot 999999" in unknown


def test_without_the_extra_the_bridge_names_the_install_command(tmp_path: Path) -> None:
    fake = tmp_path / "foxglove"  # first on the path: `import foxglove` fails as if it were not installed
    fake.mkdir()
    (fake / "__init__.py").write_text("raise ImportError('foxglove-sdk is not installed here')\n")
    env = {**os.environ, "PYTHONPATH": f"{tmp_path}{os.pathsep}{ROOT}"}
    message = _run_bridge(_bridge_cmd("http://127.0.0.1:9", 1), env)
    hint = "the Foxglove bridge needs the optional foxglove-sdk package: pip install 'linemap[foxglove]'"
    assert hint in message


def test_the_bridge_resumes_when_the_server_comes_back(tmp_path: Path) -> None:
    """The server stops under the bridge's open stream and starts again on the same port and database; the
    bridge reconnects (logging it) and the delta uploaded meanwhile reaches Foxglove."""
    url = f"sqlite:///{tmp_path / 'server.db'}"
    app = create_app(Settings(database_url=url))
    admin = ensure_admin_token(app.state.linemap.db)
    assert admin is not None
    srv = ServerThread(app).__enter__()
    port = srv.port
    try:
        live = Live(f"http://127.0.0.1:{port}", admin, app.state.linemap, "sqlite", app)
        rid, robot_token = live.new_robot()
        _upload(live, robot_token, rid, SNAPSHOT)

        async def scenario(bridge_port: int) -> None:
            nonlocal srv
            client = await FoxClient.open(f"ws://127.0.0.1:{bridge_port}")
            try:
                await client.subscribe_all(TOPICS)
                await _check_map(client, _server_map(live, rid))
                srv.__exit__(None, None, None)  # the server goes away under the open stream
                again = create_app(Settings(database_url=url))
                srv = ServerThread(again, port=port).__enter__()
                _upload(live, robot_token, rid, DELTA)
                await _check_map(client, _server_map(live, rid))
            finally:
                await client.close()

        with bridge(live.base_url, rid, admin) as b:
            asyncio.run(scenario(b.port))
        assert any("reconnecting" in line for line in b.stderr), b.stderr
    finally:
        srv.__exit__(None, None, None)
