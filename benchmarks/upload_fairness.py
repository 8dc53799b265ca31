"""Upload fairness benchmark: does one robot at its upload quota, posting near-limit snapshots, slow the
other robots down? One ``linemap server`` (SQLite temp file or ``--db``; its settings from the
``LINEMAP_*`` environment, the defaults otherwise), then ``--rounds`` times: an idle phase (``--robots``
normal robots upload deltas every ``--period-s``) and a heavy phase (the same, plus one robot posting
near-limit snapshots back to back, waiting only what the server's ``Retry-After`` says). Each phase
registers fresh normal robots. Figures: the normal robots' upload latency p50 / p99 and ``/healthz``'s,
idle vs heavy, all from this one run (pooled, and the median of the per-round p99s), and what the heavy
robot got through. Target (docs/reliability/load.md): heavy p99 at most 2x idle p99.

By default every heavy snapshot repeats the same map (only its version changes), which the server writes
as an empty diff against the stored map (server.snapdiff); ``--heavy-changing N`` makes each accepted
snapshot move N walls and extend the trajectory by ``--heavy-extend-poses`` poses, as a mapping robot's
snapshots do.

Reuses :mod:`benchmarks.server_load` (the server process, the normal robots' uploader and payloads). Exit 0
when it ran (figures, not pass/fail), 2 when the setup failed. ``--help`` for the options."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import logging
import os
import signal
import statistics
import sys
import tempfile
import threading
import time
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import httpx
import numpy as np
from rich.console import Console
from rich.logging import RichHandler
from rich.table import Table

if __package__ in (None, ""):  # run as a script: benchmarks/ is not a package on sys.path then
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.server_load import API, Config, Load, Robot, Server, SetupError, nearest_rank

__all__ = ["FairConfig", "HeavyBody", "HeavyStats", "Phase", "main", "measure"]

log = logging.getLogger("upload_fairness")
#: Heavy uploads accepted in a row after which the server is taken to have no quota (the default burst,
#: 8 MiB, passes two 3.7 MB snapshots).
NO_QUOTA_AFTER = 4


@dataclass(frozen=True, slots=True)
class FairConfig:
    db: str | None = None
    robots: int = field(default=20, metadata={"help": "normal robots per phase"})
    period_s: float = field(default=0.5, metadata={"help": "upload period of each normal robot (s)"})
    segments: int = field(default=200, metadata={"help": "walls per normal upload"})
    phase_s: float = field(default=20.0, metadata={"help": "length of each idle and heavy phase (s)"})
    rounds: int = field(default=3, metadata={"help": "idle + heavy phase pairs"})
    heavy_walls: int = field(default=20_000, metadata={"help": "walls in each heavy snapshot"})
    heavy_bytes: int = field(default=3_700_000, metadata={"help": "size of each heavy snapshot (bytes)"})
    heavy_changing: int = field(
        default=0, metadata={"help": "walls each accepted heavy snapshot moves (0: identical snapshots)"}
    )
    heavy_extend_poses: int = field(
        default=150, metadata={"help": "poses each accepted heavy snapshot adds (with --heavy-changing)"}
    )
    port: int = field(default=0, metadata={"help": "server port (0: a free one)"})


@dataclass
class HeavyStats:
    accepted: int = 0
    refused_429: int = 0
    other: dict[str, int] = field(default_factory=dict)
    accepted_bytes: int = 0
    busy_s: float = 0.0  # the phase's length, for the rates
    upload_s: list[float] = field(default_factory=list)


@dataclass
class Phase:
    kind: str  # idle | heavy
    upload_s: list[float]
    healthz_s: list[float]
    errors: dict[str, int]
    heavy: HeavyStats | None = None


class HeavyBody:
    """The heavy robot's snapshot of each version, pre-encoded (the client must not spend its own event
    loop on 4 MB of JSON while it measures the others): ``walls`` walls and trajectory poses up to about
    ``size_bytes`` at version 1. With ``changing`` > 0, version v moves walls ``[v * changing, (v + 1) *
    changing)`` (modulo ``walls``; earlier moves stay) and has ``extend * (v - 1)`` poses more than
    version 1: against the stored map of version v - 1, ``changing`` walls and ``extend`` poses differ.
    With 0, every version has the same map."""

    def __init__(self, walls: int, size_bytes: int, changing: int = 0, extend: int = 150) -> None:
        self.walls, self.changing, self.extend = walls, changing, extend
        self._wall_text = [self._wall(i, 0) for i in range(walls)]
        self._now, self._at = list(self._wall_text), 0  # the walls as of version _at
        budget = size_bytes - len(b",".join(self._wall_text)) - 100  # for the poses of version 1
        text: list[bytes] = []
        while budget > 0 and (pose := self._pose(len(text))):
            text.append(pose)
            budget -= len(pose) + 1
        self._poses0 = len(text)
        text += [self._pose(j) for j in range(len(text), len(text) + (extend * 1000 if changing else 0))]
        self._traj = b",".join(text)
        self._ends = [0, *np.cumsum([len(t) + 1 for t in text]).tolist()]  # poses[:n] end at _ends[n] - 1

    @staticmethod
    def _wall(i: int, version: int) -> bytes:
        y = 1.0 + 0.001 * (version % 1000)
        return f"[{i}.0,{i * 0.01:.2f},{y:.3f},{i * 0.01 + 0.5:.2f},2.0]".encode()

    @staticmethod
    def _pose(j: int) -> bytes:
        return f"[{0.1 * j:.1f},12.345,23.456,0.123]".encode()

    def content(self, version: int) -> bytes:
        """The body of snapshot ``version`` (>= 1)."""
        if version < self._at:  # versions only grow, but start again if not
            self._at, self._now = 0, list(self._wall_text)
        for v in range(self._at + 1, version + 1):  # the moves of every version up to this one
            for k in range(v * self.changing, (v + 1) * self.changing):
                self._now[k % self.walls] = self._wall(k % self.walls, v)
        self._at = max(self._at, version)
        walls = self._now
        n = min(self._poses0 + self.extend * (version - 1), len(self._ends) - 1)
        traj = self._traj[: max(0, self._ends[n] - 1)]
        return b'{"version":%d,"base_version":null,"stamp_s":1.0,"segments":[%s],"trajectory":[%s]}' % (
            version,
            b",".join(walls),
            traj,
        )

    def size(self) -> int:
        return len(self.content(1))


def _heavy_robot(
    base: str,
    robot_id: int,
    token: str,
    body: HeavyBody,
    end: list[float],
    drained: threading.Event,
) -> HeavyStats:
    """Back-to-back near-limit snapshots until ``end[0]`` (perf_counter; set by the caller once
    ``drained``), waiting only the server's Retry-After after a 429: the robot runs at its quota.
    ``drained`` is set at the first 429 (its burst is spent: from then on it is at its sustained quota),
    or after ``NO_QUOTA_AFTER`` uploads accepted back to back (a server without quotas).
    In a thread with its own client."""
    stats, version, drained_at = HeavyStats(), 1, time.perf_counter()
    url = f"{base}{API}/robots/{robot_id}/maps"
    headers = {"Authorization": f"Bearer {token}", "Content-Type": "application/json"}
    with httpx.Client(timeout=60.0) as client:
        while (now := time.perf_counter()) < end[0]:
            content = body.content(version)
            try:
                r = client.post(url, content=content, headers=headers)
            except httpx.HTTPError as exc:
                stats.other[type(exc).__name__] = stats.other.get(type(exc).__name__, 0) + 1
                continue
            if r.status_code == 200:
                if not drained.is_set() and stats.accepted + 1 >= NO_QUOTA_AFTER:  # a server without quotas
                    stats, drained_at = HeavyStats(), time.perf_counter()
                    drained.set()
                stats.accepted += 1
                stats.accepted_bytes += len(content)
                stats.upload_s.append(time.perf_counter() - now)
                version += 1
            elif r.status_code == 429:
                if drained.is_set():
                    stats.refused_429 += 1
                else:  # the burst is spent: the measured part starts now
                    stats, drained_at = HeavyStats(), time.perf_counter()
                    drained.set()
                wait_s = float(r.headers.get("Retry-After", "1"))
                time.sleep(max(0.0, min(wait_s, end[0] - time.perf_counter())))  # what a robot is told to do
            elif r.status_code == 409:
                version = int(r.json().get("current_version", version)) + 1
            else:
                key = f"HTTP {r.status_code}"
                stats.other[key] = stats.other.get(key, 0) + 1
                if len(stats.other) == 1 and stats.other[key] == 1:
                    log.warning("heavy upload refused: %s %s", r.status_code, r.text[:300])
    drained.set()  # also when it never met its quota
    stats.busy_s = time.perf_counter() - drained_at
    return stats


async def _healthz(base: str, end: float, out: list[float], every_s: float = 0.1) -> None:
    async with httpx.AsyncClient(timeout=30.0) as client:
        while (now := time.perf_counter()) < end:
            with contextlib.suppress(httpx.HTTPError):
                r = await client.get(f"{base}/healthz")
                if r.status_code == 200:
                    out.append(time.perf_counter() - now)
            await asyncio.sleep(max(0.0, every_s - (time.perf_counter() - now)))


async def _phase(cfg: FairConfig, base: str, load: Load, heavy: tuple[int, str, HeavyBody] | None) -> Phase:
    """One phase: the normal robots' uploaders (server_load's), /healthz probes, and the heavy robot."""
    healthz: list[float] = []
    async with contextlib.AsyncExitStack() as stack:
        clients = [await stack.enter_async_context(httpx.AsyncClient(timeout=60.0)) for _ in load.robots]
        thread_result: list[HeavyStats] = []
        thread, end, drained = None, [float("inf")], threading.Event()
        if heavy is not None:
            rid, token, body = heavy
            thread = threading.Thread(
                target=lambda: thread_result.append(_heavy_robot(base, rid, token, body, end, drained)),
                name="heavy-robot",
                daemon=True,
            )
            thread.start()
            await asyncio.to_thread(drained.wait, 300.0)  # its burst spent: at its sustained quota now
        load.t0 = time.perf_counter()
        load.end = end[0] = load.t0 + cfg.phase_s
        await asyncio.gather(
            *(load.uploader(r, c) for r, c in zip(load.robots, clients, strict=True)),
            _healthz(base, load.end, healthz),
        )
        if thread is not None:
            await asyncio.to_thread(thread.join, 120.0)
    return Phase(
        "idle" if heavy is None else "heavy",
        load.res.upload_s,
        healthz,
        load.res.errors,
        thread_result[0] if thread_result else None,
    )


def _register(base: str, admin: str, n: int, tag: str) -> list[Robot]:
    """``n`` new robots named ``tag-<i>`` (fresh ones for each phase)."""
    with httpx.Client(base_url=base + API, headers={"Authorization": f"Bearer {admin}"}, timeout=30) as c:
        made = [c.post("/robots", json={"name": f"{tag}-{i}"}).raise_for_status().json() for i in range(n)]
    return [Robot(int(r["id"]), str(r["token"])) for r in made]


def measure(cfg: FairConfig) -> list[Phase]:
    """Start the server, run the rounds, stop it: the phases in order. Raises :class:`SetupError`."""
    phases: list[Phase] = []
    body = HeavyBody(cfg.heavy_walls, cfg.heavy_bytes, cfg.heavy_changing, cfg.heavy_extend_poses)
    log.info("heavy snapshot: %d walls, %.2f MB", cfg.heavy_walls, body.size() / 1e6)
    with tempfile.TemporaryDirectory(prefix="linemap-fair-") as tmp:
        db = cfg.db or f"sqlite:///{Path(tmp) / 'server.db'}"
        server = Server(db, cfg.port, Path(tmp))
        try:
            admin = server.start()
            load_cfg = Config(robots=cfg.robots, period_s=cfg.period_s, segments=cfg.segments)
            tag = f"fair-{os.getpid()}-{int(time.time())}"
            heavy_robot = _register(server.base, admin, 1, f"{tag}-heavy")[0]
            for k in range(cfg.rounds):
                for kind in ("idle", "heavy"):
                    load = Load(load_cfg, server.base, admin)
                    load.robots = _register(server.base, admin, cfg.robots, f"{tag}-{k}-{kind}")
                    spec = (heavy_robot.id, heavy_robot.token, body) if kind == "heavy" else None
                    phases.append(asyncio.run(_phase(cfg, server.base, load, spec)))
                    log.info("round %d %s: %d uploads", k + 1, kind, len(phases[-1].upload_s))
            if server.proc is not None and server.proc.poll() is not None:
                raise SetupError(f"server died during the load: {server.tail()}")
        except (httpx.HTTPError, OSError, TimeoutError) as exc:
            raise SetupError(f"{type(exc).__name__}: {exc}") from exc
        finally:
            server.stop()
    return phases


def _ms(xs: list[float], q: float) -> float | None:
    v = nearest_rank(xs, q)
    return None if v is None else round(1000 * v, 1)


def report(cfg: FairConfig, phases: list[Phase]) -> tuple[dict[str, Any], Table]:
    """The figures as JSON and as a table (idle vs heavy, pooled and median of the rounds)."""
    data: dict[str, Any] = {"config": asdict(cfg) | {"db": cfg.db.split("://")[0] if cfg.db else "sqlite"}}
    for kind in ("idle", "heavy"):
        mine = [p for p in phases if p.kind == kind]
        ups = [x for p in mine for x in p.upload_s]
        hz = [x for p in mine for x in p.healthz_s]
        per_round = [_ms(p.upload_s, 99) for p in mine]
        data[kind] = {
            "uploads": len(ups),
            "errors": sum(sum(p.errors.values()) for p in mine),
            "upload_p50_ms": _ms(ups, 50),
            "upload_p99_ms": _ms(ups, 99),
            "upload_p99_ms_by_round": per_round,
            "upload_p99_ms_median_of_rounds": statistics.median(
                [v for v in per_round if v is not None] or [0]
            ),
            "healthz_p50_ms": _ms(hz, 50),
            "healthz_p99_ms": _ms(hz, 99),
        }
    heavy = [p.heavy for p in phases if p.heavy is not None]
    busy = sum(h.busy_s for h in heavy) or float("nan")
    data["heavy_robot"] = {
        "accepted": sum(h.accepted for h in heavy),
        "refused_429": sum(h.refused_429 for h in heavy),
        "other": {k: sum(h.other.get(k, 0) for h in heavy) for h in heavy for k in h.other},
        "accepted_bytes_per_s": round(sum(h.accepted_bytes for h in heavy) / busy),
        "upload_p50_ms": _ms([x for h in heavy for x in h.upload_s], 50),
    }
    idle, hv = data["idle"], data["heavy"]
    ratio = (hv["upload_p99_ms"] or 0) / (idle["upload_p99_ms"] or float("nan"))
    ratio_med = hv["upload_p99_ms_median_of_rounds"] / (
        idle["upload_p99_ms_median_of_rounds"] or float("nan")
    )
    data["p99_ratio_pooled"], data["p99_ratio_median_of_rounds"] = round(ratio, 2), round(ratio_med, 2)
    title = (
        f"upload fairness: {cfg.robots} robots x {cfg.period_s:g} s + 1 heavy robot "
        f"({cfg.heavy_walls} walls, {cfg.heavy_bytes / 1e6:.1f} MB snapshots, {cfg.heavy_changing} walls "
        f"moved and {cfg.heavy_extend_poses if cfg.heavy_changing else 0} poses added each), {cfg.rounds} x "
        f"{cfg.phase_s:g} s per phase, {data['config']['db']}"
    )
    table = Table(title=title)
    for name in ("figure", "idle", "heavy", "target"):
        table.add_column(name, justify="left" if name == "figure" else "right")
    rows = [
        ("others' uploads (n)", "uploads", ""),
        ("others' errors", "errors", "0"),
        ("others' upload p50 (ms)", "upload_p50_ms", ""),
        ("others' upload p99 (ms, pooled)", "upload_p99_ms", "heavy <= 2x idle"),
        ("others' upload p99 (ms, median of rounds)", "upload_p99_ms_median_of_rounds", "heavy <= 2x idle"),
        ("/healthz p50 (ms)", "healthz_p50_ms", ""),
        ("/healthz p99 (ms)", "healthz_p99_ms", ""),
    ]
    for label, key, target in rows:
        table.add_row(label, *(str(data[k][key]) for k in ("idle", "heavy")), target)
    table.add_row("p99 heavy / idle (pooled; median of rounds)", "", f"{ratio:.2f}; {ratio_med:.2f}", "<= 2")
    h = data["heavy_robot"]
    table.add_row(
        "heavy robot: accepted / 429 / bytes/s",
        "",
        f"{h['accepted']} / {h['refused_429']} / {h['accepted_bytes_per_s']}",
        "at quota",
    )
    return data, table


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    p.add_argument("--db", help="database URL (default: a fresh SQLite file in a temporary directory)")
    for f in fields(FairConfig)[1:]:
        name, default = f"--{f.name.replace('_', '-')}", f.default
        p.add_argument(name, type=type(default), default=default, help=f"{f.metadata['help']} [{default}]")
    p.add_argument("--json", type=Path, help="also write the figures to this JSON file")
    p.add_argument("-v", "--verbose", action="store_true", help="log the setup steps")
    a = p.parse_args(argv)
    console, handler = Console(), RichHandler(console=Console(stderr=True), show_path=False)
    logging.basicConfig(
        level=logging.INFO if a.verbose else logging.WARNING, handlers=[handler], format="%(message)s"
    )
    logging.getLogger("httpx").setLevel(logging.WARNING)
    if min(a.robots, a.period_s, a.phase_s, a.rounds, a.heavy_bytes) <= 0 or a.heavy_walls < 0:
        p.error("--robots, --period-s, --phase-s, --rounds and --heavy-bytes must be positive")
    if a.heavy_changing < 0 or a.heavy_extend_poses < 0 or a.heavy_changing > a.heavy_walls:
        p.error("--heavy-changing must be within 0..--heavy-walls, --heavy-extend-poses at least 0")
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    cfg = FairConfig(**{f.name: getattr(a, f.name) for f in fields(FairConfig)})
    try:
        data, table = report(cfg, measure(cfg))
    except SetupError as exc:
        console.print(f"setup failed: {exc}", soft_wrap=True, markup=False)
        return 2
    except KeyboardInterrupt:
        console.print("interrupted: server stopped")
        return 130
    console.print(table)
    if a.json:
        a.json.write_text(json.dumps(data, indent=2) + "\n")
    log.info(
        "settings from the environment: %s", {k: v for k, v in os.environ.items() if k.startswith("LINEMAP_")}
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
