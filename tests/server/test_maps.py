"""Map uploads through a real server: snapshots, deltas, idempotent retries, latest, and the SSE stream."""

from __future__ import annotations

import json
import threading
from collections.abc import Iterator
from typing import Any

import httpx

from tests.server.live import Live


def _snapshot(version: int = 1) -> dict[str, Any]:
    return {
        "version": version,
        "base_version": None,
        "stamp_s": 10.0,
        "segments": [[1, 0.0, 0.0, 4.0, 0.0], [2, 4.0, 0.0, 4.0, 3.0]],
        "centroids": [[1.0, 0.0], [4.0, 1.5]],
        "pose": [1.0, 1.0, 0.5],
        "trajectory": [[9.9, 0.9, 1.0, 0.5], [10.0, 1.0, 1.0, 0.5]],
        "status": {"mode": "online", "active_kernels": {"noise-removal": "dbscan@1.0.0"}, "step_ms": 1.2},
    }


def _delta(base: int, version: int) -> dict[str, Any]:
    return {
        "version": version,
        "base_version": base,
        "stamp_s": 10.1,
        "segments": [[2, 4.0, 0.0, 4.0, 3.5], [3, 4.0, 3.5, 0.0, 3.5]],
        "removed": [1],
        "centroids": [[2.0, 3.5]],
        "pose": [1.2, 1.0, 0.5],
        "trajectory": [[10.1, 1.2, 1.0, 0.5]],
        "wall_time_s": 1_800_000_000.25,
    }


def test_snapshot_then_delta_then_latest(live: Live) -> None:
    rid, token = live.new_robot()
    with live.client(token) as robot:
        r = robot.post(f"/robots/{rid}/maps", json=_snapshot())
        assert r.status_code == 200, r.text
        assert r.json() == {"version": 1, "duplicate": False}
        r = robot.post(f"/robots/{rid}/maps", json=_delta(1, 2))
        assert r.json() == {"version": 2, "duplicate": False}
    with live.operator() as op:
        m = op.get(f"/robots/{rid}/maps/latest").json()
        row = op.get(f"/robots/{rid}").json()
    assert m["version"] == 2
    assert m["segments"] == [[2, 4.0, 0.0, 4.0, 3.5], [3, 4.0, 3.5, 0.0, 3.5]]
    assert m["centroids"] == [[2.0, 3.5]] and m["pose"] == [1.2, 1.0, 0.5]
    assert [t[0] for t in m["trajectory"]] == [9.9, 10.0, 10.1]
    assert row["map_version"] == 2 and row["mode"] == "online" and row["step_ms"] == 1.2
    assert row["active_kernels"] == {"noise-removal": "dbscan@1.0.0"} and row["online"] is True
    assert m["wall_time_s"] == 1_800_000_000.25  # the step time of the newest version, for latency displays


def test_latest_before_any_upload_is_empty(live: Live) -> None:
    rid, _ = live.new_robot()
    with live.operator() as op:
        m = op.get(f"/robots/{rid}/maps/latest").json()
    assert m["version"] == 0 and m["segments"] == [] and m["trajectory"] == []


def test_retried_upload_is_a_no_op(live: Live) -> None:
    rid, token = live.new_robot()
    with live.client(token) as robot:
        robot.post(f"/robots/{rid}/maps", json=_snapshot(), headers={"Idempotency-Key": "a"})
        first = robot.post(f"/robots/{rid}/maps", json=_delta(1, 2), headers={"Idempotency-Key": "b"})
        retry = robot.post(f"/robots/{rid}/maps", json=_delta(1, 2), headers={"Idempotency-Key": "b"})
        assert first.json()["duplicate"] is False
        assert retry.status_code == 200 and retry.json() == {"version": 2, "duplicate": True}
        m = robot.get(f"/robots/{rid}/maps/latest").json()
    assert len(m["trajectory"]) == 3, "the retry added no pose"


def test_delta_on_a_stale_base_is_refused_with_the_current_version(live: Live) -> None:
    rid, token = live.new_robot()
    with live.client(token) as robot:
        robot.post(f"/robots/{rid}/maps", json=_snapshot(3))
        r = robot.post(f"/robots/{rid}/maps", json=_delta(1, 4))
        assert r.status_code == 409
        assert r.json()["current_version"] == 3 and "snapshot" in r.json()["detail"]
        old = robot.post(f"/robots/{rid}/maps", json=_snapshot(2))
        assert old.status_code == 409 and old.json()["current_version"] == 3
        assert robot.post(f"/robots/{rid}/maps", json=_snapshot(5)).status_code == 200


