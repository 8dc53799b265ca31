"""What one server process tells the others through PostgreSQL ``NOTIFY``: "topic T reached version V".

A notice carries ids and versions only, never data: subscribers read the data from the tables (a
``NOTIFY`` payload is limited to 8,000 bytes, and an oversized one aborts the writer's transaction). The
payload is ``<origin> <topic> <version>`` in ASCII, where ``origin`` names the sending process so that a
process skips its own notices (it has delivered those in-process already). Topics are
``<kind>:<id>`` (``maps:7``, ``messages:7``, ``acks:7``); versions are map versions or message numbers.
Encoding and decoding are O(payload).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Final

from server.errors import ServerError

__all__ = ["CHANNEL", "MAX_PAYLOAD_BYTES", "Notice", "NoticeError", "decode_notice", "encode_notice"]

#: The one PostgreSQL channel every server process listens on.
CHANNEL: Final = "linemap"
#: PostgreSQL's limit on a NOTIFY payload (bytes, default build); ours stay far below it.
MAX_PAYLOAD_BYTES: Final = 8000
_ORIGIN = re.compile(r"[0-9a-f]{1,32}")
_TOPIC = re.compile(r"[a-z]{1,32}:[0-9]{1,19}")
_VERSION_MAX = 2**63 - 1


class NoticeError(ServerError):
    """A payload on the channel that is not a notice of this format (names what was wrong)."""


@dataclass(frozen=True, slots=True)
class Notice:
    """Topic ``topic`` reached ``version`` in the database (written and committed by another process)."""

    topic: str
    version: int


def encode_notice(origin: str, topic: str, version: int) -> str:
    """The NOTIFY payload for ``topic`` at ``version`` sent by process ``origin`` (hex). Raises
    :class:`NoticeError` naming the part that is malformed (the payload then stays far below
    :data:`MAX_PAYLOAD_BYTES`: at most 32 + 52 + 19 characters and two spaces)."""
    if not _ORIGIN.fullmatch(origin):
        raise NoticeError(f"notice origin {origin[:40]!r} is not 1-32 lowercase hex digits")
    if not _TOPIC.fullmatch(topic):
        raise NoticeError(f"notice topic {topic[:60]!r} is not '<kind>:<id>' (e.g. 'maps:7')")
    if isinstance(version, bool) or not isinstance(version, int) or not 0 <= version <= _VERSION_MAX:
        raise NoticeError(f"notice version {version!r} is not an integer in 0..{_VERSION_MAX}")
    return f"{origin} {topic} {version}"


def decode_notice(payload: str) -> tuple[str, Notice]:
    """``(origin, notice)`` from a payload made by :func:`encode_notice`; :class:`NoticeError` naming what
    is wrong otherwise (e.g. another program's NOTIFY on the same channel)."""
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise NoticeError(f"notice payload of {len(payload)} characters; a notice has at most 105")
    parts = payload.split(" ")
    if len(parts) != 3:
        raise NoticeError(f"notice payload {payload[:80]!r} is not '<origin> <topic> <version>'")
    origin, topic, version = parts
    if not _ORIGIN.fullmatch(origin):
        raise NoticeError(f"notice origin {origin[:40]!r} is not 1-32 lowercase hex digits")
    if not _TOPIC.fullmatch(topic):
        raise NoticeError(f"notice topic {topic[:60]!r} is not '<kind>:<id>' (e.g. 'maps:7')")
    if not version.isascii() or not version.isdigit() or len(version) > 19 or int(version) > _VERSION_MAX:
        raise NoticeError(f"notice version {version[:30]!r} is not an integer in 0..{_VERSION_MAX}")
    return origin, Notice(topic, int(version))
