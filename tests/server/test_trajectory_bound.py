"""A robot's stored map stays bounded whatever the run's length (server/mapstore.py): its trajectory is
thinned past MAX_TRAJECTORY_POSES by the rule the robot applies (the newest half-limit whole, the first
pose kept), ``GET /maps/latest`` and the exports say so in the OpenAPI document, and the idempotency
records keep the robot's last uploads. Through the real server on both database backends."""

from __future__ import annotations

from typing import Any

import httpx
from sqlalchemy import func, select

from server.mapstore import thin_trajectory, trim_upload_records
from server.models import MapUploadRecord, TrajectoryPoint
from shared.protocol import MAX_TRAJECTORY_POSES, keyframes_in_use
from tests.server.live import Live


def _delta(version: int, base: int, first_stamp: int, n: int) -> dict[str, Any]:
    return {
        "version": version,
        "base_version": base,
        "stamp_s": float(first_stamp + n),
        "segments": [[float(version), 0.0, 0.0, 1.0, 1.0]],
        "trajectory": [[float(s), 0.001 * s, 1.0, 0.0] for s in range(first_stamp, first_stamp + n)],
    }


def test_a_long_run_keeps_a_bounded_thinned_trajectory(live: Live) -> None:
    rid, token = live.new_robot()
    per, uploads = 1000, 12  # 12,000 poses sent, 1.5 times the limit
    with live.client(token) as robot:
        first = _delta(1, 0, 0, per) | {"base_version": None}
        assert robot.post(f"/robots/{rid}/maps", json=first).status_code == 200
        for k in range(1, uploads):
            r = robot.post(f"/robots/{rid}/maps", json=_delta(k + 1, k, k * per, per))
            assert r.status_code == 200, r.text
    with live.operator() as op:
        got = op.get(f"/robots/{rid}/maps/latest")
        assert got.status_code == 200
        traj = got.json()["trajectory"]
        stamps = [row[0] for row in traj]
        assert MAX_TRAJECTORY_POSES // 2 < len(traj) <= MAX_TRAJECTORY_POSES
        assert stamps == sorted(stamps) and stamps[0] == 0.0, "the first pose stays"
        newest = [float(s) for s in range(uploads * per - MAX_TRAJECTORY_POSES // 2, uploads * per)]
        assert stamps[-len(newest) :] == newest, "the newest half-limit is kept whole"
        tail = op.get(f"/robots/{rid}/maps/latest", params={"trajectory": 10}).json()["trajectory"]
        assert [row[0] for row in tail] == newest[-10:]
    with httpx.Client(base_url=live.base_url, timeout=30) as c:
        doc = c.get("/openapi.json").json()["paths"]
        for path in ("/api/v1/robots/{robot_id}/maps/latest", "/api/v1/robots/{robot_id}/maps/export"):
            assert f"at most {MAX_TRAJECTORY_POSES} trajectory poses" in doc[path]["get"]["description"]


def test_thinning_and_trimming_in_the_upload_transaction(live: Live) -> None:
    """White-box, with small limits: the stored trajectory thinned to 50 poses (the newest 25 whole), the
    upload records trimmed to the last 3."""
    rid, token = live.new_robot()
    with live.client(token) as robot:
        first = _delta(1, 0, 0, 40) | {"base_version": None}
        assert robot.post(f"/robots/{rid}/maps", json=first).status_code == 200
        for k in range(1, 6):
            assert robot.post(f"/robots/{rid}/maps", json=_delta(k + 1, k, k * 40, 40)).status_code == 200
    with live.state.db.write_conn() as conn:
        assert thin_trajectory(conn, rid, 50) > 0
        assert thin_trajectory(conn, rid, 50) == 0, "thinned once, it fits"
        trim_upload_records(conn, rid, keep=3)
    with live.state.db.read() as s:
        stamps = list(
            s.scalars(
                select(TrajectoryPoint.stamp_s)
                .where(TrajectoryPoint.robot_id == rid)
                .order_by(TrajectoryPoint.id)
            )
        )
        kept = list(
            s.scalars(
                select(MapUploadRecord.version)
                .where(MapUploadRecord.robot_id == rid)
                .order_by(MapUploadRecord.id)
            )
        )
        total = s.scalar(
            select(func.count()).select_from(TrajectoryPoint).where(TrajectoryPoint.robot_id == rid)
        )
    assert 25 < len(stamps) <= 50 and total == len(stamps)
    assert stamps[0] == 0.0 and stamps[-25:] == [float(s) for s in range(215, 240)]
    assert kept == [4, 5, 6]


def test_keyframes_that_own_no_kept_pose_leave_with_it(live: Live) -> None:
    """With loop closure on, a keyframe per pose for 12,000 poses: once the trajectory is thinned, the
    stored keyframes are the owners of the poses kept (and the loop closures those between them), a
    correction's row for a dropped keyframe and a closure to it are left out, and one for a kept keyframe
    moves its poses (server/mapgraph.py prune_graph)."""
    rid, token = live.new_robot()
    per, uploads = 1000, 12

    def graph(v: int, first: int) -> dict[str, Any]:
        rows = [[float(k), float(k), 0.001 * k, 1.0, 0.0] for k in range(first, first + per)]
        return {"keyframes": rows, "loop_closures": [[first + per - 1, first - per]] if first else []}

    with live.client(token) as robot:
        first = _delta(1, 0, 0, per) | {"base_version": None} | graph(1, 0)
        assert robot.post(f"/robots/{rid}/maps", json=first).status_code == 200
        for k in range(1, uploads):
            r = robot.post(f"/robots/{rid}/maps", json=_delta(k + 1, k, k * per, per) | graph(k + 1, k * per))
            assert r.status_code == 200, r.text
    with live.operator() as op:
        got = op.get(f"/robots/{rid}/maps/latest").json()
    stamps = [row[0] for row in got["trajectory"]]
    held = {int(r[0]) for r in got["keyframes"]}
    assert len(stamps) < uploads * per
    assert held == keyframes_in_use(got["keyframes"], stamps) == {int(s) for s in stamps}
    assert all(a in held and b in held for a, b in got["loop_closures"])
    assert [11_999, 10_000] in got["loop_closures"], "a closure between kept keyframes stays"
    assert 1 not in held and 0 in held
    newest = uploads * per
    correction = _delta(uploads + 1, uploads, newest, 1) | {
        "keyframes": [[1.0, 1.0, 5.0, 5.0, 0.0], [0.0, 0.0, 0.0, 1.5, 0.0]],
        "loop_closures": [[newest - 1, 1], [newest - 1, 0]],
    }
    with live.client(token) as robot:
        assert robot.post(f"/robots/{rid}/maps", json=correction).status_code == 200
    with live.operator() as op:
        after = op.get(f"/robots/{rid}/maps/latest").json()
    assert 1 not in {int(r[0]) for r in after["keyframes"]}, "a dropped keyframe's row is left out"
    assert [newest - 1, 1] not in after["loop_closures"] and [newest - 1, 0] in after["loop_closures"]
    assert after["trajectory"][0][:3] == [0.0, 0.0, 1.5], "the pose keyframe 0 owns moved with it"
    assert len(after["keyframes"]) == len(got["keyframes"])
