"""The live-map stream's resumption through a real server (each backend; one process): a browser that
reconnects with ``Last-Event-ID`` gets the deltas it missed from the delta log, nothing when it missed
nothing, and the whole map when its id is not one the log can continue. (Across processes:
tests/server/test_fanout_processes.py.)"""

from __future__ import annotations

import json
import threading
from typing import Any

from tests.server.live import Live


def _snapshot(version: int) -> dict[str, Any]:
    return {
        "version": version,
        "base_version": None,
        "stamp_s": 1.0,
        "segments": [[1, 0.0, 0.0, 1.0, 0.0]],
        "centroids": [],
        "pose": [0.0, 0.0, 0.0],
        "trajectory": [],
    }


def _delta(version: int) -> dict[str, Any]:
    return {
        "version": version,
        "base_version": version - 1,
        "stamp_s": float(version),
        "segments": [[version, float(version), 0.0, float(version), 1.0]],
        "removed": [1] if version == 2 else [],
        "centroids": [],
        "pose": [float(version), 0.0, 0.0],
        "trajectory": [[float(version), 0.0, 0.0, 0.0]],
    }


def _upload(live: Live, token: str, rid: int, body: dict[str, Any]) -> None:
    with live.client(token) as robot:
        r = robot.post(f"/robots/{rid}/maps", json=body)
        assert r.status_code == 200, r.text


def _read(live: Live, rid: int, n: int, last_event_id: str | None) -> list[tuple[str, int, dict[str, Any]]]:
    """The first ``n`` events of a stream opened with ``Last-Event-ID`` (when given)."""
    headers = {} if last_event_id is None else {"Last-Event-ID": last_event_id}
    out: list[tuple[str, int, dict[str, Any]]] = []
    kind, ident = "", -1
    with live.operator() as op, op.stream("GET", f"/robots/{rid}/maps/stream", headers=headers) as resp:
        assert resp.status_code == 200
        for line in resp.iter_lines():
            if line.startswith("event: "):
                kind = line[7:]
            elif line.startswith("id: "):
                ident = int(line[4:])
            elif line.startswith("data: "):
                out.append((kind, ident, json.loads(line[6:])))
                if len(out) == n:
                    return out
    return out


def test_reconnecting_browser_gets_the_deltas_it_missed(live: Live) -> None:
    rid, token = live.new_robot()
    _upload(live, token, rid, _snapshot(1))
    for v in (2, 3, 4):
        _upload(live, token, rid, _delta(v))
    events = _read(live, rid, 3, "1")
    assert [(k, v) for k, v, _ in events] == [("delta", 2), ("delta", 3), ("delta", 4)]
    assert events[0][2]["removed"] == [1] and events[0][2]["base_version"] == 1
    assert events[2][2]["segments"] == [[4, 4.0, 0.0, 4.0, 1.0]]


def test_a_browser_that_missed_nothing_gets_only_what_comes_next(live: Live) -> None:
    rid, token = live.new_robot()
    _upload(live, token, rid, _snapshot(1))
    _upload(live, token, rid, _delta(2))
    reader: list[list[tuple[str, int, dict[str, Any]]]] = []
    thread = threading.Thread(target=lambda: reader.append(_read(live, rid, 1, "2")))
    thread.start()
    # The stream sends nothing until version 3; uploading before it subscribed changes nothing (it would
    # then catch version 3 up from the log), so no wait is needed for the result to hold.
    _upload(live, token, rid, _delta(3))
    thread.join(30)
    assert [(k, v) for k, v, _ in reader[0]] == [("delta", 3)]


def test_an_id_the_log_cannot_continue_gets_the_whole_map(live: Live) -> None:
    rid, token = live.new_robot()
    _upload(live, token, rid, _snapshot(1))
    _upload(live, token, rid, _delta(2))
    _upload(live, token, rid, _snapshot(3))  # no delta leads from 2 past a snapshot upload
    _upload(live, token, rid, _delta(4))
    for last in ("2", "99", "0"):  # behind a snapshot upload; a version never held; before the first
        events = _read(live, rid, 1, last)
        assert [(k, v) for k, v, _ in events] == [("snapshot", 4)], last
        assert {s[0] for s in events[0][2]["segments"]} == {1, 4}


def test_a_malformed_last_event_id_is_refused_naming_it(live: Live) -> None:
    rid, _ = live.new_robot()
    with live.operator() as op:
        for bad in ("x", "-1", "1.5"):
            r = op.get(f"/robots/{rid}/maps/stream", headers={"Last-Event-ID": bad})
            assert r.status_code == 422 and "last-event-id" in r.json()["detail"].lower(), r.text
