"""Killing a server process under a robot: an agent given the fleet's processes (``--server A,B``) moves to
the next one when its process is killed with SIGKILL, and no map version is lost or applied twice (the
server's record of accepted uploads is one unbroken chain of versions, and it ends at the robot's last
version); a control message queued on the survivor reaches the robot. Real ``linemap server`` processes on
one PostgreSQL database, a real ``linemap agent`` process."""

from __future__ import annotations

import itertools
from pathlib import Path

from sqlalchemy import create_engine, text

from server.database import normalize_url
from tests.robot_agent.agentproc import AgentProcess, robot_db_meta, wait_for
from tests.server.procs import fresh_database, server_procs

XML = {"Content-Type": "application/xml"}
#: Readiness deadline, s: the agent's first steps compile its kernels, slow on a loaded 2-core machine.
READY_S = 240.0


def _chain(url: str, rid: int) -> list[tuple[int, int | None]]:
    """(version, base_version) of every upload the server accepted from robot ``rid``, in order."""
    engine = create_engine(normalize_url(url))
    try:
        with engine.connect() as conn:
            rows = conn.execute(
                text("SELECT version, base_version FROM map_uploads WHERE robot_id = :r ORDER BY id"),
                {"r": rid},
            ).all()
    finally:
        engine.dispose()
    return [(int(v), None if b is None else int(b)) for v, b in rows]


def test_an_agent_rides_out_the_kill_of_its_server_process(tmp_path: Path) -> None:
    with fresh_database("postgresql", tmp_path) as url, server_procs(url, 2) as (procs, admin):
        a, b = procs
        with a.client(admin) as op:
            made = op.post("/robots", json={"name": "failover-bot"}).json()
        rid, token = int(made["id"]), str(made["token"])
        db = tmp_path / "robot.db"
        agent = AgentProcess(
            db,
            server=f"{a.base_url},{b.base_url}",
            robot_id=rid,
            token=token,
            extra=["--rate", "20", "--laps", "0", "--retry-base", "0.05"],
        )
        try:
            with b.client(admin) as op:

                def server_version() -> int:
                    return int(op.get(f"/robots/{rid}").json()["map_version"])

                wait_for("uploads through A", lambda: server_version() >= 20, READY_S)
                a.proc.kill()  # SIGKILL: no shutdown, the agent's long-poll and uploads on A are cut
                a.proc.wait(30)
                at_kill = server_version()
                wait_for("uploads through B", lambda: server_version() >= at_kill + 20, READY_S)
                r = op.post(
                    f"/robots/{rid}/messages",
                    content=b"<xml><message><n-smax>7</n-smax></message></xml>",
                    headers=XML,
                )
                assert r.status_code == 201, r.text
                seq = int(r.json()["seq"])
                wait_for(
                    "the message queued on B applied",
                    lambda: op.get(f"/robots/{rid}/messages/{seq}").json()["status"] == "applied",
                    READY_S,
                )
        finally:
            assert agent.stop(READY_S) == 0, agent.output()
        assert "Traceback" not in agent.output()
        assert "the next calls go to " + b.base_url in agent.output()
        chain = _chain(url, rid)
        assert chain and chain[0][1] is None, f"the first upload is a snapshot: {chain[:3]}"
        versions = [v for v, _ in chain]
        assert len(set(versions)) == len(versions), f"a version accepted twice: {versions}"
        broken = [(prev, cur) for prev, cur in itertools.pairwise(chain) if cur[1] != prev[0]]
        assert not broken, f"uploads whose base is not the version before them: {broken[:5]}"
        delivered = int(robot_db_meta(db, "uploaded_version") or 0)
        assert versions[-1] == delivered, "the chain ends at the robot's last delivered version"
