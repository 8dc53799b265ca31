"""A restarted agent goes on with the same map at the same pose: a real agent process mapping the simulator
against a real server on 127.0.0.1, killed with SIGKILL at several points and restarted on the same Robot
DB, ends with the trajectory and walls of an uninterrupted run, every map version once; with loop
closure, with the keyframes of an uninterrupted agent's graph and no wall left over on the server."""

from __future__ import annotations

import math
import sqlite3
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from robot_agent.mapping import PipelineSlot, RecentScans
from robot_agent.resume import Checkpoints
from robot_agent.sources import laser_offset, open_scans
from robot_agent.store import RobotDB
from shared.pipeline import Pipeline, PipelineConfig
from shared.slam import OnlineGraphMapper
from tests.robot_agent.agentproc import AgentProcess, integrity, robot_db_meta, wait_for
from tests.server.live import Live, start_live


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    yield from start_live("sqlite", tmp_path_factory.mktemp("agent-resume-server"), poll_recheck_s=1.0)


def _uninterrupted(source: str) -> Pipeline:
    """The agent's pipeline over the whole source in one go (what an uninterrupted agent maps)."""
    pipe = Pipeline(PipelineConfig(), laser_offset=laser_offset(source))
    for scan in open_scans(source, seed=0, laps=1):
        pipe.step(scan)
    return pipe


def _version(db: Path) -> int:
    return int(robot_db_meta(db, "map_version") or 0) if db.exists() else 0


def test_killed_agents_resume_the_same_map_at_the_same_pose(live: Live, tmp_path: Path) -> None:
    reference = _uninterrupted("sim")
    ref_traj = reference.snapshot().trajectory
    n_scans = len(ref_traj)
    rid, token = live.new_robot()
    db = tmp_path / "robot.db"
    args = dict(server=live.base_url, robot_id=rid, token=token)
    for kill_at in (60, 190, 330):
        agent = AgentProcess(db, **args, extra=["--rate", "0"])  # type: ignore[arg-type]
        wait_for(f"version {kill_at}", lambda at=kill_at: _version(db) >= at, 120)  # type: ignore[misc]
        agent.kill()
        assert integrity(db) == "ok"
        assert "Traceback" not in agent.output()
    last = AgentProcess(db, **args, extra=["--rate", "0", "--exit-at-end"])  # type: ignore[arg-type]
    assert last.proc.wait(300) == 0, last.output()
    last.stop()
    out = last.output()
    assert "Traceback" not in out and "did not load" not in out and "no mapping state" not in out, out

    latest = live.operator().get(f"/robots/{rid}/maps/latest").json()
    assert latest["version"] == n_scans
    traj = np.asarray(latest["trajectory"], dtype=np.float64)
    assert len(traj) == n_scans and list(traj[:, 0]) == sorted(set(traj[:, 0])), "each version once, in order"
    assert np.abs(traj[:, 1:3] - ref_traj[:, 1:3]).max() <= 0.01, "the pose jumped at a restart"
    turn = np.abs(np.remainder(traj[:, 3] - ref_traj[:, 3] + math.pi, 2 * math.pi) - math.pi)
    assert math.degrees(turn.max()) <= 0.1
    ids, segments = reference.walls()
    got = {int(row[0]): row[1:] for row in latest["segments"]}
    assert sorted(got) == sorted(int(i) for i in ids), "the same walls, with the same ids"
    for i, seg in zip(ids, segments, strict=True):
        assert np.abs(np.asarray(got[int(i)]) - seg).max() <= 0.01
    # the journal holds about one checkpoint interval of scans (50 steps, and those while the state's
    # bytes were made), not the run's 507
    with sqlite3.connect(db) as conn:
        assert conn.execute("SELECT count(*) FROM scan_journal").fetchone()[0] <= 100
        assert conn.execute("SELECT count(*) FROM mapping_state").fetchone()[0] == 1


def _final_graph(db: Path) -> OnlineGraphMapper:
    """The graph mapper a restart would resume from ``db`` (state and journal), its pending work done and
    its map drawn again from the final graph (whether the worker's last redraw was in depends on timing)."""
    store = RobotDB(db)
    try:
        slot = PipelineSlot(laser_offset("sim:loop-block"))
        slot.start(PipelineConfig.parse({"loop_closure": {}}))
        resumed = Checkpoints(store).resume(slot, RecentScans())
        assert resumed.problem is None, resumed.problem
        graph = slot.pipeline
        assert isinstance(graph, OnlineGraphMapper)
        graph._closed_since_rebuild = True  # the map drawn again from the final graph, whatever was drawn
        graph.flush()
        return graph
    finally:
        store.close()


@pytest.mark.soak  # two whole drives of sim:loop-block with loop closure, 300 s on CI: make soak
def test_killed_agents_with_loop_closure_resume_the_same_graph(live: Live, tmp_path: Path) -> None:
    extra = ["--source", "sim:loop-block", "--rate", "0", "--loop-closure"]
    runs = {}
    for name, kills in (("uninterrupted", ()), ("killed", (150, 420))):
        rid, token = live.new_robot()
        db = tmp_path / f"{name}.db"
        args = dict(server=live.base_url, robot_id=rid, token=token)
        for kill_at in kills:
            agent = AgentProcess(db, **args, extra=extra)  # type: ignore[arg-type]
            wait_for(f"version {kill_at}", lambda at=kill_at, db=db: _version(db) >= at, 300)  # type: ignore[misc]
            agent.kill()
            assert integrity(db) == "ok"
        last = AgentProcess(db, **args, extra=[*extra, "--exit-at-end"])  # type: ignore[arg-type]
        assert last.proc.wait(600) == 0, last.output()
        last.stop()
        assert "Traceback" not in last.output() and "did not load" not in last.output(), last.output()
        latest = live.operator().get(f"/robots/{rid}/maps/latest").json()
        store = RobotDB(db)
        recorded = store.walls()
        store.close()
        # the server holds exactly the walls the robot recorded last: none left over from before a kill
        assert sorted(int(r[0]) for r in latest["segments"]) == sorted(int(w[0]) for w in recorded)
        runs[name] = (latest, _final_graph(db))
    (ref, ref_graph), (got, got_graph) = runs["uninterrupted"], runs["killed"]
    try:
        n_scans = ref["version"]
        assert got["version"] == n_scans and len(got["trajectory"]) == n_scans
        stamps = [row[0] for row in got["trajectory"]]
        assert stamps == sorted(set(stamps)), "each version once, in order"
        assert got_graph.closures > 0
        a, b = ref_graph.trajectory(), got_graph.trajectory()
        steps = [k.step for k in ref_graph._mapper.keyframes]
        assert steps == [k.step for k in got_graph._mapper.keyframes]
        assert np.abs(a[steps, 1:3] - b[steps, 1:3]).max() <= 0.01
        turn = np.abs(np.remainder(a[steps, 3] - b[steps, 3] + math.pi, 2 * math.pi) - math.pi)
        assert math.degrees(turn.max()) <= 0.1
        # the map is the same whatever the worker's timing (shared.slam.online): the server's last map of
        # the killed robot is the uninterrupted one's, wall for wall
        ref_walls = {int(r[0]): r[1:] for r in ref["segments"]}
        got_walls = {int(r[0]): r[1:] for r in got["segments"]}
        assert sorted(got_walls) == sorted(ref_walls) and ref_walls
        assert max(float(np.abs(np.subtract(got_walls[i], ref_walls[i])).max()) for i in ref_walls) <= 0.01
    finally:
        ref_graph.close()
        got_graph.close()
