"""Kernel supply chain through a real server and a real agent process (docs/reliability/supply.md,
docs/design.md §9).

Each attack or faulty kernel is sent to a mapping robot as an operator would: it must be refused
(``rejected`` acknowledgement with the reason) or, when the fault only shows in service, rolled back
(``rolled-back`` acknowledgement with the reason); either way mapping goes on (the map version keeps
growing) and the operator sees why through the server API: the acknowledgement's reason, the robot's
``last_error`` and its kernel store's states. Already covered elsewhere and not repeated here: a kernel
that raises in service (tests/robot_agent/test_agent_kernels_live.py::
test_a_kernel_that_raises_is_rolled_back_while_mapping_goes_on), wrong-sha256 and unsigned uploads the
server refuses before any robot sees them (same file), and each check on its own
(tests/robot_agent/test_kernel_checks.py).
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import pytest

from shared.signing import KeyPair, generate_keypair
from tests.reliability import supplytools as st
from tests.robot_agent.agentproc import AgentProcess, wait_for
from tests.server.live import Live, start_live

UPDATE = '<kernel-update stage="noise-removal" name="dbscan" version="{v}" sha256="{d}"/>'


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    yield from start_live("sqlite", tmp_path_factory.mktemp("supply-server"), poll_recheck_s=1.0)


@pytest.fixture(scope="module")
def key(live: Live) -> KeyPair:
    return st.trusted_key(live)


@dataclass
class Robot:
    agent: AgentProcess
    rid: int
    op: httpx.Client

    def get(self) -> dict[str, Any]:
        data: dict[str, Any] = self.op.get(f"/robots/{self.rid}").json()
        return data

    def map_version(self) -> int:
        return int(self.get()["map_version"])

    def keeps_mapping(self, steps: int = 10) -> None:
        start = self.map_version()
        wait_for(f"{steps} more map versions", lambda: self.map_version() >= start + steps, 120)


@pytest.fixture(scope="module")
def robot(live: Live, key: KeyPair, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Robot]:
    """One mapping robot for the whole matrix (every case leaves it running the built-in DBSCAN)."""
    agent, rid, _token, op = st.start(live, tmp_path_factory.mktemp("supply-robot"), key)
    try:
        yield Robot(agent, rid, op)
    finally:
        code = agent.stop()
        op.close()
        assert code == 0, agent.output()


# ------------------------------------------------------------------------------------------ the matrix
@dataclass(frozen=True)
class Case:
    """One attack or faulty kernel: how the artifact is made and delivered, what the robot must answer."""

    id: str
    version: str
    outcome: str  # "rejected" or "rolled-back"
    reason: tuple[str, ...]  # parts the acknowledgement's reason must contain
    fault: str | None = None
    after: int = 0
    signer: str = "ops"  # "ops" (trusted by the robot) or "stranger" (not)
    tamper: str | None = None  # "bytes" (after signing) or "bytes+digest" (the stored sha256 too)
    any_of: tuple[str, ...] = ()  # the reason must contain one of these too (when there is more than one)
    soak: bool = False  # only in make soak: the fast part keeps one case of each kind
    worker: bool = False  # the fault is in the worker process: detection time is recorded


CASES = [
    Case("tampered-bytes", "2.0.1", "rejected", ("sha256 mismatch",), tamper="bytes"),
    Case(
        "tampered-bytes-and-digest",
        "2.0.2",
        "rejected",
        ("bad signature", "none of the trusted keys"),
        tamper="bytes+digest",
    ),
    Case(
        "untrusted-key", "2.0.3", "rejected", ("bad signature", "none of the trusted keys"), signer="stranger"
    ),
    Case(
        "hangs",
        "2.0.4",
        "rejected",
        ("dry run: ran longer than its 4500 ms budget", "killed"),
        "hangs",
        soak=True,
    ),
    # The child's memory cap (512 MB) normally stops it; on a loaded machine writing 512 MB can outlast the
    # 5 s budget first. Either way it is refused in the child process, which is killed.
    Case(
        "allocates-without-bound",
        "2.0.5",
        "rejected",
        ("dry run:",),
        "allocates",
        any_of=("out of memory: the kernel needed more than its 512 MB limit", "ran longer than"),
        soak=True,
    ),
    # Untrusted code outside any limit (docs/reliability/sandbox.md): hangs at import, loops only on an
    # empty input (passes the dry run, hangs the battery), reaches for the network or the file system.
    Case(
        "hangs-at-import",
        "2.1.1",
        "rejected",
        ("dry run: ran longer than its 4500 ms budget", "killed"),
        "import-hang",
        worker=True,
    ),
    Case(
        "loops-on-empty-input",
        "2.1.2",
        "rejected",
        ("conformance battery: did not finish within 4.5 s", "killed"),
        "empty-loop",
        worker=True,
    ),
    Case("opens-a-socket", "2.1.3", "rejected", ("dry run: the kernel raised ",), "socket", worker=True),
    Case(
        "reads-a-file-outside-scratch",
        "2.1.4",
        "rejected",
        ("dry run: the kernel raised PermissionError",),
        "read-file",
        worker=True,
    ),
    Case(
        "writes-a-file-outside-scratch",
        "2.1.5",
        "rejected",
        ("dry run: the kernel raised PermissionError",),
        "write-file",
        worker=True,
    ),
    Case("returns-nan", "2.0.6", "rejected", ("dry run: result check failed",), "nan"),
    Case(
        "returns-wrong-shapes",
        "2.0.7",
        "rejected",
        ("dry run: result check failed",),
        "wrong-shapes",
        soak=True,
    ),
    Case(
        "returns-wrong-type",
        "2.0.8",
        "rejected",
        ("returned list: expected NoiseResult",),
        "wrong-type",
        soak=True,
    ),
    # Faults that pass the dry run and the conformance battery, then show in service: rolled back. They run
    # their version, raising the robot's floor, so they come last and in increasing versions.
    Case("slow-in-service", "3.0.1", "rolled-back", ("over its 200 ms budget",), "slow", after=40, soak=True),
    Case(
        "nan-in-service",
        "3.0.2",
        "rolled-back",
        ("dbscan 3.0.2 returned a bad result", "NoiseResult.points has non-finite values"),
        "nan",
        after=40,
    ),
    # Stuck in service: the step is answered by the kernel it replaced, the worker process is killed, the
    # rollback is recorded; the agent goes on in the same process (nothing to restart).
    Case(
        "hangs-in-service",
        "3.0.3",
        "rolled-back",
        ("dbscan 3.0.3 did not return within 4.5 s (hung)", "killed"),
        "hangs",
        after=40,
        worker=True,
    ),
    Case(
        "allocates-in-service",
        "3.0.4",
        "rolled-back",
        ("dbscan 3.0.4 out of memory", "256 MB limit"),
        "allocates",
        after=40,
        worker=True,
    ),
    Case(
        "gil-holding-regex-in-service",
        "3.0.5",
        "rolled-back",
        ("dbscan 3.0.5 did not return within 4.5 s (hung)", "killed"),
        "regex",
        after=40,
        worker=True,
    ),
]


def _prepare(live: Live, key: KeyPair, case: Case) -> str:
    """Upload the case's artifact and tamper with it as the case says; the sha256 the message names."""
    source = st.dbscan(case.version, case.fault, case.after)
    signer = key
    if case.signer == "stranger":
        signer = generate_keypair()
        with live.operator() as op:
            assert (
                op.post(
                    "/keys", json={"name": f"stranger-{case.id}", "public_key": signer.public_b64}
                ).status_code
                == 201
            )
    with live.operator() as op:
        digest = st.upload(op, signer, source, case.version)
    if case.tamper is not None:
        evil = source.replace(b'"""DBSCAN, version', b'"""DBSCAN (with a planted backdoor), version')
        assert evil != source
        digest = st.tamper(live, "dbscan", case.version, evil, fix_digest=case.tamper == "bytes+digest")
    return digest


