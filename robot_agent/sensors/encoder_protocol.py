"""The encoder bridge's wire protocol (version 1), with no I/O.

Records, line parser and formatter, checksum, counter wrap and the line splitter (O(line length)); the
decoder that turns lines into odometry poses is :mod:`robot_agent.sensors.encoder_decoder`. The grammar
and the host's rules are described in :mod:`robot_agent.sensors.encoders`
(``E <t_ms> <left_ticks> <right_ticks>[*HH]``, ``I <ticks_per_rev> <wheel_diameter_mm> <tread_mm>
<firmware>[*HH]``, ``# comment``; the host sends ``?``).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from robot_agent.sensors.errors import SensorError
from shared.odometry import DiffDrive
from shared.types import Pose2D

__all__ = [
    "HELLO",
    "MAX_LINE_BYTES",
    "BridgeInfo",
    "EncoderError",
    "EncoderLine",
    "EncoderProtocolError",
    "LineSplitter",
    "checksum",
    "format_line",
    "parse_line",
    "tick_delta",
    "wrap_int32",
]

#: What the host sends to ask for the ``I`` line.
HELLO = b"?\n"
MAX_LINE_BYTES = 128
_U32 = 1 << 32
_I32_MIN, _I32_MAX = -(1 << 31), (1 << 31) - 1
_UINT = re.compile(r"[0-9]{1,10}")
_SINT = re.compile(r"-?[0-9]{1,10}")
_NUMBER = re.compile(r"[0-9]+(\.[0-9]+)?([eE][+-]?[0-9]+)?")
_FIRMWARE = re.compile(r"[!-)+-~]{1,32}")  # printable, no space, no '*'
_HEX2 = re.compile(r"[0-9A-Fa-f]{2}")


class EncoderError(SensorError):
    """The wheel-encoder source cannot be opened or read (port missing, bridge silent or gone)."""


class EncoderProtocolError(EncoderError, ValueError):
    """A line or record that does not follow the bridge protocol; ``kind`` is the short reason counted in
    :class:`EncoderStats` (e.g. ``"bad checksum"``), the message says what was wrong and what was expected."""

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(message)
        self.kind = kind


def wrap_int32(value: int) -> int:
    """``value`` as a signed 32-bit two's-complement counter would hold it. O(1)."""
    return ((value - _I32_MIN) % _U32) + _I32_MIN


def tick_delta(new: int, old: int) -> int:
    """Signed change of a wrapping 32-bit counter from ``old`` to ``new`` (|change| < 2^31). O(1)."""
    return wrap_int32(new - old)


@dataclass(frozen=True, slots=True)
class EncoderLine:
    """An ``E`` record as sent: bridge time (ms, unsigned 32-bit) and the two cumulative signed 32-bit
    tick counters."""

    device_ms: int
    left_ticks: int
    right_ticks: int

    def __post_init__(self) -> None:
        _check_int("t_ms", self.device_ms, 0, _U32 - 1)
        _check_int("left_ticks", self.left_ticks, _I32_MIN, _I32_MAX)
        _check_int("right_ticks", self.right_ticks, _I32_MIN, _I32_MAX)


@dataclass(frozen=True, slots=True)
class BridgeInfo:
    """An ``I`` record: encoder ticks per wheel revolution, wheel diameter and tread (mm), firmware."""

    ticks_per_rev: float
    wheel_diameter_mm: float
    tread_mm: float
    firmware: str

    def __post_init__(self) -> None:
        for name in ("ticks_per_rev", "wheel_diameter_mm", "tread_mm"):
            value = getattr(self, name)
            if (
                isinstance(value, bool)
                or not isinstance(value, (int, float))
                or not (math.isfinite(value) and value > 0)
            ):
                raise EncoderProtocolError("out of range", f"{name} = {value!r}: expected a positive number")
            object.__setattr__(self, name, float(value))
        if not (isinstance(self.firmware, str) and _FIRMWARE.fullmatch(self.firmware)):
            raise EncoderProtocolError(
                "bad field",
                f"firmware = {self.firmware!r}: expected 1-32 printable ASCII characters, no space or '*'",
            )

    def to_drive(self, laser_offset: Pose2D | None = None) -> DiffDrive:
        """The robot geometry this bridge reports, in metres (the laser offset is not in the protocol)."""
        return DiffDrive(
            wheel_diameter_m=self.wheel_diameter_mm / 1000.0,
            tread_m=self.tread_mm / 1000.0,
            ticks_per_turn=self.ticks_per_rev,
            laser_offset=laser_offset if laser_offset is not None else Pose2D(),
        )


