"""Load untrusted XML safely (docs/design.md §6): bounded size, UTF-8 only, no DTD, no entities, no network.

Checked in this order: input larger than :data:`MAX_MESSAGE_BYTES` is refused before anything else; the
bytes must be UTF-8 without NUL (a declared encoding other than UTF-8/ASCII is refused; so is a NUL byte,
which XML never allows and which is how UTF-16/UTF-32 without a byte-order mark look: lxml would guess such
an encoding and the DTD check below would not see ``<!DOCTYPE``); any ``<!DOCTYPE`` or
``<!ENTITY`` is refused before lxml sees the document, so "billion laughs" and external ``SYSTEM`` entities
are never expanded or fetched; lxml then parses with entity resolution, DTD loading and network access off,
``huge_tree`` off (libxml2's depth and size limits stay on), dropping comments and processing instructions.
Errors are :class:`ControlMessageError` with the line of the problem. Linear in the input size.
"""

from __future__ import annotations

import re
from typing import Any, NoReturn

from lxml import etree

from shared.control.errors import ControlMessageError

__all__ = ["MAX_MESSAGE_BYTES", "load_xml"]

#: Largest control message accepted, in bytes (UTF-8).
MAX_MESSAGE_BYTES = 64 * 1024

_DTD = re.compile(r"<!\s*(DOCTYPE|ENTITY)", re.IGNORECASE)
_ENCODING = re.compile(r"""^\s*<\?xml[^>]*?encoding\s*=\s*["']([^"']*)["']""")
_LINE_COL = re.compile(r",\s*line \d+, column (\d+)$")
_UTF8 = ("utf-8", "utf8", "us-ascii", "ascii")


def load_xml(data: bytes | str) -> Any:
    """The root element (``lxml.etree._Element``) of ``data``, loaded under the rules above."""
    return _parse(_checked_bytes(data))


def _checked_bytes(data: bytes | str) -> bytes:
    if isinstance(data, str):
        if len(data) > MAX_MESSAGE_BYTES:
            _too_big(len(data))
        try:
            raw = data.encode("utf-8")
        except UnicodeEncodeError as exc:
            raise ControlMessageError(f"text is not valid Unicode ({exc.reason})") from None
    elif isinstance(data, bytes | bytearray | memoryview):
        raw = bytes(data)
    else:
        raise ControlMessageError(f"got {type(data).__name__}: expected the message as bytes or str")
    if len(raw) > MAX_MESSAGE_BYTES:
        _too_big(len(raw))
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ControlMessageError(f"byte {exc.start} is not UTF-8: control messages are UTF-8") from None
    nul = raw.find(b"\x00")
    if nul >= 0:
        raise ControlMessageError(
            f"byte {nul} is NUL: control messages are UTF-8 text (no NUL, no UTF-16 or UTF-32)"
        )
    declared = _ENCODING.match(text)
    if declared and declared.group(1).lower().replace("_", "-") not in _UTF8:
        raise ControlMessageError(
            f"declares encoding {declared.group(1)!r}: control messages are UTF-8", element="<?xml?>", line=1
        )
    dtd = _DTD.search(text)
    if dtd is not None:
        raise ControlMessageError(
            "document type and entity declarations are not allowed (no DTD, no entities)",
            element=f"<!{dtd.group(1).upper()}>",
            line=text.count("\n", 0, dtd.start()) + 1,
        )
    return raw


def _too_big(size: int) -> NoReturn:
    raise ControlMessageError(f"message is {size} bytes: the limit is {MAX_MESSAGE_BYTES} bytes")


def _parse(raw: bytes) -> Any:
    parser = etree.XMLParser(
        resolve_entities=False,
        no_network=True,
        load_dtd=False,
        dtd_validation=False,
        huge_tree=False,
        remove_comments=True,
        remove_pis=True,
        collect_ids=False,
    )
    try:
        root = etree.fromstring(raw, parser)
    except etree.XMLSyntaxError as exc:
        text = exc.msg or "syntax error"
        where = _LINE_COL.search(text)
        reason = _LINE_COL.sub("", text)
        if reason.startswith("Excessive depth"):
            reason = "elements are nested too deeply (limit 256)"
        column = f" (column {where.group(1)})" if where else ""
        raise ControlMessageError(f"malformed XML: {reason}{column}", line=exc.lineno or None) from None
    docinfo = root.getroottree().docinfo
    if docinfo.internalDTD is not None or docinfo.externalDTD is not None:  # defence in depth
        raise ControlMessageError("document type declarations are not allowed", element="<!DOCTYPE>")
    return root
