"""Fleet load across several server processes on one PostgreSQL database (issue 22; docs/reliability/
fanout.md):
:mod:`benchmarks.server_load`'s simulated robots spread over ``--processes`` real ``linemap server``
processes (robot i on process i mod n), the operator's control messages and robot 0's live-map viewer on
the *next* process (so both latencies cross processes through LISTEN/NOTIFY), the load generator in this
process. With ``--kill-at-s T``, process 0 is killed with SIGKILL T s into the load: its robots move to the
next process on their first transport error (as the agent's link does with a list of server URLs) and
resend the upload that got no answer with its idempotency key.

Figures: server_load's table (uploads, errors, latencies; server CPU summed over the processes alive at the
end, RSS the largest of theirs), and after a kill: how long each robot of the
killed process took to upload again (median, max, share within 5 s), and from the database, per robot, the
accepted uploads as a chain: a version accepted twice, or a delta whose base is not the version before it
(a lost version), counts. Makes a fresh database on the server of ``--postgres`` (dropped afterwards).
Exit 0 when it ran (figures, not pass/fail), 2 when the setup failed.

    .venv/bin/python benchmarks/fleet_load.py --postgres postgresql://postgres@127.0.0.1:5432/postgres \\
        --processes 2 --robots 100 --period-s 0.5 --duration-s 60 --kill-at-s 30
"""

from __future__ import annotations

import argparse
import asyncio
import itertools
import json
import os
import signal
import statistics
import sys
import tempfile
import time
import uuid
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.progress import Progress
from sqlalchemy import create_engine, text
from sqlalchemy.engine import make_url

from benchmarks.server_load import Config, Load, Server, SetupError, report

__all__ = ["Chains", "chains", "fresh_postgres", "main"]

RECOVERY_TARGET_S = 5.0


@dataclass(frozen=True)
class Chains:
    """What the database accepted, over all robots: uploads, versions accepted twice, deltas whose base was
    not the version accepted before them (a version lost between them)."""

    uploads: int
    repeated: int
    broken: int


def chains(rows: Sequence[tuple[int, int, int | None]]) -> Chains:
    """``rows``: (robot_id, version, base_version) in the order accepted. O(n)."""
    repeated = broken = 0
    for _, group in itertools.groupby(rows, key=lambda r: r[0]):
        seen: set[int] = set()
        prev: int | None = None
        for _, version, base in group:
            if version in seen:  # applied again (counted once, not also as a break of the chain)
                repeated += 1
                continue
            broken += base is not None and prev is not None and base != prev
            seen.add(version)
            prev = version
    return Chains(len(rows), repeated, broken)


