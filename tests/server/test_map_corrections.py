"""Loop-closure corrections through a real server (SQLite and PostgreSQL): keyframes, loop closures and the
pose covariance are stored, merged by deltas and returned by ``/maps/latest``; a delta that moves keyframes
moves the stored trajectory with them in the same transaction; the SSE stream carries the rows; a robot
without them keeps working; bad ones are refused naming the field; OpenAPI documents them."""

from __future__ import annotations

import json
import math
import threading
from collections.abc import Iterator
from typing import Any

import httpx

from tests.server.live import Live

_COV = [[4e-4, 1e-5, 0.0], [1e-5, 9e-4, 0.0], [0.0, 0.0, 1e-4]]


def _snapshot() -> dict[str, Any]:
    return {
        "version": 1,
        "stamp_s": 3.0,
        "segments": [[1, 0.0, 0.0, 4.0, 0.0], [2, 4.0, 0.0, 4.0, 3.0]],
        "pose": [2.0, 0.0, 0.0],
        # keyframe 0 at t=0 (origin), keyframe 1 at t=2 (2 m along x)
        "trajectory": [
            [0.0, 0.0, 0.0, 0.0],
            [1.0, 1.0, 0.0, 0.0],
            [2.0, 2.0, 0.0, 0.0],
            [3.0, 3.0, 0.0, 0.0],
        ],
        "keyframes": [[0, 0.0, 0.0, 0.0, 0.0], [1, 2.0, 2.0, 0.0, 0.0]],
        "loop_closures": [],
        "pose_covariance": _COV,
    }


def _correction() -> dict[str, Any]:
    """Keyframe 1 moved 0.5 m up and turned 90 degrees; wall 2 moved, wall 1 removed; a loop closure."""
    return {
        "version": 2,
        "base_version": 1,
        "stamp_s": 4.0,
        "segments": [[2, 4.0, 0.5, 4.0, 3.5]],
        "removed": [1],
        "pose": [2.0, 2.5, math.pi / 2],
        "trajectory": [[4.0, 2.0, 2.5, math.pi / 2]],
        "keyframes": [[1, 2.0, 2.0, 0.5, math.pi / 2], [2, 4.0, 2.0, 2.5, math.pi / 2]],
        "loop_closures": [[0, 2]],
        "wall_time_s": 1_800_000_000.5,
    }


def test_a_correction_moves_walls_keyframes_and_the_stored_trajectory(live: Live) -> None:
    rid, token = live.new_robot()
    with live.client(token) as robot, live.operator() as op:
        assert robot.post(f"/robots/{rid}/maps", json=_snapshot()).status_code == 200
        first = op.get(f"/robots/{rid}/maps/latest").json()
        assert first["keyframes"] == [[0, 0, 0, 0, 0], [1, 2, 2, 0, 0]]
        assert first["loop_closures"] == [] and first["pose_covariance"] == _COV
        got = robot.post(f"/robots/{rid}/maps", json=_correction())
        assert got.status_code == 200, got.text
        m = op.get(f"/robots/{rid}/maps/latest").json()
    assert m["version"] == 2
    assert [s[0] for s in m["segments"]] == [2] and m["segments"][0][2] == 0.5
    assert m["keyframes"] == [[0, 0, 0, 0, 0], [1, 2, 2, 0.5, math.pi / 2], [2, 4, 2, 2.5, math.pi / 2]]
    assert m["loop_closures"] == [[0, 2]]
    assert m["pose_covariance"] is None  # the correction's pose came without one
    traj = {row[0]: row[1:] for row in m["trajectory"]}
    assert traj[0.0] == [0.0, 0.0, 0.0] and traj[1.0] == [1.0, 0.0, 0.0]  # before keyframe 1: stays
    assert _close(traj[2.0], [2.0, 0.5, math.pi / 2])  # keyframe 1's own pose: its new pose
    assert _close(traj[3.0], [2.0, 1.5, math.pi / 2])  # 1 m ahead of keyframe 1, turned with it
    assert traj[4.0] == [2.0, 2.5, math.pi / 2]  # the delta's own pose, as sent