def _check_int(name: str, value: int, low: int, high: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise EncoderProtocolError(
            "out of range", f"{name} = {value!r}: expected an integer in {low}..{high}"
        )


def checksum(payload: bytes) -> int:
    """NMEA-style checksum: the XOR of all bytes of ``payload`` (everything before the ``*``). O(len)."""
    value = 0
    for byte in payload:
        value ^= byte
    return value


def _number(value: float) -> str:
    text = repr(float(value))
    return text[:-2] if text.endswith(".0") else text


def format_line(record: EncoderLine | BridgeInfo, *, with_checksum: bool = True) -> bytes:
    """The protocol line for ``record``, LF included; :func:`parse_line` gives ``record`` back. O(1)."""
    if isinstance(record, EncoderLine):
        text = f"E {record.device_ms} {record.left_ticks} {record.right_ticks}"
    else:
        text = (
            f"I {_number(record.ticks_per_rev)} {_number(record.wheel_diameter_mm)} "
            f"{_number(record.tread_mm)} {record.firmware}"
        )
    payload = text.encode("ascii")
    if with_checksum:
        payload += b"*%02X" % checksum(payload)
    return payload + b"\n"


def parse_line(line: bytes | str, *, require_checksum: bool = False) -> EncoderLine | BridgeInfo | None:
    """Parse one protocol line (with or without its line ending). O(len).

    Returns the record, or None for a blank line or a ``#`` comment; raises :class:`EncoderProtocolError`
    naming what is wrong for anything else (see the module docstring for the grammar).
    """
    raw = line.encode("utf-8", "replace") if isinstance(line, str) else bytes(line)
    for ending in (b"\r\n", b"\n", b"\r"):
        if raw.endswith(ending):
            raw = raw[: -len(ending)]
            break
    if len(raw) > MAX_LINE_BYTES:
        raise EncoderProtocolError(
            "too long", f"line of {len(raw)} bytes {raw[:24]!r}...: expected at most {MAX_LINE_BYTES}"
        )
    bad = next((b for b in raw if not 0x20 <= b <= 0x7E), None)
    if bad is not None:
        raise EncoderProtocolError(
            "bad byte", f"line {raw!r} holds byte 0x{bad:02X}: expected printable ASCII (0x20-0x7E) only"
        )
    text = raw.decode("ascii")
    if not text.strip() or text.lstrip().startswith("#"):
        return None
    payload, star, given = text.rpartition("*")
    if star:
        if not _HEX2.fullmatch(given):
            raise EncoderProtocolError(
                "bad checksum", f"line {text!r}: expected '*' and two hex digits at its end"
            )
        expected = checksum(payload.encode("ascii"))
        if int(given, 16) != expected:
            raise EncoderProtocolError(
                "bad checksum", f"line {text!r}: checksum *{given} does not match the line's *{expected:02X}"
            )
        if "*" in payload:
            raise EncoderProtocolError("bad field", f"line {text!r}: '*' inside the line")
    else:
        payload = text
        if require_checksum:
            raise EncoderProtocolError("missing checksum", f"line {text!r}: expected a '*HH' checksum")
    fields = payload.split()
    kind, args = fields[0], fields[1:]
    if kind == "E":
        if len(args) != 3:
            raise EncoderProtocolError(
                "field count", f"line {text!r}: expected 'E <t_ms> <left_ticks> <right_ticks>'"
            )
        for name, value, pattern in zip(
            ("t_ms", "left_ticks", "right_ticks"), args, (_UINT, _SINT, _SINT), strict=True
        ):
            if not pattern.fullmatch(value):
                raise EncoderProtocolError(
                    "bad number", f"line {text!r}: {name} = {value!r} is not an integer"
                )
        return EncoderLine(int(args[0]), int(args[1]), int(args[2]))
    if kind == "I":
        if len(args) != 4:
            raise EncoderProtocolError(
                "field count",
                f"line {text!r}: expected 'I <ticks_per_rev> <wheel_diameter_mm> <tread_mm> <firmware>'",
            )
        for name, value in zip(("ticks_per_rev", "wheel_diameter_mm", "tread_mm"), args, strict=False):
            if not _NUMBER.fullmatch(value):
                raise EncoderProtocolError("bad number", f"line {text!r}: {name} = {value!r} is not a number")
        return BridgeInfo(float(args[0]), float(args[1]), float(args[2]), args[3])
    raise EncoderProtocolError("unknown record", f"line {text!r}: expected an 'E', 'I' or '#' line")


class LineSplitter:
    """Splits a byte stream into lines at LF. A line longer than :data:`MAX_LINE_BYTES` is cut to
    ``MAX_LINE_BYTES + 1`` bytes (so :func:`parse_line` rejects it as too long) and the rest of it dropped,
    keeping memory bounded. Amortised O(1) per byte."""

    def __init__(self) -> None:
        self._buf = bytearray()
        self._overlong = False

    def feed(self, data: bytes) -> list[bytes]:
        """The complete lines (without LF) that ``data`` finishes, in order."""
        lines: list[bytes] = []
        start = 0
        while (end := data.find(b"\n", start)) >= 0:
            self._append(data[start:end])
            lines.append(bytes(self._buf))
            self._buf.clear()
            self._overlong = False
            start = end + 1
        self._append(data[start:])
        return lines

    def _append(self, chunk: bytes) -> None:
        if self._overlong:
            return
        self._buf += chunk
        if len(self._buf) > MAX_LINE_BYTES + 2:  # room for CR LF
            del self._buf[MAX_LINE_BYTES + 1 :]
            self._overlong = True
