"""Map data inside linemap's SVG drawings, so the walls can be read back in metres (not in drawing points).

:func:`shared.export.render.render_map` draws the map segments as one ``<g id="walls">`` group (one
``<path>`` per segment, in snapshot order) and embeds, right after the ``<svg>`` start tag, an element

``<metadata id="linemap-map" data-format="linemap-map+json" data-units="m">{...}</metadata>``

whose text is JSON: ``{"format": "linemap-map", "version": 1, "units": "m", "frame": "world",
"segments": [[id, x0, y0, x1, y1], ...]}`` (metres in the log's world frame; floats written with Python's
shortest round-trip repr, so reading back is exact). Renderers ignore ``<metadata>``: the picture is
unchanged. :func:`read_svg_segments` reads it back. O(L). docs/design.md §1 (exporting the finished map), §3
(metres).
"""

from __future__ import annotations

import json
import logging
import math
import os
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from shared.export.errors import ExportIOError, SVGFormatError
from shared.types import FloatArray, IntArray

__all__ = ["SVG_METADATA_ID", "SVG_WALLS_ID", "SVGMap", "embed_map_metadata", "read_svg_segments"]

_log = logging.getLogger(__name__)

SVG_METADATA_ID = "linemap-map"
"""``id`` of the ``<metadata>`` element holding the map JSON."""

SVG_WALLS_ID = "walls"
"""``id`` of the ``<g>`` group drawing the map segments."""

_FORMAT = "linemap-map"
_VERSION = 1
_SVG_NS = "{http://www.w3.org/2000/svg}"
_START_TAG = re.compile(rb"<svg\b[^>]*>")


@dataclass(frozen=True, slots=True, eq=False)
class SVGMap:
    """The walls embedded in a linemap SVG: ``segments`` ``(L, 4)`` metres and their ``segment_ids``."""

    segments: FloatArray
    segment_ids: IntArray


def embed_map_metadata(svg: bytes, segments: FloatArray, segment_ids: IntArray) -> bytes:
    """``svg`` with the map metadata element (module docstring) inserted after its ``<svg>`` start tag.

    ``segments`` ``(L, 4)`` finite metres and ``segment_ids`` ``(L,)`` integers, already checked by the
    caller. Raises :class:`ValueError` if ``svg`` has no ``<svg>`` start tag (a programming error).
    """
    match = _START_TAG.search(svg)
    if match is None:
        raise ValueError("no <svg> start tag in the drawing")
    rows = [
        [int(i), *(float(v) + 0.0 for v in row)]
        for i, row in zip(segment_ids.tolist(), segments.tolist(), strict=True)
    ]
    doc = {"format": _FORMAT, "version": _VERSION, "units": "m", "frame": "world", "segments": rows}
    text = json.dumps(doc, separators=(",", ":"), allow_nan=False)  # numbers only: nothing to XML-escape
    element = (
        f'\n <metadata id="{SVG_METADATA_ID}" data-format="{_FORMAT}+json" data-units="m">{text}</metadata>'
    ).encode("ascii")
    return svg[: match.end()] + element + svg[match.end() :]


def _finite_number(value: object) -> bool:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return False
    try:
        return math.isfinite(float(value))
    except OverflowError:
        return False


def _rows(doc: object, where: str) -> list[list[float]]:
    if not isinstance(doc, dict) or doc.get("format") != _FORMAT:
        raise SVGFormatError(f"{where}: expected a JSON object with format {_FORMAT!r}")
    if doc.get("version") != _VERSION or doc.get("units") != "m":
        raise SVGFormatError(
            f"{where}: version {doc.get('version')!r}, units {doc.get('units')!r}: expected version "
            f"{_VERSION} in metres"
        )
    rows = doc.get("segments")
    if not isinstance(rows, list):
        raise SVGFormatError(f"{where}: 'segments' is {type(rows).__name__}: expected a list")
    for k, row in enumerate(rows):
        good = (
            isinstance(row, list)
            and len(row) == 5
            and all(_finite_number(v) for v in row)
            and isinstance(row[0], int)
            and -(2**63) <= row[0] < 2**63
        )
        if not good:
            raise SVGFormatError(f"{where}: segment {k} is {row!r}: expected [id, x0, y0, x1, y1] metres")
    return rows


def read_svg_segments(path: str | os.PathLike[str]) -> SVGMap:
    """The map segments embedded in an SVG drawn by :func:`shared.export.render.render_map`.

    Raises :class:`~shared.export.errors.ExportIOError` when the file cannot be read and
    :class:`~shared.export.errors.SVGFormatError` when it is not XML, not SVG, or holds no (or broken)
    linemap metadata. O(file size).
    """
    source = Path(path)
    try:
        data = source.read_bytes()
    except OSError as exc:
        raise ExportIOError(f"cannot read {source}: {exc.strerror or exc}") from exc
    try:
        root = ET.fromstring(data)
    except ET.ParseError as exc:
        raise SVGFormatError(f"{source}: not well-formed XML ({exc}): expected an SVG drawing") from exc
    if root.tag != f"{_SVG_NS}svg":
        raise SVGFormatError(f"{source}: root element is {root.tag!r}: expected an SVG <svg>")
    found = [m for m in root.iter(f"{_SVG_NS}metadata") if m.get("id") == SVG_METADATA_ID]
    if not found:
        raise SVGFormatError(
            f"{source}: no <metadata id={SVG_METADATA_ID!r}>: expected an SVG drawn by linemap's render_map"
        )
    where = f"{source}: <metadata id={SVG_METADATA_ID!r}>"
    try:
        doc = json.loads(found[0].text or "")
    except json.JSONDecodeError as exc:
        raise SVGFormatError(f"{where}: {exc.msg} at character {exc.pos}: expected JSON") from exc
    rows = _rows(doc, where)
    table = np.array(rows, dtype=np.float64).reshape(-1, 5)
    out = SVGMap(np.ascontiguousarray(table[:, 1:]), np.array([r[0] for r in rows], dtype=np.intp))
    _log.debug("read %d segments from %s", out.segments.shape[0], source)
    return out
