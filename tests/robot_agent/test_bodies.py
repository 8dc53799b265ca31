"""What the agent sends validates against the server's own models (server.schemas): map deltas and
snapshots from the uploader, the status sent with them, and acknowledgements from the link."""

from __future__ import annotations

import json
import threading
from pathlib import Path
from typing import Any

import httpx

from robot_agent.agent import Agent, AgentSettings
from robot_agent.health import ErrorReport
from robot_agent.link import ServerLink, UploadConflict
from robot_agent.store import RobotDB
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
    assert set(snapshot) == set(MapUpload.model_fields)
    assert set(delta) == set(MapUpload.model_fields) - {"map_session_reason"}


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
