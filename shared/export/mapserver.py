"""The two files of a ROS ``map_server`` map: a binary PGM image (netpbm P5) and the YAML that places it.

Pure encoders and decoders (bytes / text in and out); :mod:`shared.export.occupancy` does the files.

PGM (netpbm "P5"): ``P5``, width, height and maxval as ASCII decimals separated by whitespace, ``#``
comments allowed in the header, one whitespace byte, then ``width * height`` bytes, rows top to bottom.
Only 8-bit images with maxval 255 are read, which is what ``map_saver`` writes and ``map_server`` reads.

YAML (the ``map_server`` map metadata): ``image`` (path of the image, relative to the YAML's folder),
``resolution`` (m per pixel), ``origin`` ``[x, y, yaw]`` (m, m, rad: the pose of the image's lower-left
corner in the map frame), ``negate`` (0/1), ``occupied_thresh``, ``free_thresh`` and ``mode`` (trinary,
scale or raw). The reader takes the flat ``key: value`` subset of YAML these files use (numbers, plain or
quoted strings, flow lists ``[a, b, c]``, ``#`` comments); numbers are written in positional notation with
the shortest digits that read back to the same float64. O(file size) throughout. docs/design.md §3 (ROS REP
103 frames).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from shared.export.errors import OccupancyFormatError

__all__ = ["MAP_MODES", "MapYaml", "decode_map_yaml", "decode_pgm", "encode_map_yaml", "encode_pgm"]

MAP_MODES = ("trinary", "scale", "raw")
"""The ``mode`` values ``map_server`` knows."""

_WHITESPACE = b" \t\n\r\v\f"


def encode_pgm(pixels: NDArray[np.uint8], *, comment: str | None = None) -> bytes:
    """A binary PGM (P5, maxval 255) of the ``(height, width)`` uint8 image ``pixels`` (row 0 = top).

    ``comment`` (one line, ASCII) goes into the header as ``# comment``. Raises :class:`ValueError` for a
    non-2-D or non-uint8 array, an empty image or a multi-line comment (a programming error).
    """
    if pixels.ndim != 2 or pixels.dtype != np.uint8 or pixels.size == 0:
        raise ValueError(
            f"pixels: shape {pixels.shape}, dtype {pixels.dtype}: expected a non-empty 2-D uint8"
        )
    height, width = pixels.shape
    head = "P5\n"
    if comment is not None:
        if "\n" in comment or "\r" in comment:
            raise ValueError(f"comment {comment!r}: expected one line")
        head += f"# {comment}\n"
    head += f"{width} {height}\n255\n"
    return head.encode("ascii") + np.ascontiguousarray(pixels).tobytes()


def _skip_space_and_comments(data: bytes, pos: int) -> int:
    n = len(data)
    while pos < n:
        byte = data[pos : pos + 1]
        if byte in (b" ", b"\t", b"\n", b"\r", b"\v", b"\f"):
            pos += 1
        elif byte == b"#":
            while pos < n and data[pos : pos + 1] not in (b"\n", b"\r"):
                pos += 1
        else:
            break
    return pos


def decode_pgm(data: bytes, source: str = "<bytes>") -> NDArray[np.uint8]:
    """The ``(height, width)`` uint8 image of a binary PGM (P5, maxval 255), row 0 = top.

    Raises :class:`OccupancyFormatError` naming ``source`` and what was expected for another magic
    number, a bad or truncated header, a maxval other than 255, or a raster of the wrong length.
    """
    if data[:2] != b"P5":
        raise OccupancyFormatError(
            f"{source}: starts with {data[:2]!r}: expected b'P5' (a binary PGM as map_saver writes)"
        )
    pos = 2
    values: list[int] = []
    for name in ("width", "height", "maxval"):
        start = pos
        pos = _skip_space_and_comments(data, pos)
        if pos == start:
            raise OccupancyFormatError(f"{source}: PGM header: expected whitespace before the {name}")
        end = pos
        while end < len(data) and data[end : end + 1].isdigit():
            end += 1
        token = data[pos:end]
        if not token or len(token) > 9:
            found = data[pos : pos + 12]
            raise OccupancyFormatError(f"{source}: PGM {name} is {found!r}: expected a decimal integer")
        values.append(int(token))
        pos = end
    width, height, maxval = values
    if width < 1 or height < 1:
        raise OccupancyFormatError(f"{source}: PGM size {width} x {height}: expected at least 1 x 1 pixels")
    if maxval != 255:
        raise OccupancyFormatError(f"{source}: PGM maxval {maxval}: expected 255 (8-bit grey, as map_saver)")
    if pos >= len(data) or data[pos] not in _WHITESPACE:
        raise OccupancyFormatError(f"{source}: PGM header: expected one whitespace byte after the maxval")
    raster = data[pos + 1 :]
    if len(raster) != width * height:
        raise OccupancyFormatError(
            f"{source}: PGM raster has {len(raster)} bytes: expected {width} x {height} = {width * height}"
        )
    return np.frombuffer(raster, dtype=np.uint8).reshape(height, width).copy()


@dataclass(frozen=True, slots=True)
class MapYaml:
    """The metadata of a ``map_server`` map (module docstring); lengths metres, yaw radians."""

    image: str
    resolution_m: float
    origin: tuple[float, float, float]
    negate: int = 0
    occupied_thresh: float = 0.65
    free_thresh: float = 0.196
    mode: str = "trinary"


def _number(value: float) -> str:
    """Positional notation, shortest digits that read back to the same float64 (never ``1e-05``, which
    YAML 1.1 readers take for a string)."""
    return np.format_float_positional(float(value) + 0.0, unique=True, trim="0")


_PLAIN = re.compile(r"[A-Za-z0-9_./+-]+")
_RESERVED = {"~", "null", "true", "false", "yes", "no", "on", "off", "y", "n"}
_ESCAPES = {"\\": "\\", '"': '"', "/": "/", "n": "\n", "t": "\t", "r": "\r", "0": "\0"}
_ESCAPE_DIGITS = {"x": 2, "u": 4, "U": 8}


def _quoted_if_needed(text: str) -> str:
    """``text`` as a plain YAML scalar when that is unambiguous, else double-quoted with YAML escapes."""
    if _PLAIN.fullmatch(text) and text.lower() not in _RESERVED and text[0] not in "-?":
        return text
    out = []
    for ch in text:
        if ch in ('"', "\\"):
            out.append("\\" + ch)
        elif not ch.isprintable():
            code = ord(ch)
            out.append(
                f"\\x{code:02x}" if code < 0x100 else f"\\u{code:04x}" if code < 0x10000 else f"\\U{code:08x}"
            )
        else:
            out.append(ch)
    return '"' + "".join(out) + '"'


def encode_map_yaml(meta: MapYaml) -> str:
    """The ``map_server`` YAML text of ``meta`` (keys in map_saver's order, one per line)."""
    origin = ", ".join(_number(v) for v in meta.origin)
    return (
        f"image: {_quoted_if_needed(meta.image)}\n"
        f"resolution: {_number(meta.resolution_m)}\n"
        f"origin: [{origin}]\n"
        f"negate: {int(meta.negate)}\n"
        f"occupied_thresh: {_number(meta.occupied_thresh)}\n"
        f"free_thresh: {_number(meta.free_thresh)}\n"
        f"mode: {meta.mode}\n"
    )


def _escape(raw: str, k: int, out: list[str], where: str) -> int:
    """Decode the YAML escape whose letter is at ``raw[k]`` into ``out``; returns the index after it."""
    letter = raw[k]
    if letter in _ESCAPES:
        out.append(_ESCAPES[letter])
        return k + 1
    digits = _ESCAPE_DIGITS.get(letter)
    code = raw[k + 1 : k + 1 + digits] if digits else ""
    if not digits or len(code) != digits or not all(c in "0123456789abcdefABCDEF" for c in code):
        raise OccupancyFormatError(
            f"{where}: bad escape '\\{raw[k : k + 1 + (digits or 0)]}' in a quoted string"
        )
    value = int(code, 16)
    if value > 0x10FFFF:
        raise OccupancyFormatError(f"{where}: escape '\\{letter}{code}' is beyond Unicode")
    out.append(chr(value))
    return k + 1 + digits


def _unquote(raw: str, where: str) -> tuple[str, str]:
    """Split ``raw`` (a value, then maybe a comment) into the string value and the rest."""
    quote = raw[0]
    out: list[str] = []
    k = 1
    while k < len(raw):
        ch = raw[k]
        if quote == '"' and ch == "\\" and k + 1 < len(raw):
            k = _escape(raw, k + 1, out, where)
            continue
        if ch == quote:
            if quote == "'" and raw[k + 1 : k + 2] == "'":
                out.append("'")
                k += 2
                continue
            return "".join(out), raw[k + 1 :]
        out.append(ch)
        k += 1
    raise OccupancyFormatError(f"{where}: unterminated {quote} string")


def _value(raw: str, where: str) -> str | list[str]:
    """A plain or quoted scalar (as text) or a flow list of plain scalars; a trailing comment dropped."""
    raw = raw.strip()
    if raw[:1] in ("'", '"'):
        text, rest = _unquote(raw, where)
        rest = rest.strip()
        if rest and not rest.startswith("#"):
            raise OccupancyFormatError(f"{where}: {rest!r} after a quoted string: expected the end of line")
        return text
    if raw.startswith("["):
        close = raw.find("]")
        if close < 0:
            raise OccupancyFormatError(f"{where}: {raw!r}: expected a flow list closed by ']'")
        rest = raw[close + 1 :].strip()
        if rest and not rest.startswith("#"):
            raise OccupancyFormatError(f"{where}: {rest!r} after the list: expected the end of line")
        inner = raw[1:close].strip()
        return [] if not inner else [item.strip() for item in inner.split(",")]
    hash_at = raw.find(" #")
    return (raw if hash_at < 0 else raw[:hash_at]).strip()


_LINE_BREAK = re.compile(r"\r\n|\r|\n")
_Items = dict[str, tuple[str | list[str], str]]


def _parse_flat(text: str, source: str) -> _Items:
    items: _Items = {}
    for number, line in enumerate(_LINE_BREAK.split(text), start=1):  # YAML breaks: LF, CR, CRLF only
        stripped = line.strip()
        if not stripped or stripped.startswith("#") or stripped in ("---", "..."):
            continue
        where = f"{source}: line {number}"
        key, colon, raw = stripped.partition(":")
        key = key.strip()
        if not colon or not key or line[:1].isspace():
            raise OccupancyFormatError(f"{where}: {stripped!r}: expected 'key: value' (a flat YAML mapping)")
        if key in items:
            raise OccupancyFormatError(f"{where}: key {key!r} given twice")
        if not raw.strip():
            raise OccupancyFormatError(f"{where}: key {key!r} has no value")
        items[key] = (_value(raw, where), where)
    return items


def _as_float(text: str) -> float | None:
    try:
        value = float(text)
    except ValueError:
        return None
    return value if math.isfinite(value) else None


def _finite(items: _Items, key: str, default: float | None, source: str) -> float:
    if key not in items:
        if default is None:
            raise OccupancyFormatError(f"{source}: no '{key}': expected it in a map_server YAML")
        return default
    raw, where = items[key]
    value = _as_float(raw) if isinstance(raw, str) else None
    if value is None:
        raise OccupancyFormatError(f"{where}: {key} is {raw!r}: expected a finite number")
    return value


def decode_map_yaml(text: str, source: str = "<yaml>") -> MapYaml:
    """Parse a ``map_server`` YAML (module docstring). ``image``, ``resolution`` and ``origin`` are
    required; ``negate`` (0), ``occupied_thresh`` (0.65), ``free_thresh`` (0.196) and ``mode`` (trinary)
    default as in ``map_server``; other keys are ignored. Raises :class:`OccupancyFormatError` naming the
    line and what was expected."""
    items = _parse_flat(text, source)
    if "image" not in items:
        raise OccupancyFormatError(f"{source}: no 'image': expected the path of the PGM image")
    image, where = items["image"]
    if not isinstance(image, str) or not image:
        raise OccupancyFormatError(f"{where}: image is {image!r}: expected a file name")
    resolution = _finite(items, "resolution", None, source)
    if resolution <= 0.0:
        raise OccupancyFormatError(f"{items['resolution'][1]}: resolution {resolution}: expected > 0 m/pixel")
    if "origin" not in items:
        raise OccupancyFormatError(f"{source}: no 'origin': expected [x, y, yaw]")
    raw_origin, where = items["origin"]
    parsed = [_as_float(v) for v in raw_origin] if isinstance(raw_origin, list) else []
    origin = [v for v in parsed if v is not None]
    if len(parsed) != 3 or len(origin) != 3:
        raise OccupancyFormatError(
            f"{where}: origin is {raw_origin!r}: expected [x, y, yaw], three finite numbers"
        )
    negate = _finite(items, "negate", 0.0, source)
    if negate not in (0.0, 1.0):
        raise OccupancyFormatError(f"{items['negate'][1]}: negate is {negate:g}: expected 0 or 1")
    occupied = _finite(items, "occupied_thresh", 0.65, source)
    free = _finite(items, "free_thresh", 0.196, source)
    if not 0.0 <= free <= occupied <= 1.0:
        raise OccupancyFormatError(
            f"{source}: free_thresh {free:g}, occupied_thresh {occupied:g}: "
            "expected 0 <= free_thresh <= occupied_thresh <= 1"
        )
    mode, where = items.get("mode", ("trinary", source))
    if mode not in MAP_MODES:
        raise OccupancyFormatError(f"{where}: mode is {mode!r}: expected one of {', '.join(MAP_MODES)}")
    x, y, yaw = origin
    return MapYaml(image, resolution, (x, y, yaw), int(negate), occupied, free, str(mode))
