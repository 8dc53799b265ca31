"""Per-robot upload quotas and the wall cap through a real server (uvicorn on 127.0.0.1, SQLite and
PostgreSQL): an over-quota robot gets 429 with Retry-After while another robot's uploads pass; a map over
max_walls_per_map is refused with 422 naming the cap; the agent's link reports the 429 with its
Retry-After and, retried after it, delivers the same version (none is lost)."""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from typing import Any

import pytest

from robot_agent.errors import LinkError
from robot_agent.link import ServerLink
from tests.server.live import BACKENDS, Live, start_live

CAP = 50


@pytest.fixture(scope="module", params=BACKENDS)
def tight(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    """A server with small quotas: 6 uploads at once then 1 every 2 s, 256 KiB at once then 4 KiB/s."""
    tmp = tmp_path_factory.mktemp(f"quota-{request.param}")
    yield from start_live(
        request.param,
        tmp,
        max_body_bytes=256 * 1024,
        max_walls_per_map=CAP,
        upload_burst_requests=6,
        upload_requests_per_s=0.5,
        upload_burst_bytes=256 * 1024,
        upload_bytes_per_s=4 * 1024,
    )


def _walls(first: int, n: int) -> list[list[float]]:
    return [[float(i), float(i), 0.0, float(i) + 0.5, 1.0] for i in range(first, first + n)]


def _snapshot(version: int, n_walls: int = 3, trajectory: int = 1) -> dict[str, Any]:
    return {
        "version": version,
        "base_version": None,
        "segments": _walls(0, n_walls),
        "trajectory": [[0.1 * j, 1.0, 2.0, 0.0] for j in range(trajectory)],
    }


def _delta(
    base: int, version: int, segments: list[list[float]], removed: tuple[int, ...] = ()
) -> dict[str, Any]:
    return {"version": version, "base_version": base, "segments": segments, "removed": list(removed)}


def test_robot_over_its_request_rate_gets_429_while_another_robot_uploads(tight: Live) -> None:
    heavy, heavy_token = tight.new_robot()
    other, other_token = tight.new_robot()
    with tight.client(heavy_token) as h, tight.client(other_token) as o:
        codes = [h.post(f"/robots/{heavy}/maps", json=_snapshot(v)).status_code for v in range(1, 9)]
        assert codes[:6] == [200] * 6 and codes[6:] == [429, 429], codes
        r = h.post(f"/robots/{heavy}/maps", json=_snapshot(9))
        assert r.status_code == 429
        assert int(r.headers["Retry-After"]) >= 1
        body = r.json()
        assert body["error"] == "too_many_requests"
        assert f"robot {heavy}" in body["detail"] and "uploads/s" in body["detail"]
        # the other robot's own quota is untouched
        assert [o.post(f"/robots/{other}/maps", json=_snapshot(v)).status_code for v in (1, 2)] == [200, 200]
    with tight.operator() as op:
        # the refused ones changed nothing
        assert op.get(f"/robots/{heavy}/maps/latest").json()["version"] == 6


def test_robot_over_its_byte_rate_gets_429_with_retry_after(tight: Live) -> None:
    rid, token = tight.new_robot()
    big = _snapshot(1, trajectory=8000)  # ~230 kB: one fits the 256 KiB burst, two do not
    with tight.client(token) as robot:
        assert robot.post(f"/robots/{rid}/maps", json=big).status_code == 200
        big["version"] = 2
        r = robot.post(f"/robots/{rid}/maps", json=big)
    assert r.status_code == 429, r.text
    assert "bytes/s" in r.json()["detail"]
    assert int(r.headers["Retry-After"]) >= 2  # ~100+ kB missing at 4 KiB/s: many seconds


def test_snapshot_over_the_wall_cap_is_422_naming_the_cap(tight: Live) -> None:
    rid, token = tight.new_robot()
    with tight.client(token) as robot:
        r = robot.post(f"/robots/{rid}/maps", json=_snapshot(1, n_walls=CAP + 1))
    assert r.status_code == 422, r.text
    detail = r.json()["detail"]
    assert f"{CAP + 1} walls" in detail and f"limit is {CAP} walls" in detail
    assert "max_walls_per_map" in detail
    with tight.operator() as op:
        assert op.get(f"/robots/{rid}/maps/latest").json()["version"] == 0


def test_delta_that_grows_the_map_over_the_cap_is_422_but_changes_within_it_pass(tight: Live) -> None:
    rid, token = tight.new_robot()
    with tight.client(token) as robot:
        assert robot.post(f"/robots/{rid}/maps", json=_snapshot(1, n_walls=CAP)).status_code == 200
        # changing every stored wall keeps the count at the cap: passes (the exact count near the cap)
        moved = [[r[0], r[1], r[2] + 1.0, r[3], r[4]] for r in _walls(0, CAP)]
        assert robot.post(f"/robots/{rid}/maps", json=_delta(1, 2, moved)).status_code == 200
        # one new wall: over
        r = robot.post(f"/robots/{rid}/maps", json=_delta(2, 3, _walls(CAP, 1)))
        assert r.status_code == 422, r.text
        assert f"{CAP + 1} walls" in r.json()["detail"] and f"limit is {CAP}" in r.json()["detail"]
        # one new wall in place of a removed one: at the cap, passes
        r = robot.post(f"/robots/{rid}/maps", json=_delta(2, 3, _walls(CAP, 1), removed=(0,)))
        assert r.status_code == 200, r.text
    with tight.operator() as op:
        m = op.get(f"/robots/{rid}/maps/latest").json()
    assert m["version"] == 3 and len(m["segments"]) == CAP


def test_link_reports_429_and_the_retried_upload_delivers_the_version(tight: Live) -> None:
    """The agent's ServerLink: a 429 is a LinkError with status and Retry-After; the agent keeps the
    version in its outbox and sends it again after that delay (Backoff never waits less), so the map
    version arrives."""
    rid, token = tight.new_robot()
    link = ServerLink(tight.base_url, rid, token)
    try:
        for v in range(1, 7):
            assert link.upload(_snapshot(v), f"snap-{v}") == {"version": v, "duplicate": False}
        with pytest.raises(LinkError) as caught:
            link.upload(_snapshot(7), "snap-7")
        assert caught.value.status == 429
        assert caught.value.retry_after_s is not None and caught.value.retry_after_s >= 1.0
        wait_s, deadline = caught.value.retry_after_s, time.monotonic() + 30.0
        while True:  # what the uploader does: the same payload and key after Retry-After
            time.sleep(wait_s)  # the server's requested delay, not a timing guess
            try:
                got = link.upload(_snapshot(7), "snap-7")
                break
            except LinkError as exc:
                status, wait_s = exc.status, exc.retry_after_s or 1.0
            assert status == 429 and time.monotonic() < deadline
        assert got == {"version": 7, "duplicate": False}
    finally:
        link.close()
    with tight.operator() as op:
        assert op.get(f"/robots/{rid}/maps/latest").json()["version"] == 7


def test_big_upload_is_parsed_off_the_event_loop_with_the_same_result_and_errors(live: Live) -> None:
    """Bodies above INLINE_BODY_BYTES go through the parser process (server.parsepool): the stored map,
    the validation errors and the wall cap answer exactly as for small bodies."""
    from server.routers.maps import INLINE_BODY_BYTES

    rid, token = live.new_robot()
    n = 4000  # ~150 kB of JSON
    body = _snapshot(1, n_walls=n, trajectory=200)
    assert len(json.dumps(body)) > INLINE_BODY_BYTES
    with live.client(token) as robot:
        r = robot.post(f"/robots/{rid}/maps", json=body)
        assert r.status_code == 200, r.text
        bad = _snapshot(2, n_walls=n)
        bad["segments"][1234][2] = "north"
        r = robot.post(f"/robots/{rid}/maps", json=bad)
        assert r.status_code == 422 and "segments.1234.2" in r.json()["detail"], r.text
    with live.operator() as op:
        m = op.get(f"/robots/{rid}/maps/latest").json()
    assert m["version"] == 1 and m["segments"] == body["segments"] and m["trajectory"] == body["trajectory"]


def test_big_upload_over_the_wall_cap_is_422_through_the_parser_process(tight: Live) -> None:
    rid, token = tight.new_robot()
    from server.routers.maps import INLINE_BODY_BYTES

    body = _snapshot(1, n_walls=CAP + 1, trajectory=4000)  # over the inline size: the worker refuses it
    assert len(json.dumps(body)) > INLINE_BODY_BYTES
    with tight.client(token) as robot:
        r = robot.post(f"/robots/{rid}/maps", json=body)
    assert r.status_code == 422, r.text
    assert r.json()["max_walls_per_map"] == CAP and f"limit is {CAP} walls" in r.json()["detail"]
