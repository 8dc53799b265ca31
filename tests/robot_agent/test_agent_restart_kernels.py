"""What a restart must not lose about downloaded kernels, through a real server and real agent processes
(docs/reliability/agent.md):

- the message that installed a kernel is in the Robot DB: a kernel that fails in service after a kill -9
  and restart is still acknowledged ``rolled-back`` on that message;
- a kernel download answered by a login portal (200 text/html) is a link fault: fetched again once the
  portal is gone, and applied, never rejected for the portal's bytes;
- a stored kernel that no longer imports at start-up falls back for its own stage only: every other stage
  and every tuned parameter stays, and the fallback is reported (last_error, the kernel's state).
"""

from __future__ import annotations

import sqlite3
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from shared.signing import KeyPair, load_private_key, sha256_hex, sign_digest
from tests.reliability import supplytools as st
from tests.robot_agent.agentproc import AgentProcess, robot_db_meta, wait_for
from tests.robot_agent.answerproxy import AnswerProxy
from tests.robot_agent.test_agent_kernels_live import FLAKY, GOOD
from tests.server.live import Live, start_live

XML = {"Content-Type": "application/xml"}
LISTING1 = (Path(__file__).parents[1] / "shared" / "control" / "fixtures" / "listing1.xml").read_bytes()
BROKEN = b'''"""DBSCAN 1.1.0 after a software update removed what it imports (test artifact)."""
from shared.kernels.noise.dbscan import DbscanThatWasRemoved


class Dbscan110(DbscanThatWasRemoved):
    version = "1.1.0"
'''


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    yield from start_live("sqlite", tmp_path_factory.mktemp("restart-kernels"), poll_recheck_s=1.0)


@pytest.fixture(scope="module")
def key(live: Live) -> KeyPair:
    return st.trusted_key(live)


def _sign(key: KeyPair, source: bytes) -> tuple[str, str]:
    digest = sha256_hex(source)
    return digest, sign_digest(load_private_key(key.private_pem), digest)


def _upload(op: httpx.Client, key: KeyPair, source: bytes, version: str) -> str:
    digest, sig = _sign(key, source)
    r = op.post(
        "/kernels",
        data={"name": "dbscan", "stage": "noise-removal", "version": version, "signature": sig},
        files={"file": ("dbscan.py", source, "text/x-python")},
    )
    assert r.status_code in (200, 201), r.text
    return digest


def _queue(op: httpx.Client, rid: int, xml: bytes) -> int:
    r = op.post(f"/robots/{rid}/messages", content=xml, headers=XML)
    assert r.status_code == 201, r.text
    return int(r.json()["seq"])


def _message(op: httpx.Client, rid: int, seq: int) -> dict[str, Any]:
    data: dict[str, Any] = op.get(f"/robots/{rid}/messages/{seq}").json()
    return data


def _agent(live: Live, db: Path, rid: int, token: str, key: KeyPair, rate: str) -> AgentProcess:
    extra = ["--rate", rate, "--laps", "0", "--trust-key", key.public_b64, "--retry-base", "0.05"]
    return AgentProcess(db, server=live.base_url, robot_id=rid, token=token, extra=extra)


def test_a_rollback_after_kill_9_reaches_the_installing_message(
    live: Live, tmp_path: Path, key: KeyPair
) -> None:
    op = live.operator()
    digest = _upload(op, key, FLAKY, "1.2.0")
    rid, token = live.new_robot()
    db = tmp_path / "robot.db"
    first = _agent(live, db, rid, token, key, "5")  # slow: the kernel's 400 good calls outlast this run
    try:
        wait_for("first map", lambda: op.get(f"/robots/{rid}").json()["map_version"] > 0, 120)
        seq = _queue(
            op,
            rid,
            f'<xml><message><kernel-update stage="noise-removal" name="dbscan" version="1.2.0" '
            f'sha256="{digest}"/></message></xml>'.encode(),
        )
        wait_for("installed", lambda: _message(op, rid, seq)["status"] != "queued", 120)
        assert _message(op, rid, seq)["status"] == "applied"
    finally:
        first.kill()  # between the install and the failure
    second = _agent(live, db, rid, token, key, "0")  # flat out: the kernel fails after 400 calls
    try:
        rolled = wait_for(
            "the rollback acknowledged on the installing message",
            lambda: (m := _message(op, rid, seq))["status"] == "rolled-back" and m,
            180,
        )
        assert "sensor buffer overflow" in rolled["reason"], rolled
        wait_for(
            "dbscan 1.0.0 in use again",
            lambda: op.get(f"/robots/{rid}").json()["active_kernels"].get("noise-removal") == "dbscan@1.0.0",
        )
    finally:
        assert second.stop() == 0, second.output()


