"""Hostile or broken input: DTDs, entities, size, malformed XML, encodings. Rejected whole, never expanded."""

from __future__ import annotations

import pytest

from shared.control import MAX_MESSAGE_BYTES, ControlMessageError, parse_message

BILLION_LAUGHS = """<?xml version="1.0"?>
<!DOCTYPE lolz [
 <!ENTITY lol "lol">
 <!ENTITY lol2 "&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;">
 <!ENTITY lol3 "&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;">
 <!ENTITY lol4 "&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;">
 <!ENTITY lol9 "&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;">
]>
<xml><message><mode>&lol9;</mode></message></xml>
"""

EXTERNAL = """<?xml version="1.0"?>
<!DOCTYPE xml [<!ENTITY e SYSTEM "file:///etc/passwd">]>
<xml><message><mode>&e;</mode></message></xml>
"""


def reject(doc: str | bytes) -> ControlMessageError:
    with pytest.raises(ControlMessageError) as info:
        parse_message(doc)
    return info.value


def test_billion_laughs_rejected_before_parsing() -> None:
    err = reject(BILLION_LAUGHS)
    assert str(err) == (
        "line 2 <!DOCTYPE>: document type and entity declarations are not allowed (no DTD, no entities)"
    )


def test_external_entity_never_read() -> None:
    err = reject(EXTERNAL)
    assert err.element == "<!DOCTYPE>" and err.line == 2
    assert "root:" not in str(err)


@pytest.mark.parametrize(
    "doc",
    [
        '<!DOCTYPE xml SYSTEM "http://example.invalid/control.dtd"><xml><message/></xml>',
        "<!doctype xml><xml><message/></xml>",
        "<xml><message/></xml>\n<!DOCTYPE x>",
        '<xml><message/></xml><!ENTITY x "y">',
    ],
)
def test_any_dtd_rejected(doc: str) -> None:
    assert reject(doc).element in ("<!DOCTYPE>", "<!ENTITY>")


def test_undeclared_entity_is_malformed() -> None:
    err = reject("<xml><message>\n<mode>&lol;</mode></message></xml>")
    assert str(err).startswith("line 2: malformed XML: Entity 'lol' not defined")


def test_character_references_are_plain_text() -> None:
    assert parse_message("<xml><message><mode>&#111;nline</mode></message></xml>").mode == "online"


def test_oversized_input_rejected_before_parsing() -> None:
    pad = "<!--" + "x" * MAX_MESSAGE_BYTES + "-->"
    for doc in (f"<xml><message/>{pad}</xml>", f"<xml><message/>{pad}</xml>".encode()):
        err = reject(doc)
        assert "bytes: the limit is 65536 bytes" in str(err)
    # just under the limit is fine (comments are dropped)
    doc = "<xml><message/><!--" + "x" * (MAX_MESSAGE_BYTES - 40) + "--></xml>"
    assert len(doc) < MAX_MESSAGE_BYTES
    parse_message(doc)


def test_multibyte_text_counts_bytes() -> None:
    doc = "<xml><message/><!--" + "é" * (MAX_MESSAGE_BYTES // 2) + "--></xml>"
    assert len(doc) < MAX_MESSAGE_BYTES
    assert "the limit is" in str(reject(doc))


@pytest.mark.parametrize(
    ("doc", "fragment"),
    [
        ("", "line 1: malformed XML"),
        ("<xml><message></xml>", "malformed XML"),
        ("<xml><message/></xml><xml/>", "malformed XML: Extra content at the end of the document"),
        ("<xml>\n<message>\n<mode>online</mode\n</message></xml>", "line 4: malformed XML"),
        ("not xml at all", "malformed XML"),
    ],
)
def test_malformed(doc: str, fragment: str) -> None:
    assert fragment in str(reject(doc))


def test_encodings() -> None:
    assert "is not UTF-8" in str(reject(b"<xml><message><mode>\xff</mode></message></xml>"))
    latin = '<?xml version="1.0" encoding="ISO-8859-1"?><xml><message/></xml>'
    assert "declares encoding 'ISO-8859-1'" in str(reject(latin.encode()))
    ok = '\ufeff<?xml version="1.0" encoding="utf-8"?><xml><message><mode>online</mode></message></xml>'
    assert parse_message(ok.encode("utf-8")).mode == "online"
    assert "not valid Unicode" in str(reject("<xml><message><mode>\ud800</mode></message></xml>"))


def test_wrong_argument_type() -> None:
    with pytest.raises(ControlMessageError, match="expected the message as bytes or str"):
        parse_message(42)  # type: ignore[arg-type]


def test_deep_nesting_is_rejected_at_the_first_unknown_element() -> None:
    doc = "<xml><message>" + "<a>" * 5000 + "</a>" * 5000 + "</message></xml>"
    assert len(doc) < MAX_MESSAGE_BYTES
    assert "malformed XML: elements are nested too deeply (limit 256)" in str(reject(doc))
