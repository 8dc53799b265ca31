"""``linemap demo``: a real server and a real simulated robot, started, used and stopped with Ctrl-C."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import httpx

from tests.robot_agent.agentproc import wait_for

LINEMAP = str(Path(sys.executable).parent / "linemap")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_demo_serves_a_live_robot_and_stops_cleanly(tmp_path: Path) -> None:
    port = free_port()
    (tmp_path / "d").mkdir()
    theirs = tmp_path / "d" / "field-notes.log"  # the user's own file in the folder they named
    theirs.write_text("keep me")
    out = (tmp_path / "demo.out").open("wb")
    proc = subprocess.Popen(
        [LINEMAP, "demo", "--dir", str(tmp_path / "d"), "--port", str(port)],
        stdout=out,
        stderr=subprocess.STDOUT,
    )
    try:
        info_file = tmp_path / "d" / "demo.json"
        wait_for("demo.json", info_file.is_file, 120)
        info = json.loads(info_file.read_text())
        assert info["url"] == f"http://127.0.0.1:{port}/"
        text = (tmp_path / "demo.out").read_text()
        assert info["operator_token"] in text and info["url"] in text
        with httpx.Client(
            base_url=info["url"] + "api/v1", headers={"Authorization": f"Bearer {info['operator_token']}"}
        ) as op:
            wait_for(
                "the robot's map",
                lambda: op.get(f"/robots/{info['robot_id']}").json()["map_version"] > 20,
                120,
            )
            robot = op.get(f"/robots/{info['robot_id']}").json()
            assert robot["online"] and robot["config"]["mode"] == "online"
            assert [k["key_id"] for k in op.get("/keys").json()], "the demo's signing key is registered"
        assert httpx.get(info["url"]).status_code == 200  # the dashboard page
        assert Path(info["example_kernel"]).is_file() and info["example_signature"]
        kernels = Path(info["example_kernel"]).parent
        assert (kernels / "radius_outlier.py").is_file() and (kernels / "radius_outlier.sig").is_file()
        # the robot's token is not on the agent's command line (ps shows that to every local user)
        token = (tmp_path / "d" / "robot.token").read_text().strip()
        cmdline = Path(f"/proc/{info['agent_pid']}/cmdline").read_bytes().decode()
        assert token and token not in cmdline and "--token" not in cmdline, cmdline
        proc.send_signal(signal.SIGINT)
        assert proc.wait(90) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
        out.close()
    log = (tmp_path / "demo.out").read_text()
    assert "stopped" in log and "Traceback" not in log
    assert theirs.read_text() == "keep me"
    for pid in (info["server_pid"], info["agent_pid"]):
        assert not Path(f"/proc/{pid}").exists() or "zombie" in Path(f"/proc/{pid}/status").read_text()


def test_demo_refuses_a_port_in_use(tmp_path: Path) -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        r = subprocess.run(
            [LINEMAP, "demo", "--dir", str(tmp_path), "--port", str(port)],
            capture_output=True,
            text=True,
            timeout=60,
        )
    assert r.returncode == 2
    assert f"port {port}" in r.stderr and "in use" in r.stderr and "Traceback" not in r.stderr


def test_children_do_not_outlive_a_killed_demo(tmp_path: Path) -> None:
    """kill -9 of the demo itself: the server and the agent it started stop too (no orphans)."""
    port = free_port()
    (tmp_path / "d").mkdir()
    theirs = tmp_path / "d" / "field-notes.log"  # the user's own file in the folder they named
    theirs.write_text("keep me")
    out = (tmp_path / "demo.out").open("wb")
    proc = subprocess.Popen(
        [LINEMAP, "demo", "--dir", str(tmp_path / "d"), "--port", str(port)],
        stdout=out,
        stderr=subprocess.STDOUT,
    )
    try:
        info_file = tmp_path / "d" / "demo.json"
        wait_for("demo.json", info_file.is_file, 120)
        info = json.loads(info_file.read_text())
        proc.kill()
        proc.wait(30)

        def gone(pid: int) -> bool:
            try:
                return "Z" in Path(f"/proc/{pid}/stat").read_text().split(")")[1].split()[0]
            except FileNotFoundError:
                return True

        wait_for(
            "the server and agent to stop", lambda: gone(info["server_pid"]) and gone(info["agent_pid"]), 60
        )
    finally:
        if proc.poll() is None:
            proc.kill()
        out.close()


@contextmanager
def _demo(tmp_path: Path, port: int, *extra: str) -> Iterator[tuple[subprocess.Popen[bytes], Path]]:
    """``linemap demo`` in ``tmp_path/d``, stopped with Ctrl-C at the end of the block (exit code 0)."""
    log = tmp_path / f"demo-{len(list(tmp_path.glob('demo-*.out')))}.out"
    with log.open("wb") as out:
        proc = subprocess.Popen(
            [LINEMAP, "demo", "--dir", str(tmp_path / "d"), "--port", str(port), *extra],
            stdout=out,
            stderr=subprocess.STDOUT,
        )
    try:
        yield proc, log
        proc.send_signal(signal.SIGINT)
        assert proc.wait(90) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
    assert "Traceback" not in log.read_text()


def _operator(info: dict[str, object]) -> httpx.Client:
    return httpx.Client(
        base_url=f"{info['url']}api/v1", headers={"Authorization": f"Bearer {info['operator_token']}"}
    )


def _version(op: httpx.Client, robot_id: object) -> int:
    try:
        return int(op.get(f"/robots/{robot_id}").json()["map_version"])
    except (httpx.TransportError, KeyError, ValueError):
        return -1  # the server is down or starting


def test_a_killed_server_is_restarted_and_the_robot_carries_on(tmp_path: Path) -> None:
    info_file = tmp_path / "d" / "demo.json"
    with _demo(tmp_path, free_port()) as (proc, log):
        wait_for("demo.json", info_file.is_file, 120)
        info = json.loads(info_file.read_text())
        with _operator(info) as op:
            wait_for("the robot's map", lambda: _version(op, info["robot_id"]) > 20, 120)
            os.kill(info["server_pid"], signal.SIGKILL)
            wait_for(
                "a new server",
                lambda: json.loads(info_file.read_text())["server_pid"] != info["server_pid"],
                120,
            )
            before = _version(op, info["robot_id"])
            wait_for("the map to go on", lambda: _version(op, info["robot_id"]) > max(before, 0) + 20, 120)
        assert proc.poll() is None, "the demo kept running"
    text = log.read_text()
    assert "the server stopped (code -9)" in text and "restarting it" in text


def test_keep_resumes_the_last_robot_and_its_map(tmp_path: Path) -> None:
    port = free_port()
    info_file = tmp_path / "d" / "demo.json"
    with _demo(tmp_path, port):
        wait_for("demo.json", info_file.is_file, 120)
        first = json.loads(info_file.read_text())
        with _operator(first) as op:
            wait_for("the robot's map", lambda: _version(op, first["robot_id"]) > 20, 120)
    last = first["robot_id"]
    with _demo(tmp_path, port, "--keep") as (_, log):
        wait_for(
            "the resumed demo",
            lambda: json.loads(info_file.read_text())["agent_pid"] != first["agent_pid"],
            120,
        )
        second = json.loads(info_file.read_text())
        assert second["robot_id"] == last
        with _operator(second) as op:
            kept = _version(op, last)
            assert kept > 20, "the server kept the map"
            wait_for("the map to go on", lambda: _version(op, last) > kept + 20, 120)
            assert [r["id"] for r in op.get("/robots").json()] == [last]
    assert f"resuming the last demo's robot (id {last})" in log.read_text()


def test_keep_refuses_another_world(tmp_path: Path) -> None:
    d = tmp_path / "d"
    d.mkdir()
    (d / "server.db").write_bytes(b"")
    (d / "robot.token").write_text("x\n")
    (d / "demo.json").write_text(
        json.dumps({"world": "room", "robot_id": 1, "private_key": "k", "public_key": "p"})
    )
    r = subprocess.run(
        [LINEMAP, "demo", "--dir", str(d), "--port", str(free_port()), "--keep", "--world", "corridor-long"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 2, r.stderr
    assert "patrolled world 'room', not 'corridor-long'" in " ".join(r.stderr.split())
    assert "Traceback" not in r.stderr
