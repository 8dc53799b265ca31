"""Shared parts of the crash and network-fault tests (docs/reliability.md): a real server with one robot
and a signing key, a real ``linemap agent`` process, a power cut (SIGKILL to the agent and every process
it started), and the checks of the Robot DB and the server: after every kill and at the end.

The checks (what "nothing lost, nothing twice" means here):

- Robot DB: ``PRAGMA integrity_check`` is ``ok``; the map versions kept are ``k..map_version`` with every
  undelivered one there (``k <= uploaded_version + 1``: the delivered ones before the newest delivered are
  compacted away); the poses are ``1..map_version`` while the run is within the trajectory limit (past it,
  the delivered ones are thinned: every undelivered pose stays);
  ``source_index`` == ``map_version`` (every scan of the replayable source mapped once, none skipped); the
  outbox is exactly ``uploaded_version+1..map_version``; applied messages are ``1..k`` (each once), and the
  configurations they put in force are recorded once each, in order.
- Against the server: the robot holds every version the server has (``server <= map_version``) and never
  believes the server has one it lacks (``uploaded_version <= server``); a message the server has an
  acknowledgement for is one the robot recorded, with the same outcome.
- At the end: the server's trajectory stamps equal the robot's pose stamps and the source's first
  ``map_version`` scan stamps (each map version exactly once, in order, no gaps); the server's accepted
  uploads chain (each delta starts at the version before it); every message is ``applied`` on both sides
  (a kernel install may be ``rolled-back`` later by the kernel guard: applied once, then taken out).
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import sqlite3
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
from sqlalchemy import select

from server.models import MapUploadRecord
from shared.signing import KeyPair, generate_keypair, load_private_key, sha256_hex, sign_digest
from tests.robot_agent.agentproc import AgentProcess, integrity
from tests.server.live import Live

__all__ = [
    "ARTIFACTS",
    "Rig",
    "RobotDbView",
    "check_after_kill",
    "check_final",
    "check_robot_db",
    "cmdline",
    "descendants",
    "dry_run_child",
    "expected_stamps",
    "kernel_source",
    "power_cut",
    "read_robot_db",
    "server_messages",
    "upload_records",
    "write_figures",
]

ROOT = Path(__file__).resolve().parents[2]
ARTIFACTS = Path(os.environ.get("LINEMAP_TEST_ARTIFACTS", ROOT / "test-artifacts")) / "reliability"
XML = {"Content-Type": "application/xml"}


def write_figures(name: str, figures: dict[str, Any]) -> Path:
    """Keep a run's measured figures in ``test-artifacts/reliability/<name>.json`` (for the docs)."""
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    path = ARTIFACTS / f"{name}.json"
    path.write_text(json.dumps(figures, indent=2, sort_keys=True) + "\n", encoding="utf-8")
    return path


def kernel_source(minor: int, patch: int = 0) -> bytes:
    """A DBSCAN kernel artifact of version ``1.<minor>.<patch>`` (the built-in algorithm, a new version)."""
    return (
        f'"""DBSCAN 1.{minor}.{patch}: the built-in algorithm under a new version (test artifact)."""\n'
        "from shared.kernels.noise.dbscan import Dbscan\n\n\n"
        f"class Dbscan1x{minor}x{patch}(Dbscan):\n"
        f'    """DBSCAN, version 1.{minor}.{patch}."""\n\n'
        f'    version = "1.{minor}.{patch}"\n'
    ).encode()


# ---------------------------------------------------------------------------------------------- processes
def descendants(pid: int) -> list[int]:
    """Every process below ``pid`` (children, grandchildren ...), read from /proc."""
    parent_of: dict[int, int] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        parent_of[int(entry.name)] = int(stat.rsplit(")", 1)[1].split()[1])
    found: list[int] = []
    frontier = [pid]
    while frontier:
        p = frontier.pop()
        kids = [c for c, pp in parent_of.items() if pp == p]
        found += kids
        frontier += kids
    return found


def cmdline(pid: int) -> bytes:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return b""


