"""`linemap server` as a user starts it: a separate process that migrates, prints the first operator token
once, serves on 127.0.0.1 and stops on Ctrl-C; and `linemap server token create`."""

from __future__ import annotations

import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx

LINEMAP = str(Path(sys.executable).parent / "linemap")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _start(db: Path, port: int) -> tuple[subprocess.Popen[str], str]:
    proc = subprocess.Popen(
        [LINEMAP, "server", "--db", str(db), "--port", str(port)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None
    lines = [proc.stdout.readline()]
    while lines[-1] and "linemap server on" not in lines[-1]:  # the token line, if any, comes first
        lines.append(proc.stdout.readline())
    return proc, "".join(lines)


def _wait_healthy(port: int) -> dict[str, str]:
    deadline = time.monotonic() + 30
    while True:  # readiness wait, not a timing assertion
        try:
            return dict(httpx.get(f"http://127.0.0.1:{port}/healthz", timeout=2).json())
        except httpx.TransportError:
            assert time.monotonic() < deadline, "server did not come up"
            time.sleep(0.05)


def test_server_command_first_start_token_and_restart(tmp_path: Path) -> None:
    db, port = tmp_path / "srv.db", _free_port()
    proc, out = _start(db, port)
    try:
        assert f"http://127.0.0.1:{port}" in out
        token = out.split("keep it): ")[1].split()[0]
        assert token.startswith("lmo_")
        assert _wait_healthy(port)["status"] == "ok"
        r = httpx.post(
            f"http://127.0.0.1:{port}/api/v1/robots",
            json={"name": "cli-bot"},
            headers={"Authorization": f"Bearer {token}"},
        )
        assert r.status_code == 201
    finally:
        proc.send_signal(signal.SIGINT)
        assert proc.wait(30) == 0
    # Second start: same database, no new token printed, the robot is still there.
    proc, out = _start(db, port)
    try:
        assert "First start" not in out
        _wait_healthy(port)
        robots = httpx.get(
            f"http://127.0.0.1:{port}/api/v1/robots", headers={"Authorization": f"Bearer {token}"}
        )
        assert [r["name"] for r in robots.json()] == ["cli-bot"]
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(30)


def test_token_create_and_bad_database_url(tmp_path: Path) -> None:
    db = tmp_path / "t.db"
    r = subprocess.run(
        [LINEMAP, "server", "--db", str(db), "token", "create", "--name", "ops"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip().startswith("lmo_")
    bad = subprocess.run(
        [LINEMAP, "server", "--db", "nosuchdriver://x", "token", "create"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert bad.returncode == 2
    assert "Traceback" not in bad.stderr and "nosuchdriver" in bad.stderr


def test_server_keeps_idle_connections_longer_than_its_clients() -> None:
    """The server's idle timeout exceeds the agent's and httpx's default idle expiry, so a client always
    closes an idle connection first (with equal timers a request can meet the server's close and be reset),
    and the test servers serve with the same value."""
    from robot_agent.link import IDLE_CONNECTION_S, ServerLink
    from server.cli import KEEP_ALIVE_S, _uvicorn_config
    from tests.server.live import ServerThread

    served = _uvicorn_config("127.0.0.1", 8000)["timeout_keep_alive"]
    assert served == KEEP_ALIVE_S
    assert served > IDLE_CONNECTION_S
    with httpx.Client() as client:  # httpx's default pool, as a user's script has it
        default_expiry = client._transport._pool._keepalive_expiry  # type: ignore[attr-defined]
    assert served > default_expiry
    link = ServerLink("http://127.0.0.1:8000", 1, "lmr_x")
    try:
        assert link._client._transport._pool._keepalive_expiry == IDLE_CONNECTION_S  # type: ignore[attr-defined]
    finally:
        link.close()
    thread = ServerThread(object())
    thread.sock.close()
    assert thread.server.config.timeout_keep_alive == served
