"""The map history (server.maphistory) through a real server: ``GET /robots/{id}/maps/history`` lists the
replayable versions of the current session, and ``/latest?version=N`` and ``/export?version=N`` rebuild
version N from the delta log's undo records; a version outside the range is refused naming it."""

from __future__ import annotations

from typing import Any

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.server.live import Live

SESSION = "5f0c4f6e-8d7a-4c1b-9f1e-0a1b2c3d4e5f"


def _body(
    version: int, base: int | None, walls: dict[int, list[float]], removed: list[int], **kw: Any
) -> dict[str, Any]:
    return {
        "version": version,
        "base_version": base,
        "stamp_s": 10.0 + version,
        "segments": [[float(i), *xy] for i, xy in sorted(walls.items())],
        "removed": removed,
        "centroids": [[float(version), 0.5]],
        "pose": [0.1 * version, 0.2, 0.01 * version],
        "trajectory": [[10.0 + version, 0.1 * version, 0.2, 0.01 * version]],
        **kw,
    }


def _post(live: Live, rid: int, token: str, body: dict[str, Any]) -> None:
    with live.client(token) as robot:
        r = robot.post(f"/robots/{rid}/maps", json=body)
        assert r.status_code == 200, r.text


def _walls(m: dict[str, Any]) -> dict[int, list[float]]:
    return {int(row[0]): row[1:] for row in m["segments"]}


def test_every_version_since_the_snapshot_is_rebuilt_as_it_was(live: Live) -> None:
    """Snapshot 1, then deltas that add, move and remove walls (one skips a number): each listed version
    reads back with that version's walls, pose, centroids, stamp and trajectory; the export names it."""
    rid, token = live.new_robot()
    states: dict[int, dict[int, list[float]]] = {}
    walls = {1: [0.0, 0.0, 4.0, 0.0], 2: [4.0, 0.0, 4.0, 3.0]}
    _post(live, rid, token, _body(1, None, walls, []))
    states[1] = dict(walls)
    steps = [
        (2, {3: [4.0, 3.0, 0.0, 3.0]}, []),  # added
        (3, {1: [0.0, 0.0, 5.0, 0.0]}, [2]),  # moved one, removed one
        (5, {2: [5.0, 0.0, 5.0, 3.0], 4: [0.0, 3.0, 0.0, 0.0]}, [3]),  # re-added 2; skipped number 4
        (6, {}, [1]),
    ]
    base = 1
    for version, changed, removed in steps:
        _post(live, rid, token, _body(version, base, changed, removed))
        walls = {i: xy for i, xy in {**walls, **changed}.items() if i not in removed}
        states[version], base = dict(walls), version
    with live.operator() as op:
        h = op.get(f"/robots/{rid}/maps/history")
        assert h.status_code == 200, h.text
        hist = h.json()
        assert [v["version"] for v in hist["versions"]] == [1, 2, 3, 5, 6]
        assert [v["stamp_s"] for v in hist["versions"]] == [11.0, 12.0, 13.0, 15.0, 16.0]
        assert hist["first_version"] == 1 and hist["current_version"] == 6
        assert "snapshot" in hist["older"]
        for version, expected in states.items():
            r = op.get(f"/robots/{rid}/maps/latest", params={"version": version})
            assert r.status_code == 200, r.text
            m = r.json()
            assert m["version"] == version and _walls(m) == expected, (version, m["segments"])
            assert m["pose"] == [0.1 * version, 0.2, 0.01 * version]
            assert m["centroids"] == [[float(version), 0.5]] and m["stamp_s"] == 10.0 + version
            assert [p[0] for p in m["trajectory"]] == [10.0 + v for v in states if v <= version]
        tail = op.get(f"/robots/{rid}/maps/latest", params={"version": 3, "trajectory": 1}).json()
        assert tail["trajectory"] == [[13.0, 0.30000000000000004, 0.2, 0.03]]
        geo = op.get(f"/robots/{rid}/maps/export", params={"format": "geojson", "version": 2})
        assert geo.status_code == 200 and geo.headers["x-map-version"] == "2"
        lines = [f for f in geo.json()["features"] if f["properties"]["kind"] == "segment"]
        assert sorted(f["properties"]["id"] for f in lines) == sorted(states[2])
        # outside the range: each refusal names it
        skipped = op.get(f"/robots/{rid}/maps/latest", params={"version": 4})
        assert skipped.status_code == 404 and "1..6" in skipped.text and "no version 4" in skipped.text
        ahead = op.get(f"/robots/{rid}/maps/latest", params={"version": 9})
        assert ahead.status_code == 409 and ahead.json()["current_version"] == 6 and "1..6" in ahead.text
        # the current map is unchanged by the replays
        assert _walls(op.get(f"/robots/{rid}/maps/latest").json()) == states[6]


