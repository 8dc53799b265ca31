"""Map identity figure (docs/reliability/identity.md): what a new map session costs the server when it keeps
the old map, against a snapshot that replaces the map in the same session.

    .venv/bin/python benchmarks/map_session_switch.py [--walls 20000] [--poses 20000] [--runs 5]

A real server (uvicorn on 127.0.0.1, a fresh SQLite file). Per run: a robot uploads a map of ``--walls``
walls and ``--poses`` poses, then a one-wall snapshot of the same session (the map replaced: its rows
deleted); then the big map again, and a one-wall snapshot of a new session (the old map first moved to the
session archive by INSERT ... SELECT). Prints the median round trip of each kind of one-wall snapshot.
Exit 0 when it ran.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
import uuid
from pathlib import Path
from typing import Any

import httpx

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tests.server.live import start_live


def _snapshot(session: str, version: int, walls: int, poses: int) -> dict[str, Any]:
    return {
        "map_session": session,
        "version": version,
        "segments": [
            [i, float(i % 100), (i // 100) * 0.1, float(i % 100) + 0.5, (i // 100) * 0.1]
            for i in range(walls)
        ],
        "trajectory": [[0.01 * k, 0.0, 0.0, 0.0] for k in range(poses)],
    }


def _timed(client: httpx.Client, path: str, body: dict[str, Any]) -> float:
    started = time.perf_counter()
    r = client.post(path, json=body)
    took = time.perf_counter() - started
    if r.status_code != 200:
        raise SystemExit(f"upload refused: HTTP {r.status_code} {r.text[:300]}")
    return took


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--walls", type=int, default=20_000)
    ap.add_argument("--poses", type=int, default=20_000)
    ap.add_argument("--runs", type=int, default=5)
    args = ap.parse_args()
    gen = start_live(
        "sqlite", Path(tempfile.mkdtemp(prefix="linemap-switch-")), max_body_bytes=8 * 1024 * 1024
    )
    live = next(gen)
    same, switch = [], []
    try:
        for _ in range(args.runs):
            rid, token = live.new_robot()
            headers = {"Authorization": f"Bearer {token}"}
            with httpx.Client(base_url=live.base_url + "/api/v1", headers=headers, timeout=120) as c:
                path = f"/robots/{rid}/maps"
                first = str(uuid.uuid4())
                _timed(c, path, _snapshot(first, 10, args.walls, args.poses))
                same.append(_timed(c, path, _snapshot(first, 11, 1, 1)))
                _timed(c, path, _snapshot(first, 12, args.walls, args.poses))
                switch.append(_timed(c, path, _snapshot(str(uuid.uuid4()), 1, 1, 1)))
    finally:
        gen.close()
    print(
        f"stored map of {args.walls} walls and {args.poses} poses, {args.runs} runs: one-wall snapshot in "
        f"the same session (map replaced) median {statistics.median(same) * 1e3:.1f} ms; of a new session "
        f"(old map kept) median {statistics.median(switch) * 1e3:.1f} ms"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
