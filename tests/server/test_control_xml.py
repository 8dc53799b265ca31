"""``POST /control/xml``: the dashboard's tuning form becomes canonical XML, validated before it is queued."""

from __future__ import annotations

from typing import Any

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from shared.control import parse_message, to_config
from shared.pipeline.config import PipelineConfig
from tests.server.live import Live


def _xml(live: Live, draft: dict[str, Any]) -> tuple[int, dict[str, Any]]:
    with live.operator() as op:
        r = op.post("/control/xml", json=draft)
    return r.status_code, r.json()


def test_draft_becomes_xml_the_robot_reads_back(live: Live) -> None:
    draft = {
        "mode": "mixed",
        "n_smax": 12,
        "noise_removal": [{"name": "dbscan", "params": {"epsilon_m": 0.04, "min_points": 4}}],
        "clustering": {"name": "kmeans", "params": {"n_clusters": 60}},
        "straight_line": {"name": "svd", "params": {}},
        "scan_matching": "none",
    }
    code, body = _xml(live, draft)
    assert code == 200, body
    assert '<epsilon unit="m">0.04</epsilon>' in body["xml"]
    config = to_config(parse_message(body["xml"]), PipelineConfig())
    assert config.mode == "mixed" and config.n_smax == 12 and config.scan_matching is None
    assert config.noise_removal[0].params == {"epsilon_m": 0.04, "min_points": 4}
    assert config.clustering.params == {"n_clusters": 60} and config.straight_line.name == "svd"


def test_kernel_operations_are_written(live: Live) -> None:
    digest = "ab" * 32
    code, body = _xml(
        live,
        {
            "operations": [
                {
                    "kind": "install",
                    "stage": "noise-removal",
                    "name": "dbscan",
                    "version": "1.1.0",
                    "sha256": digest,
                },
                {"kind": "rollback", "stage": "clustering", "name": "kmeans", "version": "1.0.0"},
            ],
            "noise_removal": [{"name": "dbscan", "version": "1.1.0", "params": {}}],
        },
    )
    assert code == 200, body
    msg = parse_message(body["xml"])
    assert [(o.kind.value, o.name, o.version, o.sha256) for o in msg.operations] == [
        ("install", "dbscan", "1.1.0", digest),
        ("rollback", "kmeans", "1.0.0", None),
    ]
    assert msg.noise_removal is not None and msg.noise_removal[0].version == "1.1.0"


def test_bad_values_are_named(live: Live) -> None:
    code, body = _xml(live, {"clustering": {"name": "kmeans", "params": {"n_clusters": 0}}})
    assert code == 422 and "n_clusters" in body["detail"] and "kmeans" in body["detail"]
    code, body = _xml(live, {"noise_removal": [{"name": "dbscan", "params": {"epsilon_m": -1}}]})
    assert code == 422 and "epsilon_m" in body["detail"]
    code, body = _xml(live, {"noise_removal": [{"name": "dbscan", "params": {"no_such": 1}}]})
    assert code == 422 and "no_such" in body["detail"]
    code, body = _xml(live, {"n_smax": 0})
    assert code == 422 and "n_smax" in body["detail"]
    code, body = _xml(live, {"noise_removal": []})
    assert code == 422 and "noise_removal" in body["detail"]
    code, body = _xml(live, {"operations": [{"kind": "install", "stage": "clustering", "name": "kmeans",
                                             "version": "2.0.0"}]})  # fmt: skip
    assert code == 422 and "sha256" in body["detail"]
    code, body = _xml(live, {"clustering": {"name": "no-such-kernel", "params": {}}})
    assert code == 422 and "no-such-kernel" in body["detail"]


def test_robots_may_not_build_messages(live: Live) -> None:
    _rid, token = live.new_robot()
    with live.client(token) as robot:
        assert robot.post("/control/xml", json={"mode": "online"}).status_code == 403


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    epsilon_m=st.floats(min_value=0.001, max_value=1.0, allow_nan=False),
    min_points=st.integers(min_value=1, max_value=50),
    clusters=st.integers(min_value=1, max_value=500),
)
def test_any_valid_draft_round_trips(live: Live, epsilon_m: float, min_points: int, clusters: int) -> None:
    code, body = _xml(
        live,
        {
            "noise_removal": [
                {"name": "dbscan", "params": {"epsilon_m": epsilon_m, "min_points": min_points}}
            ],
            "clustering": {"name": "kmeans", "params": {"n_clusters": clusters}},
        },
    )
    assert code == 200, body
    config = to_config(parse_message(body["xml"]), PipelineConfig())
    assert config.noise_removal[0].params["min_points"] == min_points
    assert abs(float(config.noise_removal[0].params["epsilon_m"]) - epsilon_m) <= 1e-9 * max(1.0, epsilon_m)
    assert config.clustering.params == {"n_clusters": clusters}


def test_loop_closure_in_the_draft(live: Live) -> None:
    code, body = _xml(
        live,
        {"loop_closure": {"search_radius_m": 6.0, "min_inlier_share": 0.55, "params": {"window_m": 1.5}}},
    )
    assert code == 200, body
    assert '<search-radius unit="m">6.0</search-radius>' in body["xml"]
    settings = to_config(parse_message(body["xml"]), PipelineConfig()).loop_closure_settings()
    assert settings is not None
    assert (settings.search_radius_m, settings.min_inlier_share, settings.window_m) == (6.0, 0.55, 1.5)
    code, body = _xml(live, {"loop_closure": {"enabled": False}})
    assert code == 200, body
    on = PipelineConfig(loop_closure={})
    assert to_config(parse_message(body["xml"]), on).loop_closure is None


def test_a_bad_loop_closure_setting_is_named(live: Live) -> None:
    code, body = _xml(live, {"loop_closure": {"min_inlier_share": 1.5}})
    assert code == 422
    text = str(body)
    assert "<min-inlier-share>" in text and "min_inlier_share = 1.5: expected a value in [0, 1]" in text
    code, body = _xml(live, {"loop_closure": {"params": {"radius": 2}}})
    assert code == 422
    assert "unknown loop-closure setting(s) radius" in str(body)


def test_a_kernel_of_a_new_name_is_written_once_the_server_holds_it(live: Live) -> None:
    """Any kernel the server holds uploaded (or the draft installs) is named by ``<kernel name="..">``;
    its parameters are the robot's to check (the server runs no uploaded code). A name held nowhere is
    refused, naming it."""
    draft = {"noise_removal": [{"name": "radius-outlier", "version": "1.0.0", "params": {"radius_m": 0.06}}]}
    code, body = _xml(live, draft)
    assert code == 422 and "radius-outlier" in body["detail"], body
    digest = "cd" * 32
    install = {"kind": "install", "stage": "noise-removal", "name": "radius-outlier", "version": "1.0.0",
               "sha256": digest}  # fmt: skip
    code, body = _xml(live, {**draft, "operations": [install]})
    assert code == 200, body
    assert '<kernel name="radius-outlier">' in body["xml"]
    assert '<param name="radius_m" unit="m">0.06</param>' in body["xml"]
    msg = parse_message(body["xml"])
    assert msg.noise_removal is not None and msg.noise_removal[0].params_dict() == {"radius_m": 0.06}
