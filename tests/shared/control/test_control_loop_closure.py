"""``<loop-closure>`` in the control message: read in the message's units, stated whole (left-out settings
take the defaults), ``enabled`` false switching it off, bad values refused naming the element and line,
and written back so that it reads the same."""

from __future__ import annotations

import pytest
from lxml import etree

from shared.control import ControlMessageError, build_message, from_config, parse_message, to_config
from shared.control.build import xsd_schema
from shared.pipeline import PipelineConfig
from shared.slam import LoopClosureSettings


def _msg(body: str) -> bytes:
    return f"<xml><message>\n{body}\n</message></xml>".encode()


def _config(body: str, base: PipelineConfig | None = None) -> PipelineConfig:
    return to_config(parse_message(_msg(body)), base or PipelineConfig())


def test_named_settings_in_the_message_units() -> None:
    config = _config(
        "<loop-closure><search-radius>350</search-radius><min-inlier-share>0.6</min-inlier-share>"
        '<param name="window_m" unit="m">1.5</param></loop-closure>'
    )
    settings = config.loop_closure_settings()
    assert settings == LoopClosureSettings(search_radius_m=3.5, min_inlier_share=0.6, window_m=1.5)


def test_an_empty_element_switches_loop_closure_on_with_the_defaults() -> None:
    assert _config("<loop-closure/>").loop_closure_settings() == LoopClosureSettings()


@pytest.mark.parametrize("spelling", ["false", "OFF", "0", " off\n"])
def test_enabled_false_switches_it_off(spelling: str) -> None:
    on = _config("<loop-closure/>")
    off = _config(f"<loop-closure><enabled>{spelling}</enabled></loop-closure>", on)
    assert off.loop_closure is None and off.loop_closure_settings() is None


def test_a_message_without_the_element_keeps_what_the_robot_has() -> None:
    on = _config('<loop-closure><search-radius unit="m">6</search-radius></loop-closure>')
    assert _config("<n-smax>5</n-smax>", on).loop_closure == on.loop_closure


def test_the_element_is_stated_whole() -> None:
    """Like a kernel element: a setting it leaves out takes the default, not the previous value."""
    tuned = _config('<loop-closure><search-radius unit="m">6</search-radius></loop-closure>')
    again = _config("<loop-closure><min-inlier-share>0.7</min-inlier-share></loop-closure>", tuned)
    assert again.loop_closure_settings() == LoopClosureSettings(min_inlier_share=0.7)


@pytest.mark.parametrize(
    ("body", "element", "line", "reason"),
    [
        (
            "<loop-closure>\n<search-radius>-3</search-radius></loop-closure>",
            "<search-radius>",
            3,
            "search_radius_m = -0.03: expected a value in [0, 100]",
        ),
        (
            "<loop-closure>\n<min-inlier-share>1.5</min-inlier-share></loop-closure>",
            "<min-inlier-share>",
            3,
            "min_inlier_share = 1.5: expected a value in [0, 1]",
        ),
        (
            "<loop-closure>\n<enabled>maybe</enabled></loop-closure>",
            "<enabled>",
            3,
            "'maybe' is not a switch: expected true or false",
        ),
        (
            '<loop-closure>\n<param name="radius">3</param></loop-closure>',
            '<param name="radius">',
            3,
            "unknown loop-closure setting(s) radius: expected some of",
        ),
        (
            '<loop-closure>\n<param name="max_candidates">2.5</param></loop-closure>',
            '<param name="max_candidates">',
            3,
            "max_candidates = 2.5: expected an integer",
        ),
        (
            "<loop-closure><version>1.0.0</version></loop-closure>",
            "<version>",
            2,
            "<loop-closure> has no versions",
        ),
        ("<loop-closure/><loop-closure/>", "<loop-closure>", 2, "given twice"),
        ("<loop-closure>on</loop-closure>", "<loop-closure>", 2, "holds elements only"),
    ],
)
def test_bad_settings_are_refused_naming_the_element(body: str, element: str, line: int, reason: str) -> None:
    base = _config("<loop-closure/>")
    with pytest.raises(ControlMessageError) as err:
        _config(body, base)
    assert err.value.element == element
    assert err.value.line == line
    assert reason in str(err.value)


def test_written_back_it_reads_the_same_and_validates_against_the_schema() -> None:
    for config in (
        _config('<loop-closure><search-radius unit="m">2.5</search-radius></loop-closure>'),
        PipelineConfig(),
    ):
        xml = build_message(from_config(config))
        assert xsd_schema().validate(etree.fromstring(xml))
        other = PipelineConfig(loop_closure={"search_radius_m": 9.0})
        assert to_config(parse_message(xml), other) == config


def test_the_paper_listing_says_nothing_about_loop_closure() -> None:
    listing = _msg(
        "<mode>offline</mode><n-smax>9</n-smax><noise-removal><dbscan><minpts>5</minpts>"
        "<epsilon>5</epsilon></dbscan></noise-removal>"
    )
    assert parse_message(listing).loop_closure is None