@contextmanager
def fresh_postgres(server_url: str, prefix: str = "lm_fleet") -> Iterator[str]:
    """A new database on the PostgreSQL server of ``server_url`` (dropped afterwards; also the tests' way to
    a database no one else uses: tests/server/procs.py)."""
    name = f"{prefix}_{uuid.uuid4().hex[:10]}"
    admin = create_engine(
        make_url(server_url).set(drivername="postgresql+psycopg"), isolation_level="AUTOCOMMIT"
    )
    with admin.connect() as conn:
        conn.execute(text(f'CREATE DATABASE "{name}"'))
    try:
        yield make_url(server_url).set(database=name).render_as_string(hide_password=False)
    finally:
        with admin.connect() as conn:
            conn.execute(text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
        admin.dispose()


def accepted(db: str) -> list[tuple[int, int, int | None]]:
    engine = create_engine(make_url(db).set(drivername="postgresql+psycopg"))
    try:
        with engine.connect() as conn:
            q = "SELECT robot_id, version, base_version FROM map_uploads ORDER BY robot_id, id"
            return [(int(r), int(v), None if b is None else int(b)) for r, v, b in conn.execute(text(q))]
    finally:
        engine.dispose()


async def _run(load: Load, servers: list[Server], kill_at_s: float, progress: Progress) -> float | None:
    """The load, and the kill of process 0 ``kill_at_s`` into it (0: none); the kill's perf_counter."""
    killed: list[float] = []

    async def killer() -> None:
        while not load.t0:
            await asyncio.sleep(0.05)
        await asyncio.sleep(max(0.0, load.t0 + kill_at_s - time.perf_counter()))
        proc = servers[0].proc
        assert proc is not None
        proc.send_signal(signal.SIGKILL)
        killed.append(time.perf_counter())

    task = asyncio.create_task(killer()) if kill_at_s > 0 else None
    await load.run(progress)
    if task is not None:
        await task
    return killed[0] if killed else None


def measure(cfg: Config, postgres: str, processes: int, kill_at_s: float, console: Console) -> dict[str, Any]:
    with fresh_postgres(postgres) as db, tempfile.TemporaryDirectory(prefix="linemap-fleet-") as tmp:
        servers = [Server(db, 0, Path(tmp) / f"p{i}") for i in range(processes)]
        for s in servers:
            s.out.parent.mkdir()
        try:
            admin = servers[0].start()
            for s in servers[1:]:
                try:
                    s.start()
                except SetupError as exc:  # no token (the database is not fresh for it): healthy is enough
                    if "operator token" not in str(exc):
                        raise
            load = Load(cfg, [s.base for s in servers], admin)
            load.register()
            cpu0 = [s.usage()[0] for s in servers]
            with Progress(console=console, transient=True) as progress:
                kill_t = asyncio.run(_run(load, servers, kill_at_s, progress))
            alive = [(s, c) for s, c in zip(servers, cpu0, strict=True) if s.proc and s.proc.poll() is None]
            used = [(s.usage(), c) for s, c in alive]  # the surviving processes' CPU and memory
            load.res.cpu_s = (sum(u[0] - c for u, c in used), load.res.cpu_s[1])
            load.res.server_kb = (max(u[1] for u, _ in used), max(u[2] for u, _ in used))
            data, table = report(cfg, load.res, f"PostgreSQL, {processes} processes")
            console.print(table)
        finally:
            for s in servers:
                s.stop()
        data["processes"] = processes
        if kill_t is not None:
            moved = [r for i, r in enumerate(load.robots) if i % processes == 0]  # homed on process 0
            again = [next((t - kill_t for t in r.uploads_at if t > kill_t), float("inf")) for r in moved]
            within = sum(1 for s in again if s <= RECOVERY_TARGET_S)
            finite = [s for s in again if s != float("inf")]
            data["kill"] = {
                "at_s": kill_at_s,
                "robots_on_killed_process": len(moved),
                "uploading_again_within_5_s": within,
                "again_median_s": round(statistics.median(finite), 3) if finite else None,
                "again_max_s": round(max(again), 3) if again else None,
            }
        found = chains(accepted(db))
        data["accepted"] = {"uploads": found.uploads, "repeated": found.repeated, "lost": found.broken}
        return data


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    p.add_argument("--postgres", default=os.environ.get("LINEMAP_TEST_POSTGRES_URL", ""))
    p.add_argument("--processes", type=int, default=2, help="server processes [2]")
    p.add_argument("--robots", type=int, default=100, help="simulated robots [100]")
    p.add_argument("--period-s", type=float, default=0.5, help="upload period of each robot, s [0.5]")
    p.add_argument("--duration-s", type=float, default=60.0, help="length of the load, s [60]")
    p.add_argument("--segments", type=int, default=200, help="walls per upload [200]")
    p.add_argument("--messages", type=int, default=50, help="control messages during the load [50]")
    p.add_argument(
        "--kill-at-s", type=float, default=0.0, help="SIGKILL process 0 this far into the load [0: no]"
    )
    p.add_argument(
        "--moved-share",
        type=float,
        default=0.0,
        help="share of each delta's walls moved since the robot last sent them (server_load.py) [0]",
    )
    p.add_argument("--stored-poses", type=int, default=0, help="poses each map holds before the load [0]")
    p.add_argument("--json", type=Path, help="also write the figures to this JSON file")
    a = p.parse_args(argv)
    if not a.postgres:
        p.error("--postgres (or LINEMAP_TEST_POSTGRES_URL) is needed: several processes need PostgreSQL")
    if a.processes < 1 or min(a.robots, a.period_s, a.duration_s, a.segments) <= 0:
        p.error("--processes, --robots, --period-s, --duration-s and --segments must be positive")
    if not 0 <= a.moved_share <= 1 or a.stored_poses < 0:
        p.error("--moved-share must be a share in 0..1 and --stored-poses at least 0")
    if a.kill_at_s and (a.processes < 2 or not 0 < a.kill_at_s < a.duration_s):
        p.error("--kill-at-s needs --processes >= 2 and a time within the load")
    cfg = Config(
        robots=a.robots,
        period_s=a.period_s,
        duration_s=a.duration_s,
        segments=a.segments,
        messages=a.messages,
        moved_share=a.moved_share,
        stored_poses=a.stored_poses,
    )
    console = Console()
    try:
        data = measure(cfg, a.postgres, a.processes, a.kill_at_s, console)
    except SetupError as exc:
        console.print(f"setup failed: {exc}", soft_wrap=True, markup=False)
        return 2
    console.print_json(json.dumps({k: data[k] for k in ("processes", "accepted", "kill") if k in data}))
    if a.json:
        a.json.write_text(json.dumps(data, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
