"""Crash safety (docs/reliability.md): a real ``linemap agent`` is killed with SIGKILL, again and again, at
moments chosen by its progress (while mapping, just after an upload reached the server but before the
robot recorded it, while a kernel install is downloaded, dry-run, verified or applied, in the middle of
an upload burst after an outage, during start-up) against a real server. After every kill the Robot DB
passes ``PRAGMA integrity_check`` and its invariants, and agrees with the server; the agent is restarted
and resumes. At the end every map version is on the server exactly once and in order, and every control
message was applied exactly once (see :mod:`tests.reliability.crashtools` for the checks).

Fast part: ``KILLS`` kills. Soak (``-m soak``): ``LINEMAP_SOAK_KILLS`` (default 200).
"""

from __future__ import annotations

import os
import random
import time
from collections import Counter
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import pytest

from tests.reliability.crashtools import (
    Rig,
    check_after_kill,
    check_final,
    cmdline,
    descendants,
    dry_run_child,
    power_cut,
    read_robot_db,
    server_messages,
    write_figures,
)
from tests.reliability.netproxy import FaultProxy
from tests.robot_agent.agentproc import AgentProcess, robot_db_meta, wait_for
from tests.server.live import Live, start_live

KILLS = 10
EPISODE = 10  # kills per robot (Robot DB) before its end checks
LANES = int(os.environ.get("LINEMAP_CRASH_LANES", "2"))  # robots killed side by side
SOAK_KILLS = int(os.environ.get("LINEMAP_SOAK_KILLS", "200"))
SEED = int(os.environ.get("LINEMAP_CRASH_SEED", "9"))
# How often each kind of moment is chosen.
MOMENTS = {"start-up": 1, "mapping": 3, "upload in flight": 3, "kernel install": 2, "upload burst": 1}


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    yield from start_live("sqlite", tmp_path_factory.mktemp("crash-server"), poll_recheck_s=1.0)


