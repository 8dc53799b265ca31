"""Notice payloads (server.notices): what one server process NOTIFYs the others, and what a listener makes
of any payload on the channel."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from server.notices import MAX_PAYLOAD_BYTES, Notice, NoticeError, decode_notice, encode_notice

origins = st.text("0123456789abcdef", min_size=1, max_size=32)
topics = st.builds(
    lambda kind, ident: f"{kind}:{ident}",
    st.text("abcdefghijklmnopqrstuvwxyz", min_size=1, max_size=32),
    st.integers(0, 2**63 - 1),
)
versions = st.integers(0, 2**63 - 1)


@given(origins, topics, versions)
def test_every_notice_round_trips_and_fits_a_notify(origin: str, topic: str, version: int) -> None:
    payload = encode_notice(origin, topic, version)
    assert len(payload.encode()) < MAX_PAYLOAD_BYTES
    assert decode_notice(payload) == (origin, Notice(topic, version))


@given(st.text(max_size=200))
def test_any_payload_decodes_or_is_refused_with_a_notice_error(payload: str) -> None:
    try:
        origin, notice = decode_notice(payload)
    except NoticeError as exc:
        message = str(exc)
        assert message.startswith("notice "), message
        return
    assert encode_notice(origin, notice.topic, notice.version) == payload


@pytest.mark.parametrize(
    ("payload", "named"),
    [
        ("ab maps:7", "'<origin> <topic> <version>'"),
        ("AB maps:7 3", "origin"),
        ("ab maps 3", "topic"),
        ("ab maps:7 -3", "version"),
        ("ab maps:7 99999999999999999999", "version"),
        ("ab maps:7 ٣", "version"),
        ("x" * 9000, "at most"),
    ],
)
def test_bad_payloads_name_the_part(payload: str, named: str) -> None:
    with pytest.raises(NoticeError, match=named):
        decode_notice(payload)


@pytest.mark.parametrize(
    ("origin", "topic", "version", "named"),
    [
        ("xyz", "maps:7", 1, "origin"),
        ("ab", "maps:7 ", 1, "topic"),
        ("ab", "m" * 40 + ":1", 1, "topic"),
        ("ab", "maps:7", -1, "version"),
        ("ab", "maps:7", True, "version"),
        ("ab", "maps:7", 2**63, "version"),
    ],
)
def test_encoding_refuses_what_would_not_decode(origin: str, topic: str, version: int, named: str) -> None:
    with pytest.raises(NoticeError, match=named):
        encode_notice(origin, topic, version)