@pytest.mark.parametrize(
    "case", [pytest.param(c, id=c.id, marks=[pytest.mark.soak] if c.soak else []) for c in CASES]
)
def test_supply_chain_matrix(live: Live, key: KeyPair, robot: Robot, case: Case) -> None:
    digest = _prepare(live, key, case)
    before = robot.map_version()
    pid = robot.agent.proc.pid
    sent_at = time.monotonic()
    ack = st.send(robot.op, robot.rid, UPDATE.format(v=case.version, d=digest))
    seq = int(ack["seq"])
    if case.outcome == "rolled-back":
        assert ack["status"] == "applied", ack  # it passed every check before it ran
        ack = wait_for(
            f"rollback of {case.id}",
            lambda: (
                (m := robot.op.get(f"/robots/{robot.rid}/messages/{seq}").json())["status"] == "rolled-back"
                and m
            ),
            180,
        )
    assert ack["status"] == case.outcome, ack
    answered_s = time.monotonic() - sent_at
    reason = ack["reason"] or ""
    assert all(part in reason for part in case.reason), reason
    assert not case.any_of or any(part in reason for part in case.any_of), reason
    # The robot runs what it ran before, keeps mapping, and reports why.
    wait_for("the built-in DBSCAN in use", lambda: st.noise(robot.op, robot.rid) == "dbscan@1.0.0")
    robot.keeps_mapping()
    assert robot.map_version() > before
    want_error = f"message {seq} rejected" if case.outcome == "rejected" else "rolled back"
    error = wait_for(
        "the robot's last error", lambda: (e := robot.get()["last_error"] or "") and want_error in e and e
    )
    assert case.reason[0] in error
    wait_for(
        f"{case.version} reported rejected in the kernel store",
        lambda: st.state(robot.op, robot.rid, case.version) == "rejected",
    )
    assert robot.agent.proc.poll() is None and robot.agent.proc.pid == pid  # the same process, running
    # No worker is left behind: the checks' worker is killed, a rolled-back kernel's worker too.
    wait_for("no kernel worker left", lambda: not st.workers_of(pid), 30)
    _record(case, ack, before, answered_s)