def until(check: Callable[[], Any], timeout_s: float, interval_s: float = 0.005) -> bool:
    """Poll ``check`` until it holds (True) or ``timeout_s`` passes (False): finds a kill moment."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if check():
            return True
        time.sleep(interval_s)
    return False


def _meta(rig: Rig, key: str) -> int:
    return int(robot_db_meta(rig.db, key) or 0)


class Crasher:
    """Chooses kill moments (seeded), kills, checks, and counts what the kills hit."""

    def __init__(self, proxy: FaultProxy, seed: int) -> None:
        self.proxy = proxy
        self.rng = random.Random(seed)
        self.moments: Counter[str] = Counter()
        self.hits: Counter[str] = Counter()
        self.messages = 0
        self.kills = 0
        self.rig: Rig
        self.agent: AgentProcess

    def alive(self) -> bool:
        """True while the agent runs; an agent that exited by itself fails the test with its output."""
        code = self.agent.proc.poll()
        assert code is None, f"the agent exited with {code} on its own:\n{self.agent.output()[-4000:]}"
        return True

    def wait(self, what: str, check: Callable[[], Any], timeout_s: float = 90.0) -> None:
        wait_for(what, lambda: self.alive() and check(), timeout_s)

    # ------------------------------------------------------------------ moments
    def start_up(self) -> str:
        """As soon as the process has its Robot DB open (migrations, restoring state, first steps)."""
        db = str(self.rig.db.resolve())

        def opened() -> bool:
            try:
                fds = list(Path(f"/proc/{self.agent.proc.pid}/fd").iterdir())
                return any(os.readlink(fd) == db for fd in fds)
            except OSError:
                return False

        assert until(lambda: self.alive() and opened(), 60, 0.002), "the agent never opened its Robot DB"
        return "start-up"

    def mapping(self) -> str:
        """After the next k map versions reached the server."""
        k = self.rng.randint(1, 40)
        v0 = self.rig.server_version()
        self.wait(f"{k} more map versions on the server", lambda: self.rig.server_version() >= v0 + k)
        return "mapping"

    def in_flight(self) -> str:
        """When the server has applied an upload the robot has not recorded as uploaded yet."""
        v0 = self.rig.server_version()
        self.wait("uploads resume", lambda: self.rig.server_version() > v0)
        until(
            lambda: self.alive() and self.rig.server_version() > _meta(self.rig, "uploaded_version"),
            10,
            0.001,
        )
        return "upload in flight"

    def kernel_install(self) -> str:
        """A new kernel version is posted; the kill comes right away, during its dry run, once it is verified
        (stored, not yet applied), or once applied (not yet acknowledged). If the moment passes unseen,
        the kill comes as soon as the message is applied."""
        self.wait("the agent maps", lambda: _meta(self.rig, "map_version") > 0)
        sub = self.rng.choice(["posted", "dry run", "verified", "applied"])
        before = _max_kernel_id(self.rig.db)
        seq = self.rig.post(self.rig.new_kernel_message())
        self.messages += 1
        pid = self.agent.proc.pid
        if sub == "posted":
            return "kernel install: posted"
        hit: dict[str, Callable[[], bool]] = {
            "dry run": lambda: any(dry_run_child(cmdline(p)) for p in descendants(pid)),
            "verified": lambda: _max_kernel_id(self.rig.db) > before and seq not in _applied(self.rig.db),
            "applied": lambda: seq in _applied(self.rig.db),
        }
        seen: list[bool] = []

        def moment() -> bool:
            self.alive()
            if hit[sub]():
                seen.append(True)
                return True
            return seq in _applied(self.rig.db)  # passed unseen

        assert until(moment, 120, 0.002), f"kernel message {seq} was never applied"
        return f"kernel install: {sub}" + ("" if seen else " (missed: killed once applied)")

    def upload_burst(self) -> str:
        """The server is unreachable until 55-110 map versions (more than one upload batch of 50) wait in
        the outbox; the kill comes once the catch-up has begun."""
        self.wait("the agent maps", lambda: _meta(self.rig, "map_version") > 0)
        self.proxy.faults, self.proxy.fault_rate = ("drop",), 1.0
        try:
            backlog = self.rng.randint(55, 110)
            self.wait(
                f"{backlog} versions in the outbox",
                lambda: _meta(self.rig, "map_version") - _meta(self.rig, "uploaded_version") >= backlog,
            )
            v0 = self.rig.server_version()
        finally:
            self.proxy.fault_rate = 0.0
        self.wait("catch-up begins", lambda: self.rig.server_version() > v0)
        return "upload burst"

    # ------------------------------------------------------------------ one kill
    def maybe_message(self) -> None:
        """Now and then a configuration message, so messages are in flight across kills too."""
        if self.rng.random() < 0.3:
            self.rig.post(f"<n-smax>{self.rng.randint(2, 12)}</n-smax>")
            self.messages += 1

    def one(self) -> None:
        self.agent = self.rig.start()
        self.maybe_message()
        kind = self.rng.choices(list(MOMENTS), weights=list(MOMENTS.values()))[0]
        moment = {
            "start-up": self.start_up,
            "mapping": self.mapping,
            "upload in flight": self.in_flight,
            "kernel install": self.kernel_install,
            "upload burst": self.upload_burst,
        }[kind]
        try:
            label = moment()
        finally:
            for child in power_cut(self.agent):
                self.hits[f"killed with the agent: {child}"] += 1
        self.kills += 1
        self.moments[label] += 1
        view = read_robot_db(self.rig.db)
        assert view is not None, f"kill {self.kills}: no Robot DB after the agent had opened it"
        check_after_kill(view, self.rig.op, self.rig.rid, f"kill {self.kills} ({label})")
        self.hits["integrity ok"] += 1
        if self.rig.server_version() > view.uploaded_version:
            self.hits["server ahead of the robot's record (upload in flight)"] += 1
        if any(not acked for _, _, acked in view.applied):
            self.hits["message applied, acknowledgement not sent"] += 1
        if view.map_version > view.uploaded_version:
            self.hits["outbox not empty"] += 1

    def finish(self) -> int:
        """The episode's last run: the agent resumes, catches up and stops cleanly; then the end checks.
        Returns the episode's map versions."""
        rig = self.rig
        before = _meta(rig, "map_version")
        self.agent = rig.start()
        try:
            # Started (signal handlers installed, mapping): a SIGINT before that would meet the interpreter
            # still importing its site module, which no program can handle.
            self.wait("the agent maps again", lambda: _meta(rig, "map_version") > before)
            self.wait(
                "every message dealt with",
                lambda: all(m["status"] != "queued" for m in server_messages(rig.op, rig.rid)),
                180,
            )
            mapped = _meta(rig, "map_version")
            self.wait("the server caught up", lambda: rig.server_version() >= mapped, 180)
        finally:
            code = self.agent.stop()
        assert code == 0, self.agent.output()[-3000:]
        view = read_robot_db(rig.db)
        check_final(rig.live, rig.op, rig.rid, view)
        assert view is not None
        out = self.agent.output()
        assert "Traceback" not in out, out[out.index("Traceback") - 2000 :][:6000]
        return view.map_version


