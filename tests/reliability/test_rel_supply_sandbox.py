"""Downloaded kernels run in confined worker processes (docs/reliability/sandbox.md): a real server, a
real agent process and signed kernels. The matrix of faults (hangs at import, on empty input, in a
GIL-holding C call in service, allocations, network and file access) is in test_rel_supply_live.py; here:
``kill -9`` of the agent while a kernel's dry run spins leaves no process behind, and after a restart the
same message is refused within its limits (not run for ever) and the next message is applied.
"""

from __future__ import annotations

import signal
from collections.abc import Iterator
from pathlib import Path

import pytest

from shared.signing import KeyPair, generate_keypair
from tests.reliability import supplytools as st
from tests.robot_agent.agentproc import AgentProcess, wait_for
from tests.server.live import Live, start_live

UPDATE = '<kernel-update stage="noise-removal" name="dbscan" version="{v}" sha256="{d}"/>'


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    yield from start_live("sqlite", tmp_path_factory.mktemp("sandbox-server"), poll_recheck_s=1.0)


@pytest.fixture(scope="module")
def key(live: Live) -> KeyPair:
    return st.trusted_key(live)


def _kill_9_during_the_checks(agent: AgentProcess) -> None:
    """Wait until the agent's checks run in a worker, SIGKILL the agent alone (not its process group, so
    only the parent-death signal can end the worker) and wait until no worker of it is left."""
    pid = agent.proc.pid
    workers = wait_for("the checks' worker process", lambda: st.workers_of(pid), 120)
    agent.proc.send_signal(signal.SIGKILL)
    agent.proc.wait(30)
    wait_for(f"no orphaned worker (had {workers})", lambda: not st.workers_of(pid), 10)


def test_kill_9_during_a_dry_run_leaves_no_child_and_the_restart_refuses_the_message(
    live: Live, key: KeyPair, tmp_path: Path
) -> None:
    """The agent is killed while a kernel's dry run spins: its worker dies with it. After a restart the
    same message is checked again, killed at its limit and refused (recorded, so never fetched again);
    mapping goes on and the next message is applied."""
    with live.operator() as op:
        digest = st.upload(op, key, st.dbscan("4.0.1", "hangs"), "4.0.1")
    agent, rid, token, op = st.start(live, tmp_path, key)
    try:
        r = op.post(
            f"/robots/{rid}/messages",
            content=f"<xml><message>{UPDATE.format(v='4.0.1', d=digest)}</message></xml>",
            headers=st.XML,
        )
        assert r.status_code == 201, r.text
        seq = int(r.json()["seq"])
        _kill_9_during_the_checks(agent)
        agent = st.agent(live, tmp_path / "robot.db", rid, token, key)
        ack = wait_for(
            f"message {seq} answered after the restart",
            lambda: (m := op.get(f"/robots/{rid}/messages/{seq}").json())["status"] != "queued" and m,
            180,
        )
        assert ack["status"] == "rejected", ack
        assert "dry run: ran longer than its 4500 ms budget" in ack["reason"], ack
        assert agent.stop() == 0, agent.output()
        checked = agent.output().count("ran longer than")  # the log goes on across restarts
        agent = st.agent(live, tmp_path / "robot.db", rid, token, key)  # the refusal holds across a restart
        start = op.get(f"/robots/{rid}").json()["map_version"]
        wait_for("mapping goes on", lambda: op.get(f"/robots/{rid}").json()["map_version"] >= start + 10, 120)
        nxt = st.send(op, rid, "<noise-removal><dbscan><epsilon>6</epsilon></dbscan></noise-removal>")
        assert nxt["status"] == "applied", nxt
        assert op.get(f"/robots/{rid}/messages/{seq}").json()["status"] == "rejected"
        assert st.noise(op, rid) == "dbscan@1.0.0"
        assert agent.output().count("ran longer than") == checked  # the refused message was not checked again
        assert not st.workers_of(agent.proc.pid)
    finally:
        assert agent.stop() == 0, agent.output()
        op.close()


def test_a_stranger_key_never_starts_a_worker(live: Live, key: KeyPair, tmp_path: Path) -> None:
    """Nothing of an unverified artifact runs anywhere: the signature is checked before any worker."""
    stranger = generate_keypair()
    with live.operator() as op:
        assert (
            op.post("/keys", json={"name": "stranger", "public_key": stranger.public_b64}).status_code == 201
        )
        digest = st.upload(op, stranger, st.dbscan("4.0.2", "import-hang"), "4.0.2")
    agent, rid, _token, op = st.start(live, tmp_path, key)
    try:
        ack = st.send(op, rid, UPDATE.format(v="4.0.2", d=digest))
        assert ack["status"] == "rejected" and "bad signature" in ack["reason"], ack
        assert not st.workers_of(agent.proc.pid)
    finally:
        assert agent.stop() == 0, agent.output()
        op.close()
