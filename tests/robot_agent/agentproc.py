"""A real agent process (``linemap agent``) beside a real server, for the agent's integration tests."""

from __future__ import annotations

import contextlib
import os
import signal
import sqlite3
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import httpx

LINEMAP = str(Path(sys.executable).parent / "linemap")


def wait_for(what: str, check: Callable[[], Any], timeout_s: float = 60.0) -> Any:
    """Poll ``check`` until it returns something truthy (a readiness wait, not a timing assertion)."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = check()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.05)


class AgentProcess:
    """``linemap agent`` as a subprocess; ``stop()`` sends SIGINT, ``kill()`` SIGKILL."""

    def __init__(
        self,
        db: Path,
        *,
        server: str | None,
        robot_id: int = 0,
        token: str = "",
        extra: list[str] | None = None,
        log: Path | None = None,
    ):
        self.db = db
        args = [LINEMAP, "agent", "--db", str(db), *(extra or [])]
        if server is not None:
            args += ["--server", server, "--robot-id", str(robot_id), "--token", token]
        self.log = log or db.with_suffix(".log")
        self._out = self.log.open("ab")
        # Its own process group: a power cut (tests/reliability) kills it and every child it started at once.
        self.proc = subprocess.Popen(
            args, stdout=self._out, stderr=subprocess.STDOUT, env={**os.environ}, start_new_session=True
        )

    def stop(self, timeout_s: float = 60.0) -> int:
        """SIGINT, and its exit status; one that does not exit within ``timeout_s`` is killed with its whole
        process group before the timeout is raised (a failing test never leaves an agent running)."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
        try:
            return self.proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait(30)
            raise
        finally:
            self._out.close()

    def kill(self) -> None:
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait(30)
        self._out.close()

    def output(self) -> str:
        return self.log.read_text(errors="replace")


def stop_all(agents: list[AgentProcess]) -> None:
    """Stop every agent of ``agents`` (each one even when an earlier one failed to stop), then assert that
    each exited with status 0, naming the first that did not, with its output."""
    codes: list[int | BaseException] = []
    for agent in agents:
        try:
            codes.append(agent.stop())
        except subprocess.TimeoutExpired as exc:
            codes.append(exc)
    for agent, code in zip(agents, codes, strict=True):
        assert code == 0, f"agent {agent.db} ended with {code!r}: {agent.output()[-3000:]}"


def robot_db_meta(db: Path, key: str) -> Any:
    import json

    try:
        with sqlite3.connect(db) as conn:
            row = conn.execute("SELECT value FROM meta WHERE key = ?", (key,)).fetchone()
    except sqlite3.OperationalError:  # the agent is still creating its database
        return None
    return None if row is None else json.loads(row[0])["v"]


def integrity(db: Path) -> str:
    with sqlite3.connect(db) as conn:
        return str(conn.execute("PRAGMA integrity_check").fetchone()[0])


def robot_state(client: httpx.Client, robot_id: int) -> dict[str, Any]:
    data: dict[str, Any] = client.get(f"/robots/{robot_id}").json()
    return data


def send_message(op: httpx.Client, robot_id: int, body: str, timeout_s: float = 120.0) -> dict[str, Any]:
    """Queue ``<xml><message>{body}</message></xml>`` for the robot and wait for its acknowledgement;
    the message as the server then holds it (``status``, ``reason``)."""
    r = op.post(
        f"/robots/{robot_id}/messages",
        content=f"<xml><message>{body}</message></xml>",
        headers={"Content-Type": "application/xml"},
    )
    assert r.status_code == 201, r.text
    seq = r.json()["seq"]
    return dict(
        wait_for(
            f"acknowledgement of message {seq}",
            lambda: (m := op.get(f"/robots/{robot_id}/messages/{seq}").json())["status"] != "queued" and m,
            timeout_s,
        )
    )