def _max_kernel_id(db: Path) -> int:
    import sqlite3

    try:
        with sqlite3.connect(db) as conn:
            return int(conn.execute("SELECT COALESCE(MAX(id), 0) FROM kernels").fetchone()[0])
    except sqlite3.OperationalError:
        return 0


def _applied(db: Path) -> set[int]:
    import sqlite3

    try:
        with sqlite3.connect(db) as conn:
            return {r[0] for r in conn.execute("SELECT seq FROM applied_messages")}
    except sqlite3.OperationalError:
        return set()


def _lane(live: Live, tmp_path: Path, lane: int, kills: int, seed: int) -> dict[str, Any]:
    """One lane: ``kills`` kills in episodes of at most ``EPISODE``; each episode is a new robot (a new
    Robot DB) and ends with the end checks, so the map stays small enough to restart quickly."""
    host, port = live.base_url.rsplit("//", 1)[1].split(":")
    versions: list[int] = []
    starts = kernels = 0
    with FaultProxy(host, int(port), seed=seed, fault_rate=0.0, max_s=3600) as proxy:
        crasher = Crasher(proxy, seed)
        for episode, first in enumerate(range(0, kills, EPISODE)):
            crasher.rig = Rig(live, tmp_path / f"lane{lane}-robot{episode}.db", proxy.url)
            for _ in range(first, min(kills, first + EPISODE)):
                crasher.one()
            versions.append(crasher.finish())
            starts += crasher.rig.starts
            kernels += crasher.rig.kernels
        return {
            "kills": crasher.kills,
            "episodes": len(versions),
            "agent_starts": starts,
            "moments": crasher.moments,
            "observed_at_kill": crasher.hits,
            "map_versions_checked": sum(versions),
            "messages": crasher.messages,
            "kernel_versions_installed": kernels,
            "proxy": Counter(proxy.snapshot()),
        }


def run_kills(live: Live, tmp_path: Path, kills: int, seed: int) -> dict[str, Any]:
    """``kills`` kills shared out over ``LANES`` robots killed side by side (agent start-up is most of a
    kill's cost and mostly waits for imports: two lanes use the two cores)."""
    t0 = time.monotonic()
    shares = [kills // LANES + (1 if i < kills % LANES else 0) for i in range(LANES)]
    with ThreadPoolExecutor(LANES) as pool:
        futures = [
            pool.submit(_lane, live, tmp_path, i, n, seed * 100 + i) for i, n in enumerate(shares) if n
        ]
        lanes = [f.result() for f in futures]
    total: dict[str, Any] = {"seed": seed, "lanes": len(lanes)}
    for lane in lanes:
        for key, value in lane.items():
            total[key] = total.get(key, Counter() if isinstance(value, Counter) else 0) + value
    total = {k: dict(v) if isinstance(v, Counter) else v for k, v in total.items()}
    total["seconds"] = round(time.monotonic() - t0, 1)
    return total


def test_kill_9_at_chosen_moments(live: Live, tmp_path: Path) -> None:
    figures = run_kills(live, tmp_path, KILLS, SEED)
    write_figures("crash-fast", figures)
    assert figures["observed_at_kill"]["integrity ok"] == KILLS


@pytest.mark.soak
def test_kill_9_soak(live: Live, tmp_path: Path) -> None:
    figures = run_kills(live, tmp_path, SOAK_KILLS, SEED + 1)
    write_figures("crash-soak", figures)
    assert figures["observed_at_kill"]["integrity ok"] == SOAK_KILLS
