"""Building canonical XML, the published XSD, and the parse(build(m)) == m round trip."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import given, settings
from lxml import etree

from shared.control import (
    NO_SCAN_MATCHING,
    ControlMessage,
    ControlMessageError,
    KernelSpec,
    build_message,
    parse_message,
    xsd_schema,
    xsd_text,
)
from shared.pipeline import Mode
from tests.shared.control.control_strategies import messages

LISTING1 = Path(__file__).parent / "fixtures" / "listing1.xml"


def assert_valid(doc: bytes) -> None:
    schema = xsd_schema()
    assert schema.validate(etree.fromstring(doc)), schema.error_log


def test_xsd_is_package_data_and_compiles() -> None:
    text = xsd_text()
    assert text.startswith('<?xml version="1.0"')
    assert (Path(__file__).parents[3] / "shared" / "control" / "control.xsd").read_text(
        encoding="utf-8"
    ) == text
    etree.XMLSchema(etree.fromstring(text.encode()))


def test_listing1_validates_against_xsd() -> None:
    assert_valid(LISTING1.read_bytes())


@pytest.mark.parametrize(
    "body",
    [
        "<mode>sometimes</mode>",
        "<noise-removal><dbscan><epsilon unit='km'>5</epsilon></dbscan></noise-removal>",
        "<noise-removal><dbscan><minpts>fifteen</minpts></dbscan></noise-removal>",
        "<clustering><kmeans/><fcm/></clustering>",
        "<unknown/>",
        '<kernel-install stage="clustering" name="k" version="1.0.0"/>',
    ],
)
def test_xsd_rejects_what_the_parser_rejects(body: str) -> None:
    doc = etree.fromstring(f"<xml><message>{body}</message></xml>".encode())
    assert not xsd_schema().validate(doc)


def test_listing1_canonical_form() -> None:
    built = build_message(parse_message(LISTING1.read_bytes()))
    assert built == (
        b"<?xml version='1.0' encoding='UTF-8'?>\n<xml>\n  <message>\n    <mode>online</mode>\n"
        b"    <noise-removal>\n      <dbscan>\n        <minpts>15</minpts>\n"
        b'        <epsilon unit="m">0.05</epsilon>\n      </dbscan>\n      <erosion>\n'
        b"        <kernel-name>PLUSx4</kernel-name>\n      </erosion>\n    </noise-removal>\n"
        b"    <clustering>\n      <kmeans>\n        <cluster-no>2</cluster-no>\n      </kmeans>\n"
        b"    </clustering>\n    <straight-line-method>Hough</straight-line-method>\n  </message>\n</xml>\n"
    )
    assert_valid(built)


def test_build_writes_lengths_in_metres_and_paper_spellings() -> None:
    msg = ControlMessage(
        straight_line=KernelSpec.of("centroid-join", {"max_gap_m": 2.5}),
        scan_matching=NO_SCAN_MATCHING,
        mode=Mode.OFFLINE,
    )
    text = build_message(msg).decode()
    assert "<straight-line-method>CentroidJoin" in text
    assert '<param name="max_gap_m" unit="m">2.5</param>' in text
    assert "<scan-matching>none</scan-matching>" in text
    assert parse_message(text) == msg


@pytest.mark.parametrize(
    ("msg", "fragment"),
    [
        (ControlMessage(clustering=KernelSpec("Radius_Outlier")), "'Radius_Outlier' is not a kernel name"),
        (ControlMessage(straight_line=KernelSpec("ransac lines")), "'ransac lines' is not a kernel name"),
        (ControlMessage(n_smax=9.5), "<n-smax>: 9.5 is not an integer"),  # type: ignore[arg-type]
        (ControlMessage(heading_flush_deg=float("inf")), "<heading-flush>: inf is not a finite number"),
        (ControlMessage(clustering=KernelSpec.of("kmeans", {"n_clusters": 2.0})), "<cluster-no>"),
        (ControlMessage(clustering=KernelSpec.of("kmeans", {"label": " x"})), '<param name="label">'),
        (ControlMessage(clustering=KernelSpec.of("kmeans", {"label": "12"})), "reads back the same"),
        (ControlMessage(clustering=KernelSpec.of("kmeans", {"seed": (1,)})), "two or more integers"),
        (
            ControlMessage(clustering=KernelSpec.of("kmeans", {"label": "a\x01"})),
            "characters XML cannot carry",
        ),
        (
            ControlMessage(noise_removal=(KernelSpec.of("erosion", {"element": 3}),)),
            "<kernel-name>: 3 is not a name",
        ),
    ],
)
def test_unwritable_messages(msg: ControlMessage, fragment: str) -> None:
    with pytest.raises(ControlMessageError, match=None) as info:
        build_message(msg)
    assert fragment in str(info.value)


def test_kernel_spec_rejects_duplicate_params() -> None:
    with pytest.raises(ControlMessageError, match="'a' given twice"):
        KernelSpec("kmeans", (("a", 1), ("a", 2)))


@settings(max_examples=300, deadline=None)
@given(messages())
def test_parse_build_round_trip_and_xsd(msg: ControlMessage) -> None:
    built = build_message(msg)
    assert_valid(built)
    assert parse_message(built) == msg
    assert build_message(parse_message(built)) == built