def dry_run_child(cmd: bytes) -> bool:
    """Whether command line ``cmd`` is a kernel's checks (dry run) worker of the agent."""
    return b"spawn_main" in cmd or b"robot_agent.kernels.worker\0checks\0" in cmd


def power_cut(agent: AgentProcess) -> list[str]:
    """SIGKILL the agent, then the processes it had started (a kernel's checks worker, a kernel's service
    worker): as a power cut would. The agent dies first, so it records nothing about its
    children's end. Returns what the killed children were (``dry run``, ``resource tracker``, ``other``)."""
    kids = [(pid, cmdline(pid)) for pid in descendants(agent.proc.pid)]
    # The whole process group at once (the agent runs in its own session): a child spawned just after the
    # listing above dies too, instead of living on with its parent gone.
    with contextlib.suppress(ProcessLookupError):
        os.killpg(agent.proc.pid, signal.SIGKILL)
    agent.kill()
    for pid, _ in kids:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
    return [
        "dry run" if dry_run_child(cmd) else "resource tracker" if b"resource_tracker" in cmd else "other"
        for _, cmd in kids
    ]


# ---------------------------------------------------------------------------------------------- Robot DB
@dataclass(frozen=True)
class RobotDbView:
    """What a stopped (or killed) agent's Robot DB holds."""

    integrity: str
    map_version: int
    source_index: int
    uploaded_version: int
    versions: list[int]
    pose_versions: list[int]
    pose_stamps: list[float]
    outbox: list[int]
    applied: list[tuple[int, str, bool]]  # (seq, outcome, acknowledged)
    config_seqs: list[int]


def _meta(conn: sqlite3.Connection, key: str, default: Any) -> Any:
    row = conn.execute("SELECT value FROM meta WHERE key = ?", (key,)).fetchone()
    return default if row is None else json.loads(row[0])["v"]


