"""``linemap server --workers 2`` on PostgreSQL, stopped with Ctrl-C while a robot long-polls and the
dashboard streams a map: as with one process, the long-poll gets its ordinary (empty) answer, the stream
ends properly, every worker exits and nothing prints a traceback; a taken port exits 3 with the reason.
(The fan-out between workers: tests/server/test_fanout_processes.py.)"""

from __future__ import annotations

import signal
import socket
import subprocess
import threading
from pathlib import Path
from typing import Any

import httpx

from tests.robot_agent.agentproc import wait_for
from tests.server.procs import fresh_database
from tests.server.test_server_cli import LINEMAP, _free_port, _wait_healthy


def _start(url: str, port: int) -> tuple[subprocess.Popen[str], str]:
    proc = subprocess.Popen(
        [LINEMAP, "server", "--db", url, "--port", str(port), "--workers", "2"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None
    lines = [proc.stdout.readline()]
    while lines[-1] and "linemap server on" not in lines[-1]:
        lines.append(proc.stdout.readline())
    return proc, "".join(lines)


def test_ctrl_c_stops_every_worker_ending_long_polls_and_streams_cleanly(tmp_path: Path) -> None:
    results: dict[str, Any] = {}
    with fresh_database("postgresql", tmp_path) as url:
        port = _free_port()
        proc, out = _start(url, port)
        try:
            assert "2 worker processes" in out, out
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
            # In flight: the stream sent its snapshot, and the robot is seen (on either worker: the last-seen
            # times reach the database within 10 s).
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
    assert code == 0, err
    assert "Traceback" not in err and "ERROR" not in err, (err, results)
    assert results["poll"] == (200, {"messages": [], "last_seq": 0}), results
    assert results["stream"] == 200, results


def test_a_taken_port_exits_3_with_the_reason(tmp_path: Path) -> None:
    with fresh_database("postgresql", tmp_path) as url, socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        done = subprocess.run(
            [LINEMAP, "server", "--db", url, "--port", str(port), "--workers", "2"],
            capture_output=True,
            text=True,
            timeout=120,
            check=False,
        )
    assert done.returncode == 3, (done.returncode, done.stderr)
    assert "address already in use" in done.stderr.lower() and "Traceback" not in done.stderr, done.stderr
