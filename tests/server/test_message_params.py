"""``POST /robots/{id}/messages`` checks a raw XML message's settings exactly as the robot will (the same
function, :func:`shared.control.to_config`), through a real server on SQLite and PostgreSQL: a parameter
out of its range is a 422 naming the parameter and the range, never a queued message the robot refuses."""

from __future__ import annotations

from typing import Any

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from shared.control import ControlMessageError, parse_message, to_config
from shared.pipeline.config import PipelineConfig
from tests.server.live import Live

XML = {"Content-Type": "application/xml"}


def _post(live: Live, rid: int, body: str) -> tuple[int, dict[str, Any]]:
    with live.operator() as op:
        r = op.post(f"/robots/{rid}/messages", content=body.encode(), headers=XML)
        return r.status_code, r.json()


def _dbscan(epsilon: str, version: str = "") -> str:
    v = f"<version>{version}</version>" if version else ""
    return (
        f"<xml><message><noise-removal><dbscan>{v}<epsilon>{epsilon}</epsilon></dbscan></noise-removal>"
        "</message></xml>"
    )


def test_a_parameter_out_of_range_is_refused_naming_it_and_its_range(live: Live) -> None:
    rid, _ = live.new_robot()
    code, body = _post(live, rid, _dbscan("5000"))  # 5000 cm = 50 m; at most 10 m
    assert code == 422, body
    assert "epsilon_m" in body["detail"] and "10.0 m" in body["detail"] and "50.0" in body["detail"], body
    assert body["element"] == "<epsilon>"
    code, body = _post(
        live,
        rid,
        "<xml><message><clustering><kmeans><cluster-no>0</cluster-no></kmeans></clustering></message></xml>",
    )
    assert code == 422 and "n_clusters" in body["detail"], body
    code, body = _post(live, rid, "<xml><message><n-smax>0</n-smax></message></xml>")
    assert code == 422 and "n_smax" in body["detail"], body
    with live.operator() as op:  # nothing was queued
        assert op.get(f"/robots/{rid}/messages").json()["messages"] == []
    code, body = _post(live, rid, _dbscan("50"))
    assert code == 201, body


def test_a_kernel_version_only_the_robot_holds_is_left_to_the_robot(live: Live) -> None:
    rid, token = live.new_robot()
    store = [
        {
            "stage": "noise-removal",
            "name": "dbscan",
            "version": "1.0.0",
            "state": "active",
            "sha256": "0" * 64,
        },
        {
            "stage": "noise-removal",
            "name": "dbscan",
            "version": "2.0.0",
            "state": "verified",
            "sha256": "1" * 64,
        },
    ]
    with live.client(token) as robot:
        up = {"version": 1, "base_version": None, "status": {"kernels": store}}
        assert robot.post(f"/robots/{rid}/maps", json=up).status_code == 200
    # no version: the robot resolves dbscan to its 2.0.0, whose parameter model the server does not hold
    code, body = _post(live, rid, _dbscan("5000"))
    assert code == 201, body
    code, body = _post(live, rid, _dbscan("5000", "2.0.0"))
    assert code == 201, body
    # the built-in version is checked as the robot will check it
    code, body = _post(live, rid, _dbscan("5000", "1.0.0"))
    assert code == 422 and "epsilon_m" in body["detail"], body
    # a version that nobody has cannot be on the robot
    code, body = _post(live, rid, _dbscan("50", "7.7.7"))
    assert code == 422 and "7.7.7" in body["detail"], body


def _robot_accepts(xml: str) -> bool:
    try:
        to_config(parse_message(xml.encode()), PipelineConfig())
    except ControlMessageError:
        return False
    return True


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    epsilon_cm=st.floats(min_value=-10.0, max_value=3000.0, allow_nan=False),
    minpts=st.integers(min_value=-3, max_value=2000),
)
def test_the_server_queues_exactly_what_the_robot_accepts(live: Live, epsilon_cm: float, minpts: int) -> None:
    rid = _robot(live)
    xml = (
        "<xml><message><noise-removal><dbscan>"
        f"<minpts>{minpts}</minpts><epsilon>{epsilon_cm!r}</epsilon>"
        "</dbscan></noise-removal></message></xml>"
    )
    code, body = _post(live, rid, xml)
    assert code == (201 if _robot_accepts(xml) else 422), body


_ROBOTS: dict[str, int] = {}


def _robot(live: Live) -> int:
    if live.backend not in _ROBOTS:
        _ROBOTS[live.backend] = live.new_robot()[0]
    return _ROBOTS[live.backend]