def test_the_stream_carries_the_correction_as_a_delta(live: Live) -> None:
    rid, token = live.new_robot()
    with live.client(token) as robot:
        robot.post(f"/robots/{rid}/maps", json=_snapshot())
    got: list[tuple[str, dict[str, Any]]] = []
    ready = threading.Event()

    def correct_when_subscribed() -> None:
        ready.wait(20)
        with live.client(token) as robot:
            robot.post(f"/robots/{rid}/maps", json=_correction())

    t = threading.Thread(target=correct_when_subscribed)
    t.start()
    with live.operator() as op, op.stream("GET", f"/robots/{rid}/maps/stream", timeout=20) as resp:
        for event in _events(resp):
            got.append(event)
            if len(got) == 1:
                ready.set()
            if len(got) == 2:
                break
    t.join(20)
    (k0, snap), (k1, delta) = got
    assert k0 == "snapshot" and snap["keyframes"][1] == [1, 2, 2, 0, 0] and snap["pose_covariance"] == _COV
    assert k1 == "delta" and delta["keyframes"][0] == [1, 2, 2, 0.5, math.pi / 2]
    assert delta["loop_closures"] == [[0, 2]] and delta["removed"] == [1]


def test_a_robot_without_a_pose_graph_is_served_as_before(live: Live) -> None:
    rid, token = live.new_robot()
    snap = {
        k: v for k, v in _snapshot().items() if k not in ("keyframes", "loop_closures", "pose_covariance")
    }
    with live.client(token) as robot, live.operator() as op:
        assert robot.post(f"/robots/{rid}/maps", json=snap).status_code == 200
        delta = {k: v for k, v in _correction().items() if k not in ("keyframes", "loop_closures")}
        assert robot.post(f"/robots/{rid}/maps", json=delta).status_code == 200
        m = op.get(f"/robots/{rid}/maps/latest").json()
    assert m["keyframes"] is None and m["loop_closures"] is None and m["pose_covariance"] is None
    assert [row[1:] for row in m["trajectory"]][2] == [2.0, 0.0, 0.0]  # no keyframes: nothing moved


def test_a_delta_without_graph_rows_keeps_the_stored_ones(live: Live) -> None:
    rid, token = live.new_robot()
    with live.client(token) as robot, live.operator() as op:
        robot.post(f"/robots/{rid}/maps", json=_snapshot())
        plain = {
            "version": 2,
            "base_version": 1,
            "pose": [3.0, 0.0, 0.0],
            "trajectory": [[4.0, 3.0, 0.0, 0.0]],
        }
        assert robot.post(f"/robots/{rid}/maps", json=plain).status_code == 200
        m = op.get(f"/robots/{rid}/maps/latest", params={"version": 2}).json()
    assert len(m["keyframes"]) == 2 and m["loop_closures"] == []


def test_bad_graph_rows_are_refused_naming_the_field(live: Live) -> None:
    rid, token = live.new_robot()
    bad = {**_snapshot(), "pose_covariance": [[1, 2, 0], [2, 1, 0], [0, 0, 1]]}
    with live.client(token) as robot, live.operator() as op:
        got = robot.post(f"/robots/{rid}/maps", json=bad)
        assert got.status_code == 422
        assert "positive semi-definite" in got.text
        bad = {**_snapshot(), "loop_closures": [[0, 9]]}
        got = robot.post(f"/robots/{rid}/maps", json=bad)
        assert got.status_code == 422 and "does not list" in got.text
        assert op.get(f"/robots/{rid}/maps/latest").json()["version"] == 0  # nothing applied


def test_openapi_documents_the_graph_fields(live: Live) -> None:
    doc = httpx.get(f"{live.base_url}/openapi.json", timeout=30).json()
    text = json.dumps(doc)
    schemas = doc["components"]["schemas"]
    out = next(v for k, v in schemas.items() if k.startswith("MapOut"))
    assert {"keyframes", "loop_closures", "pose_covariance"} <= set(out["properties"])
    assert "keyframe_id, stamp_s, x_m, y_m, theta_rad" in text
    assert "m^2, m*rad, rad^2" in text


def _close(a: list[float], b: list[float]) -> bool:
    return all(abs(x - y) < 1e-9 for x, y in zip(a, b, strict=True))


def _events(resp: httpx.Response) -> Iterator[tuple[str, dict[str, Any]]]:
    event, data = "", ""
    for line in resp.iter_lines():
        if line.startswith("event:"):
            event = line[6:].strip()
        elif line.startswith("data:"):
            data = line[5:].strip()
        elif line == "" and event:
            yield event, json.loads(data)
            event, data = "", ""
