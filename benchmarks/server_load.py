"""Server load benchmark (docs/reliability/load.md): ``linemap server`` in its own process (SQLite temp file
or ``--db``); here, simulated robots long-poll and upload map deltas, the operator posts control messages to
long-polling robots and follows robot 0's map stream. Exit 0 when it ran (figures, not pass/fail), 2 when the
setup failed. Latencies: upload sent -> response; message POST sent -> the robot's poll returns it; upload
sent -> its SSE event parsed. The server's RSS is sampled every ``sample_s`` during the load. ``--help`` for
the options. :func:`measure` is the reusable part (the reliability soak runs it for 10 min:
tests/reliability/test_rel_soak_load.py)."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import logging
import math
import os
import random
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Awaitable, Callable
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import httpx
from rich.console import Console
from rich.logging import RichHandler
from rich.progress import Progress
from rich.table import Table

__all__ = ["Config", "Results", "Server", "SetupError", "main", "measure", "nearest_rank", "run"]

log = logging.getLogger("server_load")
API = "/api/v1"
TOKEN_MARK = "(shown once, keep it): "
MESSAGE_XML = b"<xml><message><mode>online</mode></message></xml>"
LONG_POLL_S = 20.0
#: the start-up burst (every robot's first upload, the server's caches and pools filling), reported apart
START_S = 5.0
STATUS = {"pose": [1.0, 2.0, 0.1], "status": {"mode": "online", "step_ms": 1.2}}


class SetupError(Exception):
    """The benchmark could not start (server, database, registration): reported in one line, exit 2."""


@dataclass(frozen=True, slots=True)
class Config:
    db: str | None = None
    robots: int = field(default=100, metadata={"help": "simulated robots"})
    period_s: float = field(default=0.5, metadata={"help": "upload period of each robot (s)"})
    duration_s: float = field(default=60.0, metadata={"help": "length of the load (s)"})
    segments: int = field(default=200, metadata={"help": "walls per upload"})
    messages: int = field(default=50, metadata={"help": "control messages posted during the load"})
    port: int = field(default=0, metadata={"help": "server port (0: a free one)"})
    sample_s: float = field(default=5.0, metadata={"help": "period of the server RSS samples (s)"})
    moved_share: float = field(
        default=0.0,
        metadata={
            "help": "share of each delta's walls moved since the robot last sent them (0..1); the others are "
            "sent again as they were, which the server does not write again; 1: every wall written"
        },
    )
    stored_poses: int = field(
        default=0,
        metadata={
            "help": "poses each robot's map holds before the load, sent in a snapshot first (a robot "
            "that has driven a while; the server keeps at most 8000)"
        },
    )


@dataclass
class Results:
    """Latencies and CPU times in seconds; errors by kind (upload, long-poll, message, sse). Times of
    uploads and samples are seconds since the load started (``t0``)."""

    upload_s: list[float] = field(default_factory=list)
    upload_at_s: list[float] = field(default_factory=list)  # when each upload of upload_s was sent
    message_s: list[float] = field(default_factory=list)
    sse_s: list[float] = field(default_factory=list)
    errors: dict[str, int] = field(default_factory=dict)
    skipped_slots: int = 0  # upload slots skipped because the robot's previous upload took > 1 period
    skipped_messages: int = 0  # control messages not posted: the operator fell behind the load's end
    elapsed_s: float = 0.0
    cpu_s: tuple[float, float] = (0.0, 0.0)  # server, this process
    server_kb: tuple[int, int] = (0, 0)  # RSS at the end, peak RSS
    rss_samples: list[tuple[float, int]] = field(default_factory=list)  # (time, server RSS kB)

    def error(self, kind: str, what: str) -> None:
        self.errors[kind] = self.errors.get(kind, 0) + 1
        if sum(self.errors.values()) <= 10:  # the first few in full, then only the counts
            log.warning("%s error: %s", kind, what)


class Server:
    """``linemap server`` in its own process and session (a Ctrl-C reaches only us: we stop it in order)."""

    def __init__(self, db_url: str, port: int, workdir: Path) -> None:
        if not port:
            with socket.socket() as sock:
                sock.bind(("127.0.0.1", 0))
                port = int(sock.getsockname()[1])
        self.base = f"http://127.0.0.1:{port}"
        self.out, self.err = workdir / "server.out", workdir / "server.err"
        exe = Path(sys.executable).parent / "linemap"  # else on PATH (FileNotFoundError: a setup failure)
        args = ["server", "--db", db_url, "--host", "127.0.0.1", "--port", str(port)]
        self.cmd = [str(exe) if exe.exists() else "linemap", *args]
        self.proc: subprocess.Popen[bytes] | None = None

    def tail(self) -> str:
        text = " ".join(self.err.read_text(errors="replace").split())  # one line: its end
        return text[-300:] if text else "(no output)"

    def start(self, timeout_s: float = 60.0) -> str:
        """Start the server, wait for /healthz; the first-start operator token it printed."""
        with self.out.open("wb") as out, self.err.open("wb") as err:
            env = {**os.environ, "PYTHONUNBUFFERED": "1"}
            self.proc = subprocess.Popen(self.cmd, stdout=out, stderr=err, env=env, start_new_session=True)
        log.info("server pid %d: %s", self.proc.pid, " ".join(self.cmd))
        deadline = time.monotonic() + timeout_s
        while self.proc.poll() is None and time.monotonic() < deadline:
            with contextlib.suppress(httpx.HTTPError):
                if httpx.get(f"{self.base}/healthz", timeout=2.0).status_code == 200:
                    break
            time.sleep(0.1)
        else:
            raise SetupError(f"server not healthy (exit code {self.proc.poll()}): {self.tail()}")
        for line in self.out.read_text(errors="replace").splitlines():
            if TOKEN_MARK in line:
                return line.split(TOKEN_MARK, 1)[1].strip()
        raise SetupError("no first-start operator token: the database is not fresh (alembic downgrade base)")

    def memory_kb(self) -> tuple[int, int]:
        """RSS and peak RSS of the server process (kB, from /proc/PID/status; OSError once it is gone).
        Cheap (one small file read): safe to call on the event loop."""
        assert self.proc is not None
        text = Path(f"/proc/{self.proc.pid}/status").read_text()
        status = dict(ln.split(":", 1) for ln in text.splitlines() if ":" in ln)
        rss, hwm = (int(status.get(k, "0 kB").split()[0]) for k in ("VmRSS", "VmHWM"))
        return rss, hwm

    def rss_kb(self) -> int:
        return self.memory_kb()[0]

    def usage(self) -> tuple[float, int, int]:
        """CPU seconds used so far, RSS and peak RSS (kB; /proc)."""
        assert self.proc is not None
        stat = Path(f"/proc/{self.proc.pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(stat[11]) + int(stat[12])) / os.sysconf("SC_CLK_TCK"), *self.memory_kb()

    def stop(self, timeout_s: float = 10.0) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                log.warning("server did not stop within %.0f s of SIGINT: killing it", timeout_s)
                self.proc.kill()
                self.proc.wait()


@dataclass
class Robot:
    id: int
    token: str
    poll_open_since: float | None = None  # perf_counter when its current long-poll was sent
    message_sent: float | None = None  # perf_counter just before the operator's POST to it
    home: int = 0  # index of the server process it talks to (Load.bases); moves on a transport error
    uploads_at: list[float] = field(default_factory=list)  # perf_counter of each accepted upload's answer
    version: int = 0  # its last map version the server accepted


class Load:
    """The simulated fleet, the operator's messages and the SSE subscriber, in one event loop; ``probe``
    (optional) returns the server's RSS in kB, sampled every ``cfg.sample_s``."""

    def __init__(
        self, cfg: Config, base: str | list[str], admin: str, probe: Callable[[], int] | None = None
    ) -> None:
        # several server processes on one database: robot i talks to process i mod n, the operator's messages
        # and the map viewer go to the next process (the cross-process path); on a transport error a robot
        # moves on to the next process, as the agent's link does with a list of server URLs
        self.bases = [b + API for b in ([base] if isinstance(base, str) else base)]
        self.cfg, self.base, self.admin, self.probe = cfg, self.bases[0], admin, probe
        self.robots, self.res = list[Robot](), Results()
        # version -> perf_counter: robot 0's uploads sent, and their events parsed by the subscriber
        self.sent_at, self.seen_at = dict[int, float](), dict[int, float]()
        self.walls: list[list[float]] = []  # one table of walls shared by all robots, grown as ids slide
        self.t0 = self.end = 0.0

    def register(self) -> None:
        tag, auth = f"load-{os.getpid()}-{int(time.time())}", {"Authorization": f"Bearer {self.admin}"}
        with httpx.Client(base_url=self.base, headers=auth, timeout=30) as c:
            for i in range(self.cfg.robots):
                r = c.post("/robots", json={"name": f"{tag}-{i}"}).raise_for_status()  # else: setup failed
                self.robots.append(
                    Robot(int(r.json()["id"]), str(r.json()["token"]), home=i % len(self.bases))
                )

    def at(self, robot: Robot, path: str, other: bool = False) -> str:
        """The URL of ``path`` on ``robot``'s process (``other``: on the next one)."""
        return self.bases[(robot.home + int(other)) % len(self.bases)] + path

    def payload(self, k: int, version: int, snapshot: bool, rng: random.Random) -> dict[str, Any]:
        """Upload ``k``: ``segments`` walls, ids sliding by 1/20 per upload (the rest removed), 5 poses;
        the first ``moved_share`` of them moved by k mm since upload ``k - 1`` sent them."""
        n, step = self.cfg.segments, max(1, self.cfg.segments // 20)
        first, t = k * step, k * self.cfg.period_s
        while len(self.walls) < first + n:
            self.walls.append([float(len(self.walls)), *(round(rng.uniform(-20, 20), 3) for _ in range(4))])
        walls = self.walls[first : first + n]
        if moved := round(self.cfg.moved_share * n):
            walls = [[w[0], *(c + 0.001 * k for c in w[1:])] for w in walls[:moved]] + walls[moved:]
        return {
            "version": version,
            "base_version": None if snapshot else version - 1,
            "stamp_s": t,
            "segments": walls,
            "removed": [] if snapshot else list(range(max(0, first - step), first)),
            "centroids": [[rng.uniform(-20, 20), rng.uniform(-20, 20)] for _ in range(20)],
            "trajectory": [[t + j * 0.1, 1.0 + j, 2.0, 0.1] for j in range(5)],
            **STATUS,
        }

    async def call(
        self, kind: str, request: Awaitable[httpx.Response], robot: Robot | None = None
    ) -> httpx.Response | None:
        """The response, or ``None`` on an exception (counted as an error, like a non-2xx status; a
        transport error moves ``robot`` to the next server process)."""
        try:
            r = await request
        except httpx.HTTPError as exc:
            self.res.error(kind, f"{type(exc).__name__}: {exc}")
            if robot is not None and isinstance(exc, httpx.TransportError):
                robot.home = (robot.home + 1) % len(self.bases)
            return None
        if not r.is_success:
            self.res.error(kind, f"HTTP {r.status_code} {r.text[:120]}")
        return r

    async def prefill(self, robot: Robot, client: httpx.AsyncClient) -> None:
        """Before the load: ``robot``'s snapshot (version 1) with ``stored_poses`` poses."""
        body = self.payload(0, 1, True, random.Random(-1 - robot.id))
        body["trajectory"] = [[j * 1e-5, 0.0, 0.0, 0.0] for j in range(self.cfg.stored_poses)]
        headers = {"Authorization": f"Bearer {robot.token}"}
        r = await client.post(self.at(robot, f"/robots/{robot.id}/maps"), json=body, headers=headers)
        if not r.is_success:
            raise SetupError(f"robot {robot.id}'s first snapshot got HTTP {r.status_code}: {r.text[:200]}")
        robot.version = 1

    async def uploader(self, robot: Robot, client: httpx.AsyncClient) -> None:
        """Robot ``robot``'s uploads, one per period. An upload that got no answer is sent again as it was
        (same body, same idempotency key: the server may have applied it), as the agent does."""
        idx, period, path = self.robots.index(robot), self.cfg.period_s, f"/robots/{robot.id}/maps"
        rng, start = random.Random(idx), self.t0 + idx * period / len(self.robots)
        version, snapshot, k = robot.version, robot.version == 0, 0
        headers = {"Authorization": f"Bearer {robot.token}", "Content-Type": "application/json"}
        unanswered: tuple[bytes, str] | None = None
        while (slot := start + k * period) < self.end:
            if slot > (now := time.perf_counter()):
                await asyncio.sleep(slot - now)
            elif (behind := int((now - slot) // period)) > 0:  # fell behind: the robot skips those slots
                self.res.skipped_slots += behind
                k += behind
                continue
            body, key = unanswered or (
                json.dumps(self.payload(k, version + 1, snapshot, rng)).encode(),
                f"r{robot.id}-k{k}-{rng.getrandbits(64):016x}",
            )
            headers["Idempotency-Key"] = key
            k, t_send = k + 1, time.perf_counter()
            if idx == 0:
                self.sent_at.setdefault(version + 1, t_send)
            r = await self.call(
                "upload", client.post(self.at(robot, path), content=body, headers=headers), robot
            )
            unanswered = (body, key) if r is None else None
            if r is None:
                continue
            self.res.upload_s.append(time.perf_counter() - t_send)
            self.res.upload_at_s.append(t_send - self.t0)
            snapshot = not r.is_success  # the server's version unknown: send a snapshot next
            version = int(r.json().get("current_version", version)) if r.status_code == 409 else version
            version += 0 if snapshot else 1
            if r.is_success:
                robot.uploads_at.append(time.perf_counter())
                robot.version = version

    async def poller(self, robot: Robot, client: httpx.AsyncClient) -> None:
        after, headers = 0, {"Authorization": f"Bearer {robot.token}"}
        path, wait = f"/robots/{robot.id}/messages", LONG_POLL_S
        while time.perf_counter() < self.end:
            robot.poll_open_since, q = time.perf_counter(), {"after": after, "wait": wait}
            get = client.get(self.at(robot, path), params=q, headers=headers)
            r = await self.call("long-poll", get, robot)
            now, robot.poll_open_since = time.perf_counter(), None
            if r is None or not r.is_success:
                await asyncio.sleep(0.5)
            elif messages := r.json()["messages"]:
                after = max(int(m["seq"]) for m in messages)
                if robot.message_sent is not None:
                    self.res.message_s.append(now - robot.message_sent)
                    robot.message_sent = None

    async def operator(self, client: httpx.AsyncClient) -> None:
        """``messages`` control messages over the load, each to an idle robot whose long-poll is open."""
        n, turn = self.cfg.messages, 0
        gap = max(0.0, self.end - self.t0 - 2 * self.cfg.period_s) / max(1, n)
        hdrs = {"Authorization": f"Bearer {self.admin}", "Content-Type": "application/xml"}
        for i in range(n):
            await asyncio.sleep(max(0.0, self.t0 + self.cfg.period_s + i * gap - time.perf_counter()))
            now, turn = time.perf_counter(), turn + 1
            if now >= self.end:  # a starved client: the robots' polls are closing, the rest is not sent
                self.res.skipped_messages = n - i
                break
            idle = [r for r in self.robots if not r.message_sent and now - (r.poll_open_since or now) > 0.05]
            if not idle:
                self.res.error("message", "no robot with an open long-poll")
                continue
            robot = idle[turn % len(idle)]
            robot.message_sent = time.perf_counter()
            url = self.at(robot, f"/robots/{robot.id}/messages", other=True)
            post = client.post(url, content=MESSAGE_XML, headers=hdrs)
            if (r := await self.call("message", post)) is None or not r.is_success:
                robot.message_sent = None

    async def subscriber(self, client: httpx.AsyncClient, ready: asyncio.Event) -> None:
        """Robot 0's map stream: when each event was parsed, by version."""
        url, data = self.at(self.robots[0], f"/robots/{self.robots[0].id}/maps/stream", other=True), []
        headers, timeout = {"Authorization": f"Bearer {self.admin}"}, httpx.Timeout(10, read=None)
        try:
            async with client.stream("GET", url, headers=headers, timeout=timeout) as r:
                r.raise_for_status()
                async for line in r.aiter_lines():
                    if line.startswith("data:"):
                        data.append(line[5:].strip())
                    elif not line and data:
                        event, data = json.loads("\n".join(data)), []
                        self.seen_at.setdefault(int(event["version"]), time.perf_counter())
                        ready.set()
        except httpx.HTTPError as exc:
            self.res.error("sse", f"{type(exc).__name__}: {exc}")
        finally:
            ready.set()

    def sample(self) -> None:
        """One RSS sample now (none once the server is gone: :func:`measure` reports its death)."""
        if self.probe is not None:
            with contextlib.suppress(OSError):
                self.res.rss_samples.append((time.perf_counter() - self.t0, self.probe()))

    async def sampler(self) -> None:
        k = 0
        while (due := self.t0 + k * self.cfg.sample_s) < self.end:
            await asyncio.sleep(max(0.0, due - time.perf_counter()))
            self.sample()
            k += 1

    async def run(self, progress: Progress | None = None) -> Results:
        # A client per robot, as on real robots: in one pool of 200+ connections httpcore scans the pool on
        # each request (measured: ~70% of this process's CPU in _assign_requests_to_connections).
        async with contextlib.AsyncExitStack() as stack:
            new = (httpx.AsyncClient(timeout=LONG_POLL_S + 15) for _ in range(len(self.robots) + 1))
            *clients, op = [await stack.enter_async_context(c) for c in new]
            if self.cfg.stored_poses:
                await asyncio.gather(*(self.prefill(r, c) for r, c in zip(self.robots, clients, strict=True)))
            ready = asyncio.Event()
            tasks = [asyncio.create_task(self.subscriber(op, ready))]
            await asyncio.wait_for(ready.wait(), 30)  # the first snapshot arrived: the stream is open
            self.t0, cpu0 = time.perf_counter(), time.process_time()
            self.end = self.t0 + self.cfg.duration_s
            pairs = list(zip(self.robots, clients, strict=True))
            tasks += [asyncio.create_task(self.poller(*p)) for p in pairs]
            tasks.append(asyncio.create_task(self.sampler()))
            coros = (*(self.uploader(*p) for p in pairs), self.operator(op))
            workers = [asyncio.create_task(c) for c in coros]
            bar = None if progress is None else progress.add_task("load", total=self.cfg.duration_s)
            try:
                while not all(w.done() for w in workers):
                    await asyncio.sleep(0.25)
                    text = f"uploads {len(self.res.upload_s)}  errors {sum(self.res.errors.values())}"
                    if progress is not None and bar is not None:
                        progress.update(bar, completed=time.perf_counter() - self.t0, description=text)
                self.res.elapsed_s = time.perf_counter() - self.t0
                self.sample()  # the last one, at the end of the load
                self.res.cpu_s = (0.0, time.process_time() - cpu0)
                for w in workers:
                    w.result()  # a bug in the benchmark itself surfaces here
                await asyncio.sleep(0.5)  # the last events and messages in flight
            finally:  # also on Ctrl-C: stop every task before the clients close
                for task in (*workers, *tasks):
                    task.cancel()
                await asyncio.gather(*workers, *tasks, return_exceptions=True)
        # (an upload whose event was folded into a newer snapshot by the stream has no sample)
        self.res.sse_s = [self.seen_at[v] - t for v, t in self.sent_at.items() if v in self.seen_at]
        return self.res


def nearest_rank(xs: list[float], q: float) -> float | None:
    """The nearest-rank ``q``-th percentile (0 < q <= 100) of ``xs``; ``None`` when empty. O(n log n)."""
    s = sorted(xs)
    return s[min(len(s) - 1, max(0, math.ceil(q / 100 * len(s)) - 1))] if s else None


def report(cfg: Config, res: Results, db_label: str) -> tuple[dict[str, Any], Table]:
    """The figures as JSON and as a table beside the targets (``None`` / ``-``: no sample)."""

    def ms(xs: list[float], q: float) -> float | None:
        value = nearest_rank(xs, q)
        return None if value is None else round(1000 * value, 1)

    el, up, msg, sse = res.elapsed_s or math.nan, res.upload_s, res.message_s, res.sse_s
    rows: list[tuple[str, str, Any, str]] = [  # JSON key, label, value, target
        ("uploads", "uploads (total)", len(up), ""),
        ("errors", "errors (non-2xx or exception)", sum(res.errors.values()), "0"),
        ("skipped_slots", "upload slots skipped (robot > 1 period behind)", res.skipped_slots, "0"),
        ("skipped_messages", "messages not sent (operator past the end)", res.skipped_messages, "0"),
        ("upload_p50_ms", "upload latency p50 (ms)", ms(up, 50), ""),
        ("upload_p95_ms", "upload latency p95 (ms)", ms(up, 95), ""),
        ("upload_p99_ms", "upload latency p99 (ms)", ms(up, 99), "<= 100"),
        ("upload_max_ms", "upload latency max (ms)", ms(up, 100), ""),
        (
            "upload_p99_after_start_ms",
            f"upload latency p99 after the first {START_S:g} s (ms)",
            ms([u for u, at in zip(up, res.upload_at_s, strict=True) if at >= START_S], 99),
            "",
        ),
        ("upload_rate_per_s", "upload rate (/s)", round(len(up) / el, 1), f"{cfg.robots / cfg.period_s:g}"),
        ("message_p50_ms", f"message latency median (ms, n={len(msg)}, during load)", ms(msg, 50), "<= 50"),
        ("message_p99_ms", "message latency p99 (ms)", ms(msg, 99), ""),
        ("sse_p50_ms", f"SSE latency median (ms, n={len(sse)}, during load)", ms(sse, 50), "<= 50"),
        ("sse_p99_ms", "SSE latency p99 (ms)", ms(sse, 99), ""),
        (
            "server_rss_mb",
            "server RSS at end / peak (MB)",
            " / ".join(f"{kb / 1024:.1f}" for kb in res.server_kb),
            "",
        ),
        ("server_cpu_pct", "server CPU during load (% of one core)", round(100 * res.cpu_s[0] / el, 1), ""),
        ("client_cpu_pct", "this process's CPU (% of one core)", round(100 * res.cpu_s[1] / el, 1), ""),
    ]
    title = f"linemap server load: {cfg.robots} robots x {cfg.period_s:g} s, {cfg.segments} segments"
    table = Table(title=f"{title}, {cfg.duration_s:g} s, {db_label}")
    for name in ("figure", "measured", "target"):
        table.add_column(name, justify="left" if name == "figure" else "right")
    for _, label, value, target in rows:
        table.add_row(label, "-" if value is None else str(value), target)
    data = {"config": asdict(cfg) | {"db": db_label}, **{k: v for k, _, v, _ in rows}}
    samples = [[round(t, 1), round(kb / 1024, 1)] for t, kb in res.rss_samples]
    return data | {"errors_by_kind": res.errors, "server_rss_samples_s_mb": samples}, table


def db_label(cfg: Config) -> str:
    return "SQLite (fresh temp file)" if cfg.db is None else cfg.db.split("://", 1)[0]


def measure(cfg: Config, console: Console | None = None) -> Results:
    """Start the server, load it, stop it: the raw results (with a progress bar on ``console`` if given).
    Raises :class:`SetupError` when the server cannot start, or dies during the load."""
    with tempfile.TemporaryDirectory(prefix="linemap-load-") as tmp:
        db = cfg.db or f"sqlite:///{Path(tmp) / 'server.db'}"
        server = Server(db, cfg.port, Path(tmp))
        try:
            load = Load(cfg, server.base, server.start(), probe=server.rss_kb)
            load.register()
            log.info("%d robots registered; load for %g s", cfg.robots, cfg.duration_s)
            cpu0 = server.usage()[0]
            if console is None:
                res = asyncio.run(load.run())
            else:
                with Progress(console=console, transient=True) as progress:
                    res = asyncio.run(load.run(progress))
            cpu1, *kb = server.usage()
            res.cpu_s, res.server_kb = (cpu1 - cpu0, res.cpu_s[1]), (kb[0], kb[1])
            if server.proc is not None and server.proc.poll() is not None:
                raise SetupError(f"server died during the load: {server.tail()}")
        except (httpx.HTTPError, OSError, TimeoutError) as exc:
            raise SetupError(f"{type(exc).__name__}: {exc}") from exc
        finally:
            server.stop()
        return res


def run(cfg: Config, console: Console) -> tuple[dict[str, Any], Table]:
    """Start the server, load it, stop it; the figures. Raises :class:`SetupError` when it cannot start."""
    return report(cfg, measure(cfg, console), db_label(cfg))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    p.add_argument("--db", help="database URL (default: a fresh SQLite file in a temporary directory)")
    for f in fields(Config)[1:]:
        name, default = f"--{f.name.replace('_', '-')}", f.default
        p.add_argument(name, type=type(default), default=default, help=f"{f.metadata['help']} [{default}]")
    p.add_argument("--json", type=Path, help="also write the figures to this JSON file")
    p.add_argument("-v", "--verbose", action="store_true", help="log the setup steps")
    a = p.parse_args(argv)
    console, handler = Console(), RichHandler(console=Console(stderr=True), show_path=False)
    level = logging.INFO if a.verbose else logging.WARNING
    logging.basicConfig(level=level, handlers=[handler], format="%(message)s")
    logging.getLogger("httpx").setLevel(logging.WARNING)
    if min(a.robots, a.period_s, a.duration_s, a.segments, a.sample_s) <= 0 or a.messages < 0:
        p.error("--robots, --period-s, --duration-s, --segments and --sample-s must be positive")
    if not 0 <= a.moved_share <= 1:
        p.error(f"--moved-share {a.moved_share}: expected a share in 0..1")
    signal.signal(signal.SIGTERM, signal.default_int_handler)  # a KeyboardInterrupt: the server is stopped
    try:
        data, table = run(Config(**{f.name: getattr(a, f.name) for f in fields(Config)}), console)
    except SetupError as exc:
        console.print(f"setup failed: {exc}", soft_wrap=True, markup=False)
        return 2
    except KeyboardInterrupt:
        console.print("interrupted: server stopped")
        return 130
    console.print(table)
    if a.json:
        a.json.write_text(json.dumps(data, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
