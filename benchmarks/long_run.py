"""A robot mapping for a day, fast-forwarded (issue 21's 24-hour target; docs/reliability/bounded.md): the
agent's Robot DB and uploader driven at 10 Hz of simulated time against a real ``linemap server`` (SQLite),
with a cheap synthetic map step instead of the sensor and the pipeline.

    .venv/bin/python benchmarks/long_run.py [--hours 1 6 24] [--walls 1500] [--robot-dir DIR] [--loop-closure]

Each step is what the agent records (:meth:`robot_agent.store.RobotDB.record_step`): a map version with
the walls that changed (one new wall every 4 steps until ``--walls``, then 5 walls re-estimated a step),
200 centroids, the pose on a 200 m patrol loop at 0.5 m/s, the scan's journal bytes (682 beams, the
journal's own format) and every 50 steps a saved mapping state (a fixed 256 kB stand-in). Every 5 steps
(the agent's 0.5 s upload period) the real :class:`robot_agent.uploader.Uploader` sends the outbox over
HTTP. At each mark it forces one snapshot upload and measures: the Robot DB's size, the largest upload
so far (snapshots included), ``GET /maps/latest`` (median of 3: time and bytes), the GeoJSON export, the
server database's size and the poses each side keeps. Prints the table; exit 0 when it ran.

``--loop-closure`` adds the pose graph's rows a robot with loop closure records (:class:`StepRecord`'s
``keyframes``, ``loop_closures``, ``pose_covariance``): a keyframe every 0.5 m (each 10 steps), from the
second lap on a loop closure from each keyframe to the one a lap back, and at the end of each lap a
correction moving the last lap's 400 keyframes by 1 mm (what a loop closure's optimisation sends). The
table then also gives the keyframes and closures the latest snapshot and ``/maps/latest`` carried.

The Robot DB goes to ``--robot-dir`` (default: /dev/shm when there is one, so that the per-step fsync of
``synchronous=FULL`` does not set the pace; the sizes are the same on any disk).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import re
import socket
import sqlite3
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import httpx
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from robot_agent.health import ErrorReport  # noqa: E402
from robot_agent.journal import scan_to_bytes  # noqa: E402
from robot_agent.link import ServerLink  # noqa: E402
from robot_agent.store import RobotDB, SavedState, StepRecord  # noqa: E402
from robot_agent.uploader import Uploader  # noqa: E402
from shared.protocol import RobotStatus  # noqa: E402
from shared.types import Pose2D, Scan  # noqa: E402

LINEMAP = str(Path(sys.executable).parent / "linemap")
RATE_HZ = 10.0
STEPS_PER_UPLOAD = 5
STATE_EVERY = 50


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _server(db: Path, port: int, log: Path) -> tuple[subprocess.Popen[str], str]:
    # fast-forwarded time uploads far faster than a robot's 10 Hz: the per-robot upload quota is lifted
    fast = {"LINEMAP_UPLOAD_REQUESTS_PER_S": "1e6", "LINEMAP_UPLOAD_BYTES_PER_S": "1e12"}
    proc = subprocess.Popen(
        [LINEMAP, "server", "--db", str(db), "--port", str(port)],
        env={**os.environ, **fast},
        stdout=subprocess.PIPE,
        stderr=log.open("a"),
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
            if httpx.get(f"http://127.0.0.1:{port}/healthz", timeout=2).status_code == 200 and token:
                threading.Thread(target=proc.stdout.read, daemon=True).start()  # keep its pipe drained
                return proc, token
        except httpx.TransportError:
            time.sleep(0.1)
    raise SystemExit(f"the server did not come up; see {log}")


def _table_rows(db: Path) -> dict[str, int]:
    """Rows per table of the server's SQLite database, the largest first (what grows, if anything)."""
    with contextlib.closing(sqlite3.connect(f"file:{db}?mode=ro", uri=True)) as conn:
        names = [r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type = 'table'")]
        rows = {n: int(conn.execute(f'SELECT count(*) FROM "{n}"').fetchone()[0]) for n in names}
    return dict(sorted(((n, c) for n, c in rows.items() if c), key=lambda kv: -kv[1]))


def _file_bytes(path: Path) -> int:
    return sum(p.stat().st_size for p in (path, Path(f"{path}-wal"), Path(f"{path}-shm")) if p.exists())


class World:
    """The synthetic map: walls appear until ``n_walls``, then a few are re-estimated each step."""

    def __init__(self, n_walls: int, seed: int = 1) -> None:
        self.rng = np.random.default_rng(seed)
        self.n_walls = n_walls
        self.walls: dict[int, list[float]] = {}
        self.beams = np.linspace(0.5, 5.0, 682)

    def wall(self, wid: int) -> list[float]:
        x, y = self.rng.uniform(-60.0, 60.0, 2)
        a = self.rng.uniform(0, np.pi)
        return [float(wid), x, y, x + 2.0 * np.cos(a), y + 2.0 * np.sin(a)]

    def step(self, version: int) -> StepRecord:
        changed: list[list[float]] = []
        if len(self.walls) < self.n_walls and version % 4 == 0:
            wid = len(self.walls)
            self.walls[wid] = self.wall(wid)
            changed.append(self.walls[wid])
        if self.walls:
            for wid in self.rng.integers(0, len(self.walls), 5).tolist():
                row = self.walls[wid]
                self.walls[wid] = [row[0], *(v + float(self.rng.normal(0, 0.002)) for v in row[1:])]
                changed.append(self.walls[wid])
        t = version / RATE_HZ
        cents = self.rng.uniform(-60, 60, (200, 2)).round(3).tolist()
        return StepRecord(version, t, version, changed, [], [t, *_patrol(t)], cents)

    def scan(self, version: int) -> bytes:
        t = version / RATE_HZ
        return scan_to_bytes(Scan(t, -2.09, 0.00614, 0.02, 5.6, self.beams, None, Pose2D(0.0, 0.0, 0.0)))


KEYFRAME_EVERY = 10  # steps: 0.5 m at 0.5 m/s
LAP_STEPS = 4_000  # the 200 m loop at 0.5 m/s, 10 Hz


def with_graph(rec: StepRecord, version: int) -> StepRecord:
    """``rec`` with the pose graph's rows of the synthetic patrol (module docstring): keyframe ``k`` made at
    step ``10 k`` at the step's pose; its closure to keyframe ``k - 400`` from the second lap on; at each
    lap's end the last lap's keyframes moved by 1 mm in y (x, y alternate so every lap moves them again)."""
    keyframes: list[list[float]] = []
    closures: list[list[int]] = []
    if version % KEYFRAME_EVERY == 0:
        k = version // KEYFRAME_EVERY
        keyframes.append([float(k), *rec.pose])
        lap = LAP_STEPS // KEYFRAME_EVERY
        if k > lap:  # keyframe 0 is never made (the first step is 1)
            closures.append([k, k - lap])
    if version % LAP_STEPS == 0 and version > LAP_STEPS:
        shift = 0.001 * (version // LAP_STEPS)
        first = (version - LAP_STEPS) // KEYFRAME_EVERY
        for k in range(first, version // KEYFRAME_EVERY):
            t = k * KEYFRAME_EVERY / RATE_HZ
            keyframes.append([float(k), t, *_patrol(t)[:1], _patrol(t)[1] + shift, _patrol(t)[2]])
    cov = [[1e-4, 0.0, 0.0], [0.0, 1e-4, 0.0], [0.0, 0.0, 1e-5]]
    return replace(rec, keyframes=keyframes, loop_closures=closures, pose_covariance=cov, graph=True)


def _patrol(t: float) -> tuple[float, float, float]:
    """The pose at ``t`` s on the 200 m loop at 0.5 m/s (a 50 m x 50 m square round the origin)."""
    s = (0.5 * t) % 200.0
    side, along = int(s // 50.0), s % 50.0
    x, y, th = [
        (along, 0.0, 0.0),
        (50.0, along, 1.57),
        (50.0 - along, 50.0, 3.14),
        (0.0, 50.0 - along, -1.57),
    ][side]
    return x - 25.0, y - 25.0, th


class _Sender:
    """The uploader's rounds on their own thread, as in the agent: each round sends the oldest
    ``STEPS_PER_UPLOAD`` versions, so the server gets the uploads a robot at 10 Hz makes (one per 0.5 s of
    simulated time) while the next steps are recorded. The recording waits when the outbox holds more
    than ``MAX_BEHIND`` versions (the server sets the pace then, as it would for a robot catching up)."""

    MAX_BEHIND = 100

    def __init__(self, uploader: Uploader, db: RobotDB) -> None:
        self.uploader, self.db = uploader, db
        self._lock = threading.Lock()
        self._cond = threading.Condition()
        self._recorded = self._sent_upto = 0
        self._closed = False
        self.error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="long-run-sender", daemon=True)
        self._thread.start()

    def due(self, version: int) -> None:
        """``version`` is recorded; wait while the outbox is more than ``MAX_BEHIND`` behind."""
        with self._cond:
            self._recorded = version
            self._cond.notify_all()
            self._cond.wait_for(
                lambda: self.error is not None or version - self._sent_upto <= self.MAX_BEHIND
            )
        if self.error is not None:
            raise RuntimeError(f"the upload thread failed: {self.error}") from self.error

    def _run(self) -> None:
        try:
            while True:
                with self._cond:
                    self._cond.wait_for(
                        lambda: self._closed or self._recorded - self._sent_upto >= STEPS_PER_UPLOAD
                    )
                    if self._closed:
                        return
                with self._lock:
                    self.uploader.send_maps()
                    confirmed = int(self.db.get("uploaded_version", 0) or 0)
                with self._cond:
                    self._sent_upto = max(self._sent_upto, confirmed)
                    self._cond.notify_all()
        except BaseException as exc:  # reported to the recording thread
            with self._cond:
                self.error = exc
                self._cond.notify_all()

    @contextlib.contextmanager
    def paused(self) -> Iterator[None]:
        """No round of this thread runs inside (the caller sends its own)."""
        with self._lock:
            yield
            confirmed = int(self.db.get("uploaded_version", 0) or 0)
        with self._cond:
            self._sent_upto = max(self._sent_upto, confirmed)
            self._cond.notify_all()

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()
        self._thread.join(60)


def _latest(client: httpx.Client, rid: int) -> tuple[float, int, dict[str, Any]]:
    times, size, body = [], 0, {}
    for _ in range(3):
        t0 = time.perf_counter()
        r = client.get(f"/api/v1/robots/{rid}/maps/latest")
        times.append(time.perf_counter() - t0)
        r.raise_for_status()
        size, body = len(r.content), r.json()
    return statistics.median(times), size, body


def _export(client: httpx.Client, rid: int) -> tuple[float, int]:
    t0 = time.perf_counter()
    r = client.get(f"/api/v1/robots/{rid}/maps/export", params={"format": "geojson"})
    r.raise_for_status()
    return time.perf_counter() - t0, len(r.content)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--hours", type=float, nargs="+", default=[1.0, 6.0, 24.0], help="marks [1 6 24]")
    ap.add_argument("--walls", type=int, default=1500, help="walls of the synthetic map [1500]")
    shm = Path("/dev/shm")
    ap.add_argument("--robot-dir", type=Path, default=shm if shm.is_dir() else None)
    ap.add_argument("--loop-closure", action="store_true", help="add the pose graph's rows (docstring)")
    args = ap.parse_args()
    marks = sorted(int(h * 3600 * RATE_HZ) for h in args.hours)
    with (
        tempfile.TemporaryDirectory(prefix="linemap-longrun-") as tmp,
        tempfile.TemporaryDirectory(prefix="linemap-longrun-robot-", dir=args.robot_dir) as robot_dir,
    ):
        server_db, port = Path(tmp) / "server.db", _port()
        proc, operator = _server(server_db, port, Path(tmp) / "server.log")
        base = f"http://127.0.0.1:{port}"
        op = httpx.Client(base_url=base, headers={"Authorization": f"Bearer {operator}"}, timeout=60)
        made = op.post("/api/v1/robots", json={"name": "long-run"}).json()
        rid, token = int(made["id"]), str(made["token"])
        db = RobotDB(Path(robot_dir) / "robot.db")
        link = ServerLink(base, rid, token, timeout_s=60)
        sizes: list[int] = []
        sent_keyframes: list[int] = []
        real_upload = link.upload

        def measured(payload: dict[str, Any], key: str) -> Any:
            sizes.append(len(json.dumps(payload, separators=(",", ":")).encode()))
            sent_keyframes.append(len(payload.get("keyframes") or ()))
            return real_upload(payload, key)

        link.upload = measured  # type: ignore[method-assign]
        status = RobotStatus.model_validate({"mode": "online"})
        uploader = Uploader(
            link,
            db,
            lambda: status,
            lambda v: None,
            threading.Event(),
            threading.Event(),
            ErrorReport(),
            robot_id=rid,
        )
        uploader.upload_batch = STEPS_PER_UPLOAD  # what a robot at 10 Hz sends each 0.5 s
        world, state = World(args.walls), b"\x00" * 256 * 1024
        rows: list[dict[str, Any]] = []
        sender = _Sender(uploader, db)
        t_start = time.perf_counter()
        print(f"fast-forwarding {marks[-1]:,} steps at {RATE_HZ:g} Hz of simulated time ...", flush=True)
        progress = max(marks[-1] // 20, 1)
        try:
            for version in range(1, marks[-1] + 1):
                saved = SavedState(version, "bench", 1, 0, state) if version % STATE_EVERY == 0 else None
                rec = world.step(version)
                rec = with_graph(rec, version) if args.loop_closure else rec
                db.record_step(rec, world.scan(version), saved)
                if version % STEPS_PER_UPLOAD == 0:
                    sender.due(version)
                if version % progress == 0:
                    rate = version / (time.perf_counter() - t_start)
                    print(
                        f"  {version:,} steps ({version / RATE_HZ / 3600:.2f} h), {rate:.0f} steps/s",
                        flush=True,
                    )
                if version in marks:
                    # the outbox drained, then one round that sends the whole map: the largest upload
                    with sender.paused():
                        while uploader.send_maps() and db.outbox_size():
                            pass
                        uploader.need_snapshot = True
                        uploader.send_maps()
                    latest_s, latest_b, latest = _latest(op, rid)
                    export_s, export_b = _export(op, rid)
                    rows.append(
                        {
                            "hours": version / RATE_HZ / 3600,
                            "poses": version,
                            "robot_db_mb": db.size_bytes() / 1e6,
                            "max_upload_kib": max(sizes) / 1024,
                            "snapshot_kib": sizes[-1] / 1024,
                            "latest_s": latest_s,
                            "latest_mib": latest_b / 2**20,
                            "export_s": export_s,
                            "export_mib": export_b / 2**20,
                            "server_db_mb": _file_bytes(server_db) / 1e6,
                            "server_wal_mb": _file_bytes(Path(f"{server_db}-wal")) / 1e6,
                            "server_poses": len(latest["trajectory"]),
                            "snapshot_keyframes": sent_keyframes[-1],
                            "server_keyframes": len(latest.get("keyframes") or ()),
                            "server_closures": len(latest.get("loop_closures") or ()),
                            "walls": len(world.walls),
                            "elapsed_s": time.perf_counter() - t_start,
                        }
                    )
                    print(json.dumps({k: round(v, 3) for k, v in rows[-1].items()}), flush=True)
                    print(f"  server rows: {_table_rows(server_db)}", flush=True)
        finally:
            sender.close()
            db.close()
            link.close()
            op.close()
            proc.terminate()
            proc.wait(30)
    print()
    print(
        "| simulated | poses | Robot DB | max upload | snapshot | /maps/latest | export (GeoJSON) "
        "| server DB (of it WAL) | poses kept |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['hours']:g} h | {r['poses']:,} | {r['robot_db_mb']:.1f} MB "
            f"| {r['max_upload_kib']:.0f} KiB "
            f"| {r['snapshot_kib']:.0f} KiB | {r['latest_s'] * 1000:.0f} ms, {r['latest_mib']:.2f} MiB "
            f"| {r['export_s'] * 1000:.0f} ms, {r['export_mib']:.2f} MiB "
            f"| {r['server_db_mb']:.1f} MB ({r['server_wal_mb']:.1f}) "
            f"| {r['server_poses']:,} |"
        )
    if args.loop_closure:
        print("\n| simulated | keyframes made | in the snapshot | held by the server | closures held |")
        print("|---|---|---|---|---|")
        for r in rows:
            print(
                f"| {r['hours']:g} h | {r['poses'] // KEYFRAME_EVERY:,} | {r['snapshot_keyframes']:,} "
                f"| {r['server_keyframes']:,} | {r['server_closures']:,} |"
            )
    print(f"\n{marks[-1]:,} steps in {rows[-1]['elapsed_s']:.0f} s ({args.walls} walls)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