def test_versions_before_a_snapshot_are_gone_and_the_answer_says_why(live: Live) -> None:
    rid, token = live.new_robot()
    _post(live, rid, token, _body(1, None, {1: [0.0, 0.0, 1.0, 0.0]}, []))
    _post(live, rid, token, _body(2, 1, {2: [1.0, 0.0, 1.0, 1.0]}, []))
    _post(live, rid, token, _body(3, None, {5: [0.0, 0.0, 2.0, 2.0]}, []))  # a resync snapshot
    _post(live, rid, token, _body(4, 3, {6: [2.0, 2.0, 3.0, 2.0]}, []))
    with live.operator() as op:
        hist = op.get(f"/robots/{rid}/maps/history").json()
        assert [v["version"] for v in hist["versions"]] == [3, 4]
        assert hist["older"].startswith("version 3 is the oldest replayable: it is a snapshot upload")
        gone = op.get(f"/robots/{rid}/maps/latest", params={"version": 2})
        assert gone.status_code == 410, gone.text
        body = gone.json()
        assert body["first_version"] == 3 and body["current_version"] == 4
        assert "version 2 of robot" in body["detail"] and "3..4" in body["detail"]
        assert "snapshot" in body["detail"]
        exp = op.get(f"/robots/{rid}/maps/export", params={"format": "svg", "version": 1})
        assert exp.status_code == 410 and "3..4" in exp.text
        three = op.get(f"/robots/{rid}/maps/latest", params={"version": 3}).json()
        assert _walls(three) == {5: [0.0, 0.0, 2.0, 2.0]}


def test_a_new_robot_has_version_0_only(live: Live) -> None:
    rid, _token = live.new_robot()
    with live.operator() as op:
        hist = op.get(f"/robots/{rid}/maps/history").json()
        assert [v["version"] for v in hist["versions"]] == [0] and "empty map" in hist["older"]
        assert op.get("/robots/999999/maps/history").status_code == 404


_coord = st.floats(-50.0, 50.0, allow_nan=False).map(lambda x: round(x, 3))
_step = st.tuples(
    st.dictionaries(st.integers(0, 12), st.lists(_coord, min_size=4, max_size=4), max_size=5),
    st.lists(st.integers(0, 12), max_size=3, unique=True),
)


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    start=st.dictionaries(st.integers(0, 12), st.lists(_coord, min_size=4, max_size=4), max_size=6),
    steps=st.lists(_step, min_size=1, max_size=6),
)
def test_any_delta_sequence_replays_exactly(
    live: Live, start: dict[int, list[float]], steps: list[Any]
) -> None:
    """Property: whatever walls deltas add, move or remove (an id both changed and removed in one delta is
    removed first, then written, as the server applies it), every version reads back as it was."""
    rid, token = live.new_robot()
    _post(live, rid, token, _body(1, None, start, []))
    states = {1: dict(start)}
    walls = dict(start)
    for n, (changed, removed) in enumerate(steps, start=2):
        _post(live, rid, token, _body(n, n - 1, changed, removed))
        walls = {i: xy for i, xy in walls.items() if i not in removed} | changed
        states[n] = dict(walls)
    with live.operator() as op:
        listed = [v["version"] for v in op.get(f"/robots/{rid}/maps/history").json()["versions"]]
        assert listed == sorted(states)
        for version, expected in states.items():
            m = op.get(f"/robots/{rid}/maps/latest", params={"version": version}).json()
            assert _walls(m) == expected, version
