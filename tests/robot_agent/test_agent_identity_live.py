"""Map identity through the real thing (docs/reliability/identity.md): real ``linemap agent``
processes against a real server on 127.0.0.1 (uvicorn in-process, or ``linemap server`` processes for the
restore from a backup). A Robot DB deleted and started again makes a new map on the server (the old one
kept and listed, the new one holding only its own walls); of two agents started with one token the later
takes over and the earlier stops with a clear error; two agents on one Robot DB are refused at start; a
server database put back from an older copy continues the robot's message numbering (a new message is
applied, not skipped) and ends with the robot's map."""

from __future__ import annotations

import shutil
import sqlite3
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from tests.robot_agent.agentproc import AgentProcess, robot_db_meta, wait_for
from tests.server.live import Live, start_live
from tests.server.procs import ServerProc, _free_port

LINEMAP = str(Path(sys.executable).parent / "linemap")


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    yield from start_live("sqlite", tmp_path_factory.mktemp("identity-live"), poll_recheck_s=1.0)


def _robot_walls(db: Path) -> list[list[float]]:
    with sqlite3.connect(db) as conn:
        rows = conn.execute("SELECT segment_id, x0_m, y0_m, x1_m, y1_m FROM walls ORDER BY segment_id")
        return [[float(r[0]), *r[1:]] for r in rows]


def _latest(op: httpx.Client, rid: int, session: str | None = None) -> dict[str, object]:
    r = op.get(f"/robots/{rid}/maps/latest", params={"session": session} if session else {})
    assert r.status_code == 200, r.text
    out: dict[str, object] = r.json()
    return out


def _forget(db: Path) -> None:
    for suffix in ("", "-wal", "-shm", ".lock"):
        Path(f"{db}{suffix}").unlink(missing_ok=True)


def test_a_deleted_robot_db_makes_a_new_map_and_the_old_one_is_kept(live: Live, tmp_path: Path) -> None:
    rid, token = live.new_robot()
    db = tmp_path / "robot.db"
    op = live.operator()
    first = AgentProcess(db, server=live.base_url, robot_id=rid, token=token, extra=["--rate", "60"])
    wait_for("uploads", lambda: (robot_db_meta(db, "uploaded_version") or 0) >= 40 if db.exists() else False)
    assert first.stop() == 0, first.output()
    old_session, old_walls = robot_db_meta(db, "map_session"), _robot_walls(db)
    assert _latest(op, rid)["segments"] == old_walls
    _forget(db)  # the Robot DB is lost

    second = AgentProcess(db, server=live.base_url, robot_id=rid, token=token, extra=["--rate", "60"])
    wait_for("uploads", lambda: (robot_db_meta(db, "uploaded_version") or 0) >= 20 if db.exists() else False)
    assert second.stop() == 0, second.output()
    new_session = robot_db_meta(db, "map_session")
    assert new_session != old_session
    now = _latest(op, rid)
    assert now["map_session"] == new_session
    assert now["segments"] == _robot_walls(db), "the server's map is the new Robot DB's, nothing mixed in"
    assert _latest(op, rid, old_session)["segments"] == old_walls, "the old map is kept whole"
    listed = op.get(f"/robots/{rid}/maps").json()
    assert [(m["map_session"], m["current"]) for m in listed] == [(new_session, True), (old_session, False)]
    assert listed[0]["reason"] == "new Robot DB"


def test_of_two_agents_on_one_token_the_later_takes_over(live: Live, tmp_path: Path) -> None:
    rid, token = live.new_robot()
    op = live.operator()
    db_a, db_b = tmp_path / "a.db", tmp_path / "b.db"
    a = AgentProcess(db_a, server=live.base_url, robot_id=rid, token=token, extra=["--rate", "30"])
    wait_for(
        "A uploads", lambda: (robot_db_meta(db_a, "uploaded_version") or 0) >= 10 if db_a.exists() else False
    )
    b = AgentProcess(db_b, server=live.base_url, robot_id=rid, token=token, extra=["--rate", "30"])
    try:
        code = a.proc.wait(120)  # A is refused at its next request and stops
    finally:
        if a.proc.poll() is None:
            a.kill()
    out = a.output()
    assert code == 2, out
    assert "another agent with robot" in out and "took over at" in out, out
    assert "Traceback" not in out
    wait_for("B uploads", lambda: (robot_db_meta(db_b, "uploaded_version") or 0) >= 10)
    assert b.stop() == 0, b.output()
    now = _latest(op, rid)
    assert now["map_session"] == robot_db_meta(db_b, "map_session")
    assert now["segments"] == _robot_walls(db_b), "the server's map holds B's session's walls only"
    actions = {e["action"] for e in op.get("/audit", params={"target": f"robot:{rid}"}).json()}
    assert {"agent.takeover", "agent.refused", "map.session.start"} <= actions


