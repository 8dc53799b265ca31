"""The one spelling of a kernel version (shared.kernels.versions): properties of the pattern, the parser and
the order, and that every other place that checks a version (the XSD, the server's JSON drafts, the
control XML parser) agrees with it."""

from __future__ import annotations

import re

import pytest
from hypothesis import given
from hypothesis import strategies as st
from lxml import etree

from server.routers.control import OperationDraft
from shared.control import ControlMessageError, parse_message, xsd_text
from shared.kernels.versions import VERSION_PATTERN, is_version, legacy_version_key, parse_version

ROLLBACK = (
    '<xml><message><kernel-rollback stage="noise-removal" name="dbscan" version="{v}"/></message></xml>'
)
COMPONENT = st.integers(min_value=0, max_value=999_999)
TRIPLE = st.tuples(COMPONENT, COMPONENT, COMPONENT)


def spell(t: tuple[int, int, int]) -> str:
    return ".".join(map(str, t))


@given(TRIPLE)
def test_every_triple_has_a_spelling_that_parses_back(t: tuple[int, int, int]) -> None:
    assert is_version(spell(t)) and parse_version(spell(t)) == t


@given(st.text(max_size=24))
def test_a_spelling_is_unique_for_its_triple(text: str) -> None:
    """Whatever string is accepted is exactly the canonical spelling of its triple (no two spellings)."""
    if is_version(text):
        assert spell(parse_version(text)) == text
    else:
        with pytest.raises(ValueError, match=r"expected MAJOR\.MINOR\.PATCH"):
            parse_version(text)


@given(TRIPLE, st.integers(min_value=0, max_value=2), st.integers(min_value=1, max_value=3))
def test_leading_zeros_are_refused(t: tuple[int, int, int], where: int, zeros: int) -> None:
    parts = [str(p) for p in t]
    parts[where] = "0" * zeros + parts[where]
    respelled = ".".join(parts)
    assert not is_version(respelled)
    assert legacy_version_key(respelled) == t  # what an old stored row with that spelling meant


@given(TRIPLE, TRIPLE)
def test_order_is_the_order_of_the_triples(a: tuple[int, int, int], b: tuple[int, int, int]) -> None:
    assert (parse_version(spell(a)) < parse_version(spell(b))) == (a < b)
    assert (spell(a) == spell(b)) == (a == b)


@pytest.mark.parametrize(
    "bad",
    [
        "01.0.0",
        "1.00.0",
        "1.0.00",
        "1.0.0\n",
        " 1.0.0",
        "+1.0.0",
        "-1.0.0",
        "1.0",
        "1.0.0.0",
        "\u0661.0.0",
        "1_0.0.0",
        "1000000.0.0",
        "1e3.0.0",
        "",
    ],
)
def test_other_spellings_are_refused_everywhere(bad: str) -> None:
    assert not is_version(bad)
    schema = etree.XMLSchema(etree.fromstring(xsd_text().encode()))
    xml = ROLLBACK.format(v=bad)
    if "\n" not in bad and bad.strip() == bad:  # (XML attribute normalisation would hide these)
        assert not schema.validate(etree.fromstring(xml.encode()))
        with pytest.raises(ControlMessageError):
            parse_message(xml.encode())
    with pytest.raises(ValueError, match="version"):
        OperationDraft(kind="rollback", stage="noise-removal", name="dbscan", version=bad)


def test_the_xsd_uses_the_canonical_pattern() -> None:
    found = re.search(r'<xs:simpleType name="Version">.*?<xs:pattern value="([^"]+)"', xsd_text(), re.S)
    assert found is not None and found.group(1) == VERSION_PATTERN


@given(TRIPLE)
def test_the_xsd_and_the_drafts_accept_every_canonical_version(t: tuple[int, int, int]) -> None:
    version = spell(t)
    xml = ROLLBACK.format(v=version)
    assert parse_message(xml.encode()).operations[0].version == version
    assert (
        OperationDraft(kind="rollback", stage="noise-removal", name="dbscan", version=version).version
        == version
    )
