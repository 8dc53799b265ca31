"""Any kernel is nameable: ``<kernel name="..">`` in every stage's element, read, written, checked against
the XSD, and validated against that kernel's own parameter model where it is built."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest
from lxml import etree
from numpy.typing import ArrayLike

from shared.control import (
    ControlMessage,
    ControlMessageError,
    KernelSpec,
    build_message,
    from_config,
    parse_message,
    to_config,
    xsd_schema,
)
from shared.kernels import REGISTRY, NoiseRemovalKernel, Stage, StraightLineKernel, param
from shared.kernels.params import KernelParams
from shared.kernels.results import Lines, NoiseResult
from shared.pipeline import KernelChoice, PipelineConfig


class _GapParams(KernelParams):
    gap_m: float = param(0.05, description="test", unit="m", gt=0.0, le=1.0)


class _KeepAll(NoiseRemovalKernel[_GapParams]):
    """A noise filter of a new name (test kernel)."""

    name = "keep-all-test"
    version = "1.0.0"
    Params = _GapParams

    def apply(self, points: ArrayLike) -> NoiseResult:
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        return NoiseResult(np.ones(len(pts), bool), pts, np.zeros(len(pts), np.intp))


class _NoLines(StraightLineKernel[_GapParams]):
    """A straight-line method of a new name (test kernel)."""

    name = "no-lines-test"
    version = "1.0.0"
    Params = _GapParams

    def apply(self, points: ArrayLike, groups: ArrayLike | None = None) -> Lines:
        empty = np.zeros((0,))
        return Lines(np.zeros((0, 4)), empty, empty, np.zeros((0,), np.intp), np.zeros((0,), np.intp))


@pytest.fixture
def new_kernels() -> Iterator[None]:
    REGISTRY.register(_KeepAll)
    REGISTRY.register(_NoLines)
    try:
        yield
    finally:
        REGISTRY.unregister(Stage.NOISE_REMOVAL, _KeepAll.name, "1.0.0")
        REGISTRY.unregister(Stage.STRAIGHT_LINE, _NoLines.name, "1.0.0")


def _doc(body: str) -> str:
    return f"<xml><message>\n{body}\n</message></xml>"


def _valid(doc: str | bytes) -> bool:
    raw = doc.encode() if isinstance(doc, str) else doc
    return bool(xsd_schema().validate(etree.fromstring(raw)))


def test_generic_element_in_every_stage_reads_and_validates() -> None:
    doc = _doc(
        '<segmentation><kernel name="my-seg"><version>2.0.0</version></kernel></segmentation>\n'
        "<noise-removal><dbscan><minpts>3</minpts></dbscan>"
        '<kernel name="radius-outlier"><param name="radius_m" unit="cm">6</param></kernel></noise-removal>\n'
        '<clustering><kernel name="mean-shift"><param name="bandwidth_m">0.5</param></kernel></clustering>\n'
        '<straight-line-method><kernel name="ransac"><param name="min_points">4</param></kernel>'
        "</straight-line-method>\n"
        '<scan-matching><kernel name="ndt"/></scan-matching>'
    )
    assert _valid(doc)
    msg = parse_message(doc)
    assert msg.segmentation == KernelSpec("my-seg", (), "2.0.0")
    assert msg.noise_removal is not None
    assert [s.name for s in msg.noise_removal] == ["dbscan", "radius-outlier"]
    assert msg.noise_removal[1].params_dict() == {"radius_m": pytest.approx(0.06)}  # centimetres read
    assert msg.clustering is not None and msg.clustering.params_dict() == {"bandwidth_m": 0.005}
    assert msg.straight_line == KernelSpec.of("ransac", {"min_points": 4})
    assert msg.scan_matching == KernelSpec("ndt")
    written = build_message(msg)
    assert _valid(written)
    assert parse_message(written) == msg
    assert b'<kernel name="radius-outlier">' in written and b"<dbscan>" in written  # paper elements kept


@pytest.mark.parametrize(
    ("body", "fragment"),
    [
        ('<noise-removal><kernel name="Radius_Outlier"/></noise-removal>', "is not a kernel name"),
        ("<noise-removal><kernel/></noise-removal>", "name='' is not a kernel name"),
        ('<clustering><kernel name="k" extra="1"/></clustering>', "unknown attribute 'extra'"),
        (
            '<noise-removal><kernel name="x"><minpts>3</minpts></kernel></noise-removal>',
            "<minpts>: unknown element in <kernel>: expected <param>, <version>",
        ),
        (
            '<straight-line-method>Hough<kernel name="ransac"/></straight-line-method>',
            "either by its text or by one <kernel>",
        ),
        (
            '<straight-line-method><kernel name="a"/><kernel name="b"/></straight-line-method>',
            "either by its text or by one <kernel>",
        ),
        ("<straight-line-method>Ransac</straight-line-method>", 'or <kernel name=".."> for any other kernel'),
        ('<clustering><kernel name="a"/><kmeans/></clustering>', "a second kernel"),
    ],
)
def test_generic_element_errors_name_the_element(body: str, fragment: str) -> None:
    with pytest.raises(ControlMessageError) as info:
        parse_message(_doc(body))
    assert fragment in str(info.value)
    assert "line 2" in str(info.value)


@pytest.mark.parametrize(
    "body",
    [
        '<noise-removal><kernel name="Radius_Outlier"/></noise-removal>',
        "<noise-removal><kernel/></noise-removal>",
        '<noise-removal><kernel name="x"><minpts>3</minpts></kernel></noise-removal>',
        '<clustering><kernel name="a"/><kmeans/></clustering>',
    ],
)
def test_xsd_refuses_what_the_parser_refuses(body: str) -> None:
    assert not _valid(_doc(body))


@pytest.mark.usefixtures("new_kernels")
def test_a_registered_kernel_of_a_new_name_is_configured_with_its_own_parameters() -> None:
    msg = parse_message(
        _doc(
            '<noise-removal><kernel name="keep-all-test"><param name="gap_m" unit="cm">7</param></kernel>'
            "</noise-removal>\n"
            '<straight-line-method><kernel name="no-lines-test"/></straight-line-method>'
        )
    )
    config = to_config(msg, PipelineConfig())
    assert config.noise_removal == (KernelChoice(name="keep-all-test", params={"gap_m": 0.07}),)
    assert config.straight_line == KernelChoice(name="no-lines-test")
    # and back: the configuration states itself with the generic element, and reads back equal
    assert to_config(parse_message(build_message(from_config(config))), PipelineConfig()) == config


@pytest.mark.usefixtures("new_kernels")
def test_a_new_kernels_parameters_are_checked_against_its_model() -> None:
    doc = _doc(
        '<noise-removal><kernel name="keep-all-test">\n<param name="gap_m" unit="m">3</param>'
        "</kernel></noise-removal>"
    )
    with pytest.raises(ControlMessageError) as info:
        to_config(parse_message(doc), PipelineConfig())
    text = str(info.value)
    assert text.startswith('line 3 <param name="gap_m">') and "gap_m" in text and "1" in text
    with pytest.raises(ControlMessageError, match=r'^<param name="no_such">: .*expected one of: gap_m'):
        to_config(
            ControlMessage(noise_removal=(KernelSpec.of("keep-all-test", {"no_such": 1}),)), PipelineConfig()
        )


def test_an_unknown_kernel_is_refused_naming_it_and_the_known_ones() -> None:
    msg = parse_message(_doc('<clustering><kernel name="mean-shift"/></clustering>'))
    with pytest.raises(ControlMessageError) as info:
        to_config(msg, PipelineConfig())
    text = str(info.value)
    assert text.startswith('line 2 <kernel name="mean-shift">')
    assert "mean-shift" in text and "kmeans" in text and "fcm" in text
