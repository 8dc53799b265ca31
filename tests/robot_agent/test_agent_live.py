"""The agent as a real process against a real server on 127.0.0.1: control messages take effect, every
map version arrives exactly once and in order (also across kill -9 and a server outage)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from server.app import create_app
from server.bootstrap import ensure_admin_token
from server.settings import Settings
from shared.sim import default_world, simulate_run
from tests.robot_agent.agentproc import AgentProcess, integrity, robot_db_meta, wait_for
from tests.server.live import Live, ServerThread, start_live

LISTING1 = (Path(__file__).parents[1] / "shared" / "control" / "fixtures" / "listing1.xml").read_bytes()
N_SCANS = len(simulate_run(default_world(), seed=0).scans)


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    yield from start_live("sqlite", tmp_path_factory.mktemp("agent-server"), poll_recheck_s=1.0)


def _agent(live: Live, tmp_path: Path, *extra: str) -> tuple[AgentProcess, int, httpx.Client]:
    rid, token = live.new_robot()
    agent = AgentProcess(
        tmp_path / "robot.db", server=live.base_url, robot_id=rid, token=token, extra=list(extra)
    )
    return agent, rid, live.operator()


def _trajectory_stamps(op: httpx.Client, rid: int) -> list[float]:
    return [row[0] for row in op.get(f"/robots/{rid}/maps/latest").json()["trajectory"]]


def test_listing1_takes_effect_on_the_robot(live: Live, tmp_path: Path) -> None:
    agent, rid, op = _agent(live, tmp_path, "--rate", "20")
    try:
        wait_for("first map", lambda: op.get(f"/robots/{rid}").json()["map_version"] > 0)
        r = op.post(f"/robots/{rid}/messages", content=LISTING1, headers={"Content-Type": "application/xml"})
        assert r.status_code == 201
        seq = r.json()["seq"]
        msg = wait_for(
            "ack", lambda: (m := op.get(f"/robots/{rid}/messages/{seq}").json())["status"] != "queued" and m
        )
        assert msg["status"] == "applied", msg
        kernels = wait_for(
            "status with erosion",
            lambda: "erosion" in str(k := op.get(f"/robots/{rid}").json()["active_kernels"]) and k,
        )
        assert kernels["noise-removal"] == "dbscan@1.0.0, erosion@1.0.0"
        assert kernels["clustering"] == "kmeans@1.0.0" and kernels["straight-line"] == "hough@1.0.0"
        steps_then = op.get(f"/robots/{rid}").json()["map_version"]
        wait_for("mapping goes on", lambda: op.get(f"/robots/{rid}").json()["map_version"] > steps_then + 5)
    finally:
        assert agent.stop() == 0, agent.output()
    config = robot_db_meta(agent.db, "config")
    dbscan, erosion = config["noise_removal"]
    assert dbscan["name"] == "dbscan" and dbscan["params"] == {"epsilon_m": 0.05, "min_points": 15}
    assert erosion["params"] == {"element": "PLUSx4"}
    assert erosion["name"] == "erosion"
    assert config["clustering"]["name"] == "kmeans" and config["straight_line"]["name"] == "hough"


def test_invalid_config_is_rejected_and_mapping_continues(live: Live, tmp_path: Path) -> None:
    agent, rid, op = _agent(live, tmp_path, "--rate", "20")
    try:
        wait_for("first map", lambda: op.get(f"/robots/{rid}").json()["map_version"] > 0)
        # A valid message the server queues, but the robot has no dbscan 9.9.9 to roll back to.
        bad = (
            b'<xml><message><kernel-rollback stage="noise-removal" name="dbscan" version="9.9.9"/>'
            b"</message></xml>"
        )
        r = op.post(f"/robots/{rid}/messages", content=bad, headers={"Content-Type": "application/xml"})
        assert r.status_code == 201, r.text
        seq = r.json()["seq"]
        msg = wait_for(
            "ack", lambda: (m := op.get(f"/robots/{rid}/messages/{seq}").json())["status"] != "queued" and m
        )
        assert msg["status"] == "rejected" and "9.9.9" in msg["reason"], msg
        before = op.get(f"/robots/{rid}").json()["map_version"]
        wait_for("mapping goes on", lambda: op.get(f"/robots/{rid}").json()["map_version"] > before + 5)
    finally:
        agent.stop()


def test_every_scan_reaches_the_server_once_across_kill_9(live: Live, tmp_path: Path) -> None:
    rid, token = live.new_robot()
    db = tmp_path / "robot.db"
    op = live.operator()
    first = AgentProcess(db, server=live.base_url, robot_id=rid, token=token, extra=["--rate", "0"])
    wait_for("some steps", lambda: (robot_db_meta(db, "map_version") or 0) >= 80 if db.exists() else False)
    first.kill()
    assert integrity(db) == "ok"
    killed_at = robot_db_meta(db, "map_version")
    second = AgentProcess(db, server=live.base_url, robot_id=rid, token=token, extra=["--rate", "0"])
    try:
        wait_for(
            "all versions uploaded", lambda: op.get(f"/robots/{rid}").json()["map_version"] >= N_SCANS, 120
        )
    finally:
        assert second.stop() == 0, second.output()
    assert integrity(db) == "ok"
    stamps = _trajectory_stamps(op, rid)
    assert len(stamps) == N_SCANS, f"killed at version {killed_at}; the server holds {len(stamps)} poses"
    assert stamps == sorted(set(stamps)), "each scan exactly once, in order"
    assert robot_db_meta(db, "uploaded_version") == N_SCANS


def test_server_outage_is_bridged(tmp_path: Path) -> None:
    """The server goes away mid-run and comes back on the same port and database: the robot kept mapping,
    and the server ends with every scan's pose exactly once, in order."""
    url = f"sqlite:///{tmp_path / 'server.db'}"
    app = create_app(Settings(database_url=url, poll_recheck_s=1.0))
    token = ensure_admin_token(app.state.linemap.db)
    assert token is not None
    with ServerThread(app) as srv:
        port = srv.port
        base = f"http://127.0.0.1:{port}"
        with httpx.Client(base_url=base + "/api/v1", headers={"Authorization": f"Bearer {token}"}) as op:
            robot = op.post("/robots", json={"name": "outage"}).json()
        db = tmp_path / "robot.db"
        agent = AgentProcess(
            db, server=base, robot_id=robot["id"], token=robot["token"], extra=["--rate", "40"]
        )
        wait_for(
            "uploads begin",
            lambda: (robot_db_meta(db, "uploaded_version") or 0) >= 20 if db.exists() else False,
        )
    # The server is down: the robot maps on.
    down_at = robot_db_meta(db, "map_version")
    wait_for("mapping while the server is down", lambda: robot_db_meta(db, "map_version") >= down_at + 40)
    app2 = create_app(Settings(database_url=url, poll_recheck_s=1.0))
    try:
        with (
            ServerThread(app2, port=port),
            httpx.Client(base_url=base + "/api/v1", headers={"Authorization": f"Bearer {token}"}) as op,
        ):
            wait_for(
                "everything uploaded",
                lambda: op.get(f"/robots/{robot['id']}").json()["map_version"] >= N_SCANS,
                180,
            )
            stamps = [r[0] for r in op.get(f"/robots/{robot['id']}/maps/latest").json()["trajectory"]]
    finally:
        agent.stop()
    assert len(stamps) == N_SCANS and stamps == sorted(set(stamps))