def test_bad_upload_names_the_field(live: Live) -> None:
    rid, token = live.new_robot()
    bad = _snapshot()
    bad["segments"] = [[1, 0.0, 0.0, 1.0]]
    with live.client(token) as robot:
        r = robot.post(f"/robots/{rid}/maps", json=bad)
        assert r.status_code == 422 and "segments" in r.json()["detail"]
        nan = robot.post(
            f"/robots/{rid}/maps",
            content=json.dumps(_snapshot()).replace("4.0", "NaN"),
            headers={"Content-Type": "application/json"},
        )
        assert nan.status_code == 422
        base_above = robot.post(f"/robots/{rid}/maps", json={**_delta(5, 4)})
        assert base_above.status_code == 422 and "base_version" in base_above.json()["detail"]


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


def test_stream_pushes_a_snapshot_then_each_upload(live: Live) -> None:
    """The subscriber gets the current map, then each new upload as it lands (the server re-reads the
    database only every 30 s, so prompt events come from the in-process push)."""
    rid, token = live.new_robot()
    with live.client(token) as robot:
        robot.post(f"/robots/{rid}/maps", json=_snapshot())
    got: list[tuple[str, dict[str, Any]]] = []
    ready = threading.Event()

    def upload_when_subscribed() -> None:
        ready.wait(20)
        with live.client(token) as robot:
            robot.post(f"/robots/{rid}/maps", json=_delta(1, 2))

    uploader = threading.Thread(target=upload_when_subscribed)
    uploader.start()
    with live.operator() as op, op.stream("GET", f"/robots/{rid}/maps/stream", timeout=20) as resp:
        assert resp.status_code == 200
        assert resp.headers["content-type"].startswith("text/event-stream")
        for event in _events(resp):
            got.append(event)
            if len(got) == 1:
                ready.set()
            if len(got) == 2:
                break
    uploader.join(20)
    (k0, snap), (k1, delta) = got
    assert k0 == "snapshot" and snap["version"] == 1 and len(snap["segments"]) == 2
    assert k1 == "delta" and delta["version"] == 2 and delta["base_version"] == 1
    assert delta["removed"] == [1] and [s[0] for s in delta["segments"]] == [2, 3]
    assert snap["wall_time_s"] is None and delta["wall_time_s"] == 1_800_000_000.25


def test_stream_of_unknown_robot_is_404(live: Live) -> None:
    with live.operator() as op:
        assert op.get("/robots/999999/maps/stream").status_code == 404


def test_concurrent_retries_apply_once(live: Live) -> None:
    """Eight copies of one upload at once (a robot retrying over a flaky link): one applies, the others
    are reported as duplicates; nothing fails."""
    from concurrent.futures import ThreadPoolExecutor

    rid, token = live.new_robot()

    def send(_: int) -> httpx.Response:
        with live.client(token) as robot:
            return robot.post(f"/robots/{rid}/maps", json=_snapshot(), headers={"Idempotency-Key": "same"})

    with ThreadPoolExecutor(8) as pool:
        results = list(pool.map(send, range(8)))
    assert [r.status_code for r in results] == [200] * 8
    assert sorted(r.json()["duplicate"] for r in results) == [False] + [True] * 7
    with live.operator() as op:
        assert len(op.get(f"/robots/{rid}/maps/latest").json()["trajectory"]) == 2


def test_status_reports_configuration_and_kernel_store(live: Live) -> None:
    """What the robot runs (its whole configuration) and holds (its kernels) reach the robot's record."""
    rid, token = live.new_robot()
    config = {
        "mode": "online",
        "n_smax": 9,
        "noise_removal": [{"name": "dbscan", "params": {"epsilon_m": 0.04}}],
    }
    kernel = {
        "stage": "noise-removal",
        "name": "dbscan",
        "version": "1.1.0",
        "state": "verified",
        "sha256": "a" * 64,
    }
    up = _snapshot()
    up["status"] = {**up["status"], "config": config, "kernels": [kernel]}
    with live.client(token) as robot:
        assert robot.post(f"/robots/{rid}/maps", json=up).status_code == 200
        row = robot.get(f"/robots/{rid}").json()
    assert row["config"] == config and row["kernels"] == [kernel]
    bad = _delta(1, 2)
    bad["status"] = {"kernels": [{**kernel, "state": "x" * 40}]}
    with live.client(token) as robot:
        r = robot.post(f"/robots/{rid}/maps", json=bad)
    assert r.status_code == 422 and "state" in r.json()["detail"]


def test_a_bad_robot_id_in_the_path_is_named_once(live: Live) -> None:
    """The robot id is read by the route and by its access check: its error is reported once."""
    with live.operator() as op:
        r = op.get("/robots/abc/maps/latest")
    assert r.status_code == 422
    body = r.json()
    once = "path.robot_id: Input should be a valid integer, unable to parse string as an integer"
    assert body["detail"] == once
    assert len(body["errors"]) == 1
