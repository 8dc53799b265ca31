"""Authentication across server processes: how long a revocation on one `linemap server` takes to reach
another on the same database, and what the short credential cache costs per request.

Starts three server processes on one database (``--db``: a PostgreSQL URL or a SQLite file; default a
SQLite temp file): A and B with the default ``credential_cache_s`` (0.5 s), C with 0 (a lookup per
request). Figures (medians of ``--rounds``):

- revocation delay: a token used on B (its lookup cached there) is revoked on A; time from A's answer to
  B's first 401 (B polled as fast as it answers), and to the end of a live-map stream opened on B;
- request cost: ``GET /whoami`` latency on B (cached) against C (no cache), interleaved, same run.

Exit 0 when it ran (figures, not pass/fail), 2 when the setup failed.
"""

from __future__ import annotations

import argparse
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx

__all__ = ["main"]

API = "/api/v1"
LINEMAP = str(Path(sys.executable).parent / "linemap")


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _start(db: str, env: dict[str, str]) -> tuple[subprocess.Popen[str], str, str]:
    port = _port()
    proc = subprocess.Popen(
        [LINEMAP, "server", "--db", db, "--port", str(port)],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        env={**os.environ, **env},
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
    xs = sorted(xs)
    p90 = xs[int(0.9 * (len(xs) - 1))]
    med = statistics.median(xs)
    return f"median {med * 1e3:7.1f} ms  p90 {p90 * 1e3:7.1f} ms  max {xs[-1] * 1e3:7.1f} ms"


def _stream(c: httpx.Client, rid: int, opened: threading.Event, ended: list[float]) -> None:
    with c.stream("GET", f"/robots/{rid}/maps/stream", timeout=30) as r:
        for line in r.iter_lines():
            if line.startswith("event: snapshot"):
                opened.set()
    ended.append(time.perf_counter())


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    p.add_argument("--db", help="database URL or SQLite file [a SQLite temp file]")
    p.add_argument("--rounds", type=int, default=20, help="revocations measured [20]")
    p.add_argument("--requests", type=int, default=2000, help="requests per variant for the cost [2000]")
    args = p.parse_args(argv)
    tmp = tempfile.TemporaryDirectory(prefix="linemap-auth-bench-")
    db = args.db or f"sqlite:///{Path(tmp.name) / 'bench.db'}"
    procs = []
    try:
        a_proc, a, admin = _start(db, {})
        procs.append(a_proc)
        if not admin:
            print("the database is not fresh: no admin token printed", file=sys.stderr)
            return 2
        b_proc, b, _ = _start(db, {})
        c_proc, c, _ = _start(db, {"LINEMAP_CREDENTIAL_CACHE_S": "0"})
        procs += [b_proc, c_proc]
        hdr = {"Authorization": f"Bearer {admin}"}
        with httpx.Client(base_url=a, headers=hdr, timeout=30) as op:
            rid = op.post("/robots", json={"name": "bench-bot"}).json()["id"]
            refused, stream_end = [], []
            for i in range(args.rounds):
                made = op.post("/tokens", json={"name": f"bench-{i}"}).json()
                auth = {"Authorization": f"Bearer {made['token']}"}
                with httpx.Client(base_url=b, headers=auth, timeout=30) as on_b:
                    assert on_b.get("/whoami").status_code == 200  # cached on B now
                    opened, ended = threading.Event(), list[float]()
                    reader = threading.Thread(target=_stream, args=(on_b, rid, opened, ended))
                    reader.start()
                    opened.wait(30)
                    with httpx.Client(base_url=b, headers=auth, timeout=30) as poller:
                        assert poller.get("/whoami").status_code == 200
                        assert op.delete(f"/tokens/{made['id']}").status_code == 204
                        t0 = time.perf_counter()
                        while poller.get("/whoami").status_code != 401:
                            pass
                        refused.append(time.perf_counter() - t0)
                    reader.join(30)
                    stream_end.append(ended[0] - t0 if ended else float("inf"))
        print(f"database: {db.split('://')[0]}, {args.rounds} revocations on A, observed on B")
        print(f"  token refused on B after   {_ms(refused)}")
        print(f"  stream on B ended after    {_ms(stream_end)}")
        times: dict[str, list[float]] = {"B, cache 0.5 s (default)": [], "C, no cache (baseline)": []}
        with httpx.Client(base_url=b, headers=hdr) as cb, httpx.Client(base_url=c, headers=hdr) as cc:
            for _ in range(args.requests):
                for name, client in zip(times, (cb, cc), strict=True):
                    t0 = time.perf_counter()
                    client.get("/whoami")
                    times[name].append(time.perf_counter() - t0)
        base = statistics.median(times["C, no cache (baseline)"])
        print(f"GET /whoami, {args.requests} each, interleaved:")
        for name, ts in times.items():
            med = statistics.median(ts)
            print(f"  {name:28s} median {med * 1e3:6.3f} ms  ({(med - base) * 1e6:+7.1f} us vs no cache)")
        return 0
    except (OSError, AssertionError, httpx.HTTPError) as exc:
        print(f"setup failed: {exc!r}", file=sys.stderr)
        return 2
    finally:
        for proc in procs:
            proc.terminate()
        for proc in procs:
            proc.wait(15)
        tmp.cleanup()


if __name__ == "__main__":
    raise SystemExit(main())
