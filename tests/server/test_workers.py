"""``linemap server --workers 2`` on PostgreSQL, stopped with Ctrl-C while a robot long-polls and the
dashboard streams a map: as with one process, the long-poll gets its ordinary (empty) answer, the stream
ends properly, every worker exits and nothing prints a traceback; a taken port exits 3 with the reason.
(The fan-out between workers: tests/server/test_fanout_processes.py.)"""

from __future__ import annotations

import socket
import subprocess
from pathlib import Path

from tests.server.interrupt import interrupt_mid_poll_and_stream
from tests.server.procs import fresh_database
from tests.server.test_server_cli import LINEMAP, _free_port


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
    with fresh_database("postgresql", tmp_path) as url:
        port = _free_port()
        proc, out = _start(url, port)
        code, err, results = interrupt_mid_poll_and_stream(proc, out, port)
    assert "2 worker processes" in out, out
    assert code == 0, err
    assert "Traceback" not in err and "ERROR" not in err, (err, results)
    assert results["poll"] == (200, {"messages": [], "last_seq": 0, "map_version": 0, "map_session": None}), (
        results
    )
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
