"""The agent with loop closure as a real process against a real server on 127.0.0.1: two laps round a
block close their loop on the robot, every map version still reaches the server once and in order, and the
server's last map is the corrected one."""

from __future__ import annotations

import json
import math
import sqlite3
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from shared.metrics import line_accuracy
from shared.sim.worlds import simulate_case
from tests.robot_agent.agentproc import AgentProcess, integrity, send_message
from tests.server.live import Live, start_live


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    yield from start_live("sqlite", tmp_path_factory.mktemp("agent-loop-server"), poll_recheck_s=1.0)


def test_two_laps_close_their_loop_on_the_robot(live: Live, tmp_path: Path) -> None:
    case = simulate_case("loop-block", 0)
    n_scans = len(case.run.scans)
    rid, token = live.new_robot()
    agent = AgentProcess(
        tmp_path / "robot.db",
        server=live.base_url,
        robot_id=rid,
        token=token,
        extra=["--source", "sim:loop-block", "--rate", "0", "--loop-closure", "--exit-at-end"],
    )
    assert agent.proc.wait(600) == 0, agent.output()
    agent.stop()
    out = agent.output()
    assert "Traceback" not in out
    closures = int(out.split(" loop closures")[0].rsplit(", ", 1)[-1])
    assert closures >= 3, out
    assert integrity(agent.db) == "ok"
    op = live.operator()
    latest = op.get(f"/robots/{rid}/maps/latest").json()
    stamps = [row[0] for row in latest["trajectory"]]
    assert len(stamps) == n_scans and stamps == sorted(set(stamps)), "each scan exactly once, in order"
    walls = np.array([row[1:] for row in latest["segments"]], dtype=np.float64)
    acc = line_accuracy(walls.reshape(-1, 4), case.run.world.walls)
    assert acc.mean_distance_m < 0.025
    assert acc.spurious_share < 0.03
    _check_pose_graph(latest, closures, agent.db, _logged_keyframe_ids(live, rid))


#: the robot re-sends a keyframe once it moved by more than this (m, rad; robot_agent.mapping), so the
#: server's keyframes and the trajectory it moved with them agree to this precision, not exactly
KEYFRAME_RESEND = 1e-3


def _logged_keyframe_ids(live: Live, rid: int) -> list[set[int]]:
    """The keyframe ids of each delta upload in the server's delta log (its last 256 uploads), in order."""
    from server.models import MapDeltaRecord

    with live.state.db.read() as s:
        bodies = (
            s.query(MapDeltaRecord.body)
            .filter(MapDeltaRecord.robot_id == rid)
            .order_by(MapDeltaRecord.version)
        )
        return [{int(r[0]) for r in json.loads(b).get("keyframes") or []} for (b,) in bodies if b]


def _check_pose_graph(latest: dict[str, Any], closures: int, db: Path, logged: list[set[int]]) -> None:
    """The corrections reached the server as the robot holds them: every loop closure once, the keyframes,
    a covariance, and a trajectory that passes through each keyframe's corrected pose (the server moved the
    poses it held when the keyframes moved; within the robot's re-send threshold) and equals the Robot DB's
    own (corrected there too); and corrections went as keyframe rows sent again (the delta log's uploads)."""
    keyframes = latest["keyframes"]
    assert keyframes and len(latest["loop_closures"]) == closures
    assert len({tuple(p) for p in latest["loop_closures"]}) == closures
    cov = np.array(latest["pose_covariance"])
    assert cov.shape == (3, 3) and np.allclose(cov, cov.T) and np.linalg.eigvalsh(cov)[0] >= -1e-12
    by_stamp = {row[0]: row[1:] for row in latest["trajectory"]}
    off = [
        max(
            abs(by_stamp[k[1]][0] - k[2]),
            abs(by_stamp[k[1]][1] - k[3]),
            abs(math.remainder(by_stamp[k[1]][2] - k[4], math.tau)),
        )
        for k in keyframes
    ]
    assert max(off) <= KEYFRAME_RESEND, f"the server's trajectory is off its keyframes by up to {max(off)}"
    with sqlite3.connect(db) as conn:
        own = conn.execute("SELECT stamp_s, x_m, y_m, theta_rad FROM poses ORDER BY version").fetchall()
    assert np.allclose(np.array(own), np.array(latest["trajectory"]), atol=1e-9)
    # corrections went as keyframe rows sent again (moved), not as every pose: read from the server's delta
    # log (the Robot DB drops delivered versions: robot_agent.store_map's compaction)
    seen: set[int] = set()
    resent = 0
    for ids in logged:
        resent += len(ids & seen)
        seen |= ids
    assert resent > 0, "no keyframe was ever sent again corrected"


