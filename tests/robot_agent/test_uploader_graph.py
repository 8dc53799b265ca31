"""Pose-graph corrections through the uploader and a real server (uvicorn on 127.0.0.1, SQLite on disk):
when the outbox holds more versions than one upload takes, a keyframe moved by a later version has
already moved the earlier poses it owns in the Robot DB; the server must move them once, not twice
(robot_agent.store_map.RobotDB.pending_upload). And the keyframe rows stay bounded by the poses kept."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import pytest
from sqlalchemy import select

from robot_agent.link import ServerLink
from robot_agent.models import MapVersion, PoseRecord
from robot_agent.store import RobotDB, StepRecord
from shared.protocol import keyframes_in_use
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


def test_the_robot_keeps_and_sends_the_keyframes_its_kept_poses_own(live: Live, tmp_path: Path) -> None:
    """A keyframe each step and a trajectory thinned at 50 poses (a day's 70,000 keyframes in small): the
    Robot DB keeps the keyframes its kept poses own (and the closures between them), a later row for a
    dropped keyframe is not recorded, and the snapshot the server stores carries the same rows."""
    rid, token = live.new_robot()
    db = RobotDB(tmp_path / "robot.db")
    db.max_poses = 50
    up = bare_uploader(ServerLink(live.base_url, rid, token), db, rid, upload_batch=20)

    def row(v: int, y: float = 0.0) -> list[float]:
        return [float(v), round(v * 0.1, 6), round(v * 0.1, 6), y, 0.0]

    for v in range(1, 301):
        closures = [[v, v - 100]] if v > 100 else []
        db.record_step(replace(_step(v, [row(v)]), loop_closures=closures))
        if v % 20 == 0:
            assert up.send_maps()
    snap = db.snapshot()
    assert snap is not None
    held = {int(r[0]) for r in snap["keyframes"]}
    with db.tx() as s:
        stamps = list(s.scalars(select(PoseRecord.stamp_s)))
    assert held == keyframes_in_use(snap["keyframes"], stamps)
    assert len(held) <= len(stamps) + 1 < 300, "one keyframe per kept pose, not per step"
    assert all(a in held and b in held for a, b in snap["loop_closures"])
    dropped = min(set(range(1, 301)) - held)
    db.record_step(replace(_step(301, [row(dropped, 0.5), row(1, 0.5)]), loop_closures=[[301, dropped]]))
    with db.tx() as s:
        recorded = s.get(MapVersion, 301)
        assert recorded is not None
        change = recorded.change
    assert [int(r[0]) for r in change["keyframes"]] == [1], "the dropped keyframe's row is not recorded"
    assert change["loop_closures"] == []
    up.need_snapshot = True
    assert up.send_maps()
    with live.operator() as op:
        latest = op.get(f"/robots/{rid}/maps/latest").json()
    assert {int(r[0]) for r in latest["keyframes"]} == held