# --------------------------------------------------------------------------------- the rollback attack
def test_replayed_older_version_is_refused_even_after_a_restart(
    live: Live, key: KeyPair, tmp_path: Path
) -> None:
    """A validly signed older version (a replayed message, or one the server is made to send) is refused
    once the robot has run a newer one, in every form (update, install plus rollback), also after the agent
    restarts; only the operator's override (below-floor="allow", in the audit log) goes below the floor."""
    with live.operator() as op:
        old = st.upload(op, key, st.dbscan("1.1.0"), "1.1.0")
        new = st.upload(op, key, st.dbscan("1.2.0"), "1.2.0")
    agent, rid, token, op = st.start(live, tmp_path, key)
    robot = Robot(agent, rid, op)
    try:
        assert st.send(op, rid, UPDATE.format(v="1.1.0", d=old))["status"] == "applied"
        assert st.send(op, rid, UPDATE.format(v="1.2.0", d=new))["status"] == "applied"
        wait_for("dbscan 1.2.0 in use", lambda: st.noise(op, rid) == "dbscan@1.2.0")
        replay = st.send(op, rid, UPDATE.format(v="1.1.0", d=old))
        assert replay["status"] == "rejected", replay
        assert "1.1.0 is lower than 1.2.0" in replay["reason"] and "rollback attack?" in replay["reason"]
        robot.keeps_mapping()
        assert st.noise(op, rid) == "dbscan@1.2.0"
        wait_for("the refusal as last error", lambda: "rollback attack?" in (robot.get()["last_error"] or ""))
        plain = '<kernel-rollback stage="noise-removal" name="dbscan" version="1.1.0"/>'
        for body in (plain, UPDATE.format(v="1.1.0", d=old).replace("update", "install") + plain):
            # the rollback alone, or the replayed install plus a rollback in one message: refused alike
            refused = st.send(op, rid, body)
            assert refused["status"] == "rejected" and "is lower than 1.2.0" in refused["reason"], refused
            assert 'below-floor="allow"' in refused["reason"], refused
        back = st.send(op, rid, plain.replace("/>", ' below-floor="allow"/>'))
        assert back["status"] == "applied", back
        audit = [e for e in op.get("/audit").json() if e["action"] == "kernel.below_floor"]
        assert any(
            e["target"] == f"robot:{rid}"
            and e["detail"]["kernel"] == "dbscan@1.1.0"
            and e["actor"].startswith("operator:")
            for e in audit
        ), audit
        wait_for("dbscan 1.1.0 in use (explicit rollback)", lambda: st.noise(op, rid) == "dbscan@1.1.0")
        assert agent.stop() == 0, agent.output()
        agent = robot.agent = st.agent(live, tmp_path / "robot.db", rid, token, key)
        robot.keeps_mapping()
        assert st.noise(op, rid) == "dbscan@1.1.0"  # the rolled-back configuration survives the restart
        for body in (
            UPDATE.format(v="1.1.0", d=old),  # the floor (1.2.0) survives it too
            "<noise-removal><dbscan><version>1.0.0</version></dbscan></noise-removal>",
        ):
            again = st.send(op, rid, body)
            assert again["status"] == "rejected" and "is lower than 1.2.0" in again["reason"], again
        up = st.send(op, rid, UPDATE.format(v="1.2.0", d=new))
        assert up["status"] == "applied", up  # going forward again is fine
        robot.keeps_mapping()
    finally:
        assert agent.stop() == 0, agent.output()
        op.close()


# ----------------------------------------------------------------------------------------- the figures
_RESULTS: list[dict[str, Any]] = []


def _record(case: Case, ack: dict[str, Any], before: int, answered_s: float) -> None:
    _RESULTS.append(
        {
            "case": case.id,
            "outcome": ack["status"],
            "reason": ack["reason"],
            "map_version_before": before,
            "answered_s": round(answered_s, 2),  # from sending the message to the final acknowledgement
        }
    )
    out = Path(os.environ.get("LINEMAP_TEST_ARTIFACTS", "test-artifacts")) / "reliability"
    out.mkdir(parents=True, exist_ok=True)
    (out / "supply-matrix.json").write_text(json.dumps(_RESULTS, indent=2))
