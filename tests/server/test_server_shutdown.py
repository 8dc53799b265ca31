"""Ctrl-C on a real ``linemap server`` while a robot long-polls and the dashboard streams a map: the
long-poll gets its ordinary (empty) answer, the stream ends, the process exits 0 and prints no traceback
(:mod:`server.shutdown`)."""

from __future__ import annotations

import socket
import subprocess
from pathlib import Path

from tests.server.interrupt import interrupt_mid_poll_and_stream
from tests.server.test_server_cli import LINEMAP, _free_port, _start


def test_ctrl_c_ends_long_polls_and_streams_cleanly(tmp_path: Path) -> None:
    port = _free_port()
    proc, out = _start(tmp_path / "srv.db", port)
    code, err, results = interrupt_mid_poll_and_stream(proc, out, port)
    assert code == 0, err
    assert "Traceback" not in err and "ERROR" not in err, (err, results)
    assert results["poll"] == (200, {"messages": [], "last_seq": 0, "map_version": 0, "map_session": None}), (
        results
    )
    assert results["stream"] == 200, results


def test_a_taken_port_exits_non_zero(tmp_path: Path) -> None:
    """The port is taken: the command says so and exits 3 (as it did with ``uvicorn.run``), no traceback."""
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        done = subprocess.run(
            [LINEMAP, "server", "--db", str(tmp_path / "s.db"), "--port", str(port)],
            capture_output=True,
            text=True,
            timeout=120,
            check=False,
        )
    assert done.returncode == 3, (done.returncode, done.stderr)
    assert "address already in use" in done.stderr and "Traceback" not in done.stderr, done.stderr
