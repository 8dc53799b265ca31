"""``linemap agent --continue-map`` through the real thing: real agent processes against a real server on
127.0.0.1 (docs/reliability/identity.md, "Continuing the server's map"). A robot whose Robot DB was lost
continues the server's map: the same map session (no second map listed), the next versions after the
server's, the walls kept with their ids, nothing drawn twice, and poses that follow those of a robot that
mapped the whole way without a break (within 5 cm). The flag on a Robot DB with a map of its own does
nothing; without a server, or with one that does not answer, the agent stops with a clear error."""

from __future__ import annotations

import math
import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from tests.robot_agent.agentproc import AgentProcess, robot_db_meta, wait_for
from tests.server.live import Live, start_live

LINEMAP = str(Path(sys.executable).parent / "linemap")
STEPS = (
    250  # before the Robot DB is lost, and again after (the robot turning then: scan 250 of the simulator)
)


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    yield from start_live("sqlite", tmp_path_factory.mktemp("continue-live"))


def _map(op: httpx.Client, rid: int) -> dict[str, Any]:
    r = op.get(f"/robots/{rid}/maps/latest")
    assert r.status_code == 200, r.text
    out: dict[str, Any] = r.json()
    return out


def _start(live: Live, rid: int, token: str, db: Path, steps: int, *extra: str) -> AgentProcess:
    """An agent mapping ``steps`` scans of the simulated world flat out."""
    args = ["--rate", "0", "--max-steps", str(steps), *extra]
    return AgentProcess(db, server=live.base_url, robot_id=rid, token=token, extra=args)


def _mapped(
    live: Live, rid: int, token: str, db: Path, until: int, *extra: str, steps: int = STEPS
) -> AgentProcess:
    """An agent mapping ``steps`` scans of the simulated world flat out until the server holds version
    ``until``, then stopped (killed, whatever happened, if it is still running)."""
    agent = _start(live, rid, token, db, steps, *extra)
    try:
        with live.operator() as op:
            wait_for(f"version {until} on the server", lambda: _map(op, rid)["version"] == until, 300)
        assert agent.stop() == 0, agent.output()
    finally:
        if agent.proc.poll() is None:
            agent.kill()
    return agent


def test_a_new_robot_db_continues_the_servers_map(live: Live, tmp_path: Path) -> None:
    rid, token = live.new_robot()
    op = live.operator()
    _mapped(live, rid, token, tmp_path / "lost.db", STEPS)
    before = _map(op, rid)

    again = _mapped(live, rid, token, tmp_path / "new.db", 2 * STEPS, "--continue-map")
    out = again.output()
    assert "continued the server's map" in out and "Traceback" not in out, out[-3000:]
    after = _map(op, rid)
    assert after["map_session"] == before["map_session"], "the same map, not a new one"
    listed = op.get(f"/robots/{rid}/maps").json()
    assert [m["map_session"] for m in listed] == [before["map_session"]]
    stamps = [row[0] for row in after["trajectory"]]
    assert len(stamps) == 2 * STEPS and stamps == sorted(set(stamps)), "each pose once, in order"
    old_ids = {int(s[0]) for s in before["segments"]}
    new_ids = {int(s[0]) for s in after["segments"]}
    assert len(old_ids - new_ids) <= 1, "the server's walls go on with their ids"
    assert all(i > max(old_ids) for i in new_ids - old_ids)

    # a robot that mapped the same way without a break
    rid2, token2 = live.new_robot()
    _mapped(live, rid2, token2, tmp_path / "through.db", 2 * STEPS, steps=2 * STEPS)
    ref = _map(op, rid2)
    assert abs(len(after["segments"]) - len(ref["segments"])) <= 1, "a wall drawn twice"
    offs = [
        math.hypot(a[1] - b[1], a[2] - b[2])
        for a, b in zip(after["trajectory"], ref["trajectory"], strict=True)
    ]
    assert max(offs) < 0.05, f"the continued poses left the uninterrupted run's by {max(offs):.3f} m"

    # the flag kept on a later start: this Robot DB has its own map now, and goes on with it
    # (the simulator's drive is 507 scans)
    later = _mapped(live, rid, token, tmp_path / "new.db", 2 * STEPS + 5, "--continue-map", steps=5)
    assert "holds a map of its own" in later.output()
    assert robot_db_meta(tmp_path / "new.db", "map_session") == before["map_session"]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.mark.parametrize("server", [None, "unreachable"])
def test_continue_map_without_a_server_stops_with_a_clear_error(server: str | None, tmp_path: Path) -> None:
    args = [LINEMAP, "agent", "--db", str(tmp_path / "r.db"), "--continue-map", "--max-steps", "1"]
    if server is not None:
        args += ["--server", f"http://127.0.0.1:{_free_port()}", "--robot-id", "1", "--token", "lmr_x"]
    done = subprocess.run(args, capture_output=True, text=True, timeout=120)
    assert done.returncode != 0
    said = done.stdout + done.stderr
    assert "Traceback" not in said
    expected = "needs the server" if server is None else "could not be read"
    assert expected in said, said
    assert robot_db_meta(tmp_path / "r.db", "map_version") is None, "no map started instead"


def test_with_loop_closure_the_continued_graph_keyframes_follow_the_servers(
    live: Live, tmp_path: Path
) -> None:
    rid, token = live.new_robot()
    op = live.operator()
    _mapped(live, rid, token, tmp_path / "lost.db", STEPS, "--loop-closure")
    before = _map(op, rid)
    old = {int(k[0]) for k in before["keyframes"] or []}
    assert old, "the first robot's pose graph made keyframes"
    again = _mapped(live, rid, token, tmp_path / "new.db", 2 * STEPS, "--loop-closure", "--continue-map")
    assert "Traceback" not in again.output()
    after = _map(op, rid)
    assert after["map_session"] == before["map_session"]
    ids = [int(k[0]) for k in after["keyframes"] or []]
    assert len(ids) == len(set(ids)), "keyframe ids repeat"
    assert old <= set(ids), "the server's keyframes are kept"
    kept = {int(k[0]): k for k in after["keyframes"] if int(k[0]) in old}
    assert kept == {int(k[0]): k for k in before["keyframes"]}, "the server's keyframes were moved"
    assert after["trajectory"][:STEPS] == before["trajectory"], "the poses mapped before were moved"
    assert min(set(ids) - old) > max(old), "the continued graph's keyframes follow the server's"
