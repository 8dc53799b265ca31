"""Mapping from the emulated URG-04LX: ``urg:DEVICE`` scans through the pipeline give the same walls as the
simulated scans themselves (to the mm the sensor sends), close to the true walls; and ``linemap agent
--source urg:DEVICE`` maps into a real server."""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from robot_agent.sensors.emulator import UrgEmulator
from robot_agent.sources import open_scans
from shared.metrics import line_accuracy
from shared.pipeline import Pipeline
from shared.sim import SimRun
from shared.types import FloatArray, Pose2D, Scan
from tests.robot_agent.agentproc import AgentProcess, wait_for
from tests.server.live import Live, start_live

N = 60


def _as_sent(scan: Scan) -> Scan:
    """The scan as the sensor sends it: mm resolution, no odometry."""
    r = np.asarray(scan.ranges_m)
    rounded = np.where(np.isfinite(r), np.rint(np.where(np.isfinite(r), r, 0.0) * 1000.0) / 1000.0, np.nan)
    return dataclasses.replace(scan, ranges_m=rounded, odometry=None)


def _in_world(segments: FloatArray, first_laser: Pose2D) -> FloatArray:
    """Map segments (frame of the first laser pose: no odometry) in the world frame."""
    return first_laser.transform_points(np.asarray(segments).reshape(-1, 2)).reshape(-1, 4)


def test_urg_scans_map_into_the_walls(sim_run: SimRun, tmp_path: Path) -> None:
    with UrgEmulator(sim_run.scans, link=tmp_path / "ttyURG") as emu:
        source = open_scans("urg:" + emu.path)
        got = list(itertools.islice(source, N))
        source.close()
    assert all(s.odometry is None for s in got)
    ours, reference = Pipeline(), Pipeline()
    for scan, sim in zip(got, sim_run.scans, strict=False):
        ours.step(scan)
        reference.step(_as_sent(sim))
    _, walls = ours.walls()
    _, expected = reference.walls()
    assert len(walls) >= 8
    np.testing.assert_allclose(walls, expected, atol=1e-9)  # nothing lost or bent on the way
    first = sim_run.drive.laser_pose(sim_run.true_poses[0])
    acc = line_accuracy(_in_world(walls, first), sim_run.world.walls)
    assert acc.mean_distance_m < 0.02 and acc.spurious_share < 0.05


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    yield from start_live("sqlite", tmp_path_factory.mktemp("urg-server"), poll_recheck_s=1.0)


def test_the_agent_maps_from_the_emulated_sensor(live: Live, sim_run: SimRun, tmp_path: Path) -> None:
    rid, token = live.new_robot()
    with UrgEmulator(sim_run.scans, link=tmp_path / "ttyURG", at_end="hold") as emu:
        agent = AgentProcess(
            tmp_path / "robot.db",
            server=live.base_url,
            robot_id=rid,
            token=token,
            extra=["--source", "urg:" + emu.path, "--rate", "0"],
        )
        with live.operator() as op:
            try:
                wait_for(
                    "40 map versions from the laser",
                    lambda: op.get(f"/robots/{rid}").json()["map_version"] >= 40,
                )
                latest = op.get(f"/robots/{rid}/maps/latest").json()
            finally:
                code = agent.stop()
        out = agent.output()
        assert code == 0, out
        assert "Traceback" not in out and "source urg:" in out
        assert b"MD0044072501000" in emu.commands and emu.commands[-1] == b"QT"  # streamed, then stopped
    stamps = [row[0] for row in latest["trajectory"]]
    assert len(stamps) >= 40 and all(b > a for a, b in itertools.pairwise(stamps))
    segments = np.array([row[-4:] for row in latest["segments"]], dtype=float)
    assert len(segments) >= 5
    first = sim_run.drive.laser_pose(sim_run.true_poses[0])
    acc = line_accuracy(_in_world(segments, first), sim_run.world.walls)
    assert acc.mean_distance_m < 0.05 and acc.spurious_share < 0.2, acc


def test_a_restarted_agent_maps_every_new_scan_of_a_live_sensor(sim_run: SimRun, tmp_path: Path) -> None:
    """A log replays, so a restarted agent skips what it mapped before; a live sensor does not replay:
    after a restart its scans are all new and none may be thrown away as 'already mapped'."""
    import threading

    from robot_agent.agent import Agent, AgentSettings
    from robot_agent.store import RobotDB

    db = tmp_path / "robot.db"
    with UrgEmulator(sim_run.scans, link=tmp_path / "ttyURG", at_end="hold") as emu:
        sent = []
        for run in (1, 2):
            settings = AgentSettings(
                source="urg:" + emu.path, db_path=db, rate_hz=0, max_steps=12, stay=False
            )
            agent = Agent(settings)
            agent.run(threading.Event())
            assert agent.stats.steps == 12, f"run {run} mapped {agent.stats.steps} of 12 live scans"
            sent.append(len(emu.delivered()))
    # skipping 12 'already mapped' scans would have read 24 in the second run (plus any in flight)
    assert sent[1] - sent[0] < 24
    store = RobotDB(db)
    try:
        assert int(store.get("map_version")) == 24
        assert int(store.get("source_index")) == 24
    finally:
        store.close()
