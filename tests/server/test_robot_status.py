"""``PUT /robots/{id}/status`` (server/routers/robots.py): a robot with nothing to upload reports its status
alone; the server shows its ``last_error`` (null clears it); only the robot's own token may, and a bad
body is refused naming the field. Through the real server on both backends."""

from __future__ import annotations

from tests.server.live import Live


def test_a_robot_reports_its_status_without_a_map(live: Live) -> None:
    rid, token = live.new_robot()
    other, other_token = live.new_robot()
    with live.client(token) as robot, live.operator() as op:
        r = robot.put(f"/robots/{rid}/status", json={"mode": "online", "last_error": "disk is full"})
        assert r.status_code == 204, r.text
        got = op.get(f"/robots/{rid}").json()
        assert got["last_error"] == "disk is full" and got["mode"] == "online" and got["map_version"] == 0
        assert robot.put(f"/robots/{rid}/status", json={"mode": "online"}).status_code == 204
        assert op.get(f"/robots/{rid}").json()["last_error"] is None, "null clears it"
        bad = robot.put(f"/robots/{rid}/status", json={"mode": "online", "last_error": "x" * 5000})
        assert bad.status_code == 422 and "last_error" in bad.text
        assert robot.put(f"/robots/{other}/status", json={"mode": "online"}).status_code == 403
        assert op.put(f"/robots/{rid}/status", json={"mode": "online"}).status_code == 403
    with live.client(other_token) as second:
        assert second.put(f"/robots/{other}/status", json={"mode": "offline"}).status_code == 204