def read_robot_db(db: Path) -> RobotDbView | None:
    """The Robot DB's state, or None if the agent was killed before it created its tables."""
    if not db.exists():
        return None
    check = integrity(db)
    with sqlite3.connect(db) as conn:
        tables = {r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        if "meta" not in tables or "applied_messages" not in tables:
            return RobotDbView(check, 0, 0, 0, [], [], [], [], [], [])
        poses = conn.execute("SELECT version, stamp_s FROM poses ORDER BY version").fetchall()
        return RobotDbView(
            integrity=check,
            map_version=int(_meta(conn, "map_version", 0) or 0),
            source_index=int(_meta(conn, "source_index", 0) or 0),
            uploaded_version=int(_meta(conn, "uploaded_version", 0) or 0),
            versions=[r[0] for r in conn.execute("SELECT version FROM map_versions ORDER BY version")],
            pose_versions=[r[0] for r in poses],
            pose_stamps=[r[1] for r in poses],
            outbox=[r[0] for r in conn.execute("SELECT version FROM outbox ORDER BY version")],
            applied=[
                (r[0], r[1], r[2] is not None)
                for r in conn.execute("SELECT seq, outcome, acked_at FROM applied_messages ORDER BY seq")
            ],
            config_seqs=[
                r[0] for r in conn.execute("SELECT seq FROM config_history WHERE seq IS NOT NULL ORDER BY id")
            ],
        )


def check_robot_db(view: RobotDbView, where: str) -> None:
    """The Robot DB's own invariants (see the module docstring); AssertionError names what broke."""
    assert view.integrity == "ok", f"{where}: PRAGMA integrity_check says {view.integrity!r}"
    n = view.map_version
    from shared.protocol import MAX_TRAJECTORY_POSES

    low = view.versions[0] if view.versions else n + 1
    assert view.versions == list(range(low, n + 1)) and low <= view.uploaded_version + 1, (
        f"{where}: map versions are not k..{n} with k <= uploaded_version + 1 "
        f"({view.uploaded_version} + 1): {_ends(view.versions)}"
    )
    if n <= MAX_TRAJECTORY_POSES:
        assert view.pose_versions == list(range(1, n + 1)), f"{where}: poses are not 1..{n}"
    else:
        undelivered = list(range(view.uploaded_version + 1, n + 1))
        assert view.pose_versions[-len(undelivered) :] == undelivered or not undelivered, (
            f"{where}: an undelivered pose is missing"
        )
    assert view.source_index == n, f"{where}: source_index {view.source_index} != map_version {n}"
    assert view.outbox == list(range(view.uploaded_version + 1, n + 1)), (
        f"{where}: outbox {_ends(view.outbox)} is not uploaded_version+1..map_version "
        f"({view.uploaded_version}+1..{n})"
    )
    seqs = [seq for seq, _, _ in view.applied]
    assert seqs == list(range(1, len(seqs) + 1)), f"{where}: applied messages {seqs} are not 1..k"
    # A kernel message the guard rolled back later (over its time budget, or it raised) was applied too.
    applied = [seq for seq, outcome, _ in view.applied if outcome in ("applied", "rolled-back")]
    assert view.config_seqs == applied, (
        f"{where}: configurations put in force by messages {view.config_seqs}, applied messages {applied}: "
        "each applied message must have put its configuration in force exactly once"
    )


def _ends(values: list[int]) -> str:
    return f"{values[:3]}...{values[-3:]} ({len(values)})" if len(values) > 6 else str(values)


# ---------------------------------------------------------------------------------------------- server
def server_messages(op: httpx.Client, rid: int) -> list[dict[str, Any]]:
    out: list[dict[str, Any]] = []
    while True:
        r = op.get(f"/robots/{rid}/messages", params={"after": len(out), "limit": 1000})
        assert r.status_code == 200, r.text
        batch = r.json()["messages"]
        if not batch:
            return out
        out += batch


def upload_records(live: Live, rid: int) -> list[tuple[int, int | None]]:
    """The server's accepted uploads of robot ``rid`` in the order applied: (version, base_version)."""
    with live.state.db.read() as s:
        rows = s.execute(
            select(MapUploadRecord.version, MapUploadRecord.base_version)
            .where(MapUploadRecord.robot_id == rid)
            .order_by(MapUploadRecord.id)
        )
        return [(int(v), None if b is None else int(b)) for v, b in rows]


def check_after_kill(view: RobotDbView | None, op: httpx.Client, rid: int, where: str) -> None:
    """After a kill: the Robot DB's invariants, and the Robot DB against the server."""
    if view is None:
        return
    check_robot_db(view, where)
    robot = op.get(f"/robots/{rid}").json()
    server_v = int(robot["map_version"])
    assert server_v <= view.map_version, (
        f"{where}: the server has map version {server_v}, the robot only {view.map_version}: "
        "an acknowledged map version was lost on the robot"
    )
    assert view.uploaded_version <= server_v, (
        f"{where}: the robot believes the server has version {view.uploaded_version}, it has {server_v}"
    )
    outcomes = {seq: outcome for seq, outcome, _ in view.applied}
    for m in server_messages(op, rid):
        if m["status"] != "queued":
            assert outcomes.get(m["seq"]) in (m["status"], "rolled-back"), (
                f"{where}: the server has message {m['seq']} as {m['status']}, the robot as "
                f"{outcomes.get(m['seq'])}"
            )


def expected_stamps(n: int, laps: int = 0) -> list[float]:
    """The stamps of the simulated source's first ``n`` scans (what the agent maps, in order)."""
    from robot_agent.sources import open_scans

    out: list[float] = []
    scans = open_scans("sim", laps=laps)
    try:
        for scan in scans:
            if len(out) >= n:
                break
            out.append(scan.stamp_s)
    finally:
        scans.close()
    return out


def check_final(live: Live, op: httpx.Client, rid: int, view: RobotDbView | None, laps: int = 0) -> None:
    """After the last, graceful stop: everything reached the server exactly once and in order."""
    assert view is not None, "the Robot DB exists after the final run"
    check_robot_db(view, "final")
    robot = op.get(f"/robots/{rid}").json()
    n = view.map_version
    assert robot["map_version"] == n == view.uploaded_version and not view.outbox, (
        f"final: server at {robot['map_version']}, robot at {n}, uploaded {view.uploaded_version}, "
        f"outbox {_ends(view.outbox)}"
    )
    stamps = [row[0] for row in op.get(f"/robots/{rid}/maps/latest").json()["trajectory"]]
    assert len(stamps) == n, f"final: the server holds {len(stamps)} poses for {n} map versions"
    assert stamps == view.pose_stamps, "final: the server's trajectory differs from the robot's"
    assert stamps == expected_stamps(n, laps), "final: the trajectory is not the source's scans, in order"
    previous = 0
    for version, base in upload_records(live, rid):
        assert version > previous, f"final: upload of version {version} applied after {previous}"
        assert base is None or base == previous, f"final: delta from {base} applied on version {previous}"
        previous = version
    messages = server_messages(op, rid)
    assert [m["seq"] for m in messages] == list(range(1, len(messages) + 1))
    bad = [
        (m["seq"], m["status"], m["reason"])
        for m in messages
        if m["status"] != "applied" and not (m["status"] == "rolled-back" and "<kernel-" in m["xml"])
    ]
    assert not bad, f"final: messages not applied: {bad}"
    assert view.applied == [(m["seq"], m["status"], True) for m in messages], (
        f"final: the robot's record {view.applied} differs from the server's messages"
    )


# ---------------------------------------------------------------------------------------------- the rig
@dataclass
class Rig:
    """One robot on a live server, with a trusted signing key registered; ``server_url`` is where the
    agent connects (the server itself or a proxy in front of it)."""

    live: Live
    db: Path
    server_url: str
    rate: str = "0"
    laps: int = 0
    # Retries after a fault start at 50 ms (the product's default is 0.5 s): ten times the retries in the
    # same time, so more of them meet faults and kills, and long runs fit in make soak.
    retry_base: str = "0.05"
    key: KeyPair = field(default_factory=generate_keypair)
    rid: int = 0
    token: str = ""
    kernels: int = 0  # kernel versions uploaded so far (1.1.0, 1.2.0, ...)
    starts: int = 0

    def __post_init__(self) -> None:
        self.rid, self.token = self.live.new_robot()
        self.op = self.live.operator()
        r = self.op.post("/keys", json={"name": f"ops-{self.rid}", "public_key": self.key.public_b64})
        assert r.status_code in (201, 409), r.text

    def start(self) -> AgentProcess:
        self.starts += 1
        extra = ["--rate", self.rate, "--laps", str(self.laps), "--trust-key", self.key.public_b64]
        extra += ["--retry-base", self.retry_base]
        return AgentProcess(self.db, server=self.server_url, robot_id=self.rid, token=self.token, extra=extra)

    def server_version(self) -> int:
        return int(self.op.get(f"/robots/{self.rid}").json()["map_version"])

    def post(self, body: str) -> int:
        r = self.op.post(
            f"/robots/{self.rid}/messages", content=f"<xml><message>{body}</message></xml>", headers=XML
        )
        assert r.status_code == 201, r.text
        return int(r.json()["seq"])

    def new_kernel_message(self) -> str:
        """Upload the next DBSCAN version (signed) and return the ``<kernel-update>`` putting it in force.
        Versions only go up (so the robot's anti-rollback floor never refuses one) and are this robot's
        own (``1.<n>.<robot id>``: robots with other keys on the same server get other versions)."""
        self.kernels += 1
        version = f"1.{self.kernels}.{self.rid}"
        source = kernel_source(self.kernels, self.rid)
        digest = sha256_hex(source)
        sig = sign_digest(load_private_key(self.key.private_pem), digest)
        r = self.op.post(
            "/kernels",
            data={"name": "dbscan", "stage": "noise-removal", "version": version, "signature": sig},
            files={"file": ("dbscan.py", source, "text/x-python")},
        )
        assert r.status_code == 201, r.text
        return f'<kernel-update stage="noise-removal" name="dbscan" version="{version}" sha256="{digest}"/>'

    def status_of(self, seq: int) -> str:
        return str(self.op.get(f"/robots/{self.rid}/messages/{seq}").json()["status"])
