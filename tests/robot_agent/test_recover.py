"""A stored configuration whose downloaded kernel no longer loads is repaired stage by stage
(robot_agent/recover.py, docs/reliability/agent.md)."""

from __future__ import annotations

from robot_agent.recover import repair_config
from shared.pipeline import PipelineConfig


def _stored() -> dict:  # type: ignore[type-arg]
    cfg = PipelineConfig.parse(
        {
            "mode": "offline",
            "n_smax": 12,
            "noise_removal": [
                {"name": "dbscan", "version": "1.0.0", "params": {"epsilon_m": 0.05, "min_points": 15}},
                {"name": "erosion", "params": {"element": "PLUSx4"}},
            ],
            "clustering": {"name": "kmeans", "params": {}},
        }
    ).model_dump(mode="json")
    return cfg


def test_an_unloadable_kernel_version_falls_back_for_that_stage_only_keeping_its_parameters() -> None:
    stored = _stored()
    stored["noise_removal"][0]["version"] = "1.7.0"  # a downloaded version that did not load again
    config, notes = repair_config(stored, PipelineConfig())
    assert config.mode == "offline" and config.n_smax == 12
    dbscan, erosion = config.noise_removal
    assert dbscan.name == "dbscan" and dbscan.version == "1.0.0"
    assert dbscan.params == {"epsilon_m": 0.05, "min_points": 15}
    assert erosion.params == {"element": "PLUSx4"}
    assert config.clustering == PipelineConfig.parse(_stored()).clustering
    assert len(notes) == 1 and "dbscan 1.7.0 is not available" in notes[0]


def test_an_unknown_kernel_leaves_the_stage_default_and_keeps_the_rest() -> None:
    stored = _stored()
    stored["clustering"] = {"name": "gone-kernel", "version": "2.0.0", "params": {"k": 3}}
    config, notes = repair_config(stored, PipelineConfig())
    assert config.clustering == PipelineConfig().clustering
    assert config.noise_removal == PipelineConfig.parse(_stored()).noise_removal
    assert any("gone-kernel 2.0.0" in n for n in notes)


def test_parameters_the_stand_in_refuses_reset_that_stage_only() -> None:
    stored = _stored()
    stored["noise_removal"][0] = {"name": "dbscan", "version": "1.7.0", "params": {"no_such_param": 1}}
    config, notes = repair_config(stored, PipelineConfig())
    assert config.noise_removal == PipelineConfig().noise_removal
    assert config.mode == "offline" and any("do not build" in n for n in notes)


def test_garbage_is_not_repaired() -> None:
    assert repair_config("not a dict", PipelineConfig()) == (PipelineConfig(), [])
