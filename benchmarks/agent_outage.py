"""Agent figures (docs/reliability/agent.md), with real processes: CPU and memory of ``linemap agent`` at 10
Hz, and a long server outage bridged with nothing lost and nothing twice.

    .venv/bin/python benchmarks/agent_outage.py [--source LOG] [--down-s 600] [--rate 10]

Starts ``linemap server`` (fresh SQLite file) and ``linemap agent`` on SOURCE (default: the ACES log,
7,374 scans, about 12 minutes at 10 Hz), samples the agent's CPU and RSS while the server is up, stops the
server for ``--down-s`` seconds while the agent maps on, starts it again on the same database and port,
lets the agent finish the log and upload, and checks that the server holds every scan's pose exactly once,
in order. Prints figures; exit 0 when it ran, 2 when the setup failed.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import socket
import sqlite3
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import httpx

ROOT = Path(__file__).resolve().parents[1]
LINEMAP = str(Path(sys.executable).parent / "linemap")
DEFAULT_LOG = ROOT.parent / "shared" / "data" / "aces" / "aces.clf.gz"


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _server(db: Path, port: int, log: Path) -> tuple[subprocess.Popen[str], str | None]:
    out = log.open("a")
    proc = subprocess.Popen(
        [LINEMAP, "server", "--db", str(db), "--port", str(port)],
        stdout=subprocess.PIPE,
        stderr=out,
        text=True,
    )
    assert proc.stdout is not None
    token = None
    for line in proc.stdout:
        found = re.search(r"(lmo_\S+)", line)
        token = token or (found.group(1) if found else None)
        if "linemap server on" in line:
            break
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        try:
            if httpx.get(f"http://127.0.0.1:{port}/healthz", timeout=2).status_code == 200:
                return proc, token
        except httpx.TransportError:
            time.sleep(0.1)
    raise SystemExit(f"server did not come up; see {log}")


def _meta(db: Path, key: str) -> Any:
    try:
        with sqlite3.connect(db) as conn:
            row = conn.execute("SELECT value FROM meta WHERE key = ?", (key,)).fetchone()
    except sqlite3.OperationalError:
        return None
    return None if row is None else json.loads(row[0])["v"]


def _cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def _stop(proc: subprocess.Popen[Any]) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(60)
        except subprocess.TimeoutExpired:
            proc.kill()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--source", default=str(DEFAULT_LOG), help="scan source for the agent [ACES log]")
    ap.add_argument("--down-s", type=float, default=600.0, help="how long the server stays down [600]")
    ap.add_argument("--rate", type=float, default=10.0, help="agent steps per second [10]")
    ap.add_argument("--sample-s", type=float, default=30.0, help="CPU/RSS sampling window before the outage")
    args = ap.parse_args()
    if not args.source.startswith("sim") and not Path(args.source).is_file():
        print(f"setup failed: no source {args.source}", file=sys.stderr)
        return 2
    work = Path(tempfile.mkdtemp(prefix="linemap-outage-"))
    port, sdb, rdb, log = _port(), work / "server.db", work / "robot.db", work / "run.log"
    server, token = _server(sdb, port, log)
    api = f"http://127.0.0.1:{port}/api/v1"
    op = httpx.Client(base_url=api, headers={"Authorization": f"Bearer {token}"}, timeout=30)
    robot = op.post("/robots", json={"name": "outage"}).json()
    agent = subprocess.Popen(
        [
            LINEMAP,
            "agent",
            "--server",
            f"http://127.0.0.1:{port}",
            "--robot-id",
            str(robot["id"]),
            "--token",
            robot["token"],
            "--db",
            str(rdb),
            "--source",
            args.source,
            "--rate",
            str(args.rate),
            "--exit-at-end",
        ],
        stdout=log.open("a"),
        stderr=subprocess.STDOUT,
    )
    try:
        while (_meta(rdb, "uploaded_version") or 0) < 20:
            time.sleep(0.2)
        c0, t0, rss = _cpu_s(agent.pid), time.monotonic(), []
        while time.monotonic() - t0 < args.sample_s:
            rss.append(_rss_mb(agent.pid))
            time.sleep(1.0)
        cpu_pct = 100 * (_cpu_s(agent.pid) - c0) / (time.monotonic() - t0)
        rss_mb = max(rss)
        print(
            f"agent at {args.rate:g} Hz, server up: CPU {cpu_pct:.1f} % of one core, RSS {rss_mb:.0f} MB max"
        )
        _stop(server)
        down_at, v_down = time.monotonic(), _meta(rdb, "map_version")
        print(f"server stopped at robot map version {v_down}; down for {args.down_s:g} s", flush=True)
        while time.monotonic() - down_at < args.down_s and agent.poll() is None:
            time.sleep(1.0)
        v_back, pending = _meta(rdb, "map_version"), _meta(rdb, "uploaded_version")
        print(f"robot mapped {v_back - v_down} steps while the server was down (server has up to {pending})")
        server, _ = _server(sdb, port, log)
        back_at = time.monotonic()
        if agent.wait() != 0 or (_meta(rdb, "uploaded_version") or 0) < (_meta(rdb, "map_version") or 0):
            # The source ended while the server was down: a restarted agent resumes and uploads the rest.
            agent = subprocess.Popen(agent.args, stdout=log.open("a"), stderr=subprocess.STDOUT)
            agent.wait()
        final = _meta(rdb, "map_version")
        deadline = time.monotonic() + 600
        while op.get(f"/robots/{robot['id']}").json()["map_version"] < final and time.monotonic() < deadline:
            time.sleep(0.5)
        caught_up = time.monotonic() - back_at
        stamps = [r[0] for r in op.get(f"/robots/{robot['id']}/maps/latest").json()["trajectory"]]
        unique_in_order = stamps == sorted(set(stamps))
        print(
            f"agent steps {final}; server poses {len(stamps)}; each exactly once, in order: {unique_in_order}"
        )
        print(f"server back -> agent done and everything uploaded: {caught_up:.1f} s")
        ok = len(stamps) == final and unique_in_order
        print("RESULT:", "nothing lost, nothing twice" if ok else "MISMATCH", f"(work dir {work})")
        return 0
    finally:
        _stop(agent)
        _stop(server)


if __name__ == "__main__":
    raise SystemExit(main())