def test_two_agents_on_one_robot_db_are_refused_at_start(live: Live, tmp_path: Path) -> None:
    rid, token = live.new_robot()
    db = tmp_path / "robot.db"
    first = AgentProcess(db, server=live.base_url, robot_id=rid, token=token, extra=["--rate", "30"])
    try:
        wait_for(
            "the first maps", lambda: (robot_db_meta(db, "map_version") or 0) >= 5 if db.exists() else False
        )
        second = AgentProcess(db, server=live.base_url, robot_id=rid, token=token, extra=["--rate", "30"])
        code = second.proc.wait(60)
        out = second.output()
        assert code == 2, out
        assert f"another agent (pid {first.proc.pid}) is running on the Robot DB" in out, out
        assert "Traceback" not in out
        assert first.proc.poll() is None, "the first agent goes on"
    finally:
        assert first.stop() == 0, first.output()


class _Server:
    """``linemap server`` on a SQLite file and a fixed port (the agent keeps its URL across restarts)."""

    def __init__(self, db: Path, port: int) -> None:
        self.db, self.port = db, port
        self.base_url = f"http://127.0.0.1:{port}"
        self.token: str | None = None
        self.srv: ServerProc | None = None

    def start(self) -> None:
        proc = subprocess.Popen(
            [LINEMAP, "server", "--db", f"sqlite:///{self.db}", "--port", str(self.port)],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        assert proc.stdout is not None
        lines = [proc.stdout.readline()]
        while lines[-1] and "linemap server on" not in lines[-1]:
            lines.append(proc.stdout.readline())
        text = "".join(lines)
        assert "linemap server on" in text, text
        if "keep it): " in text:
            self.token = text.split("keep it): ")[1].split()[0]
        self.srv = ServerProc(proc, self.base_url)
        wait_for("the server", self._up, 30)

    def _up(self) -> bool:
        try:
            return httpx.get(f"{self.base_url}/healthz", timeout=2).status_code == 200
        except httpx.TransportError:
            return False

    def stop(self) -> None:
        if self.srv is not None:
            self.srv.proc.terminate()
            self.srv.proc.communicate(timeout=30)
            self.srv = None

    def client(self) -> httpx.Client:
        assert self.srv is not None
        return self.srv.client(self.token)


def _post(op: httpx.Client, rid: int, body: str) -> int:
    r = op.post(
        f"/robots/{rid}/messages",
        content=f"<xml><message>{body}</message></xml>",
        headers={"Content-Type": "application/xml"},
    )
    assert r.status_code == 201, r.text
    return int(r.json()["seq"])


def _applied(db: Path) -> list[int]:
    try:
        with sqlite3.connect(db) as conn:
            return [r[0] for r in conn.execute("SELECT seq FROM applied_messages ORDER BY seq")]
    except sqlite3.OperationalError:  # the agent is still creating its Robot DB
        return []


def test_a_server_restored_from_an_older_copy_continues_the_robots_numbering(tmp_path: Path) -> None:
    server = _Server(tmp_path / "server.db", _free_port())
    server.start()
    db = tmp_path / "robot.db"
    with server.client() as op:
        robot = op.post("/robots", json={"name": "restored"}).json()
        rid = int(robot["id"])
        assert _post(op, rid, "<mode>offline</mode>") == 1
    agent = AgentProcess(
        db, server=server.base_url, robot_id=rid, token=robot["token"], extra=["--rate", "30"]
    )
    try:
        wait_for("message 1 applied", lambda: _applied(db) == [1] if db.exists() else False)
        server.stop()
        shutil.copy(server.db, tmp_path / "backup.db")  # the backup: message 1 only
        server.start()
        with server.client() as op:
            assert _post(op, rid, "<mode>online</mode>") == 2
            assert _post(op, rid, "<n-smax>5</n-smax>") == 3
        wait_for("messages 2 and 3 applied", lambda: _applied(db) == [1, 2, 3])
        server.stop()
        for suffix in ("-wal", "-shm"):
            Path(f"{server.db}{suffix}").unlink(missing_ok=True)
        shutil.copy(tmp_path / "backup.db", server.db)  # the restore: the server's numbering is at 1
        server.start()
        with server.client() as op:
            wait_for("the numbering resynchronised", lambda: op.get(f"/robots/{rid}").json()["last_seq"] >= 3)
            seq = _post(op, rid, "<mode>offline</mode>")
            assert seq == 4, "numbering continues after the robot's"
            wait_for(
                "message 4 applied",
                lambda: op.get(f"/robots/{rid}/messages/{seq}").json()["status"] == "applied",
            )
            assert _applied(db) == [1, 2, 3, 4]
            audit = op.get("/audit", params={"action": "messages.resync"}).json()
            assert (
                audit
                and audit[0]["detail"]["robot_applied"] == 3
                and audit[0]["detail"]["server_last_seq"] == 1
            )
        assert agent.stop() == 0, agent.output()
        with server.client() as op:
            latest = _latest(op, rid)
            assert latest["version"] == robot_db_meta(db, "map_version"), "the map versions agree"
            assert latest["map_session"] == robot_db_meta(db, "map_session")
            assert latest["segments"] == _robot_walls(db)
    finally:
        if agent.proc.poll() is None:
            agent.kill()
        server.stop()
