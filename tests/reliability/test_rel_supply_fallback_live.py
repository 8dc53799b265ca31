"""The last fallback of a kernel in service, through a real server and a real agent process with a signed
kernel: ``<kernel-delete>`` of the built-in version that a downloaded one in service falls back to is
rejected with a reason naming that kernel; when the downloaded one then fails in service it is rolled back
to the built-in version, the agent keeps mapping (same process), and the next message is applied."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from shared.signing import KeyPair
from tests.reliability import supplytools as st
from tests.robot_agent.agentproc import wait_for
from tests.server.live import Live, start_live

UPDATE = '<kernel-update stage="noise-removal" name="dbscan" version="{v}" sha256="{d}"/>'
DELETE = '<kernel-delete stage="noise-removal" name="dbscan" version="{v}"/>'


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    yield from start_live("sqlite", tmp_path_factory.mktemp("fallback-server"), poll_recheck_s=1.0)


@pytest.fixture(scope="module")
def key(live: Live) -> KeyPair:
    return st.trusted_key(live)


def test_the_built_in_fallback_cannot_be_deleted_and_a_later_failure_rolls_back(
    live: Live, key: KeyPair, tmp_path: Path
) -> None:
    with live.operator() as op:
        # behaves through the dry run and the conformance battery, then answers the wrong type in service
        digest = st.upload(op, key, st.dbscan("1.1.0", "wrong-type", after=150), "1.1.0")
    agent, rid, _token, op = st.start(live, tmp_path, key)
    pid = agent.proc.pid
    try:
        up = st.send(op, rid, UPDATE.format(v="1.1.0", d=digest))
        assert up["status"] == "applied", up
        deleted = st.send(op, rid, DELETE.format(v="1.0.0"))
        assert deleted["status"] == "rejected", deleted
        reason = deleted["reason"]
        assert "built-in version cannot be deleted" in reason and "dbscan 1.1.0" in reason, reason
        rolled: dict[str, Any] = wait_for(
            "the failing 1.1.0 rolled back",
            lambda: (
                (m := op.get(f"/robots/{rid}/messages/{up['seq']}").json())["status"] == "rolled-back" and m
            ),
            120,
        )
        assert "wrong" in (rolled["reason"] or "") or "result" in (rolled["reason"] or ""), rolled
        wait_for("the built-in dbscan in use", lambda: st.noise(op, rid) == "dbscan@1.0.0")
        start = op.get(f"/robots/{rid}").json()["map_version"]
        wait_for("mapping goes on", lambda: op.get(f"/robots/{rid}").json()["map_version"] > start + 10, 120)
        after = st.send(op, rid, "<mode>online</mode>")
        assert after["status"] == "applied", after  # the control channel lives
        assert agent.proc.poll() is None and agent.proc.pid == pid, agent.output()[-3000:]
        assert "no fallback" not in agent.output()
    finally:
        assert agent.stop() == 0, agent.output()[-3000:]
        op.close()