def test_a_stored_kernel_that_no_longer_imports_keeps_the_other_settings(
    live: Live, tmp_path: Path, key: KeyPair
) -> None:
    op = live.operator()
    digest = _upload(op, key, GOOD, "1.1.0")
    rid, token = live.new_robot()
    db = tmp_path / "robot.db"
    first = _agent(live, db, rid, token, key, "20")
    try:
        wait_for("first map", lambda: op.get(f"/robots/{rid}").json()["map_version"] > 0, 120)
        update = (
            f'<xml><message><kernel-update stage="noise-removal" name="dbscan" version="1.1.0" '
            f'sha256="{digest}"/></message></xml>'
        ).encode()
        for xml in (update, LISTING1):  # dbscan 1.1.0, then tuned parameters on every stage
            seq = _queue(op, rid, xml)
            wait_for(f"message {seq}", lambda s=seq: _message(op, rid, s)["status"] != "queued", 120)  # type: ignore[misc]
            assert _message(op, rid, seq)["status"] == "applied", _message(op, rid, seq)
    finally:
        assert first.stop() == 0, first.output()
    tuned = robot_db_meta(db, "config")
    assert tuned["noise_removal"][0]["version"] == "1.1.0"
    # A software update removed what the stored module imports (still validly signed: it is not tampered).
    broken_digest, broken_sig = _sign(key, BROKEN)
    with sqlite3.connect(db) as conn:
        conn.execute(
            "UPDATE kernels SET source = ?, sha256 = ?, signature = ? "
            "WHERE name = 'dbscan' AND version = '1.1.0'",
            (BROKEN, broken_digest, broken_sig),
        )
    second = _agent(live, db, rid, token, key, "20")
    try:
        robot = wait_for(
            "the fallback reported",
            lambda: "no longer loads" in ((r := op.get(f"/robots/{rid}").json())["last_error"] or "") and r,
            120,
        )
        assert "dbscan 1.1.0" in robot["last_error"], robot["last_error"]
        assert robot["active_kernels"]["noise-removal"] == "dbscan@1.0.0, erosion@1.0.0"
        states = {(k["name"], k["version"]): k["state"] for k in robot["kernels"]}
        assert states[("dbscan", "1.1.0")] == "rejected"
        before = robot["map_version"]
        wait_for("mapping goes on", lambda: op.get(f"/robots/{rid}").json()["map_version"] > before + 5)
    finally:
        assert second.stop() == 0, second.output()
    assert "no longer loads" in second.output()
    config = robot_db_meta(db, "config")
    dbscan, erosion = config["noise_removal"]
    assert dbscan["version"] == "1.0.0" and dbscan["params"] == tuned["noise_removal"][0]["params"]
    assert erosion == tuned["noise_removal"][1]
    for stage in ("mode", "clustering", "straight_line", "segmentation", "scan_matching"):
        assert config[stage] == tuned[stage], stage
    assert dbscan["params"] == {"epsilon_m": 0.05, "min_points": 15}


def test_a_kernel_download_met_by_a_portal_is_fetched_again_not_rejected(
    live: Live, tmp_path: Path, key: KeyPair
) -> None:
    op = live.operator()
    digest = _upload(op, key, GOOD, "1.1.0")
    rid, token = live.new_robot()
    with AnswerProxy(live.base_url) as proxy:
        proxy.mode, proxy.only = "portal", frozenset({"kernel"})
        extra = ["--rate", "20", "--laps", "0", "--trust-key", key.public_b64, "--retry-base", "0.05"]
        agent = AgentProcess(tmp_path / "robot.db", server=proxy.url, robot_id=rid, token=token, extra=extra)
        try:
            wait_for("first map", lambda: op.get(f"/robots/{rid}").json()["map_version"] > 0, 120)
            seq = _queue(
                op,
                rid,
                f'<xml><message><kernel-update stage="noise-removal" name="dbscan" version="1.1.0" '
                f'sha256="{digest}"/></message></xml>'.encode(),
            )
            wait_for("downloads met the portal", lambda: proxy.count("portal", "kernel") >= 3, 120)
            assert _message(op, rid, seq)["status"] == "queued", "a portal page is no reason to reject"
            proxy.mode = "pass"
            wait_for("acknowledged", lambda: _message(op, rid, seq)["status"] != "queued", 120)
            assert _message(op, rid, seq)["status"] == "applied", _message(op, rid, seq)
            wait_for(
                "dbscan 1.1.0 in use",
                lambda: (
                    op.get(f"/robots/{rid}").json()["active_kernels"].get("noise-removal") == "dbscan@1.1.0"
                ),
            )
        finally:
            assert agent.stop() == 0, agent.output()
