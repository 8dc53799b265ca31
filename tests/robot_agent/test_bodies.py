"""What the agent sends validates against the server's own models (server.schemas): map deltas and
snapshots from the uploader, the status sent with them, and acknowledgements from the link."""

from __future__ import annotations

import json
import threading
from dataclasses import replace
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest

from robot_agent.agent import Agent, AgentSettings
from robot_agent.health import ErrorReport
from robot_agent.link import ServerLink, UploadConflict
from robot_agent.store import RobotDB, StepRecord
from robot_agent.uploader import Uploader
from server.schemas import AckIn, MapUpload, RobotStatus
from shared.protocol import RobotStatus as SentStatus
from tests.robot_agent.records import step_record


class _Recorder:
    """A link that records the bodies it is given and answers as the server would."""

    def __init__(self) -> None:
        self.bodies: list[tuple[dict[str, Any], str]] = []

    def upload(self, payload: dict[str, Any], key: str) -> dict[str, Any] | UploadConflict:
        self.bodies.append((json.loads(json.dumps(payload)), key))  # as it goes on the wire
        return {"version": payload["version"], "duplicate": False}


def _status() -> SentStatus:
    return SentStatus(mode="online", active_kernels={"clustering": "kmeans@1.0.0"}, step_ms=2.0)


def test_uploaded_snapshots_and_deltas_validate_against_the_servers_model(tmp_path: Path) -> None:
    db = RobotDB(tmp_path / "robot.db")
    link = _Recorder()
    uploader = Uploader(
        link,  # type: ignore[arg-type]
        db,
        _status,
        lambda version: 1.8e9 + version,
        threading.Event(),
        threading.Event(),
        ErrorReport(60.0),
        robot_id=3,
    )
    try:
        for v in (1, 2):
            db.record_step(step_record(v))
        assert uploader.send_maps()  # nothing uploaded yet: a snapshot
        for v in (3, 4):
            db.record_step(step_record(v))
        assert uploader.send_maps()  # then a delta from version 2
        session = db.map_session()
    finally:
        db.close()
    (snapshot, snap_key), (delta, delta_key) = link.bodies
    # idempotency keys name the map session: a retried upload of another session is another upload
    assert (snap_key, delta_key) == (f"r3-{session}-snapshot-2", f"r3-{session}-2-4")
    assert snapshot["map_session"] == delta["map_session"] == session
    snap = MapUpload.model_validate(snapshot)
    assert snap.base_version is None and snap.version == 2 and len(snap.trajectory) == 2
    assert snap.wall_time_s == 1.8e9 + 2
    got = MapUpload.model_validate(delta)
    assert (got.base_version, got.version, got.removed) == (2, 4, [2, 3])
    assert got.status is not None and got.status.active_kernels == {"clustering": "kmeans@1.0.0"}
    # every field the server's model has; a delta leaves out only why its session began (a snapshot's)
    # every field the server's model has but the pose graph's (no graph here: left out, as before them);
    # a delta leaves out only why its session began (a snapshot's)
    graph = {"keyframes", "loop_closures", "pose_covariance"}
    assert set(snapshot) == set(MapUpload.model_fields) - graph
    assert set(delta) == set(MapUpload.model_fields) - {"map_session_reason"} - graph


_COV = [[1e-4, 0.0, 0.0], [0.0, 2e-4, 0.0], [0.0, 0.0, 1e-5]]


def _graph_step(version: int, keyframes: list[list[float]], closures: list[list[int]]) -> StepRecord:
    return replace(
        step_record(version), keyframes=keyframes, loop_closures=closures, pose_covariance=_COV, graph=True
    )


def test_a_correction_goes_as_moved_keyframes_and_the_robot_db_moves_its_poses(tmp_path: Path) -> None:
    """With a pose graph the bodies carry the keyframes, closures and covariance; a step that moves a
    keyframe goes as that keyframe's row, and the Robot DB moves the poses it recorded after it (so the
    delta's poses and a later snapshot's are the corrected ones)."""
    db = RobotDB(tmp_path / "robot.db")
    link = _Recorder()
    uploader = Uploader(
        link,  # type: ignore[arg-type]
        db,
        _status,
        lambda version: 1.8e9 + version,
        threading.Event(),
        threading.Event(),
        ErrorReport(60.0),
        robot_id=3,
    )
    kf0 = [0, 0.1, 1.0, 2.0, 0.5]  # at step 1's pose (x 1, y 2, heading 0.5)
    kf0_moved = [0, 0.1, 2.0, 2.0, 0.5]  # a loop closure moved it 1 m along x
    kf1 = [1, 0.3, 1.0, 2.0, 0.5]
    try:
        db.record_step(_graph_step(1, [kf0], []))
        assert uploader.send_maps()  # a snapshot of version 1
        db.record_step(_graph_step(2, [], []))  # its pose recorded after keyframe 0
        db.record_step(_graph_step(3, [kf0_moved, kf1], [[0, 1]]))
        assert db.trajectory()[1] == pytest.approx([0.2, 2.0, 2.0, 0.5])  # moved with keyframe 0
        assert db.trajectory()[2] == pytest.approx([0.3, 1.0, 2.0, 0.5])  # its own pose
        assert uploader.send_maps()  # a delta 1 -> 3
        uploader.need_snapshot = True
        db.record_step(_graph_step(4, [], []))
        assert uploader.send_maps()
    finally:
        db.close()
    (snap, _), (delta, _), (snap2, _) = link.bodies
    assert snap["keyframes"] == [kf0] and snap["loop_closures"] == [] and snap["pose_covariance"] == _COV
    got = MapUpload.model_validate(delta)
    assert got.base_version == 1 and got.keyframes == [kf0_moved, kf1] and got.loop_closures == [[0, 1]]
    assert got.trajectory[0] == pytest.approx([0.2, 2.0, 2.0, 0.5])  # unsent when corrected: sent corrected
    again = MapUpload.model_validate(snap2)
    assert again.keyframes == [kf0_moved, kf1] and again.loop_closures == [[0, 1]]
    assert np.allclose(
        again.trajectory,
        [[0.1, 2.0, 2.0, 0.5], [0.2, 2.0, 2.0, 0.5], [0.3, 1.0, 2.0, 0.5], [0.4, 1.0, 2.0, 0.5]],
    )


def test_acknowledgements_validate_against_the_servers_model() -> None:
    seen: list[dict[str, Any]] = []

    def answer(request: httpx.Request) -> httpx.Response:
        seen.append(json.loads(request.content))
        return httpx.Response(200, json={"ok": True})

    link = ServerLink("http://robots.invalid", 1, "t", transport=httpx.MockTransport(answer))
    try:
        link.ack(4, "applied", None)
        link.ack(5, "rejected", "unknown kernel")
        link.ack(6, "rolled-back", "kernel hung")
    finally:
        link.close()
    assert [AckIn.model_validate(b).outcome for b in seen] == ["applied", "rejected", "rolled-back"]
    assert seen[0] == {"outcome": "applied", "reason": None}


def test_the_agents_status_validates_against_the_servers_model(tmp_path: Path) -> None:
    agent = Agent(AgentSettings(source="sim", db_path=tmp_path / "robot.db", max_steps=3, stay=False))
    agent.run(threading.Event())
    status = agent.status().model_dump(mode="json")
    got = RobotStatus.model_validate(json.loads(json.dumps(status)))
    assert got.mode == "online" and got.active_kernels and got.config is not None
