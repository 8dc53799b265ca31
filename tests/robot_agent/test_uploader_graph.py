"""Pose-graph corrections through the uploader and a real server (uvicorn on 127.0.0.1, SQLite on disk):
when the outbox holds more versions than one upload takes, a keyframe moved by a later version has
already moved the earlier poses it owns in the Robot DB; the server must move them once, not twice
(robot_agent.store_map.RobotDB.pending_upload)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from robot_agent.link import ServerLink
from robot_agent.store import RobotDB, StepRecord
from tests.robot_agent.uploaders import bare_uploader
from tests.server.live import Live, start_live


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    yield from start_live("sqlite", tmp_path_factory.mktemp("graph-server"))


def _step(v: int, keyframes: list[list[float]]) -> StepRecord:
    """Version ``v``: the robot at x = v / 10 m on a straight line, stamped v / 10 s."""
    t = round(v * 0.1, 6)
    return StepRecord(
        version=v,
        stamp_s=t,
        source_index=v,
        segments=[[float(v), 0.0, 0.0, 1.0, 0.0]] if v == 1 else [],
        removed=[],
        pose=[t, t, 0.0, 0.0],
        centroids=[],
        keyframes=keyframes,
        loop_closures=[],
        graph=True,
    )


@pytest.mark.parametrize("batch", [50, 200])
def test_a_keyframe_moved_after_the_batch_moves_the_servers_poses_once(
    live: Live, tmp_path: Path, batch: int
) -> None:
    rid, token = live.new_robot()
    db = RobotDB(tmp_path / "robot.db")
    k0, k1 = [0.0, 0.1, 0.1, 0.0, 0.0], [1.0, 3.0, 3.0, 0.0, 0.0]
    up = bare_uploader(ServerLink(live.base_url, rid, token), db, rid, upload_batch=batch)
    db.record_step(_step(1, [k0]))
    assert up.send_maps() and db.outbox_size() == 0  # the first upload: a snapshot of version 1
    for v in range(2, 61):
        db.record_step(_step(v, [k1] if v == 30 else []))
    moved = [0.0, 0.1, 0.1, 0.01, 0.0]  # a loop closure moves keyframe 0 by 1 cm in y
    db.record_step(_step(61, [moved]))
    for _ in range(5):  # deltas of at most ``batch`` versions
        if not up.send_maps():
            break
    assert db.outbox_size() == 0
    with live.operator() as op:
        latest = op.get(f"/robots/{rid}/maps/latest").json()
    by_stamp = {round(r[0], 6): r[1:] for r in latest["trajectory"]}
    assert len(by_stamp) == 61
    keyframes = {int(r[0]): r for r in latest["keyframes"]}
    assert keyframes[0][2:] == moved[2:] and keyframes[1][2:] == k1[2:]
    owned_by_k0 = [by_stamp[round(v * 0.1, 6)][1] for v in range(1, 30)]
    assert owned_by_k0 == pytest.approx([0.01] * 29, abs=1e-12), "moved once, with keyframe 0"
    assert [by_stamp[round(v * 0.1, 6)][1] for v in range(30, 62)] == pytest.approx([0.0] * 32, abs=1e-12)
