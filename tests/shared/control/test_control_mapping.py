"""Control message -> PipelineConfig and back: Listing 1, partial updates, validation errors, round trips."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import given, settings

from shared.control import (
    NO_SCAN_MATCHING,
    ControlMessage,
    ControlMessageError,
    KernelSpec,
    ScheduleEntry,
    build_message,
    from_config,
    parse_message,
    to_config,
)
from shared.kernels import Stage
from shared.pipeline import KernelChoice, Mode, PipelineConfig, StageSchedule
from tests.shared.control.control_strategies import configs

LISTING1 = Path(__file__).parent / "fixtures" / "listing1.xml"


def wrap(body: str) -> str:
    return f'<?xml version="1.0"?>\n<xml><message>\n{body}\n</message></xml>\n'


def test_listing1_on_default_config() -> None:
    config = to_config(parse_message(LISTING1.read_bytes()), PipelineConfig())
    base = PipelineConfig()
    assert config.mode is Mode.ONLINE
    assert config.noise_removal == (
        KernelChoice(name="dbscan", params={"min_points": 15, "epsilon_m": 0.05}),
        KernelChoice(name="erosion", params={"element": "PLUSx4"}),
    )
    assert config.clustering == KernelChoice(name="kmeans", params={"n_clusters": 2})
    assert config.straight_line == KernelChoice(name="hough")
    # what Listing 1 does not mention keeps the base's values
    assert (config.segmentation, config.scan_matching, config.n_smax) == (
        base.segmentation,
        base.scan_matching,
        base.n_smax,
    )
    kernels = config.build()
    dbscan, erosion = kernels[Stage.NOISE_REMOVAL]
    assert dbscan.get_params() == {"epsilon_m": 0.05, "min_points": 15, "spacing_factor": 1.4}
    assert erosion.get_params()["element"] == "PLUSx4"
    assert kernels[Stage.CLUSTERING][0].get_params()["n_clusters"] == 2


def test_partial_message_keeps_the_rest_and_kernel_elements_replace_whole() -> None:
    base = to_config(parse_message(LISTING1.read_bytes()), PipelineConfig())
    config = to_config(
        parse_message(wrap("<clustering><fcm><cluster-no>3</cluster-no></fcm></clustering>")), base
    )
    assert config.clustering == KernelChoice(name="fcm", params={"n_clusters": 3})
    assert config.model_dump(exclude={"clustering"}) == base.model_dump(exclude={"clustering"})
    # a kernel element states the whole kernel: unnamed parameters go back to the kernel's defaults
    again = to_config(
        parse_message(wrap("<noise-removal><dbscan><epsilon>4</epsilon></dbscan></noise-removal>")), base
    )
    assert again.noise_removal == (KernelChoice(name="dbscan", params={"epsilon_m": 0.04}),)


def test_mixed_schedule_and_switches() -> None:
    msg = parse_message(
        wrap(
            "<mode>mixed</mode><n-smax>5</n-smax><heading-flush unit='deg'>30</heading-flush>"
            "<noise-removal/><scan-matching>none</scan-matching>"
            "<schedule><stage name='clustering' mode='offline' n-smax='3'/>"
            "<stage name='straight-line' mode='offline'/></schedule>"
        )
    )
    config = to_config(msg, PipelineConfig())
    assert (config.mode, config.n_smax, config.heading_flush_deg) == (Mode.MIXED, 5, 30.0)
    assert config.noise_removal == () and config.scan_matching is None
    assert config.schedule == {
        Stage.CLUSTERING: StageSchedule(mode=Mode.OFFLINE, n_smax=3),
        Stage.STRAIGHT_LINE: StageSchedule(mode=Mode.OFFLINE, n_smax=9),
    }
    assert config.stage_schedule(Stage.CLUSTERING) == StageSchedule(mode=Mode.OFFLINE, n_smax=3)
    assert config.stage_schedule(Stage.NOISE_REMOVAL).mode is Mode.ONLINE


@pytest.mark.parametrize(
    ("body", "fragments"),
    [
        (
            "<noise-removal>\n<dbscan><minpts>15</minpts>\n<epsilon>-5</epsilon></dbscan></noise-removal>",
            [
                "line 5 <epsilon>: invalid parameters for kernel 'dbscan': "
                "dbscan.epsilon_m: -0.05 is invalid",
                "allowed range 0.0001 <= epsilon_m <= 10.0 m",
            ],
        ),
        (
            "<noise-removal><erosion><kernel-name>PLUSx5</kernel-name></erosion></noise-removal>",
            ["line 3 <kernel-name>: invalid parameters for kernel 'erosion'", "PLUSx5"],
        ),
        (
            "<clustering><kmeans><cluster-no>0</cluster-no></kmeans></clustering>",
            ["<cluster-no>", "kmeans.n_clusters"],
        ),
        (
            "<clustering><kmeans><param name='colour'>red</param></kmeans></clustering>",
            ['<param name="colour">', "unknown parameter"],
        ),
        ("<clustering><fcm><fuzzifier>1</fuzzifier></fcm></clustering>", ["<fuzzifier>", "fcm.fuzzifier"]),
        (
            "<straight-line-method>svd<param name='min_points'>1</param></straight-line-method>",
            ['line 3 <param name="min_points">', "svd.min_points"],
        ),
        (
            "<straight-line-method>Hough<version>9.0.0</version></straight-line-method>",
            ["line 3 <straight-line-method>", "has no version '9.0.0'"],
        ),
        ("<scan-matching>icp<param name='max_iterations'>0</param></scan-matching>", ["icp.max_iterations"]),
        (
            "<segmentation><abd-iepf><param name='lambda_deg'>95</param></abd-iepf></segmentation>",
            ["abd-iepf.lambda_deg"],
        ),
        ("<n-smax>0</n-smax>", ["line 3 <n-smax>: n_smax: Input should be greater than or equal to 1"]),
        ("<heading-flush>-1</heading-flush>", ["<heading-flush>: heading_flush_deg"]),
        (
            "<schedule>\n<stage name='clustering' mode='offline' n-smax='0'/></schedule>",
            ["line 4 <stage>: stage clustering: n_smax"],
        ),
    ],
)
def test_invalid_values_name_the_element_and_the_kernel_message(body: str, fragments: list[str]) -> None:
    msg = parse_message(wrap(body))
    with pytest.raises(ControlMessageError) as info:
        to_config(msg, PipelineConfig())
    for fragment in fragments:
        assert fragment in str(info.value), (fragment, str(info.value))


def test_errors_without_source_lines() -> None:
    msg = ControlMessage(noise_removal=(KernelSpec.of("dbscan", {"epsilon_m": -1.0}),))
    with pytest.raises(ControlMessageError, match=r"^<epsilon>: invalid parameters"):
        to_config(msg, PipelineConfig())
    # a kernel this process does not have is stated by name, and refused where it is built
    stated = from_config(PipelineConfig.model_construct(noise_removal=(KernelChoice(name="median"),)))
    assert stated.noise_removal == (KernelSpec("median"),)
    with pytest.raises(ControlMessageError, match=r'^<kernel name="median">: .*median'):
        to_config(stated, PipelineConfig())


def test_from_config_default() -> None:
    msg = from_config(PipelineConfig(), seq=7)
    assert msg.seq == 7 and msg.mode is Mode.ONLINE and msg.n_smax == 9
    assert msg.straight_line == KernelSpec.of("hough-cluster", {"min_points": 8})
    assert msg.scan_matching == KernelSpec("icp") and msg.schedule == ()
    off = from_config(PipelineConfig(scan_matching=None))
    assert off.scan_matching == NO_SCAN_MATCHING


def test_from_config_rejects_mixed_stage_mode() -> None:
    config = PipelineConfig(schedule={Stage.CLUSTERING: StageSchedule(mode=Mode.MIXED)})
    with pytest.raises(ControlMessageError, match="scheduled 'mixed'"):
        from_config(config)


def test_schedule_entries_from_config_in_stage_order() -> None:
    config = PipelineConfig(
        mode=Mode.MIXED,
        schedule={
            Stage.STRAIGHT_LINE: StageSchedule(mode=Mode.OFFLINE, n_smax=4),
            Stage.NOISE_REMOVAL: StageSchedule(mode=Mode.ONLINE),
        },
    )
    assert from_config(config).schedule == (
        ScheduleEntry(Stage.NOISE_REMOVAL, Mode.ONLINE, 9),
        ScheduleEntry(Stage.STRAIGHT_LINE, Mode.OFFLINE, 4),
    )


@settings(max_examples=150, deadline=None)
@given(configs(), configs())
def test_config_round_trip_through_xml(config: PipelineConfig, base: PipelineConfig) -> None:
    msg = from_config(config, seq=1)
    assert to_config(msg, PipelineConfig()) == config
    assert to_config(msg, base) == config  # the message states everything
    assert to_config(parse_message(build_message(msg)), base) == config
