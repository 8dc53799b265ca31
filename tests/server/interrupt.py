"""Ctrl-C on a running ``linemap server`` while a robot long-polls and the dashboard streams a map: the
scenario the one-process and the ``--workers`` shutdown tests share (their assertions stay theirs)."""

from __future__ import annotations

import signal
import subprocess
import threading
from typing import Any

import httpx

from tests.robot_agent.agentproc import wait_for
from tests.server.test_server_cli import _wait_healthy


def interrupt_mid_poll_and_stream(
    proc: subprocess.Popen[str], out: str, port: int
) -> tuple[int, str, dict[str, Any]]:
    """Start a robot's long-poll and a map stream on the server ``proc`` (its start-up output ``out``),
    send SIGINT once both are in flight; (exit code, stderr, what the two requests got: ``poll`` as
    (status, body), ``stream`` its status, or the error each met). Kills ``proc`` if it outlives this."""
    results: dict[str, Any] = {}
    try:
        base = f"http://127.0.0.1:{port}/api/v1"
        _wait_healthy(port)
        token = out.split("keep it): ")[1].split()[0]
        op = {"Authorization": f"Bearer {token}"}
        robot = httpx.post(f"{base}/robots", json={"name": "poller"}, headers=op, timeout=10).json()
        rid, robot_auth = robot["id"], {"Authorization": f"Bearer {robot['token']}"}

        def long_poll() -> None:
            try:
                r = httpx.get(
                    f"{base}/robots/{rid}/messages", params={"wait": 60}, headers=robot_auth, timeout=90
                )
                results["poll"] = (r.status_code, r.json())
            except httpx.HTTPError as exc:
                results["poll"] = exc

        def stream() -> None:
            try:
                with httpx.stream("GET", f"{base}/robots/{rid}/maps/stream", headers=op, timeout=90) as r:
                    for line in r.iter_lines():
                        if line.startswith("event: snapshot"):
                            results["snapshot"] = True
                results["stream"] = r.status_code
            except httpx.HTTPError as exc:
                results["stream"] = exc

        threads = [threading.Thread(target=long_poll), threading.Thread(target=stream)]
        for t in threads:
            t.start()
        # Both requests are inside the server: the robot is seen (its long-poll authenticated; with several
        # workers the last-seen times reach the database within 10 s) and the stream sent its snapshot.
        wait_for(
            "the long-poll and the stream to be in flight",
            lambda: (
                results.get("snapshot")
                and httpx.get(f"{base}/robots/{rid}", headers=op, timeout=10).json()["online"]
            ),
        )
        proc.send_signal(signal.SIGINT)
        code = proc.wait(60)
        for t in threads:
            t.join(60)
        assert proc.stderr is not None
        err = proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return code, err, results
