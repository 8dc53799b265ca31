"""The map upload's write path alone, on SQLite and PostgreSQL in the same run (issue 22 item 3): what the
server's writer does for one upload (:func:`server.mapstore.apply_upload`, the notice to other processes,
the delta log entry), one transaction per upload, in this process, without HTTP. ``--robots`` robots each
send a snapshot, then ``--uploads`` deltas of ``--segments`` walls (ids sliding as in
``benchmarks/server_load.py``: 1/20 of the walls new, as many removed, 5 poses). Prints per backend the
median and p99 wall time of one upload's transaction, its CPU time in this process (thread time: Python,
driver and SQLAlchemy; on PostgreSQL the database's own CPU is in another process and not counted), and
the uploads/s of one writer. ``--stored-poses`` and ``--stored-walls`` give each robot a trajectory and
walls stored before the deltas (the snapshot brings them), as after a while of driving: the costs that grow
with what is stored show there (the trajectory's cap is 8,000 poses).

Usage: ``python benchmarks/write_path.py [--pg postgresql://USER@HOST/DB]`` (the PostgreSQL database is
emptied: its public schema is dropped and made again). Exit 0 when it ran (figures, not pass/fail).
To measure older code in the same run, run it with ``PYTHONPATH`` at that code's tree (docs/fleet-scale.md
alternates the tree before issue 22's write path with this one)."""

from __future__ import annotations

import argparse
import json
import random
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from sqlalchemy import insert, text

from server.database import Database
from server.hub import Hub
from server.maplog import append as log_upload
from server.mapstore import apply_upload
from server.migrate import upgrade
from server.models import Robot
from server.parsepool import parse_upload

try:
    from server.pgrows import pipelined
except ImportError:  # the code before issue 22 item 3 (to measure it with PYTHONPATH at its tree)
    from contextlib import nullcontext as pipelined  # type: ignore[assignment]

_ROBOTS_T: Any = Robot.__table__


def _payloads(
    n_uploads: int, segments: int, seed: int, stored_poses: int = 0, stored_walls: int = 0, moved: float = 0.0
) -> list[bytes]:
    """The snapshot, then ``n_uploads`` deltas; the snapshot also brings ``stored_poses`` poses and
    ``stored_walls`` walls that no delta touches (ids from 10**9): a robot that has run for a while. The
    first ``moved`` share of a delta's walls are moved by k mm since the delta before sent them (the rest
    are sent again as they were, which the server does not write again)."""
    rng = random.Random(seed)
    walls: list[list[float]] = []
    step, out = max(1, segments // 20), []
    for k in range(n_uploads + 1):
        first = k * step
        while len(walls) < first + segments:
            walls.append([float(len(walls)), *(round(rng.uniform(-20, 20), 3) for _ in range(4))])
        body = {
            "version": k + 1,
            "base_version": None if k == 0 else k,
            "stamp_s": k * 0.5,
            "segments": [
                [w[0], *(c + 0.001 * k for c in w[1:])] if j < round(moved * segments) else w
                for j, w in enumerate(walls[first : first + segments])
            ],
            "removed": [] if k == 0 else list(range(max(0, first - step), first)),
            "centroids": [[rng.uniform(-20, 20), rng.uniform(-20, 20)] for _ in range(20)],
            "trajectory": [[k * 0.5 + j * 0.1, 1.0 + j, 2.0, 0.1] for j in range(5)],
            "pose": [1.0, 2.0, 0.1],
            "status": {"mode": "online", "step_ms": 1.2},
        }
        if k == 0:
            body["segments"] = [
                *walls[:segments],
                *([10**9 + i, 0.0, 0.0, 1.0, 1.0] for i in range(stored_walls)),
            ]
            body["trajectory"] = [[j * 1e-5, 0.0, 0.0, 0.0] for j in range(stored_poses)]
        out.append(json.dumps(body).encode())
    return out


def _fresh(url: str, tmp: Path) -> Database:
    if url == "sqlite":
        db = Database(str(tmp / "write_path.db"))
    else:
        db = Database(url)
        with db.engine.begin() as conn:
            conn.execute(text("DROP SCHEMA public CASCADE"))
            conn.execute(text("CREATE SCHEMA public"))
    upgrade(db.engine)
    return db


def measure(
    url: str,
    robots: int,
    uploads: int,
    segments: int,
    tmp: Path,
    stored_poses: int = 0,
    stored_walls: int = 0,
    moved: float = 0.0,
) -> dict[str, Any]:
    """Apply every robot's uploads, robot after robot in turn; the figures of the deltas."""
    db = _fresh(url, tmp)
    hub = Hub(cross_process=not db.is_sqlite)
    ids = []
    with db.write_conn() as conn:
        for i in range(robots):
            r = conn.execute(
                insert(_ROBOTS_T).values(name=f"wp-{i}", token_hash=f"{i:064d}").returning(_ROBOTS_T.c.id)
            )
            ids.append(int(r.scalar_one()))
    bodies = _payloads(uploads, segments, 1, stored_poses, stored_walls, moved)
    wall_s: list[float] = []
    cpu_s: list[float] = []
    for k, raw in enumerate(bodies):
        for rid in ids:
            up = parse_upload(raw, rid, 200_000, 1000.0)
            t0, c0 = time.perf_counter(), time.thread_time()
            with db.write_conn() as conn:
                applied = apply_upload(conn, rid, up, f"version-{up.version}", None, 200_000)
                assert applied.event is not None
                with pipelined(conn):  # as server/routers/maps.py does
                    hub.announce(conn, f"maps:{rid}", up.version)
                    log_upload(conn, rid, applied.event)
            t1, c1 = time.perf_counter(), time.thread_time()
            if k > 0:  # the deltas
                wall_s.append(t1 - t0)
                cpu_s.append(c1 - c0)
    db.dispose()
    wall_s.sort()
    n = len(wall_s)
    return {
        "backend": "sqlite" if url == "sqlite" else "postgresql",
        "deltas": n,
        "wall_ms_median": statistics.median(wall_s) * 1e3,
        "wall_ms_p99": wall_s[min(n - 1, int(0.99 * n))] * 1e3,
        "cpu_ms_median": statistics.median(cpu_s) * 1e3,
        "uploads_per_s_one_writer": n / sum(wall_s),
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    p.add_argument("--pg", help="PostgreSQL URL (emptied); without it SQLite only")
    p.add_argument("--robots", type=int, default=10)
    p.add_argument("--uploads", type=int, default=60, help="deltas per robot")
    p.add_argument("--segments", type=int, default=200)
    p.add_argument(
        "--stored-poses",
        type=int,
        default=0,
        help="poses each robot stores before the deltas (a full trajectory: 7000; the cap is 8000) [0]",
    )
    p.add_argument("--stored-walls", type=int, default=0, help="walls no delta touches, stored before [0]")
    p.add_argument(
        "--moved-share",
        type=float,
        default=0.0,
        help="share of a delta's walls moved since the last (0..1; 1: every wall written) [0]",
    )
    p.add_argument("--json", type=Path, help="also write the figures to this JSON file")
    args = p.parse_args(argv)
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        for url in ["sqlite", *([args.pg] if args.pg else [])]:
            results.append(
                measure(
                    url,
                    args.robots,
                    args.uploads,
                    args.segments,
                    Path(tmp),
                    args.stored_poses,
                    args.stored_walls,
                    args.moved_share,
                )
            )
    keys = list(results[0])
    print(" | ".join(keys))
    for r in results:
        print(" | ".join(f"{r[k]:.2f}" if isinstance(r[k], float) else str(r[k]) for k in keys))
    if args.json:
        args.json.write_text(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