@pytest.mark.parametrize(
    ("setting", "message"),
    [
        ("[loop_closure]\nsearch_radius_m = -3\n", "search_radius_m = -3: expected a value in [0, 100]"),
        ('loop_closure = "yes"\n', "loop_closure = 'yes': expected true, false or a table of settings"),
        ("[loop_closure]\nradius = 3.0\n", "unknown loop-closure setting(s) radius"),
    ],
)
def test_a_bad_loop_setting_in_the_agent_file_is_refused(tmp_path: Path, setting: str, message: str) -> None:
    """The agent's TOML file takes loop_closure as true / false or a table of settings; a bad one is
    refused before anything runs, naming the setting, with no traceback."""
    import subprocess

    from tests.robot_agent.agentproc import LINEMAP

    file = tmp_path / "agent.toml"
    file.write_text(f'source = "sim"\ndb = "{tmp_path / "robot.db"}"\n{setting}', encoding="utf-8")
    run = subprocess.run(
        [LINEMAP, "agent", "--file", str(file), "--max-steps", "3", "--exit-at-end"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 2, run.stderr
    assert message in " ".join(run.stderr.split())
    assert "Traceback" not in run.stderr
    assert not (tmp_path / "robot.db").exists()


def test_loop_closure_settings_from_the_agent_file_run(tmp_path: Path) -> None:
    import subprocess

    from tests.robot_agent.agentproc import LINEMAP

    file = tmp_path / "agent.toml"
    db = tmp_path / "robot.db"
    file.write_text(f'source = "sim"\ndb = "{db}"\n[loop_closure]\nsearch_radius_m = 6.0\n', encoding="utf-8")
    run = subprocess.run(
        [LINEMAP, "agent", "--file", str(file), "--max-steps", "20", "--exit-at-end", "--rate", "0"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert run.returncode == 0, run.stderr
    assert "stopped after 20 steps, 0 loop closures" in run.stderr


def test_the_operator_switches_loop_closure_on_while_the_robot_maps(live: Live, tmp_path: Path) -> None:
    """A robot started without loop closure gets ``<loop-closure>`` in a control message: it applies it
    between two steps, reports the settings it runs and closes the loop on the second lap; a bad setting
    is refused by the server before it is queued, naming the element, and the robot keeps its settings."""
    from tests.robot_agent.agentproc import wait_for

    case = simulate_case("loop-block", 0)
    rid, token = live.new_robot()
    op = live.operator()
    agent = AgentProcess(
        tmp_path / "robot.db",
        server=live.base_url,
        robot_id=rid,
        token=token,
        extra=["--source", "sim:loop-block", "--rate", "40", "--exit-at-end"],
    )
    try:
        wait_for("first map", lambda: op.get(f"/robots/{rid}").json()["map_version"] > 0, 120)
        on = send_message(op, rid, '<loop-closure><search-radius unit="m">5</search-radius></loop-closure>')
        assert on["status"] == "applied", on
        config = wait_for(
            "the robot's report of loop closure",
            lambda: (c := op.get(f"/robots/{rid}").json()["config"]) and c.get("loop_closure") and c,
        )
        assert config["loop_closure"]["search_radius_m"] == 5.0
        bad = op.post(
            f"/robots/{rid}/messages",
            content="<xml><message><loop-closure><min-inlier-share>2</min-inlier-share></loop-closure>"
            "</message></xml>",
            headers={"Content-Type": "application/xml"},
        )
        assert bad.status_code == 422, bad.text  # the server checks it as the robot would: never queued
        assert "<min-inlier-share>" in bad.text and "expected a value in [0, 1]" in bad.text
        assert agent.proc.wait(600) == 0, agent.output()
    finally:
        agent.stop()
    out = agent.output()
    assert "Traceback" not in out
    closures = int(out.split(" loop closures")[0].rsplit(", ", 1)[-1])
    assert closures >= 3, out
    assert op.get(f"/robots/{rid}").json()["config"]["loop_closure"]["search_radius_m"] == 5.0
    latest = op.get(f"/robots/{rid}/maps/latest").json()
    walls = np.array([row[1:] for row in latest["segments"]], dtype=np.float64)
    acc = line_accuracy(walls.reshape(-1, 4), case.run.world.walls)
    assert acc.mean_distance_m < 0.03
