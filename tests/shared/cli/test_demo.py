"""``linemap demo``: a real server and a real simulated robot, started, used and stopped with Ctrl-C."""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys
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
        proc.send_signal(signal.SIGINT)
        assert proc.wait(90) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
        out.close()
    log = (tmp_path / "demo.out").read_text()
    assert "stopped" in log and "Traceback" not in log
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