def test_a_missing_laser_fails_clearly(tmp_path: Path) -> None:
    device = tmp_path / "ttyACM9"  # no such device
    agent = AgentProcess(tmp_path / "r.db", server=None, extra=["--source", f"urg:{device}"])
    code = agent.proc.wait(60)
    out = agent.output()
    assert code == 2, out
    assert "URG-04LX serial driver could not start" in out and str(device) in out
    assert "Traceback" not in out


def test_messages_apply_exactly_once_across_kill_9(live: Live, tmp_path: Path) -> None:
    """Messages applied before a kill -9 are not applied again after the restart; later ones are, in order."""
    import sqlite3

    rid, token = live.new_robot()
    db = tmp_path / "robot.db"
    op = live.operator()
    first = AgentProcess(db, server=live.base_url, robot_id=rid, token=token, extra=["--rate", "20"])
    for mode in ("offline", "online"):
        r = op.post(
            f"/robots/{rid}/messages",
            content=f"<xml><message><mode>{mode}</mode></message></xml>",
            headers={"Content-Type": "application/xml"},
        )
        assert r.status_code == 201
    wait_for("both applied", lambda: robot_db_meta(db, "config") is not None and _applied(db) == [1, 2])
    first.kill()
    r = op.post(
        f"/robots/{rid}/messages",
        content=b"<xml><message><n-smax>5</n-smax></message></xml>",
        headers={"Content-Type": "application/xml"},
    )
    assert r.status_code == 201
    second = AgentProcess(db, server=live.base_url, robot_id=rid, token=token, extra=["--rate", "20"])
    try:
        wait_for(
            "message 3 acknowledged",
            lambda: op.get(f"/robots/{rid}/messages/3").json()["status"] == "applied",
        )
    finally:
        assert second.stop() == 0, second.output()
    assert _applied(db) == [1, 2, 3]
    with sqlite3.connect(db) as conn:
        seqs = [
            row[0] for row in conn.execute("SELECT seq FROM config_history WHERE seq IS NOT NULL ORDER BY id")
        ]
    assert seqs == [1, 2, 3], "each message put its configuration in force exactly once"
    assert robot_db_meta(db, "config")["n_smax"] == 5


def _applied(db: Path) -> list[int]:
    import sqlite3

    try:
        with sqlite3.connect(db) as conn:
            return [row[0] for row in conn.execute("SELECT seq FROM applied_messages ORDER BY seq")]
    except sqlite3.OperationalError:
        return []
