"""The stage descriptions: one per stage, and what reads them agrees with them."""

from __future__ import annotations

import numpy as np
import pytest

from shared.control import from_config, to_config
from shared.kernels import REGISTRY, Kernel, Stage
from shared.kernels.conformance import check_result, run_stage
from shared.kernels.probes import wall_points
from shared.kernels.stages import SCHEDULED, STAGES, spec_of, stage_of_field
from shared.pipeline import KernelChoice, PipelineConfig


def test_every_stage_has_one_description_in_order() -> None:
    assert list(STAGES) == list(Stage)
    assert [s.stage for s in STAGES.values()] == list(Stage)
    assert len({s.field for s in STAGES.values()}) == len(Stage)
    assert len({s.element for s in STAGES.values()}) == len(Stage)
    assert SCHEDULED == (Stage.NOISE_REMOVAL, Stage.CLUSTERING, Stage.STRAIGHT_LINE)


def test_fields_are_the_configuration_fields() -> None:
    config = PipelineConfig()
    for stage, spec in STAGES.items():
        assert spec.field in PipelineConfig.model_fields
        assert stage_of_field(spec.field) is stage
        kernels = config.build()[stage]
        assert all(isinstance(k, spec.base) for k in kernels)
        assert kernels, f"{stage}: the default pipeline runs it"
    with pytest.raises(ValueError, match="unknown stage field 'mode'"):
        stage_of_field("mode")
    with pytest.raises(ValueError, match="unknown stage 'walls'"):
        spec_of("walls")


def test_every_registered_kernel_derives_from_its_stage_base_and_returns_its_result() -> None:
    for info in REGISTRY.list():
        spec = STAGES[info.stage]
        cls = REGISTRY.get(info.stage, info.name, info.version)
        assert issubclass(cls, spec.base), info
        kernel: Kernel = cls()  # type: ignore[type-arg]
        result = run_stage(kernel, wall_points(300))
        assert isinstance(result, spec.result), info
        assert check_result(info.stage, result, 300) == [], info


def test_a_result_of_the_wrong_type_is_named() -> None:
    for stage, spec in STAGES.items():
        other = next(s.result for s in STAGES.values() if s.result is not spec.result)
        problems = check_result(stage, object.__new__(other), 3)
        assert problems == [f"returned {other.__name__}: expected {spec.result.__name__}"]


def test_chain_and_optional_drive_the_configuration_and_the_message() -> None:
    config = PipelineConfig(
        noise_removal=(KernelChoice(name="dbscan"), KernelChoice(name="dbscan", params={"min_points": 3})),
        scan_matching=None,
    )
    assert [c.name for c in config.choices(Stage.NOISE_REMOVAL)] == ["dbscan", "dbscan"]
    assert config.choices(Stage.SCAN_MATCHING) == []
    assert config.build()[Stage.SCAN_MATCHING] == []
    # the control message states the chain whole and the switched-off matcher, and reads them back
    msg = from_config(config)
    assert len(msg.noise_removal or ()) == 2 and msg.scan_matching == "none"
    assert to_config(msg, PipelineConfig()) == config


def test_probes_feed_every_stage_in_its_apply_form() -> None:
    pts = np.array([[1.0, 0.0], [1.0, 0.1]])
    for stage, spec in STAGES.items():
        args = spec.probe(pts)
        assert 1 <= len(args) <= 3, stage
    assert STAGES[Stage.STRAIGHT_LINE].probe(pts)[1].tolist() == [0, 0]
