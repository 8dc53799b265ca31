"""Live fan-out across server processes: how long a map upload on one `linemap server` takes to reach an
operator's live map (SSE) on another, and a control message queued on one to reach a robot long-polling
the other.

Starts two server processes (A and B) on a fresh PostgreSQL database made on the server of ``--postgres``
(dropped afterwards). Figures (median, p99, max):

- map: a viewer streams robot R's map from B (and one from A, for comparison); R uploads a snapshot then
  ``--versions`` deltas to A at ``--rate_hz``; per version, time from sending the upload to A to the event
  with that version arriving on B (on A), and how many arrived as deltas (the rest as snapshots);
- message: R long-polls B (then A, in turn); an operator queues a message on A; time from sending it to A
  to the poll's answer.

Both include A's handling of the request (the notice is sent when A commits, before A answers).

Exit 0 when it ran (figures, not pass/fail), 2 when the setup failed.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import socket
import statistics
import subprocess
import sys
import threading
import time
import uuid
from pathlib import Path
from typing import Any

import httpx
from sqlalchemy import create_engine, text
from sqlalchemy.engine import make_url

__all__ = ["main"]

API = "/api/v1"
LINEMAP = str(Path(sys.executable).parent / "linemap")
MESSAGE = b"<xml><message><mode>online</mode></message></xml>"


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _start(db: str, env: dict[str, str], workers: int) -> tuple[subprocess.Popen[str], str, str]:
    port = _port()
    cmd = [LINEMAP, "server", "--db", db, "--port", str(port)]
    if workers > 1:
        cmd += ["--workers", str(workers)]
    proc = subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env={**os.environ, **env}
    )
    assert proc.stdout is not None
    out = proc.stdout.readline()
    while out and "linemap server on" not in out.splitlines()[-1]:
        out += proc.stdout.readline()
    base = f"http://127.0.0.1:{port}"
    for _ in range(600):
        try:
            if httpx.get(base + "/healthz", timeout=2).status_code == 200:
                break
        except httpx.TransportError:
            time.sleep(0.05)
    token = out.split("keep it): ")[1].split()[0] if "keep it): " in out else ""
    return proc, base + API, token


def _ms(xs: list[float]) -> str:
    if not xs:
        return "no samples"
    xs = sorted(xs)
    p99 = xs[round(0.99 * (len(xs) - 1))]
    return (
        f"median {statistics.median(xs) * 1e3:7.1f} ms  p99 {p99 * 1e3:7.1f} ms  max {xs[-1] * 1e3:7.1f} ms"
    )


def _snapshot(version: int) -> dict[str, Any]:
    return {
        "version": version,
        "base_version": None,
        "stamp_s": 1.0,
        "segments": [[i, float(i), 0.0, float(i), 1.0] for i in range(1, 201)],
        "centroids": [[0.0, 0.0]],
        "pose": [0.0, 0.0, 0.0],
        "trajectory": [[1.0, 0.0, 0.0, 0.0]],
    }


def _delta(base: int, version: int) -> dict[str, Any]:
    return {
        "version": version,
        "base_version": base,
        "stamp_s": float(version),
        "segments": [[version % 200 + 1, 0.0, float(version), 1.0, float(version)]],
        "removed": [],
        "centroids": [[0.0, 0.0]],
        "pose": [float(version), 0.0, 0.0],
        "trajectory": [[float(version), float(version), 0.0, 0.0]],
    }


def _viewer(c: httpx.Client, rid: int, opened: threading.Event, got: dict[int, tuple[float, str]]) -> None:
    with contextlib.suppress(httpx.HTTPError), c.stream("GET", f"/robots/{rid}/maps/stream") as r:
        event = ""
        for line in r.iter_lines():  # until the client is closed
            if line.startswith("event: "):
                event = line[7:]
            elif line.startswith("id: "):
                got[int(line[4:])] = (time.perf_counter(), event)
                if event == "snapshot":
                    opened.set()


def _maps(a: str, b: str, admin: str, versions: int, rate_hz: float) -> None:
    hdr = {"Authorization": f"Bearer {admin}"}
    with httpx.Client(base_url=a, headers=hdr, timeout=30) as op:
        made = op.post("/robots", json={"name": f"fan-{uuid.uuid4().hex[:6]}"}).json()
    rid, robot_hdr = made["id"], {"Authorization": f"Bearer {made['token']}"}
    got: dict[str, dict[int, tuple[float, str]]] = {"B": {}, "A": {}}
    sent: dict[int, float] = {}
    clients = {
        name: httpx.Client(base_url=url, headers=hdr, timeout=60) for name, url in (("A", a), ("B", b))
    }
    try:
        with httpx.Client(base_url=a, headers=robot_hdr, timeout=30) as robot:
            assert robot.post(f"/robots/{rid}/maps", json=_snapshot(1)).status_code == 200
            for name, client in clients.items():
                opened = threading.Event()
                args = (client, rid, opened, got[name])
                threading.Thread(target=_viewer, args=args, daemon=True).start()
                assert opened.wait(30), f"the stream on {name} sent no snapshot"
            for v in range(2, versions + 2):
                t0 = time.perf_counter()
                sent[v] = t0
                r = robot.post(f"/robots/{rid}/maps", json=_delta(v - 1, v))
                assert r.status_code == 200, r.text
                time.sleep(max(0.0, 1.0 / rate_hz - (time.perf_counter() - t0)))
            deadline = time.monotonic() + 10
            while any(versions + 1 not in g for g in got.values()) and time.monotonic() < deadline:
                time.sleep(0.05)
    finally:
        for client in clients.values():
            client.close()
    print(f"map: {versions} versions uploaded to A at {rate_hz:g} Hz, a viewer on B and one on A")
    for name, where in (("B", "other process"), ("A", "same process, for comparison")):
        lat = [got[name][v][0] - sent[v] for v in sent if v in got[name]]
        deltas = sum(1 for v in sent if v in got[name] and got[name][v][1] == "delta")
        shown = f"{len(lat)} events ({deltas} deltas, {len(lat) - deltas} snapshots)"
        print(f"  viewer on {name} ({where}): {shown}")
        print(f"    upload sent to A -> event on {name}   {_ms(lat)}")


def _messages(a: str, b: str, admin: str, rounds: int) -> None:
    hdr = {"Authorization": f"Bearer {admin}"}
    with httpx.Client(base_url=a, headers=hdr, timeout=30) as op:
        made = op.post("/robots", json={"name": f"fan-{uuid.uuid4().hex[:6]}"}).json()
        rid, robot_hdr = made["id"], {"Authorization": f"Bearer {made['token']}"}
        lat: dict[str, list[float]] = {"B": [], "A": []}
        robots = {
            name: httpx.Client(base_url=url, headers=robot_hdr, timeout=60)
            for name, url in (("A", a), ("B", b))
        }
        try:
            for seq in range(2 * rounds):  # the robot polls B and A in turn
                name = "B" if seq % 2 == 0 else "A"
                done: list[float] = []

                def poll(
                    after: int = seq, done: list[float] = done, robot: httpx.Client = robots[name]
                ) -> None:
                    r = robot.get(f"/robots/{rid}/messages", params={"after": after, "wait": 30})
                    done.append(time.perf_counter())
                    assert r.json()["messages"], "the long-poll ended empty"

                poller = threading.Thread(target=poll)
                poller.start()
                time.sleep(0.05)  # let the poll reach the server and begin waiting
                t0 = time.perf_counter()
                r = op.post(
                    f"/robots/{rid}/messages", content=MESSAGE, headers={"Content-Type": "application/xml"}
                )
                assert r.status_code == 201, r.text
                poller.join(40)
                lat[name].append(done[0] - t0)
        finally:
            for client in robots.values():
                client.close()
    print(
        f"message: {rounds} control messages queued on A per poller, the robot long-polling B and A in turn"
    )
    print(f"  message sent to A -> poll answered on B   {_ms(lat['B'])}")
    print(f"  message sent to A -> poll answered on A   {_ms(lat['A'])}   (same process, for comparison)")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    p.add_argument(
        "--postgres",
        default=os.environ.get("LINEMAP_TEST_POSTGRES_URL", ""),
        help="PostgreSQL server URL to make the database on [$LINEMAP_TEST_POSTGRES_URL]",
    )
    p.add_argument("--versions", type=int, default=200, help="map deltas uploaded [200]")
    p.add_argument("--rate_hz", type=float, default=10.0, help="upload rate [10]")
    p.add_argument("--messages", type=int, default=50, help="control messages [50]")
    args = p.parse_args(argv)
    if not args.postgres:
        print("--postgres (or LINEMAP_TEST_POSTGRES_URL) is needed", file=sys.stderr)
        return 2
    name = f"lm_fanout_{uuid.uuid4().hex[:8]}"
    admin_engine = create_engine(
        make_url(args.postgres).set(drivername="postgresql+psycopg"), isolation_level="AUTOCOMMIT"
    )
    with admin_engine.connect() as conn:
        conn.execute(text(f'CREATE DATABASE "{name}"'))
    db = make_url(args.postgres).set(database=name).render_as_string(hide_password=False)
    procs = []
    try:
        a_proc, a, admin = _start(db, {}, 1)
        procs.append(a_proc)
        b_proc, b, _ = _start(db, {}, 1)
        procs.append(b_proc)
        print("2 server processes (A, B) on one PostgreSQL database")
        _maps(a, b, admin, args.versions, args.rate_hz)
        _messages(a, b, admin, args.messages)
        return 0
    except (OSError, AssertionError, httpx.HTTPError) as exc:
        print(f"setup failed: {exc!r}", file=sys.stderr)
        return 2
    finally:
        for proc in procs:
            proc.terminate()
        for proc in procs:
            try:
                proc.communicate(timeout=15)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.communicate()
        with admin_engine.connect() as conn:
            conn.execute(text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
        admin_engine.dispose()


if __name__ == "__main__":
    sys.exit(main())
